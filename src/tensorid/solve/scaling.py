"""Scaled variables and best-point tracking.

Every method works on scaled variables φ = θ / scale and a cost normalised by its
value at the start, so that the Silverbox parameters (5e-6 .. 4) look alike to the
optimiser; results are reported in natural units. The ``Tracker`` sees every
evaluation and remembers the best finite point, so that whatever a method does, a
fit never returns NaN.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from ..engine.assembly.problem import Problem


def auto_scale(
    theta0: np.ndarray,
    J0: float,
    H_gn: np.ndarray,
    n_init: int = 0,
    reach: Callable[[], np.ndarray | None] | None = None,
) -> np.ndarray:
    """Typical magnitudes: |θ0| where it is not zero; otherwise the step that changes
    the cost by about its own size according to the Gauss-Newton curvature.

    The first ``n_init`` entries, free initial states, are floored at that step, but
    no higher than what the state reaches along the simulation at θ0 (``reach()``:
    per free initial state, its largest |x|; None where that is not known), both
    rounded down to a power of two. Their guess is often 0 or a tiny number (an
    initial velocity of 1e-4 where the fit's is -1.3): |θ0| alone put the optimum 1e4
    scaled units away, which the trust radius took many doublings to reach
    (Silverbox from velocities of ±1e-3: Gauss-Newton's 18-20 iterations became
    7-11; from 1e-6, 178 became 8). The reach keeps the floor to the state's own
    size where the curvature at θ0 says little: a state that enters the outputs only
    through a cubic has almost none there, and a step of 1e6 for a state of size
    0.05 left a fit stalled at its optimum (radius collapsed, "NOT converged").
    Rounded down, the floor acts only where |θ0| is below it, and a power of two does
    not move by a rounding difference in H_gn (a start fitted alone or in a batch
    gets the same scale). Parameters keep |θ0|: their guess is usually of the right
    size. A zero guess takes the curvature step itself, as before the floor."""
    scale = np.abs(theta0).astype(float)
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        curv = np.sqrt(max(abs(J0), 1e-300) / np.diag(H_gn))  # |J0|: a likelihood
    curv = np.where(np.isfinite(curv) & (curv > 0), curv, 0.0)
    zero = scale == 0
    scale[zero] = np.where(curv[zero] > 0, curv[zero], 1.0)
    floor = _power_of_two_below(curv[:n_init])  # never above a zero guess's own step
    if (floor > scale[:n_init]).any():
        size = reach() if reach is not None else None  # unknown: no floor
        cap = 0.0 if size is None else _power_of_two_below(np.asarray(size, dtype=float))
        scale[:n_init] = np.maximum(scale[:n_init], np.minimum(floor, cap))
    return scale


def _power_of_two_below(v: np.ndarray) -> np.ndarray:
    """2^⌊log2 v⌋ where v is positive and finite, else 0."""
    ok = np.isfinite(v) & (v > 0)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(ok, 2.0 ** np.floor(np.log2(np.where(ok, v, 1.0))), 0.0)


def state_reach(problem: Problem, theta0) -> np.ndarray | None:
    """Per free initial state, in θ's order (experiment by experiment), the largest
    |x| that state reaches along the simulation at θ0; None where it fails."""
    try:
        sims = problem.simulate(theta0)
        idx = [problem.model.states.index(n) for n in problem.free_x0]
        out = [np.max(np.abs(np.asarray(s.x)[:, idx]), axis=0) for s in sims]
    except Exception:  # noqa: BLE001 - no size known: the floor is left out
        return None
    size = np.concatenate(out) if out else np.zeros(0)
    return size if np.isfinite(size).all() else None


def resolve_scale(
    K: int,
    theta0: np.ndarray,
    J0: float,
    H_gn: np.ndarray,
    x_scale,
    n_init: int = 0,
    reach: Callable[[], np.ndarray | None] | None = None,
) -> np.ndarray:
    """The scale of θ: from ``x_scale`` ("auto" or K positive magnitudes); the first
    ``n_init`` entries of θ are free initial states (see :func:`auto_scale`)."""
    if isinstance(x_scale, str):
        if x_scale != "auto":
            raise ValueError("x_scale must be 'auto' or an array of typical magnitudes")
        return auto_scale(theta0, J0, H_gn, n_init, reach)
    scale = np.asarray(x_scale, dtype=float).reshape(-1)
    if scale.shape != (K,) or not (np.isfinite(scale) & (scale > 0)).all():
        raise ValueError(f"x_scale must hold {K} positive finite values")
    return scale


class Tracker:
    """Wraps evaluations in scaled variables; remembers the best finite point."""

    def __init__(self, problem: Problem, scale: np.ndarray, J_ref: float, theta0=None):
        self.problem, self.scale, self.J_ref = problem, scale, J_ref
        self.theta0 = problem.theta0 if theta0 is None else np.asarray(theta0, dtype=float)
        self.nfev = 0
        self.best_phi: np.ndarray | None = None
        self.best_J = np.inf
        self.nonfinite = 0
        self.first_nonfinite: np.ndarray | None = None
        self.known: tuple | None = None  # (θ, J, g, H) computed already at some θ

    @classmethod
    def start(cls, problem: Problem, theta0, J0: float, H_gn, x_scale) -> Tracker:
        """A tracker for a fit from θ0 with cost J0 and Gauss-Newton Hessian H_gn."""
        n_init = len(problem.experiments) * len(problem.free_x0)
        reach = lambda: state_reach(problem, theta0)  # noqa: E731 - only where needed
        scale = resolve_scale(problem.K, theta0, J0, H_gn, x_scale, n_init, reach)
        # |J0|: a likelihood's J (predictor="ekf") may be negative
        tracker = cls(problem, scale, abs(J0) if J0 != 0 else 1.0, theta0)
        tracker.best_J, tracker.best_phi = J0, tracker.phi(theta0)  # the start counts
        return tracker

    def theta(self, phi) -> np.ndarray:
        """Natural units; clipped because θ/scale·scale may miss a bound by an ulp."""
        return np.clip(self.scale * phi, self.problem.lower, self.problem.upper)

    def phi(self, theta) -> np.ndarray:
        return np.asarray(theta, dtype=float) / self.scale

    def box(self) -> tuple[np.ndarray, np.ndarray]:
        """The bounds in scaled units."""
        return self.problem.lower / self.scale, self.problem.upper / self.scale

    @property
    def fatol(self) -> float:
        """The rounding floor of the data, in scaled cost units."""
        return self.problem.rounding_floor / self.J_ref

    def _seen(self, phi, J):
        self.nfev += 1
        if np.isfinite(J) and J < self.best_J:
            self.best_J, self.best_phi = J, np.array(phi, dtype=float)
        elif not np.isfinite(J):
            self.nonfinite += 1
            if self.first_nonfinite is None:
                self.first_nonfinite = self.theta(phi)

    def notes(self) -> list[str]:
        """What the user should know about trial points that were rejected."""
        if not self.nonfinite or self.first_nonfinite is None:
            return []
        why = self.problem.diagnose(self.first_nonfinite) or "the simulation was not finite"
        # a filter's failure is not the simulation's (its simulation may be finite)
        what = "the filter failed" if why.startswith("the filter") else "the simulation blew up"
        return [
            f"{self.nonfinite} trial point(s) were rejected because {what} there; the first: {why}"
        ]

    def scaled(self, phi, J, g, H):
        """(J, g, H) at θ(φ) in scaled variables, relative to the starting cost."""
        self._seen(phi, J)
        if not np.isfinite(J):
            return np.inf, g, H
        s = self.scale
        return J / self.J_ref, g * s / self.J_ref, self.scaled_hessian(H)

    def scaled_hessian(self, H):
        """H (natural units) in scaled units; None stays None. H may be a product
        function v -> Hv (truncated-CG steps): then so is the result, a failed
        product's entries zero."""
        if H is None or not callable(H):
            return None if H is None else H * np.outer(self.scale, self.scale) / self.J_ref
        s, J_ref = self.scale, self.J_ref

        def hessp(v):
            Hv = H(s * v)
            return np.where(np.isfinite(Hv), Hv, 0.0) * s / J_ref

        return hessp

    def derivs(self, fn):
        """φ -> scaled (J, g, H) from ``fn(θ) -> (J, g, H)`` in natural units."""

        def wrapped(phi):
            return self.scaled(phi, *fn(self.theta(phi)))

        return wrapped

    def cost(self, phi):
        J = self.problem.cost(self.theta(phi))
        self._seen(phi, J)
        return J / self.J_ref if np.isfinite(J) else np.inf

    def residuals(self, phi):
        r = self.problem.residuals(self.theta(phi))
        J = float(r @ r)
        self._seen(phi, J if np.isfinite(J) else np.inf)
        return r / np.sqrt(self.J_ref)

    def recorder(self, history: list, callback):
        """A trust-region callback that records entries in the user's cost units."""

        def natural(entry):
            entry = dict(
                entry, cost=entry["cost"] * self.J_ref, grad_norm=entry["grad_norm"] * self.J_ref
            )
            history.append(entry)
            if callback is not None:
                callback(entry)

        return natural
