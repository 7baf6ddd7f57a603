"""The driver behind fit() and fit_batch(): the shared set-up (starting cost, scale,
tracker), one start evaluated point by point (any method), or several starts in
lock-step with their points evaluated in one vectorised call; and the result at the
end, which is the best finite point seen.
"""

from __future__ import annotations

import time

import numpy as np

from ..engine.status import Status
from .baselines import BASELINES, run_baseline
from .options import FitOptions
from .results import FitResult
from .scaling import Tracker
from .trust_region import minimize_trust_region, trust_region_steps


def fit_many(problem, method, thetas, options: FitOptions, started) -> list[FitResult]:
    """Fits from every row of ``thetas``: lock-step for several starts, otherwise one
    start evaluated point by point. The set-up (cost, scale, tracker) is shared."""
    batched = len(thetas) > 1
    if batched:
        J0, _, H0 = problem.cost_grad_hess_batch(thetas, gauss_newton=True)
    else:
        J, _, H = problem.cost_grad_gn(thetas[0])
        J0, H0 = np.array([J]), H[None]
    results: list[FitResult | None] = [None] * len(thetas)
    trackers = {}
    for i, th in enumerate(thetas):
        if np.isfinite(J0[i]):
            trackers[i] = Tracker.start(problem, th, J0[i], H0[i], options.x_scale)
        else:
            results[i] = _failed_start(problem, method, th, started)
    if batched:
        results = _lockstep(problem, method, trackers, options, started, results)
    elif trackers:
        results = [_single(method, trackers[0], options, started)]
    for r in results:
        assert r is not None
        if batched:
            r.seconds = time.perf_counter() - started
    return results  # type: ignore[return-value]


def _single(method, tr: Tracker, options: FitOptions, started) -> FitResult:
    """One start, evaluated point by point: any method."""
    problem, theta0 = tr.problem, tr.theta0
    history: list[dict] = []
    record = tr.recorder(history, options.callback)
    phi0, (lo, hi) = tr.phi(theta0), tr.box()
    nhev, detail = 0, ""
    # what each path may raise: SciPy's baselines give up in their own ways; the
    # eigen-solver of an exact subproblem may not converge on a Hessian at the edge
    # of overflow. Anything else is a bug and is not hidden.
    expected = (
        (ValueError, ArithmeticError, np.linalg.LinAlgError)
        if method in BASELINES
        else (np.linalg.LinAlgError,)
    )
    try:
        if method in BASELINES:
            phi, nit, status, detail = run_baseline(method, tr, phi0, options, record)
        else:
            r = minimize_trust_region(
                _derivatives(method, tr),
                phi0,
                lo,
                hi,
                fatol=tr.fatol,
                callback=record,
                **options.trust_region(),
            )
            phi, nit, status, detail, nhev = r.x, r.nit, r.status, r.detail, r.nhev
    except expected as e:
        detail = f"{method} raised {type(e).__name__}: {e}"
        if tr.best_phi is None:
            return failed(problem, method, theta0, started, detail, Status.SOLVER_FAILED)
        phi, nit, status = tr.best_phi, len(history), Status.SOLVER_FAILED
    except KeyboardInterrupt:
        return interrupted(tr, method, started, history)
    try:
        res = _finish(tr, method, phi, nit, status, detail, started, history)
    except KeyboardInterrupt:  # while evaluating the end point: keep the best seen
        return interrupted(tr, method, started, history)
    res.nhev = nhev
    return res


def _derivatives(method: str, tr: Tracker):
    """φ -> scaled (J, g, H or v -> Hv) for an exact-derivative method."""
    if method == "newton-cg":
        return tr.derivs_hessp
    problem = tr.problem
    return tr.derivs(problem.cost_grad_hess if method == "newton" else problem.cost_grad_gn)


