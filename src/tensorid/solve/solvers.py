"""The fitting methods as objects, after optimistix's solvers. A method is a small
stateless class with four calls,

    state = method.init(tracker, options)   # state.point: the first point to evaluate
    method.step(state, values)              # the values at state.point; a new point
    method.terminate(state) -> bool         # has the run ended?
    method.result(state) -> Outcome         # where, and how (a Status)

and markers saying what it can do: ``needs_hessian`` (its steps use ∇²J or its
products: with segments it then uses the exact Lagrangian Hessian),
``exact_derivatives`` (False: finite differences), ``supports_batch`` (starts can
march in lock-step, their points evaluated in one vectorised call),
``supports_bounds``, ``supports_segments`` (multiple shooting), ``supports_likelihood``
(J need not be a sum of squares, as a filter's −2 log L is not). Between ``init`` and
the end, ``method.sweep(state)`` says which derivatives ``state.point`` needs; the
driver evaluates the points of every unfinished start (one at a time, or together)
and the one loop in endings.py hands each its values and decides how each run
ends. A method that evaluates for itself (SciPy's, baselines.py) asks for no point
and does its whole run in one step.

Adding a method: a class here (or in a module of its own) and its line in
registry.py, where method names are looked up, and nowhere else.
"""

from __future__ import annotations

import enum
from collections.abc import Callable, Generator
from dataclasses import dataclass, field
from typing import Any, ClassVar, NamedTuple

import numpy as np

from ..engine.schemes.status import Status
from .curvature import negative_curvature
from .endings import Outcome
from .hybrid import Hybrid
from .options import FitOptions
from .scaling import Tracker
from .trust_region import TRResult, trust_region_steps


class Sweep(enum.Enum):
    """The derivatives a point needs (driver.py runs the sweep that gives them)."""

    EXACT = "J, ∇J, ∇²J"
    GN = "J, ∇J, the Gauss-Newton Hessian"
    BOTH = "J, ∇J, ∇²J and the Gauss-Newton Hessian"
    HESSP = "J, ∇J and v -> ∇²J v"


class Values(NamedTuple):
    """What a sweep gave at a point, in natural units: ``H`` is ∇²J (or v -> ∇²J v),
    ``G`` the Gauss-Newton Hessian; None where the sweep has not got it."""

    J: float
    g: np.ndarray
    H: Any = None
    G: np.ndarray | None = None


@dataclass
class State:
    """One start's run: the tracker (scaled units, best point), the history in the
    user's units, and ``point``, the next point to evaluate (None: none asked)."""

    tr: Tracker
    options: FitOptions
    history: list[dict] = field(default_factory=list)
    record: Callable = field(default=lambda entry: None)  # the tracker's recorder
    point: np.ndarray | None = None
    outcome: Outcome | None = None
    steps: Generator[np.ndarray, tuple, TRResult] | None = None  # trust_region_steps
    hybrid: Hybrid | None = None  # method "auto"
    before: tuple[int, int] = (0, 0)  # iterations and products before a restart


class Method:
    """The common interface; see the module docstring."""

    name: ClassVar[str] = ""
    needs_hessian: ClassVar[bool] = False
    exact_derivatives: ClassVar[bool] = True
    supports_batch: ClassVar[bool] = False
    supports_bounds: ClassVar[bool] = True
    supports_segments: ClassVar[bool] = True
    supports_likelihood: ClassVar[bool] = True
    raises: ClassVar[tuple[type[Exception], ...]] = ()  # what its own steps may raise

    def init(self, tr: Tracker, options: FitOptions) -> State:
        state = State(tr, options)
        state.record = tr.recorder(state.history, options.callback)
        return state

    def sweep(self, state: State) -> Sweep:
        raise NotImplementedError

    def step(self, state: State, values: Values | None) -> None:
        raise NotImplementedError

    def terminate(self, state: State) -> bool:
        return state.outcome is not None

    def result(self, state: State) -> Outcome:
        assert state.outcome is not None
        return state.outcome

    def best(self, state: State) -> tuple[np.ndarray | None, int]:
        """Where the run ends if it is stopped now: the best point seen, and the
        iterations recorded so far."""
        return state.tr.best_phi, state.history[-1]["iteration"] if state.history else 0

    def report(self, state: State) -> dict | None:
        """What the run used, for ``FitResult.hybrid`` (method "auto")."""
        return None

    def __repr__(self) -> str:
        return f"{type(self).__name__}()"


class TrustRegion(Method):
    """A trust-region method (trust_region.py) on the derivatives ``sweep_kind``."""

    sweep_kind: ClassVar[Sweep]

    def init(self, tr: Tracker, options: FitOptions) -> State:
        state = super().init(tr, options)
        self.prepare(state)
        state.steps = _steps(state, tr.phi(tr.theta0), options.maxiter, self.callback(state))
        state.point = next(state.steps)
        return state

    def prepare(self, state: State) -> None:
        """What a method keeps beside the trust region, set up before its first step."""

    def callback(self, state: State) -> Callable:
        return state.record

    def sweep(self, state: State) -> Sweep:
        return self.sweep_kind

    def scaled(self, state: State, v: Values) -> tuple:
        """(J, g, H) at ``state.point`` in the trust region's scaled units."""
        H = v.G if self.sweep_kind is Sweep.GN else v.H
        return state.tr.scaled(state.point, v.J, v.g, H)

    def step(self, state: State, values: Values | None) -> None:
        assert values is not None and state.steps is not None
        try:
            state.point = state.steps.send(self.scaled(state, values))
        except StopIteration as done:
            state.point = None
            state.outcome = self.finished(state, done.value)

    def finished(self, state: State, r: TRResult) -> Outcome | None:
        """How the trust-region run ``r`` ends the method's run (None: it goes on)."""
        return Outcome(r.x, r.nit, r.status, r.detail, r.nhev)


