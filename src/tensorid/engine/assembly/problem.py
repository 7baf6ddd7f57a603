"""Problem: a model, measured experiments and what is unknown, as a function of θ.

θ = (free initial states of experiment 1, ..., of experiment E, free parameters),
free initial states in ``free_x0`` order and parameters in model order, in natural
units. Every check of the user's input happens here, before anything compiles.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import jax.numpy as jnp
import numpy as np

from ... import _config  # noqa: F401
from ..compiling.compiled import on_device, on_host
from ..modelling.checks import (
    check_bounds,
    check_data,
    check_p0,
    check_threads,
    check_weights,
    check_x0,
    name_list,
)
from ..modelling.data import Experiment
from ..modelling.fleet import check_fleet
from ..modelling.model import Model
from ..schemes.discretisation import Discretisation, DiscretisationSettings
from ..schemes.integrators import Scheme
from ..sweeping.dosing import Dosing, check_events, masks_records, measured
from ..sweeping.hessians import HessianPath, choose_hessian
from ..sweeping.losses import Loss, make_loss
from ..sweeping.packing import unpack_symmetric
from ..sweeping.predictors import Predictor, make_predictor
from ..sweeping.shooting import Shooting, resolve_segments
from ..sweeping.sweeps import Sweeps, shared_sweeps
from .constraints import add_penalty_terms, check_constraints, penalty_jax
from .layout import ThetaLayout
from .priors import PriorTerms
from .problem_loss import LossSettings, checked_predictor, observed_rows
from .simulate import Simulation, run_simulation
from .start import Start, resolve_start


class Problem(ThetaLayout, PriorTerms, DiscretisationSettings, LossSettings):
    """An identification problem: a model, measured records and the unknowns, with its
    cost (least squares, a robust loss, or an extended Kalman filter's likelihood).

    Arguments:
        model: Model
        data: Experiment or list of Experiment
            Each experiment has its own initial state; all share the parameters.
        p0: dict {name: value} or array (M,)
            Parameter values: the start for free parameters, the value of fixed ones.
            Or an earlier fit to start from: a FitResult or a Start (tensorid.engine.start).
        x0: array (N,), array (E, N), dict {state: value} or list of dicts; default zeros
            Initial states: the start for free entries, the value of fixed ones.
        free_x0: list of state names whose initial value is estimated (in every experiment).
        fixed: list of parameter names held at their p0 value.
        bounds: dict {name: (lo, hi)} for parameters or free initial states; None or
            ±inf for an open side.
        substeps: Runge-Kutta steps per sample interval (default 4, which a population
            fit raises where doubling them moves its predictions; for an adaptive
            scheme: the first trial step is one sample interval / substeps).
        interpolation: the input between samples: "linear", "zoh", "cubic",
            "bandlimited" or "periodic" (docs/your-own-model.md says which to choose).
        scheme: explicit fixed-step "rk4" (default), "rk38", "heun", "euler"; implicit
            (L-stable, for stiff models) "sdirk3", "sdirk2", "implicit-euler"; adaptive
            (error-controlled) "dopri5", "bosh3".
        rtol: relative error tolerance of an adaptive scheme (default 1e-6).
        atol: absolute error tolerance of an adaptive scheme (default 1e-9).
        priors: dict {parameter: (mean, sd)}: Gaussian priors on free parameters (MAP
            estimation). J gains σ² Σ ((θ_i − mean)/sd)², σ² the variance of a unit-weight
            residual (``noise``² when given, else estimated from the measured outputs' second
            differences, ``noise_variance``), so that J/σ² is −2 log posterior; the exact
            Hessian includes the prior's curvature.
        noise: standard deviation of a unit-weight residual (weighted measurement noise),
            for priors. Without it, :func:`tensorid.fit` checks the estimate against the
            residual variance at the fit and, where they disagree, re-estimates it from the
            residuals and refits (``noise_estimated`` is then True).
        weights: dict {output: weight} or array (S,); J = Σ_h Σ_g w_g r_g². "auto":
            1 / (variance of each measured output, all experiments together), so that
            outputs on very different scales (volts and micrometres) count alike. Without
            weights, outputs whose scales differ by more than 1e3 raise a warning.
        discretisation: a :class:`Discretisation`, in place of scheme, substeps,
            interpolation, rtol and atol.
        segments: multiple shooting: cut each experiment into this many segments (or a
            list, one count per experiment), each with its own initial state as an unknown
            and continuity as a constraint (see :mod:`tensorid.engine.shooting`); 1, the
            default, is single shooting. θ, ``theta0`` and every result stay in the layout
            above; only :func:`tensorid.fit` sees the segments.
        segment_length: instead of segments: samples per segment (about).
        loss: what a sample's misfit costs: "squared" (default; weighted least squares,
            J = Σ w r²), or a robust loss that lets gross outliers pull less, "huber"
            (linear beyond the scale), "cauchy" or "student-t" (logarithmic beyond it); or
            a :class:`tensorid.engine.losses.Loss`. Each equals the squared loss for
            residuals well inside its scale (see :mod:`tensorid.engine.losses`).
        loss_scale: a robust loss's scale in the outputs' units: a number for every
            output or {output: value}. Default: estimated from the data, 1.345 (Huber),
            2.385 (Cauchy) or 1 (Student-t) times each output's noise level from its
            second differences (a median, so outliers do not inflate it), which
            :func:`tensorid.fit` then replaces by one from the residuals (the scale a fit
            used is ``result.problem.loss_scale``).
        threads: at most this many threads for the second-order adjoint's stretches of
            the record (default: the cores this process may use, at most 8); 1 turns them
            off, as each worker of a multi-start pool does.
        hessian: how exact Hessians are computed: "tensors" (the paper's transition
            tensors, forward in time), "adjoint" (second-order adjoints, parallel in time:
            faster for many states or unknowns; explicit schemes and discrete-time models
            only) or "auto" (default): the faster of the two by a cost model measured on
            N, K and the record length (:func:`tensorid.engine.hessians.choose_hessian`); or
            a :class:`tensorid.engine.hessians.HessianPath`. Both give the same Hessian to
            rounding; the resolved choice: ``Problem.hessian`` (its name), ``.hessian_path``.
        predictor: how the state is carried from sample to sample: "simulation" (default:
            output error, the model simulated from its initial state) or "ekf" (a
            continuous-discrete extended Kalman filter: prediction error, J = −2 log L of
            the innovations; see :mod:`tensorid.engine.predictors`), or a
            :class:`tensorid.engine.predictors.Predictor`. With "ekf" the model
            gains a parameter log σ per noise intensity (``log_sigma_w_<state>``,
            ``log_sigma_e_<output>``), estimated unless named in ``fixed``.
        process_noise: {state: σ_w}: the states driven by process noise dω, each with the
            start of its intensity (a standard deviation per √time unit); states not
            listed have none ("ekf" only).
        measurement_noise: {output: σ_e}: the start of each output's measurement noise
            (standard deviation); an output not listed starts from its noise level in the
            data ("ekf" only).
        population: {parameter: ω start}: a fleet's random effects (one experiment per
            unit; the unit's value is the typical value times exp(η), η ~ N(0, ω²));
            ``individual``: parameters each unit has its own value of (no distribution);
            ``residual_error``: "additive" (default), "proportional", "combined" or
            "exponential" (population/errors.py), for every output or {output: kind};
            ``omega``: "diagonal" (default) or "full" (correlated random effects).
            :func:`tensorid.fit` then estimates by the marginal likelihood, or least
            squares for individual parameters alone (docs: Fleets and populations).
        constraints: inequalities between parameters such as ["Fs >= Fc", "k <= 2*m"]
            (plain arithmetic on parameter names, or a single record's free initial
            states), which :func:`tensorid.fit` keeps by an augmented Lagrangian around
            its exact-derivative trust region (see :mod:`tensorid.solve.constrained`).
        doses: {state: expression} for the records' events (:class:`tensorid.Events`):
            what a dose puts into the state (of ``amt``, parameters and inputs: ``{"depot":
            "F * amt"}``); ``lags``: how long after its time (``{"depot": "tlag"}``);
            ``durations``: how long a modelled infusion (rate −2) lasts.
    """

    dosing: Dosing | None  # what the records' events do (dosing.py); None: no events

    def __init__(
        self,
        model: Model,
        data: Experiment | Sequence[Experiment],
        p0: Mapping[str, float] | Sequence[float] | np.ndarray | Start | None = None,
        x0: Mapping[str, float] | Sequence | np.ndarray | None = None,
        free_x0: Sequence[str] | None = None,
        fixed: Sequence[str] | None = None,
        bounds: Mapping[str, tuple[float, float]] | None = None,
        substeps: int | None = None,
        interpolation: str = "linear",
        scheme: str | Scheme = "rk4",
        weights: Mapping[str, float] | Sequence[float] | np.ndarray | str | None = None,
        rtol: float | None = None,
        atol: float | None = None,
        discretisation: Discretisation | None = None,
        priors: Mapping[str, tuple[float, float]] | None = None,
        noise: float | None = None,
        segments: int | Sequence[int] | None = None,
        segment_length: int | None = None,
        hessian: str | HessianPath = "auto",
        loss: str | Loss = "squared",
        loss_scale: float | Mapping[str, float] | None = None,
        threads: int | None = None,
        predictor: str | Predictor = "simulation",
        process_noise: Mapping[str, float] | None = None,
        measurement_noise: Mapping[str, float] | None = None,
        population: Mapping[str, float] | None = None,
        individual: Sequence[str] | None = None,
        residual_error: str | Mapping[str, str] | None = None,
        omega: str = "diagonal",
        constraints: Sequence[str] | str | None = None,
        doses: Mapping[str, str] | None = None,
        lags: Mapping[str, str] | None = None,
        durations: Mapping[str, str] | None = None,
    ):
        predictor = checked_predictor(
            predictor, model, fixed, bounds, loss=loss, loss_scale=loss_scale, weights=weights,
            noise=noise, segments=segments, segment_length=segment_length, hessian=hessian,
        )  # fmt: skip
        p0, x0, filt = resolve_start(model, p0, x0, predictor, process_noise, measurement_noise)
        self.model = model
        self.experiments = check_data(self, data)
        self.p0 = check_p0(self, p0)
        model = self._with_predictor(predictor, *filt)
        self.x0 = check_x0(self, x0)
        self.free_x0 = name_list("free_x0", free_x0, model.states, "states")
        self.fixed = name_list("fixed", fixed, model.params, "params")
        self.free_params = [n for n in model.params if n not in self.fixed]
        self.discretisation = discretisation = Discretisation.resolve(
            discretisation, scheme, substeps, interpolation, rtol, atol
        ).for_model(model)
        self.weights = check_weights(self, weights)
        self.loss, scale = make_loss(
            self.predictor.own_loss or loss,
            loss_scale, list(model.outputs), self.weights, observed_rows(self.experiments),
        )  # fmt: skip
        self.loss_weights = np.stack([self.weights, scale])  # every sweep's [w; c] (losses.py)
        # an estimated scale is checked against the residuals after a fit (fitting/robust.py)
        self.loss_scale_estimated = self.loss.robust and loss_scale is None
        self.lower, self.upper = check_bounds(self, bounds or {})
        self._set_priors(priors, noise)
        kinds = check_fleet(self, population, individual, residual_error, omega, segments)
        self.population, self.individual, self.residual_error, self.omega = kinds  # fleet.py
        if self.K == 0:
            raise ValueError("nothing to estimate: every parameter is fixed and free_x0 is empty")
        self.constraints, self.penalty = check_constraints(self, constraints), None  # Fs >= Fc
        gaps = check_events(self, doses, hessian, segments, segment_length, lags, durations)
        self._sweeps, self.threads = self._shared_sweeps(), check_threads(threads)
        self.hessian_path = choose_hessian(
            hessian, discretisation, model.N, self._sweeps.K, [e.P for e in self.experiments],
            threads, adjoint=self.predictor.supports_adjoint and not gaps,
        )  # fmt: skip
        counts = resolve_segments(self.experiments, segments, segment_length)  # shooting.py
        self.masked = masks_records(self, counts)  # y with a mask (dosing.measured)
        self._arrays = [self.arrays_of(e) for e in self.experiments]
        self.shooting = Shooting(self, counts) if counts else None

    def _shared_sweeps(self) -> Sweeps:
        m, d = self.model, self.discretisation
        states = tuple(m.states.index(n) for n in self.free_x0)
        params = tuple(m.params.index(n) for n in self.free_params)
        return shared_sweeps(m, states, params, d, self.loss, self.predictor, self.dosing)

    def _with_predictor(self, predictor, process_noise, measurement_noise) -> Model:
        """Set the predictor; a filter's model has its noise intensities appended to the
        parameters (and p0), started from the measured samples (NaN elsewhere)."""
        measured = [None if e.y is None else e.measured_with_gaps for e in self.experiments]
        self.model, self.predictor, starts = make_predictor(
            self.model, predictor, process_noise, measurement_noise, measured
        )
        self.p0 = np.concatenate([self.p0, list(starts.values())])
        return self.model

    def inputs(self, e: Experiment) -> np.ndarray:
        """The inputs the model sees on experiment e: delayed where the model says so
        (a smooth interpolation's: each interval's coefficients, Discretisation.inputs)."""
        return self.grid(e)[1]

    def grid(self, e: Experiment) -> tuple[np.ndarray, np.ndarray]:
        """(t, u) of record e as the march reads them: with its events' channels after
        the inputs and its moving events' nodes after its own samples (dosing.py)."""
        u = self.discretisation.inputs(self.model, e.t, e.inputs_held(self.interpolation))
        return (e.t, u) if self.dosing is None else self.dosing.arrays(e, u)

    hessian = property(lambda self: self.hessian_path.name, doc="fit.json's hessian_path")

    def arrays_of(self, e: Experiment) -> tuple:
        """(t, u, y) of record e as the sweeps take them (``grid``; y with its mask where
        the record has gaps or moving events' nodes: dosing.measured)."""
        t, u = self.grid(e)
        return on_device(t), on_device(u), measured(e, t.size, self.masked)

    @property
    def sweeps(self) -> Sweeps:
        """The compiled sweeps of this θ layout, discretisation and loss (shared by every
        Problem with the same ones)."""
        return self._sweeps

    @property
    def arrays(self) -> list[tuple]:
        """Per experiment, (t, u as the model sees it (delayed), y) as JAX arrays."""
        return self._arrays

    @property
    def segments(self) -> list[int]:
        """The number of shooting segments of each experiment (all 1: single shooting)."""
        return self.shooting.counts if self.shooting else [1] * len(self.experiments)

    # -- cost and derivatives ------------------------------------------------------------
    def _assemble(self, sweep, theta, *more, parts: str):
        """Run ``sweep`` on every experiment and sum its results into θ's layout.

        θ (and each of ``more``, e.g. a direction v) may hold one point per row. Each
        experiment sees its own entries of them (its free x0, then the free
        parameters). ``parts`` names the sweep's results, one letter each: "J" a
        cost, "g" a θ-vector, "H" a θ-matrix, "P" a packed symmetric θ-matrix, "r" a
        residual vector (concatenated). Where a result is not finite, J is inf:
        the simulation blew up, which callers treat as a rejected point.
        """
        theta = np.asarray(theta, dtype=float)
        lead, K = theta.shape[:-1], self.K
        shapes = {"J": (), "g": (K,), "H": (K, K), "P": (K, K)}
        out: list = [[] if c == "r" else np.zeros(lead + shapes[c]) for c in parts]
        # NumPy arrays: the compiled program copies them in (compiled.on_host)
        w = on_host(self.loss_weights)
        for e, (t, u, y) in enumerate(self._arrays):
            idx = self._slices(e)
            local = [on_host(a[..., idx]) for a in (theta, *more)]
            values = sweep(*local, on_host(self.x0[e]), on_host(self.p0), t, u, y, w)
            for acc, c, v in zip(out, parts, values if len(parts) > 1 else (values,), strict=True):
                v = np.asarray(v)
                if c == "J":
                    acc += v
                elif c == "g":
                    acc[..., idx] += v
                elif c == "r":
                    acc.append(v)
                else:
                    v = unpack_symmetric(v, idx.size) if c == "P" else v
                    acc[..., idx[:, None], idx[None, :]] += v
        out = [np.concatenate(a) if c == "r" else a for a, c in zip(out, parts, strict=True)]
        if self.priors:
            self.add_prior_terms(theta, parts, more, out)
        if self.penalty is not None:  # a constrained fit's augmented Lagrangian
            add_penalty_terms(self, theta, parts, more, out)
        ok = np.ones(lead, dtype=bool)
        for a in out:
            ok &= (
                np.isfinite(a).reshape(lead + (-1,)).all(axis=-1)
                if a.ndim > len(lead)
                else np.isfinite(a)
            )
        if "J" in parts:
            j = parts.index("J")
            out[j] = np.where(ok, out[j], np.inf) if lead else (float(out[j]) if ok else np.inf)
        return out

    def cost(self, theta) -> float:
        """J(θ) by plain simulation; inf when the simulation is not finite."""
        return self._assemble(self._sweeps.cost, self.check_theta(theta), parts="J")[0]

    def jax_cost(self, theta):
        """J(θ) as a traceable JAX function (for jax.grad / jax.hessian checks)."""
        w = jnp.asarray(self.loss_weights)
        J = 0.0
        for e, (t, u, y) in enumerate(self._arrays):
            y = y["y"] if self.masked and self.experiments[e].observed is None else y  # plain
            J = J + self._sweeps._cost(
                theta[self._slices(e)], jnp.asarray(self.x0[e]), jnp.asarray(self.p0), t, u, y, w
            )
        for i, (mean, sd) in self.priors.items():
            J = J + self.noise_variance * ((theta[i] - mean) / sd) ** 2
        return J if self.penalty is None else J + penalty_jax(self, theta)

    def residuals(self, theta) -> np.ndarray:
        """sqrt(w)·(y_obs - y_sim) for every sample, output and experiment, flattened
        (for a robust loss, the signed square roots of each term of J: the sum of
        their squares is J without the priors)."""
        return self._assemble(self._sweeps.residuals, self.check_theta(theta), parts="r")[0]

    def cost_grad_hess(self, theta) -> tuple[float, np.ndarray, np.ndarray]:
        """(J, ∇J, ∇²J) at θ, exact for the discretised model: from the transition
        matrices and tensors integrated alongside the states, or by second-order
        adjoints (``self.hessian``). J is inf (and g, H are not meaningful) when the
        simulation blows up."""
        return self.cost_grad_hess_gn(theta)[:3]

    def cost_grad_gn(self, theta) -> tuple[float, np.ndarray, np.ndarray]:
        """(J, ∇J, Gauss-Newton Hessian 2 Σ (∂ỹ/∂θ)ᵀ W ∂ỹ/∂θ): first-order
        sensitivities only."""
        J, g, H = self._assemble(self._sweeps.first_order_gn, self.check_theta(theta), parts="JgH")
        return J, g, H

    def cost_grad_hess_gn(self, theta) -> tuple[float, np.ndarray, np.ndarray, np.ndarray]:
        """(J, ∇J, ∇²J, Gauss-Newton Hessian) from one second-order sweep (by
        ``self.hessian``): the Gauss-Newton part is a term of the exact Hessian, so it
        comes for free, and every exact Hessian of a Problem comes from this one
        compiled sweep."""
        sweep, parts = self._hessian_sweep(batched=False)
        return tuple(self._assemble(sweep, self.check_theta(theta), parts=parts))

    def _hessian_sweep(self, batched: bool):
        """The sweep giving (J, ∇J, ∇²J, Gauss-Newton part) and its parts letters."""
        return self.hessian_path.made(self._sweeps, batched, self.threads)

    def cost_grad_hess_batch(self, thetas, gauss_newton: bool = False, both: bool = False):
        """cost_grad_hess (or cost_grad_gn) at every row of ``thetas`` (B, K) in one
        vectorised (jax.vmap) call per experiment: (J (B,), g (B, K), H (B, K, K)),
        J inf where a simulation blows up. With ``both``, as cost_grad_hess_gn: the
        Gauss-Newton Hessians (B, K, K) follow."""
        thetas = np.asarray(thetas, dtype=float)
        if thetas.ndim != 2 or thetas.shape[1] != self.K:
            raise ValueError(f"thetas must have shape (B, {self.K}), got {thetas.shape}")
        if gauss_newton and not both:
            return tuple(self._assemble(self._sweeps.first_order_batch, thetas, parts="JgH"))
        sweep, parts = self._hessian_sweep(batched=True)
        out = tuple(self._assemble(sweep, thetas, parts=parts))
        return out if both else out[:3]

    def cost_grad(self, theta) -> tuple[float, np.ndarray]:
        """(J, ∇J) from first-order sensitivities; J is inf when the simulation blows up."""
        J, g = self._assemble(self._sweeps.gradient, self.check_theta(theta), parts="Jg")
        return J, g

    def cost_grad_hessp(self, theta, v) -> tuple[float, np.ndarray, np.ndarray]:
        """(J, ∇J, ∇²J v): the exact Hessian times a direction v (K,), by one
        forward-over-forward sweep that carries 2K + 1 copies of the state instead of
        the full Hessian's 1 + K + K(K+1)/2. For large K with Newton-CG."""
        theta = self.check_theta(theta)
        v = np.asarray(v, dtype=float).reshape(-1)
        if v.shape != (self.K,):
            raise ValueError(f"v must have {self.K} entries (one per θ entry), got {v.size}")
        J, g, Hv = self._assemble(self._sweeps.hessp, theta, v, parts="Jgg")
        return J, g, Hv

    def output_sensitivities(self, theta) -> list[np.ndarray]:
        """∂ŷ/∂θ per experiment, (P, S, K): the simulated outputs' derivatives, exact for
        the discretised model (forward-mode differentiation of the simulation)."""
        theta = self.check_theta(theta)
        out = []
        for e, (t, u, y) in enumerate(self._arrays):
            idx = self._slices(e)
            x0, p = on_device(self.x0[e]), on_device(self.p0)
            dy = np.asarray(self._sweeps.output_jacobian(on_device(theta[idx]), x0, p, t, u))
            full = np.zeros(np.shape(y["y"] if isinstance(y, dict) else y) + (self.K,))
            full[..., idx] = dy
            out.append(full)
        return out

    def predict(self, theta, horizon: int = 1) -> list:
        """Per experiment, what the predictor makes of the record at θ: outputs
        predicted ``horizon`` samples ahead (1: one step), the filter's innovation
        covariances and standardised innovations (see
        :class:`tensorid.engine.predictions.Prediction`). For output error every
        horizon gives the simulation."""
        from ..sweeping.predictions import predictions

        return predictions(self, theta, horizon)

    def simulate(self, theta) -> list[Simulation]:
        """Simulate every experiment at θ (the model alone, whatever the predictor);
        returns a list of Simulation."""
        p, x0 = self.unpack(theta)
        sw = self._sweeps
        sw = shared_sweeps(
            self.model, sw.free_states, sw.free_params, self.discretisation, dosing=self.dosing
        )
        return [run_simulation(sw, ex, x0[e], p) for e, ex in enumerate(self.experiments)]

    def diagnose(self, theta) -> str | None:
        """None when every experiment simulates to finite values at θ; otherwise a
        plain-language account of where the simulation first fails and what to try."""
        from .diagnostics import diagnose

        return diagnose(self, self.check_theta(theta))

    def __repr__(self) -> str:
        return (
            f"Problem({self.model.name!r}, experiments={len(self.experiments)}, theta="
            f"{self.theta_names}, scheme={self.scheme.name}, substeps={self.substeps}, "
            f"interpolation={self.interpolation!r}, hessian={self.hessian!r})"
        )
