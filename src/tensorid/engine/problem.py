"""Problem: a model, measured experiments and what is unknown, as a function of θ.

θ = (free initial states of experiment 1, ..., of experiment E, free parameters),
free initial states in ``free_x0`` order and parameters in model order, in natural
units. Every check of the user's input happens here, before anything compiles.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import jax.numpy as jnp
import numpy as np

from . import _config  # noqa: F401
from .data import Experiment
from .integrate import (
    INTERPOLATIONS,
    AdaptiveRungeKutta,
    DiagonallyImplicitRungeKutta,
    Scheme,
    get_scheme,
)
from .model import Model
from .sensitivity import Sensitivities, unpack_symmetric


def _name_list(what: str, names, known: Sequence[str], kind: str) -> list[str]:
    if names is None:
        return []
    if isinstance(names, str):
        names = [names]
    names = list(names)
    unknown = [n for n in names if n not in known]
    if unknown:
        raise ValueError(
            f"{what} names unknown {kind} {unknown}; the model's {kind} are {list(known)}"
        )
    dup = sorted({n for n in names if names.count(n) > 1})
    if dup:
        raise ValueError(f"{what} repeats {dup}")
    return names


class Problem:
    """A least-squares identification problem.

    Parameters
    ----------
    model : Model
    data : Experiment or list of Experiment
        Each experiment has its own initial state; all share the parameters.
    p0 : dict {name: value} or array (M,)
        Parameter values: the start for free parameters, the value of fixed ones.
    x0 : array (N,), array (E, N), dict {state: value} or list of dicts; default zeros
        Initial states: the start for free entries, the value of fixed ones.
    free_x0 : list of state names whose initial value is estimated (in every experiment).
    fixed : list of parameter names held at their p0 value.
    bounds : dict {name: (lo, hi)} for parameters or free initial states; None or
        ±inf for an open side.
    substeps : Runge-Kutta steps per sample interval (for an adaptive scheme: the
        first trial step is one sample interval / substeps).
    interpolation : "linear" or "zoh" for the input between samples.
    scheme : explicit fixed-step "rk4" (default), "rk38", "heun", "euler"; implicit
        (L-stable, for stiff models) "sdirk3", "sdirk2", "implicit-euler"; adaptive
        (error-controlled) "dopri5", "bosh3".
    rtol, atol : error tolerances of an adaptive scheme (defaults 1e-6, 1e-9).
    weights : dict {output: weight} or array (S,); J = Σ_h Σ_g w_g r_g².
    """

    def __init__(
        self,
        model: Model,
        data: Experiment | Sequence[Experiment],
        p0=None,
        x0=None,
        free_x0: Sequence[str] | None = None,
        fixed: Sequence[str] | None = None,
        bounds: Mapping[str, tuple[float, float]] | None = None,
        substeps: int = 4,
        interpolation: str = "linear",
        scheme: str | Scheme = "rk4",
        weights=None,
        rtol: float | None = None,
        atol: float | None = None,
    ):
        if not isinstance(model, Model):
            raise TypeError(f"model must be a tensorid.Model, got {type(model).__name__}")
        self.model = model
        self.experiments = self._check_data(data)
        if p0 is None:
            raise ValueError(
                f"p0 is required: give a start value for every parameter "
                f"{list(model.params)} (dict or array)"
            )
        self.p0 = model.params_array(p0, "p0")
        self.x0 = self._check_x0(x0)
        self.free_x0 = _name_list("free_x0", free_x0, model.states, "states")
        self.fixed = _name_list("fixed", fixed, model.params, "params")
        self.free_params = [n for n in model.params if n not in self.fixed]
        if not isinstance(substeps, int | np.integer) or substeps < 1:
            raise ValueError(f"substeps must be a positive integer, got {substeps!r}")
        if interpolation not in INTERPOLATIONS:
            raise ValueError(
                f"interpolation must be one of {INTERPOLATIONS}, got {interpolation!r}"
            )
        self.substeps = int(substeps)
        self.interpolation = interpolation
        self.scheme = get_scheme(scheme, rtol, atol)
        self.weights = self._check_weights(weights)
        self.lower, self.upper = self._check_bounds(bounds or {})
        if self.K == 0:
            raise ValueError("nothing to estimate: every parameter is fixed and free_x0 is empty")
        self._sens = Sensitivities(
            model,
            tuple(model.states.index(n) for n in self.free_x0),
            tuple(model.params.index(n) for n in self.free_params),
            self.scheme,
            self.substeps,
            interpolation,
        )
        self._arrays = [
            (jnp.asarray(e.t), jnp.asarray(e.u), jnp.asarray(e.y)) for e in self.experiments
        ]

    @property
    def rounding_floor(self) -> float:
        """The cost of residuals at 1e-13 of the data (double precision leaves a few
        digits to the simulation): a fit that reaches it has matched the data exactly."""
        return 1e-26 * sum(
            float(np.sum(self.weights * np.asarray(y) ** 2)) for _, _, y in self._arrays
        )

    # -- input checks ---------------------------------------------------------------
    def _check_data(self, data) -> list[Experiment]:
        exps = [data] if isinstance(data, Experiment) else list(data)
        if not exps:
            raise ValueError("data is empty: pass an Experiment or a list of them")
        m = self.model
        for i, e in enumerate(exps):
            where = f"experiment {i}" + (f" ({e.name})" if e.name else "")
            if not isinstance(e, Experiment):
                raise TypeError(f"{where} is a {type(e).__name__}, not a tensorid.Experiment")
            if e.y is None:
                raise ValueError(f"{where} has no measured outputs y; a fit needs them")
            if e.u.shape[1] != m.U:
                raise ValueError(
                    f"{where} has {e.u.shape[1]} input column(s) but the model "
                    f"has {m.U} inputs {list(m.inputs)}"
                )
            if e.y.shape[1] != m.S:
                raise ValueError(
                    f"{where} has {e.y.shape[1]} output column(s) but the model "
                    f"has {m.S} outputs {list(m.outputs)}"
                )
        return exps

    def _check_x0(self, x0) -> np.ndarray:
        m, E = self.model, len(self.experiments)
        if x0 is None:
            return np.zeros((E, m.N))
        if isinstance(x0, Mapping):
            return np.tile(m.states_array(x0), (E, 1))
        if isinstance(x0, Sequence) and x0 and isinstance(x0[0], Mapping):
            if len(x0) != E:
                raise ValueError(f"x0 has {len(x0)} dicts but there are {E} experiments")
            return np.stack([m.states_array(d, f"x0[{i}]") for i, d in enumerate(x0)])
        arr = np.asarray(x0, dtype=float)
        if arr.ndim == 1:
            return np.tile(m.states_array(arr), (E, 1))
        if arr.shape != (E, m.N):
            raise ValueError(
                f"x0 must have shape ({m.N},) or ({E}, {m.N}) for "
                f"{E} experiment(s) and states {list(m.states)}, got {arr.shape}"
            )
        if not np.isfinite(arr).all():
            raise ValueError("x0 contains non-finite values")
        return arr

    def _check_weights(self, weights) -> np.ndarray:
        m = self.model
        if weights is None:
            return np.ones(m.S)
        if isinstance(weights, Mapping):
            w = _name_list("weights", list(weights), m.outputs, "outputs")
            out = np.ones(m.S)
            for n in w:
                out[m.outputs.index(n)] = float(weights[n])
        else:
            out = np.asarray(weights, dtype=float).reshape(-1)
            if out.shape != (m.S,):
                raise ValueError(f"weights must have one value per output {list(m.outputs)}")
        if not np.isfinite(out).all() or (out < 0).any():
            raise ValueError("weights must be finite and non-negative")
        return out

    def _check_bounds(self, bounds: Mapping) -> tuple[np.ndarray, np.ndarray]:
        m = self.model
        _name_list("bounds", list(bounds), list(m.params) + list(m.states), "params or states")
        for name in bounds:
            if name in self.fixed:
                raise ValueError(f"bounds given for {name!r}, which is fixed; drop one of them")
            if name in m.states and name not in self.free_x0:
                raise ValueError(
                    f"bounds given for the initial state {name!r}, which is not "
                    "in free_x0; add it to free_x0 or drop the bound"
                )
        lo = np.full(self.K, -np.inf)
        hi = np.full(self.K, np.inf)
        names = self.theta_entries
        for k, (name, _) in enumerate(names):
            if name in bounds:
                try:
                    a, b = bounds[name]
                except (TypeError, ValueError):
                    raise ValueError(
                        f"bounds[{name!r}] must be a pair (lo, hi), got {bounds[name]!r}"
                    ) from None
                a = -np.inf if a is None else float(a)
                b = np.inf if b is None else float(b)
                if np.isnan(a) or np.isnan(b) or a > b:
                    raise ValueError(f"bounds[{name!r}] = ({a}, {b}) has lo > hi")
                lo[k], hi[k] = a, b
        theta0 = self.theta0
        out = (theta0 < lo) | (theta0 > hi)
        if out.any():
            k = int(np.argmax(out))
            what = "p0" if names[k][0] in m.params else "x0"
            raise ValueError(
                f"{what}[{names[k][0]!r}] = {theta0[k]:g} is outside its bounds "
                f"({lo[k]:g}, {hi[k]:g}); move the start inside or widen the "
                "bounds"
            )
        return lo, hi

    # -- θ layout ---------------------------------------------------------------------
    @property
    def theta_entries(self) -> list[tuple[str, int | None]]:
        """(name, experiment index or None for parameters) for each entry of θ."""
        out: list[tuple[str, int | None]] = []
        for e in range(len(self.experiments)):
            out += [(n, e) for n in self.free_x0]
        return out + [(n, None) for n in self.free_params]

    @property
    def theta_names(self) -> list[str]:
        """Names of the entries of θ: "state(t0)" (with "[experiment]" when there are
        several) for free initial states, then parameter names."""
        E = len(self.experiments)
        names = []
        for n, e in self.theta_entries:
            if e is None:
                names.append(n)
            else:
                label = self.experiments[e].name or str(e)
                names.append(f"{n}(t0)" if E == 1 else f"{n}(t0)[{label}]")
        return names

    @property
    def K(self) -> int:
        """Number of unknowns (entries of θ)."""
        return len(self.experiments) * len(self.free_x0) + len(self.free_params)

    @property
    def theta0(self) -> np.ndarray:
        """The start: free x0 entries then free parameters, natural units."""
        m = self.model
        xs = [
            self.x0[e, m.states.index(n)]
            for e in range(len(self.experiments))
            for n in self.free_x0
        ]
        ps = [self.p0[m.params.index(n)] for n in self.free_params]
        return np.array(xs + ps, dtype=float)

    def _check_theta(self, theta) -> np.ndarray:
        theta = np.asarray(theta, dtype=float).reshape(-1)
        if theta.shape != (self.K,):
            raise ValueError(
                f"theta must have {self.K} entries {self.theta_names}, got {theta.size}"
            )
        return theta

    def _slices(self, e: int) -> np.ndarray:
        """Indices into θ of experiment e's local θ (its free x0, then free params)."""
        nx, E = len(self.free_x0), len(self.experiments)
        return np.concatenate([np.arange(e * nx, (e + 1) * nx), np.arange(E * nx, self.K)]).astype(
            int
        )

    def unpack(self, theta) -> tuple[np.ndarray, np.ndarray]:
        """(params (M,), x0 (E, N)) with θ written into the fixed values."""
        theta = self._check_theta(theta)
        m = self.model
        p = self.p0.copy()
        x0 = self.x0.copy()
        for k, (name, e) in enumerate(self.theta_entries):
            if e is None:
                p[m.params.index(name)] = theta[k]
            else:
                x0[e, m.states.index(name)] = theta[k]
        return p, x0

    # -- cost and derivatives ------------------------------------------------------------
    def _each(self, fn, theta, *more):
        """(idx, fn(θ_e, *more_e, x0_e, p0, t, u, y, w)) per experiment e, where θ_e and
        more_e are the experiment's entries (last axis) of θ and of further θ-shaped
        arrays; θ may hold one point per row."""
        w = jnp.asarray(self.weights)
        for e, (t, u, y) in enumerate(self._arrays):
            idx = self._slices(e)
            local = [jnp.asarray(a[..., idx]) for a in (theta, *more)]
            yield idx, fn(*local, jnp.asarray(self.x0[e]), jnp.asarray(self.p0), t, u, y, w)

    def cost(self, theta) -> float:
        """J(θ) by plain simulation; inf when the simulation is not finite."""
        theta = self._check_theta(theta)
        J = sum(float(Je) for _, Je in self._each(self._sens.cost, theta))
        return J if np.isfinite(J) else np.inf

    def jax_cost(self, theta):
        """J(θ) as a traceable JAX function (for jax.grad / jax.hessian checks)."""
        w = jnp.asarray(self.weights)
        J = 0.0
        for e, (t, u, y) in enumerate(self._arrays):
            J = J + self._sens._cost(
                theta[self._slices(e)], jnp.asarray(self.x0[e]), jnp.asarray(self.p0), t, u, y, w
            )
        return J

    def residuals(self, theta) -> np.ndarray:
        """sqrt(w)·(y_obs - y_sim) for every sample, output and experiment, flattened."""
        theta = self._check_theta(theta)
        return np.concatenate([np.asarray(r) for _, r in self._each(self._sens.residuals, theta)])

    def _assemble(self, fn, theta, packed: bool):
        K = self.K
        J, g, H = 0.0, np.zeros(K), np.zeros((K, K))
        for idx, (Je, ge, He) in self._each(fn, self._check_theta(theta)):
            He = np.asarray(He)
            if packed:
                He = unpack_symmetric(He, idx.size)
            J += float(Je)
            g[idx] += np.asarray(ge)
            H[np.ix_(idx, idx)] += He
        if not (np.isfinite(J) and np.isfinite(g).all() and np.isfinite(H).all()):
            return np.inf, g, H
        return J, g, H

    def cost_grad_hess(self, theta) -> tuple[float, np.ndarray, np.ndarray]:
        """(J, ∇J, ∇²J) at θ, exact for the discretised model, from the transition
        matrices and tensors integrated alongside the states. J is inf (and g, H are
        not meaningful) when the simulation blows up."""
        return self._assemble(self._sens.second_order, theta, packed=True)

    def cost_grad_gn(self, theta) -> tuple[float, np.ndarray, np.ndarray]:
        """(J, ∇J, Gauss-Newton Hessian 2 Σ (∂ỹ/∂θ)ᵀ W ∂ỹ/∂θ): first-order
        sensitivities only."""
        return self._assemble(self._sens.first_order, theta, packed=False)

    def cost_grad_hess_batch(
        self, thetas, gauss_newton: bool = False
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """cost_grad_hess (or cost_grad_gn) at every row of ``thetas`` (B, K) in one
        vectorised (jax.vmap) call per experiment: (J (B,), g (B, K), H (B, K, K)),
        J inf where a simulation blows up."""
        thetas = np.asarray(thetas, dtype=float)
        if thetas.ndim != 2 or thetas.shape[1] != self.K:
            raise ValueError(f"thetas must have shape (B, {self.K}), got {thetas.shape}")
        B, K = thetas.shape
        fn = self._sens.first_order_batch if gauss_newton else self._sens.second_order_batch
        J, g, H = np.zeros(B), np.zeros((B, K)), np.zeros((B, K, K))
        for idx, (Je, ge, He) in self._each(fn, thetas):
            He = np.asarray(He) if gauss_newton else unpack_symmetric(np.asarray(He), idx.size)
            J += np.asarray(Je)
            g[:, idx] += np.asarray(ge)
            H[:, idx[:, None], idx[None, :]] += He
        ok = np.isfinite(J) & np.isfinite(g).all(axis=1) & np.isfinite(H).all(axis=(1, 2))
        return np.where(ok, J, np.inf), g, H

    def cost_grad(self, theta) -> tuple[float, np.ndarray]:
        """(J, ∇J) from first-order sensitivities; J is inf when the simulation blows up."""
        J, g = 0.0, np.zeros(self.K)
        for idx, (Je, ge) in self._each(self._sens.gradient, self._check_theta(theta)):
            J += float(Je)
            g[idx] += np.asarray(ge)
        return (J, g) if np.isfinite(J) and np.isfinite(g).all() else (np.inf, g)

    def cost_grad_hessp(self, theta, v) -> tuple[float, np.ndarray, np.ndarray]:
        """(J, ∇J, ∇²J v): the exact Hessian times a direction v (K,), by one
        forward-over-forward sweep that carries 2K + 1 copies of the state instead of
        the full Hessian's 1 + K + K(K+1)/2. For large K with Newton-CG."""
        theta = self._check_theta(theta)
        v = np.asarray(v, dtype=float).reshape(-1)
        if v.shape != (self.K,):
            raise ValueError(f"v must have {self.K} entries (one per θ entry), got {v.size}")
        J, g, Hv = 0.0, np.zeros(self.K), np.zeros(self.K)
        for idx, (Je, ge, hv) in self._each(self._sens.hessp, theta, v):
            J += float(Je)
            g[idx] += np.asarray(ge)
            Hv[idx] += np.asarray(hv)
        if not (np.isfinite(J) and np.isfinite(g).all() and np.isfinite(Hv).all()):
            return np.inf, g, Hv
        return J, g, Hv

    def simulate(self, theta) -> list:
        """Simulate every experiment at θ; returns a list of Simulation."""
        from .simulate import Simulation

        p, x0 = self.unpack(theta)
        out = []
        for e, (t, u, _) in enumerate(self._arrays):
            xs, ys = self._sens.simulate(jnp.asarray(x0[e]), jnp.asarray(p), t, u)
            out.append(Simulation(self.model, self.experiments[e], np.asarray(xs), np.asarray(ys)))
        return out

    def diagnose(self, theta) -> str | None:
        """None when every experiment simulates to finite values at θ; otherwise a
        plain-language account of where the simulation first fails and what to try."""
        theta = self._check_theta(theta)
        m = self.model
        p, x0 = self.unpack(theta)
        values = ", ".join(f"{n}={v:.4g}" for n, v in zip(self.theta_names, theta, strict=True))
        for e, sim in enumerate(self.simulate(theta)):
            if sim.finite:
                continue
            where = f"experiment {e}" + (f" ({sim.experiment.name})" if sim.experiment.name else "")
            bad_x = ~np.isfinite(sim.x).all(axis=1)
            bad_y = ~np.isfinite(sim.y).all(axis=1)
            h = int(np.argmax(bad_x | bad_y))
            if bad_x[h]:
                states = [
                    n for n, ok in zip(m.states, np.isfinite(sim.x[h]), strict=True) if not ok
                ]
                what = f"state(s) {states} are not finite"
            else:
                outs = [n for n, ok in zip(m.outputs, np.isfinite(sim.y[h]), strict=True) if not ok]
                what = f"output(s) {outs} are not finite although the states are"
            last = (
                "from the initial state"
                if h == 0
                else "after "
                + ", ".join(f"{n}={v:.4g}" for n, v in zip(m.states, sim.x[h - 1], strict=True))
            )
            hints = [
                "a state or parameter outside the model's domain (square root or log of a "
                "negative value, division by a parameter near 0): add bounds, or write the "
                "model with tensorid.functions.safe_sqrt",
            ]
            if isinstance(self.scheme, AdaptiveRungeKutta):
                hints.append(
                    f"a stiff model: the adaptive scheme gives up after "
                    f"{self.scheme.max_steps} steps per sample; use scheme='sdirk3'"
                )
            elif isinstance(self.scheme, DiagonallyImplicitRungeKutta):
                hints.append("a stage's Newton iteration did not converge: raise substeps")
            else:
                hints.append(
                    "a stiff model, or a step too large for an explicit scheme: raise "
                    "substeps, or use scheme='sdirk3'"
                )
            hints.append("dynamics that really diverge at these values: start closer")
            return (
                f"the simulation is not finite at {values}: in {where}, {what} at "
                f"t = {sim.t[h]:.6g} (sample {h} of {sim.t.size}), {last}. Likely causes: "
                + "; ".join(hints)
                + "."
            )
        return None

    def __repr__(self) -> str:
        return (
            f"Problem({self.model.name!r}, experiments={len(self.experiments)}, "
            f"theta={self.theta_names}, scheme={self.scheme.name}, "
            f"substeps={self.substeps}, interpolation={self.interpolation!r})"
        )