def _steps(state: State, phi, maxiter: int, callback) -> Generator[np.ndarray, tuple, TRResult]:
    tr, options = state.tr, state.options
    lo, hi = tr.box()
    kw = options.trust_region() | {"maxiter": maxiter}
    return trust_region_steps(phi, lo, hi, fatol=tr.fatol, callback=callback, **kw)


class GaussNewton(TrustRegion):
    """Trust-region Gauss-Newton (Levenberg-Marquardt) with the exact Jacobian."""

    name = "gauss-newton"
    supports_batch = True
    sweep_kind = Sweep.GN


class NewtonCG(TrustRegion):
    """Trust-region Newton with truncated CG on exact Hessian-vector products."""

    name = "newton-cg"
    needs_hessian = True
    sweep_kind = Sweep.HESSP


class Auto(TrustRegion):
    """Gauss-Newton while it converges fast, the exact Hessian where it does not
    (hybrid.py), and on past a saddle where Gauss-Newton converged but ∇²J curves
    downward (once: the restart runs in exact mode)."""

    name = "auto"
    needs_hessian = True
    supports_batch = True

    def prepare(self, state: State) -> None:
        state.hybrid = Hybrid(state.tr.problem.K)

    def callback(self, state: State) -> Callable:
        return _observed(state.record, state.hybrid)

    def sweep(self, state: State) -> Sweep:
        assert state.hybrid is not None
        return Sweep.BOTH if state.hybrid.exact else Sweep.GN

    def scaled(self, state: State, v: Values) -> tuple:
        tr, hybrid, phi = state.tr, state.hybrid, state.point
        assert hybrid is not None
        exact = hybrid.exact  # the mode the point was evaluated in
        H = tr.scaled_hessian(v.H) if exact and np.isfinite(v.J) else None
        J, g, G = tr.scaled(phi, v.J, v.g, v.G)
        return hybrid.take(phi, J, g, G, H, exact)

    def finished(self, state: State, r: TRResult) -> Outcome | None:
        r.nit, r.nhev = r.nit + state.before[0], r.nhev + state.before[1]
        hybrid, maxiter = state.hybrid, state.options.maxiter
        assert hybrid is not None
        if _at_saddle(state.tr, hybrid, r, maxiter):
            state.before = (r.nit, r.nhev)
            record = _observed(_after(state.record, r.nit, r.nfev), hybrid)
            state.steps = _steps(state, r.x, maxiter - r.nit, record)
            state.point = next(state.steps)
            return None
        if hybrid.saddles and r.status is Status.MAXITER:
            r.detail = f"maxiter={maxiter}"
        return super().finished(state, r)

    def report(self, state: State) -> dict | None:
        assert state.hybrid is not None
        return state.hybrid.report()


class Newton(Auto):
    """Trust-region Newton on exact sweeps (the transition tensors') throughout, each
    step by whichever model predicted the last step better, the exact Hessian or its
    Gauss-Newton part from the same sweep (NL2SOL's rule; the first step by the
    Gauss-Newton part): far from the optimum the residual term's negative curvature
    would otherwise send every step to the boundary, where the cost does not follow."""

    name = "newton"

    def prepare(self, state: State) -> None:
        state.hybrid = Hybrid(state.tr.problem.K, exact=True, locked=True)


def _observed(record, hybrid):
    """A trust-region callback that shows each step to ``hybrid`` first."""

    def both(entry):
        hybrid.observe(entry)
        record(entry)

    return both


def _after(record, iterations: int, evaluations: int):
    """A recorder whose counts continue from a run's (its iteration 0, the restart
    point, is that run's last and already recorded)."""

    def shifted(entry):
        if entry["iteration"] > 0:
            it, nfev = entry["iteration"] + iterations, entry["nfev"] + evaluations
            record(dict(entry, iteration=it, nfev=nfev))

    return shifted


def _at_saddle(tr: Tracker, hybrid: Hybrid, r: TRResult, maxiter: int) -> bool:
    """Did a run that ended in Gauss-Newton mode stop where ∇²J has negative
    curvature along the unknowns off their bounds? Then ``hybrid`` goes exact."""
    if hybrid.checked or not r.status.success or r.nit >= maxiter:
        return False
    hybrid.checked = True
    theta = tr.theta(r.x)
    J, g, H = tr.problem.cost_grad_hess(theta)
    lo, hi = tr.problem.lower, tr.problem.upper
    tol = 1e-12 * (1 + np.abs(theta))
    off = (theta > lo + tol) & (theta < hi - tol)
    tr.known = (theta, J, g, H)  # the result at this point needs them too
    if not np.isfinite(J) or not negative_curvature(tr.scaled_hessian(H)[np.ix_(off, off)]):
        return False
    hybrid.restart_exact()
    return True