def _lockstep(problem, method, trackers: dict, options, started, results) -> list:
    """The trust-region runs of several starts, their points evaluated together."""
    gn = method == "gauss-newton"
    runs, pending = {}, {}
    for i, tr in trackers.items():
        history: list[dict] = []
        lo, hi = tr.box()
        steps = trust_region_steps(
            tr.phi(tr.theta0),
            lo,
            hi,
            fatol=tr.fatol,
            callback=tr.recorder(history, None),
            **options.trust_region(),
        )
        runs[i] = (tr, steps, history)
        pending[i] = next(steps)
    try:
        _march_together(problem, method, runs, pending, started, results, gn)
    except KeyboardInterrupt:  # every unfinished start keeps its best point
        for i in pending:
            tr, _, history = runs[i]
            results[i] = interrupted(tr, method, started, history)
    return results


def _march_together(problem, method, runs, pending, started, results, gn) -> None:
    """Evaluate the pending points of every unfinished start in one call, until none
    is left; ``results`` is filled in as starts finish."""
    B = len(results)
    while pending:
        ids = list(pending)
        points = [runs[i][0].theta(pending[i]) for i in ids]
        points += [points[0]] * (B - len(ids))  # one shape: one compilation
        J, g, H = problem.cost_grad_hess_batch(np.array(points), gauss_newton=gn)
        for k, i in enumerate(ids):
            tr, steps, history = runs[i]
            try:
                pending[i] = steps.send(tr.scaled(pending[i], J[k], g[k], H[k]))
            except StopIteration as done:
                r = done.value
                results[i] = _finish(tr, method, r.x, r.nit, r.status, r.detail, started, history)
                del pending[i]  # only once finished: Ctrl-C in _finish keeps it pending
            except np.linalg.LinAlgError as e:  # as in _single: this start ends, not the batch
                del pending[i]
                phi = tr.phi(tr.theta0) if tr.best_phi is None else tr.best_phi
                detail = f"{method} raised LinAlgError: {e}"
                status = Status.SOLVER_FAILED
                results[i] = _finish(
                    tr, method, phi, len(history), status, detail, started, history
                )


def _finish(tr: Tracker, method, phi, nit, status, detail, started, history) -> FitResult:
    """The result at the end point, or at the best point seen if that is better."""
    problem = tr.problem
    if tr.best_phi is not None and tr.best_J < problem.cost(tr.theta(phi)):
        phi = tr.best_phi
    message = status.describe(detail)
    if not status.success and tr.nonfinite:
        message += f" ({tr.nonfinite} trial points blew up; see warnings)"
    res = FitResult.at(
        problem,
        method,
        tr.theta(phi),
        tr.scale,
        status,
        message=message,
        nit=nit,
        nfev=tr.nfev,
        started=started,
        history=history,
    )
    res.notes = tr.notes()
    return res


def interrupted(tr: Tracker, method, started, history) -> FitResult:
    """The result of a start stopped by Ctrl-C: its best point, at once (nothing more
    is evaluated, so the user is not kept waiting)."""
    theta = tr.theta0 if tr.best_phi is None else tr.theta(tr.best_phi)
    J = tr.best_J if tr.best_phi is not None else np.inf
    res = FitResult.at(
        tr.problem,
        method,
        theta,
        tr.scale,
        Status.INTERRUPTED,
        nit=history[-1]["iteration"] if history else 0,
        nfev=tr.nfev,
        started=started,
        history=history,
        evaluate=False,
        cost=J,
    )
    res.notes = tr.notes()
    return res


def _failed_start(problem, method, theta0, started) -> FitResult:
    """The result for a start where the simulation already blows up, saying where."""
    why = problem.diagnose(theta0)
    if why is None:  # every simulation is finite: the sum of squares overflowed
        with np.errstate(over="ignore"):
            big = max(float(np.abs(e.y).max()) for e in problem.experiments)
        why = (
            "the cost overflows at the start although the simulation is finite (the "
            f"measured outputs reach {big:.1e}): rescale the data, e.g. to units near 1, "
            "or give weights"
        )
        return failed(problem, method, theta0, started, why)
    return failed(problem, method, theta0, started, why + " Choose another initial guess.")


def failed(problem, method, theta0, started, message, status=Status.NONFINITE_START):
    return FitResult.at(
        problem,
        method,
        theta0,
        np.ones(problem.K),
        status,
        message=message,
        nfev=1,
        started=started,
        evaluate=False,
    )
