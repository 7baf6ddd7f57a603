"""How a model is discretised on a record's sample grid (``Discretisation``, checked
once and shared by Problem, simulate, the sweeps and the CLI), and the one routine
that marches any state (a pytree) across the grid (``march``).

Between samples t_h and t_{h+1} the input u(t) is known only at the samples, so a
stage at fraction s of the interval sees u_h + s (u_{h+1} - u_h) ("linear"), u_h
("zoh"), or a smooth interpolant of the samples around it ("cubic", "bandlimited",
"periodic": ``intersample.py``), whose coefficients on each interval the record
carries in place of its samples (``Discretisation.inputs``).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import jax
import jax.numpy as jnp
import numpy as np

from ... import _config  # noqa: F401
from ..modelling.checks import did_you_mean
from .implicit import DiagonallyImplicitRungeKutta
from .integrators import (
    DISCRETE,
    DiscreteMap,
    ExplicitRungeKutta,
    RungeKuttaScheme,
    Scheme,
    _x,
    get_scheme,
)
from .intersample import SMOOTH, chebyshev_at, track
from .status import Status

FIXED_STEPS = ExplicitRungeKutta | DiagonallyImplicitRungeKutta  # substeps equal steps

INTERPOLATIONS = ("linear", "zoh", *SMOOTH)
DEFAULT_SUBSTEPS = 4


@dataclass(frozen=True)
class Discretisation:
    """The integration scheme, the steps per sample interval and the input
    interpolation. Build it with :meth:`of`, which checks every value once.

    Arguments:
        scheme: a scheme object (see ``tensorid.SCHEMES``); an adaptive one carries
            its rtol/atol.
        substeps: steps per sample interval (adaptive schemes: the first trial step
            is one interval / substeps).
        interpolation: the input between samples: "linear", "zoh" (held), "cubic"
            (not-a-knot spline), "bandlimited" (windowed sinc) or "periodic"
            (trigonometric, for a record of whole periods); see ``intersample.py``.
        chosen: whether the substeps are the user's (False: the default, which a
            population fit raises by itself where its check finds them too coarse).
            Not part of the discretisation's identity (its compiled programs).
    """

    scheme: Scheme | RungeKuttaScheme
    substeps: int = DEFAULT_SUBSTEPS
    interpolation: str = "linear"
    chosen: bool = field(default=True, compare=False)

    def __post_init__(self) -> None:
        if not isinstance(self.scheme, RungeKuttaScheme):
            raise TypeError(
                f"scheme must be a scheme object (name, order, interval(...)), got "
                f"{type(self.scheme).__name__}; use Discretisation.of('{self.scheme}') for a name"
            )
        if not isinstance(self.substeps, int | np.integer) or isinstance(self.substeps, bool):
            raise ValueError(f"substeps must be a positive integer, got {self.substeps!r}")
        if self.substeps < 1:
            raise ValueError(f"substeps must be a positive integer, got {self.substeps!r}")
        if self.interpolation not in INTERPOLATIONS:
            raise ValueError(
                f"interpolation must be one of {INTERPOLATIONS}, got {self.interpolation!r}"
                + did_you_mean(self.interpolation, INTERPOLATIONS)
            )
        object.__setattr__(self, "substeps", int(self.substeps))

    @classmethod
    def of(
        cls,
        scheme: str | Scheme = "rk4",
        substeps: int | None = None,
        interpolation: str = "linear",
        rtol: float | None = None,
        atol: float | None = None,
    ) -> Discretisation:
        """The discretisation from user-level settings (scheme by name, tolerances;
        substeps None: the default 4, not the user's choice)."""
        steps = DEFAULT_SUBSTEPS if substeps is None else substeps
        return cls(get_scheme(scheme, rtol, atol), steps, interpolation, substeps is not None)

    @classmethod
    def resolve(cls, given: Discretisation | None, scheme, substeps, interpolation, rtol, atol):
        """``given``, or one built from the separate settings; both at once is an error
        (one of them would be silently ignored)."""
        if given is None:
            return cls.of(scheme, substeps, interpolation, rtol, atol)
        if not isinstance(given, Discretisation):
            raise TypeError(
                f"discretisation must be a tensorid.Discretisation, got {type(given).__name__}"
            )
        steps = substeps in (None, DEFAULT_SUBSTEPS)
        defaults = (scheme == "rk4", steps, interpolation == "linear")
        if not all(defaults) or rtol is not None or atol is not None:
            raise ValueError(
                "give either discretisation= or scheme/substeps/interpolation/rtol/atol, not both"
            )
        return given

    def for_model(self, model) -> Discretisation:
        """This discretisation, checked against the model's kind of time: a discrete-time
        model steps once per sample (the default settings become that); a
        continuous-time one cannot use the discrete map."""
        discrete = isinstance(self.scheme, DiscreteMap)
        if not model.discrete:
            if discrete:
                raise ValueError(
                    "scheme 'discrete' is for discrete-time models: "
                    "build the model with tensorid.Model(..., discrete=True)"
                )
            return self
        if discrete:
            return Discretisation(DISCRETE, 1, "zoh")
        # the defaults: not a choice
        if (self.scheme.name, self.substeps) == ("rk4", DEFAULT_SUBSTEPS):
            return Discretisation(DISCRETE, 1, "zoh")
        raise ValueError(
            f"{model.name} is a discrete-time model (x[k+1] = f(x[k], p, u[k])): it steps "
            f"once per sample; drop scheme={self.scheme.name!r} and substeps="
            f"{self.substeps}"
        )

    @property
    def fixed_steps(self) -> bool:
        """Whether the scheme takes ``substeps`` equal steps per interval (explicit or
        diagonally implicit Runge-Kutta): its answer moves with them."""
        return isinstance(self.scheme, FIXED_STEPS)

    def at_run_time(self, substeps) -> Discretisation:
        """This fixed-step discretisation with its substeps an integer given when the
        program runs (a traced int32 scalar), so that one compiled program serves every
        number of substeps (a population fit's predictions, which its substeps check
        compares at s and 2s; the loop over steps is then a while loop)."""
        if not isinstance(self.scheme, FIXED_STEPS):
            raise TypeError(f"the {self.scheme.name} scheme does not take a fixed number of steps")
        return Discretisation(_RunTimeSteps(self.scheme, substeps), 1, self.interpolation)

    def inputs(self, model, t, u) -> np.ndarray:
        """The inputs as the march reads them: the samples (P, U), delayed where the
        model says so; for a smooth interpolation, each interval's coefficients
        (P, Q, U) of the (delayed) input (``intersample.track``)."""
        if self.interpolation in SMOOTH:
            return track(model, t, u, self.interpolation)
        return model.delayed(t, u, self.interpolation)

    def as_dict(self) -> dict:
        """What a reader needs to reproduce a cost: scheme, substeps, interpolation and,
        for an adaptive scheme, rtol and atol (fit.json's "integration")."""
        d: dict = {
            "scheme": self.scheme.name,
            "substeps": self.substeps,
            "interpolation": self.interpolation,
        }
        for tol in ("rtol", "atol"):
            if hasattr(self.scheme, tol):
                d[tol] = getattr(self.scheme, tol)
        return d


@dataclass(frozen=True, eq=False)
class _RunTimeSteps:
    """A fixed-step scheme whose substeps are a number given at run time
    (Discretisation.at_run_time): an interval asked to take k steps per substep (the
    discretisation's own 1, a steady-state dose's CYCLE_STEPS per part of its cycle)
    takes k times that number."""

    scheme: ExplicitRungeKutta | DiagonallyImplicitRungeKutta
    substeps: jax.Array

    name = property(lambda self: self.scheme.name)
    order = property(lambda self: self.scheme.order)

    def interval(self, f, fs, y, dt, carry, substeps: int):
        return self.scheme.interval(f, fs, y, dt, carry, substeps * self.substeps)


class DiscretisationSettings:
    """``scheme``, ``substeps`` and ``interpolation`` as attributes of an object that
    has a ``discretisation`` (a Problem)."""

    discretisation: Discretisation

    @property
    def scheme(self) -> Scheme | RungeKuttaScheme:
        """The integration scheme (of ``discretisation``)."""
        return self.discretisation.scheme

    @property
    def substeps(self) -> int:
        """Steps per sample interval (of ``discretisation``)."""
        return self.discretisation.substeps

    @property
    def interpolation(self) -> str:
        """Input interpolation between samples (of ``discretisation``)."""
        return self.discretisation.interpolation


def input_at(u0: jax.Array, u1: jax.Array, s, interpolation: str) -> jax.Array:
    """The input at fraction s of an interval: from its end samples u0, u1, or, for a
    smooth interpolation, from u0 = the interval's coefficients (u1 unused)."""
    if interpolation == "zoh":
        return u0
    if interpolation in SMOOTH:
        return chebyshev_at(u0, s)
    return u0 + s * (u1 - u0)


def _inputs_at(ua, ub, s, interpolation: str, held: int):
    """``input_at``, the last ``held`` columns read at the interval's start."""
    if not held:
        return input_at(ua, ub, s, interpolation)
    return jnp.concatenate([input_at(ua[:-held], ub[:-held], s, interpolation), ua[-held:]])


def _settle(y, obs_h, u_h, update, jump):
    """The state after a sample: a filter's update, then the record's events."""
    if update is not None:
        y = update(y, obs_h, u_h)
    return y if jump is None else jump(y, u_h)


def march(
    field: Callable,
    observe: Callable,
    y0,
    acc0,
    t,
    u,
    obs,
    *,
    discretisation: Discretisation,
    state_field: Callable | None = None,
    update: Callable | None = None,
    skip_first: bool = False,
    jump: Callable | None = None,
    held: int = 0,
):
    """Integrate ``y' = field(y, u)`` over the sample grid ``t`` and fold every sample
    into an accumulator.

    Arguments:
        observe: ``observe(acc, y, obs_h, u_h) -> (acc, out_h)``, called at t_0 and
            after each interval with the sample's row of ``u`` (an output may read the
            inputs); ``obs`` is a pytree whose leaves have a leading sample axis.
        state_field: ``state_field(x, u)``, the model's own F, needed by implicit
            schemes (for F_x) when ``y`` is augmented.
        update: ``update(y, obs_h, u_h) -> y``, applied at each sample after ``observe``:
            a filter's measurement update (None: the state is not corrected).
        skip_first: the accumulator leaves out t_0's sample (its ``out_h`` is kept).
        jump: ``jump(y, u_h) -> y``, after ``update``: a record's events (dosing.py).
        held: the last ``held`` input columns are read at each interval's start.

    Returns:
        (final accumulator, stacked ``out_h`` (P leading), failure) where failure is
        (code, sample): the integrator's ``Status.code`` of the first interval that
        failed (0: none) and the index of the sample it should have reached.
    """
    scheme, substeps = discretisation.scheme, discretisation.substeps
    interpolation = discretisation.interpolation
    state_field = field if state_field is None else state_field
    first = jax.tree_util.tree_map(lambda a: a[0], obs)
    rest = jax.tree_util.tree_map(lambda a: a[1:], obs)
    acc, out0 = observe(acc0, y0, first, u[0])
    if skip_first:  # acc0 as the scan will carry it (its dtypes and shapes)
        acc = jax.tree_util.tree_map(
            lambda a, b: jnp.broadcast_to(jnp.asarray(b, jnp.result_type(a)), jnp.shape(a)),
            acc,
            acc0,
        )
    y0 = _settle(y0, first, u[0], update, jump)

    def interval(carry, data):
        y, h_trial, acc, fail, at = carry
        k, dt, ua, ub, obs_h = data

        def vf(yy, s):
            return field(yy, _inputs_at(ua, ub, s, interpolation, held))

        def fs(x, s):
            return state_field(x, _inputs_at(ua, ub, s, interpolation, held))

        y, h_trial, code = scheme.interval(vf, fs, y, dt, h_trial, substeps)
        blown = ~jnp.all(jnp.isfinite(_x(y)))
        code = jnp.where((code == 0) & blown, Status.NONFINITE_STATE.code, code)
        new = (fail == 0) & (code != 0)
        fail, at = jnp.where(new, code, fail), jnp.where(new, k, at)
        acc, out = observe(acc, y, obs_h, ub)
        y = _settle(y, obs_h, ub, update, jump)
        return (y, h_trial, acc, fail, at), out

    P = t.shape[0]
    h_first = (t[1] - t[0]) / substeps if P > 1 else jnp.ones(())
    zero = jnp.int32(0)
    (_, _, acc, fail, at), outs = jax.lax.scan(
        interval,
        (y0, h_first, acc, zero, zero),
        (jnp.arange(1, P, dtype=jnp.int32), jnp.diff(t), u[:-1], u[1:], rest),
    )
    outs = jax.tree_util.tree_map(lambda a, b: jnp.concatenate([a[None], b]), out0, outs)
    return acc, outs, (fail, at)
