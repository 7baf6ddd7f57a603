"""How the state is carried from one sample to the next: the predictor.

The sweeps march a *carried state* z across the record and ask the predictor three
things about it (every derivative of them comes from forward-mode differentiation,
so a predictor is only these maps, written once):

    dz/dt = field(z, p, u)          between samples (or z⁺ = field(z, p, u) for a
                                    discrete-time model)
    π     = predict(z, p[, u])      at each sample: what the loss compares with y
    z⁺    = update(z, p, y[, u])    at each sample, after the loss has seen z
                                    (None: the state is not corrected)

(u, the sample's inputs, is passed where the model's output reads them.)

:class:`OutputError` (``"simulation"``; ``Simulation`` is its deprecated name) is
the default: z = x, the model's own F and C, no update; π = ŷ.
:class:`ExtendedKalman` is a continuous-discrete extended Kalman filter: z = (x̂, P)
with P the state covariance, π = (ŷ, S) the predicted output and its covariance,
and the measurement update at each sample, so that the loss (``losses.GAUSSIAN``)
is the negative log-likelihood of the innovations.

The transition tensors differentiate the whole chain — propagation, the update and
the loss — exactly, so the EKF's gradient and Hessian are those of its discretised
likelihood (to rounding), as for output error. A predictor is one class, subclass of
:class:`Predictor`, registered by name with :func:`register_predictor` (or passed as
an object); the rest of the package asks its markers, never its name.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass
from typing import Any, ClassVar, TypeVar

import jax
import jax.numpy as jnp
import numpy as np

from ... import _config  # noqa: F401
from ..modelling.checks import from_registry
from .losses import GAUSSIAN, robust_noise

# a filter's noise parameters: these prefixes and the state's or output's name
NOISE_PREFIXES = {"process": "log_sigma_w_", "measurement": "log_sigma_e_"}

# the predictors by name: the one place a predictor's name is looked up
# (``get_predictor``); a class joins it with @register_predictor. tensorid/names.py
# spells the command line's --predictor choices out (tests/test_recipes.py checks them)
REGISTRY: dict[str, type[Predictor]] = {}


@dataclass(frozen=True)
class Predictor:
    """How the state is carried between samples (see the module docstring): the maps
    ``size``, ``start``, ``states``, ``field``, ``predict`` and ``update`` (None: no
    correction), and ``build``, which makes the one a Problem uses from its arguments.

    Markers (what the checks and the commands ask instead of the name):
        has_noise_model: the model gains noise intensities among its parameters
            (``process_noise``, ``measurement_noise``), which fit.json records.
        filters: the state is corrected at each sample (it has an ``update``):
            predictions k samples ahead differ from the simulation.
        supports_segments, supports_fleet, supports_adjoint: multiple shooting, a
            fleet's population or individual parameters, the second-order adjoint's
            Hessian; each of them reads the model's own F and C, so only output
            error sets them (a new predictor is refused there, one line, until it
            says otherwise).
        takes_loss: the user's loss and weights apply; False where the predictor
            brings its own (``own_loss``, e.g. a filter's Gaussian likelihood).
        takes_gaps: a filter whose ``update`` takes ``seen=`` (S,), the outputs
            measured at the sample, so that it corrects with those alone (records
            with gaps); a predictor without an update takes gaps as it is.
    """

    name: ClassVar[str] = ""
    has_noise_model: ClassVar[bool] = False
    supports_segments: ClassVar[bool] = False
    supports_fleet: ClassVar[bool] = False
    supports_adjoint: ClassVar[bool] = False
    takes_loss: ClassVar[bool] = True
    takes_gaps: ClassVar[bool] = False
    own_loss: ClassVar[Any] = None
    update: ClassVar[Any] = None

    @property
    def filters(self) -> bool:
        return type(self).update is not None

    def size(self, model) -> int:
        return model.N

    def start(self, x0):
        return x0

    def states(self, z):
        return z

    def field(self, model, z, p, u):
        return model.f(z, p, u)

    def predict(self, model, z, p, u=None):
        return model.h(z, p, u)

    def masked(self, pi, seen, y):
        """π as the loss sees it at a sample where only the outputs ``seen`` (S,) were
        measured: y itself where not, so that those add nothing (nor their NaN)."""
        return jnp.where(seen, pi, y)

    def build(self, model, process_noise, measurement_noise, measured) -> tuple:
        """(model, predictor, {noise parameter: start}) for a Problem of ``model``:
        without a noise model, the model and this predictor as they are."""
        for what, v in (("process_noise", process_noise), ("measurement_noise", measurement_noise)):
            if v:
                raise ValueError(
                    f"{what} is for predictor='ekf' (output error has no noise model); "
                    "add predictor='ekf'"
                )
        return model, self, {}


_P = TypeVar("_P", bound=type[Predictor])


def register_predictor(cls: _P) -> _P:
    """Class decorator: ``cls`` chosen by its ``name`` wherever a predictor is named
    (``Problem(predictor=...)``, the model file's ``predictor``, fit.json read back)."""
    REGISTRY[cls.name] = cls
    return cls


def get_predictor(predictor) -> Predictor:
    """The predictor called ``predictor`` (a Predictor object is returned as it is);
    one line for anything else."""
    return from_registry(predictor, REGISTRY, Predictor, "predictor")


@register_predictor
@dataclass(frozen=True)
class OutputError(Predictor):
    """Output error: the model simulated from its initial state, never corrected
    (fit.json's ``"predictor": "simulation"``).

    ``size``, ``start`` and ``states`` map between the model's states x and the
    carried state z (here the same)."""

    name: ClassVar[str] = "simulation"
    takes_gaps: ClassVar[bool] = True
    supports_segments: ClassVar[bool] = True
    supports_fleet: ClassVar[bool] = True
    supports_adjoint: ClassVar[bool] = True


SIMULATION = OutputError()


def __getattr__(name: str):
    if name in ("Prediction", "predictions", "check_horizon"):  # their home before
        from . import predictions

        return getattr(predictions, name)
    if name == "Simulation":  # the name before issue 39: a simulation is engine/assembly/simulate's
        warnings.warn(
            "tensorid.engine.predictors.Simulation is deprecated: it is OutputError",
            DeprecationWarning,
            stacklevel=2,
        )
        return OutputError
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


@register_predictor
@dataclass(frozen=True)
class ExtendedKalman(Predictor):
    """A continuous-discrete extended Kalman filter (EKF).

    Carried state z = (x̂, vec P), P the covariance of the state estimate (N + N²).
    Between samples, with A = ∂F/∂x at x̂ and Q = diag(σ_w²) (per unit time)::

        dx̂/dt = F(x̂, p, u),    dP/dt = A P + P Aᵀ + Q            (continuous time)
        x̂⁺ = F(x̂, p, u),       P⁺ = A P Aᵀ + Q                   (discrete time)

    integrated by the model's own scheme and substeps (the right-hand side is
    symmetric in P by construction, so P stays symmetric). At each sample, with
    C = ∂h/∂x, R = diag(σ_e²) and the innovation ε = y − h(x̂)::

        S = C P Cᵀ + R,   K = P Cᵀ S⁻¹,   x̂ ← x̂ + K ε,
        P ← (I − K C) P (I − K C)ᵀ + K R Kᵀ                        (Joseph form)

    The Joseph form keeps P symmetric and positive semi-definite under rounding.
    ``predict`` gives π = (ŷ, vec S) before the update, which the Gaussian loss
    turns into log det S + εᵀ S⁻¹ ε. Where only some outputs were measured (a record
    with gaps), C's other rows are 0 and S is 1 on their diagonal: the update uses
    the measured outputs alone (their gains are 0), and the likelihood is that of the
    measured block S_mm (log det and εᵀ S⁻¹ ε of a block-diagonal matrix, ε = 0
    elsewhere). A sample where nothing was measured is a prediction, with no update.
    The initial covariance is P0 = 0: an initial state is either estimated (a free
    x0, an unknown of θ) or known.

    Arguments:
        process: (state index, parameter index) pairs: the states with process noise
            and where each one's log σ_w sits in p.
        measurement: per output, the parameter index of its log σ_e.
    """

    name: ClassVar[str] = "ekf"
    has_noise_model: ClassVar[bool] = True
    takes_loss: ClassVar[bool] = False
    takes_gaps: ClassVar[bool] = True
    own_loss: ClassVar[Any] = GAUSSIAN
    process: tuple[tuple[int, int], ...] = ()
    measurement: tuple[int, ...] = ()

    def size(self, model) -> int:
        return model.N + model.N**2

    def start(self, x0):
        return jnp.concatenate([x0, jnp.zeros(x0.shape[0] ** 2, dtype=x0.dtype)])

    def states(self, z):
        n = _n(z)
        return z[..., :n]

    def _split(self, z):
        n = _n(z)
        return z[:n], z[n:].reshape(n, n)

    def _Q(self, n, p):
        q = jnp.zeros(n, dtype=p.dtype)
        for i, k in self.process:
            q = q.at[i].set(jnp.exp(2.0 * p[k]))
        return q

    def field(self, model, z, p, u):
        x, P = self._split(z)

        def f(xx):
            return model.f(xx, p, u)

        fx, A = f(x), jax.jacfwd(f)(x)
        AP = A @ P
        if model.discrete:
            Pn = AP @ A.T + jnp.diag(self._Q(x.shape[0], p))
        else:
            Pn = AP + AP.T + jnp.diag(self._Q(x.shape[0], p))
        return jnp.concatenate([fx, Pn.reshape(-1)])

    def _R(self, p):
        return jnp.exp(2.0 * p[jnp.array(self.measurement, dtype=int)])

    def _measurement(self, model, z, p, u, seen=None):
        """(x̂, P, ŷ, C, R, S); with ``seen``, C's rows of the outputs not measured
        are 0 and S is 1 on their diagonal (selects: an output not finite there
        stays out of every derivative)."""
        x, P = self._split(z)

        def h(xx):
            return model.h(xx, p, u)

        C = jax.jacfwd(h)(x)
        R = self._R(p)
        if seen is None:
            return x, P, h(x), C, R, C @ P @ C.T + jnp.diag(R)
        C = jnp.where(seen[:, None], C, 0.0)
        return x, P, h(x), C, R, C @ P @ C.T + jnp.diag(jnp.where(seen, R, 1.0))

    def predict(self, model, z, p, u=None):
        _, _, yhat, _, _, S = self._measurement(model, z, p, u)
        return jnp.concatenate([yhat, S.reshape(-1)])

    def masked(self, pi, seen, y):
        """(ŷ, vec S) of the measured outputs: y and S's rows and columns of the
        identity elsewhere (the likelihood of the measured block, see the class)."""
        n = y.shape[-1]
        both = seen[:, None] & seen[None, :]
        S = jnp.where(both, pi[n:].reshape(n, n), jnp.eye(n, dtype=pi.dtype))
        return jnp.concatenate([jnp.where(seen, pi[:n], y), S.reshape(-1)])

    def update(self, model, z, p, y, u=None, seen=None):  # type: ignore[override]
        x, P, yhat, C, R, S = self._measurement(model, z, p, u, seen)
        PCt = P @ C.T
        K = jnp.linalg.solve(S, PCt.T).T  # P Cᵀ S⁻¹ (S symmetric)
        IKC = jnp.eye(x.shape[0], dtype=z.dtype) - K @ C
        P = IKC @ P @ IKC.T + (K * R) @ K.T
        eps = y - yhat if seen is None else jnp.where(seen, y - yhat, 0.0)
        return jnp.concatenate([x + K @ eps, P.reshape(-1)])

    def build(self, model, process_noise, measurement_noise, measured) -> tuple:
        """(the filter's model, the filter, {noise parameter: start (log σ)}): the
        model gains one parameter per noise intensity (see :func:`noise_names`),
        started at log of the given σ; an output without a given measurement noise
        starts from its noise level in the data (second differences,
        :func:`tensorid.engine.losses.robust_noise`)."""
        from ..modelling.model import Model

        q = _intensities("process_noise", process_noise, model.states, "state")
        r = _intensities("measurement_noise", measurement_noise, model.outputs, "output")
        records = [np.asarray(m, dtype=float) for m in measured if m is not None]
        level = robust_noise(np.concatenate(records)) if records else np.zeros(model.S)
        for k, o in enumerate(model.outputs):
            if o not in r:
                if not level[k] > 0:
                    raise ValueError(
                        f"predictor={self.name!r}: output {o!r} shows no noise in the data to "
                        f"start its measurement noise from; give measurement_noise={{{o!r}: σ}}"
                    )
                r[o] = float(level[k])
        states = [s for s in model.states if s in q]
        wq, wr = noise_names(model, states, list(model.outputs))
        clash = sorted(set(wq + wr) & set(model.params))
        if clash:
            raise ValueError(f"the model already has parameters named {clash}; rename them")
        M = model.M
        # one filter model per model and set of noisy states, kept in the model's cache of
        # compiled sweeps: its own sweeps (cached on it) are then shared by every Problem
        noisy = model.compiled_sweeps.get(("ekf model", tuple(states)))
        if noisy is None:
            noisy = Model(
                _Leading(model.rhs, M),
                _Leading(model.h, M, like=model.output, reads_inputs=model.reads_inputs),
                states=model.states,
                params=list(model.params) + wq + wr,
                inputs=model.inputs,
                outputs=model.outputs,
                name=model.name,
                input_delays=model.input_delays,
                discrete=model.discrete,
            )
            model.compiled_sweeps[("ekf model", tuple(states))] = noisy
        filt = type(self)(
            process=tuple((model.states.index(s), M + i) for i, s in enumerate(states)),
            measurement=tuple(range(M + len(states), M + len(states) + model.S)),
        )
        starts = dict(zip(wq, [float(np.log(q[s])) for s in states], strict=True))
        starts.update(zip(wr, [float(np.log(r[o])) for o in model.outputs], strict=True))
        return noisy, filt, starts


# the command line's order (tensorid/names.py); a predictor registered later joins REGISTRY
PREDICTORS = ("simulation", "ekf")


def _n(z) -> int:
    """N from the carried state's length N + N²."""
    m = z.shape[-1]
    return int(round((-1 + np.sqrt(1 + 4 * m)) / 2))


class _Leading:
    """A model function of (x, p[:M], ...) called with the longer p of a filter's
    model (its noise intensities appended): picklable, for worker processes."""

    def __init__(self, fn, M: int, like=None, reads_inputs: bool | None = None):
        self.fn, self.M = fn, M
        marker = fn if like is None else like  # the user's function that ``fn`` wraps
        if hasattr(marker, "equations"):  # text equations: no index to check (model.py)
            self.equations = marker.equations
        self.reads_inputs = reads_inputs  # None: read from the signature (model.py)

    def __call__(self, x, p, *rest):
        return self.fn(x, p[: self.M], *rest)


def noise_names(model, process, measurement) -> tuple[list[str], list[str]]:
    """The filter's parameter names: log σ_w of each state with process noise
    (``log_sigma_w_<state>``) and log σ_e of each output (``log_sigma_e_<output>``)."""
    w, e = NOISE_PREFIXES["process"], NOISE_PREFIXES["measurement"]
    return [w + s for s in process], [e + o for o in measurement]


# a noise intensity's start: its square, in the filter's covariances, far from over- or
# underflow
SIGMA_RANGE = (1e-100, 1e100)


def _intensities(what: str, given, names: tuple[str, ...], kind: str) -> dict[str, float]:
    if given is None:
        return {}
    if not isinstance(given, dict):
        raise ValueError(f"{what} must be a dict {{{kind}: standard deviation}}, got {given!r}")
    unknown = [k for k in given if k not in names]
    if unknown:
        raise ValueError(
            f"{what} names {unknown}, which the model lacks; its {kind}s: {list(names)}"
        )
    out = {}
    for k, v in given.items():
        if isinstance(v, bool | np.bool_):  # True is 1.0 to float(): a flag, not a level
            raise ValueError(f"{what}[{k!r}] must be a number (a standard deviation), got {v!r}")
        try:
            v = float(v)
        except (TypeError, ValueError):
            raise ValueError(f"{what}[{k!r}] must be a number, got {v!r}") from None
        if not (np.isfinite(v) and v > 0):
            raise ValueError(
                f"{what}[{k!r}] = {v}: a noise intensity is a standard deviation, give a "
                "finite number > 0 (it is estimated on a log scale from there)"
            )
        if not SIGMA_RANGE[0] <= v <= SIGMA_RANGE[1]:
            raise ValueError(
                f"{what}[{k!r}] = {v:g} is out of the range a filter can compute with "
                f"({SIGMA_RANGE[0]:g} to {SIGMA_RANGE[1]:g}: its square enters the "
                "covariances); give a start near the noise you expect (it is estimated "
                "from there)"
            )
        out[k] = v
    return out


def make_predictor(model, predictor, process_noise, measurement_noise, measured):
    """(model, predictor, {noise parameter: start (log σ)}) from the Problem's
    arguments: ``predictor`` a name or a :class:`Predictor`, which builds itself
    (:meth:`Predictor.build`; a filter's model gains its noise intensities)."""
    return get_predictor(predictor).build(model, process_noise, measurement_noise, measured)


def corrected(predictor, model, z, p, y, *u):
    """``predictor.update`` at a sample whose y may carry its mask ({"y", "mask"}: a
    record with gaps; ``seen=`` the outputs measured there)."""
    if isinstance(y, dict):
        return predictor.update(model, z, p, y["y"], *u, seen=y["mask"] > 0)
    return predictor.update(model, z, p, y, *u)
