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
from .hybrid import Hybrid
from .options import FitOptions
from .results import FitResult
from .scaling import Tracker
from .trust_region import minimize_trust_region, negative_curvature, trust_region_steps


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
    hybrid = Hybrid.for_method(method, problem.K)
    # what each path may raise: SciPy's baselines give up in their own ways; the
    # eigen-solver of an exact subproblem may not converge on a Hessian at the edge
    # of overflow. Anything else is a bug and is not hidden.
    expected = (ValueError, ArithmeticError) * (method in BASELINES) + (np.linalg.LinAlgError,)
    try:
        if method in BASELINES:
            phi, nit, status, detail = run_baseline(method, tr, phi0, options, record)
        elif hybrid is not None:  # methods "auto" and "newton"
            r = _auto(tr, hybrid, phi0, options, record)
            phi, nit, status, detail, nhev = r.x, r.nit, r.status, r.detail, r.nhev
        else:
            fun, opts = _derivatives(method, tr), options.trust_region()
            r = minimize_trust_region(fun, phi0, lo, hi, fatol=tr.fatol, callback=record, **opts)
            phi, nit, status, detail, nhev = r.x, r.nit, r.status, r.detail, r.nhev
    except expected as e:
        detail = f"{method} raised {type(e).__name__}: {e}"
        status = Status.SOLVER_FAILED
        if tr.best_phi is None:
            return _with(hybrid, failed(problem, method, theta0, started, detail, status))
        phi, nit = tr.best_phi, len(history)
    except KeyboardInterrupt:
        return _with(hybrid, interrupted(tr, method, started, history))
    try:
        res = _finish(tr, method, phi, nit, status, detail, started, history)
    except KeyboardInterrupt:  # while evaluating the end point: keep the best seen
        return _with(hybrid, interrupted(tr, method, started, history))
    res.nhev = nhev
    return _with(hybrid, res)


def _with(hybrid: Hybrid | None, res: FitResult) -> FitResult:
    """``res``, with what method "auto" used (on every path, failures included)."""
    if hybrid is not None:
        res.hybrid = hybrid.report()
    return res


def _auto(tr: Tracker, hybrid: Hybrid, phi0, options: FitOptions, record):
    """The trust-region run of method "auto", on past a saddle where Gauss-Newton
    converged but ∇²J curves downward (once: the restart runs in exact mode)."""
    lo, hi = tr.box()
    fun = _derivatives("auto", tr, hybrid)
    r = minimize_trust_region(
        fun, phi0, lo, hi, fatol=tr.fatol, callback=_observed(record, hybrid),
        **options.trust_region(),
    )  # fmt: skip
    if _at_saddle(tr, hybrid, r, options):
        more = minimize_trust_region(
            fun, r.x, lo, hi, fatol=tr.fatol,
            callback=_observed(_after(record, r.nit, r.nfev), hybrid),
            **(options.trust_region() | {"maxiter": options.maxiter - r.nit}),
        )  # fmt: skip
        more.nit += r.nit
        more.nhev += r.nhev
        if more.status is Status.MAXITER:
            more.detail = f"maxiter={options.maxiter}"
        r = more
    return r


def _observed(record, hybrid: Hybrid):
    """A trust-region callback that shows each step to ``hybrid`` first."""

    def both(entry):
        hybrid.observe(entry)
        record(entry)

    return both


def _derivatives(method: str, tr: Tracker, hybrid: Hybrid | None = None):
    """φ -> scaled (J, g, H or v -> Hv) for an exact-derivative method; for "auto",
    the sweep and the model ``hybrid`` chooses."""
    problem = tr.problem
    if method == "newton-cg":
        return tr.derivs_hessp
    if method != "auto":
        return tr.derivs(problem.cost_grad_hess if method == "newton" else problem.cost_grad_gn)
    assert hybrid is not None

    def fun(phi):
        theta, exact = tr.theta(phi), hybrid.exact
        if exact:
            J, g, H, G = problem.cost_grad_hess_gn(theta)
        else:
            (J, g, G), H = problem.cost_grad_gn(theta), None
        return hybrid.take(phi, *tr.scaled(phi, J, g, G), _scaled_hessian(tr, J, H), exact)

    return fun


def _scaled_hessian(tr: Tracker, J, H):
    """H in the tracker's scaled units (None stays None, as does a failed point's)."""
    return tr.scaled_hessian(H) if np.isfinite(J) else None


def _at_saddle(tr: Tracker, hybrid: Hybrid, r, options: FitOptions) -> bool:
    """Did a run that ended in Gauss-Newton mode stop where ∇²J has negative
    curvature along the unknowns off their bounds? Then ``hybrid`` goes exact."""
    if hybrid.checked or not r.status.success or r.nit >= options.maxiter:
        return False
    hybrid.checked = True
    theta = tr.theta(r.x)
    J, g, H = tr.problem.cost_grad_hess(theta)
    lo, hi = tr.problem.lower, tr.problem.upper
    tol = 1e-12 * (1 + np.abs(theta))
    off = (theta > lo + tol) & (theta < hi - tol)
    tr.known = (theta, J, g, H)  # the result at this point needs them too
    if not np.isfinite(J) or not negative_curvature(_scaled_hessian(tr, J, H)[np.ix_(off, off)]):
        return False
    hybrid.restart_exact()
    return True


def _after(record, iterations: int, evaluations: int):
    """A recorder whose counts continue from a run's (its iteration 0, the restart
    point, is that run's last and already recorded)."""

    def shifted(entry):
        if entry["iteration"] > 0:
            it, nfev = entry["iteration"] + iterations, entry["nfev"] + evaluations
            record(dict(entry, iteration=it, nfev=nfev))

    return shifted


def _lockstep(problem, method, trackers: dict, options, started, results) -> list:
    """The trust-region runs of several starts, their points evaluated together."""
    runs, pending = {}, {}
    for i, tr in trackers.items():
        history: list[dict] = []
        hybrid = Hybrid.for_method(method, problem.K)
        record = tr.recorder(history, None)
        callback = record if hybrid is None else _observed(record, hybrid)
        steps = _steps(tr, tr.phi(tr.theta0), options, callback)
        runs[i] = [tr, steps, history, hybrid, 0]  # 0: iterations before a restart
        pending[i] = next(steps)
    try:
        _march_together(problem, method, runs, pending, options, started, results)
    except KeyboardInterrupt:  # every unfinished start keeps its best point
        for i in pending:
            tr, _, history, hybrid, _ = runs[i]
            results[i] = _with(hybrid, interrupted(tr, method, started, history))
    return results


def _steps(tr: Tracker, phi, options: FitOptions, callback, maxiter=None):
    lo, hi = tr.box()
    kw = options.trust_region() | ({} if maxiter is None else {"maxiter": maxiter})
    return trust_region_steps(phi, lo, hi, fatol=tr.fatol, callback=callback, **kw)


def _march_together(problem, method, runs, pending, options, started, results) -> None:
    """Evaluate the pending points of every unfinished start together, until none is
    left; ``results`` is filled in as starts finish."""
    while pending:
        values = _evaluate_together(problem, method, runs, pending, len(results))
        for i, value in values.items():
            tr, steps, history, hybrid, before = runs[i]
            try:
                pending[i] = steps.send(value)
            except StopIteration as done:
                r = done.value
                r.nit += before
                if hybrid is not None and _at_saddle(tr, hybrid, r, options):
                    record = _observed(_after(tr.recorder(history, None), r.nit, r.nfev), hybrid)
                    runs[i][1] = _steps(tr, r.x, options, record, options.maxiter - r.nit)
                    runs[i][4] = r.nit
                    pending[i] = next(runs[i][1])
                    continue
                if before and r.status is Status.MAXITER:
                    r.detail = f"maxiter={options.maxiter}"
                res = _finish(tr, method, r.x, r.nit, r.status, r.detail, started, history)
                results[i] = _with(hybrid, res)
                del pending[i]  # only once finished: Ctrl-C in _finish keeps it pending
            except np.linalg.LinAlgError as e:  # as in _single: this start ends, not the batch
                del pending[i]
                phi = tr.phi(tr.theta0) if tr.best_phi is None else tr.best_phi
                detail = f"{method} raised LinAlgError: {e}"
                status = Status.SOLVER_FAILED
                res = _finish(tr, method, phi, len(history), status, detail, started, history)
                results[i] = _with(hybrid, res)


def _evaluate_together(problem, method, runs, pending, B) -> dict:
    """Scaled (J, g, H) at every pending point, in one vectorised call padded to B
    points (one compilation). For "auto", one second-order sweep for all as soon as
    any start is in exact mode (the others use its Gauss-Newton part: one sweep of B
    costs less than two), else a first-order one."""
    hybrids = [runs[i][3] for i in pending]
    if hybrids[0] is not None:  # "auto" and "newton"
        kind = "both" if any(h.exact for h in hybrids) else "gn"
    else:
        kind = "exact" if method == "newton" else "gn"
    ids = list(pending)
    points = [runs[i][0].theta(pending[i]) for i in ids]
    points += [points[0]] * (B - len(ids))
    vals = problem.cost_grad_hess_batch(
        np.array(points), gauss_newton=kind == "gn", both=kind == "both"
    )
    out = {}
    for k, i in enumerate(ids):
        tr, hybrid, phi = runs[i][0], runs[i][3], pending[i]
        J, g, H = vals[0][k], vals[1][k], vals[2][k]
        if hybrid is None:
            out[i] = tr.scaled(phi, J, g, H)
        elif kind == "both":  # the Gauss-Newton part, and ∇²J where the start asked for it
            exact = _scaled_hessian(tr, J, H) if hybrid.exact else None
            out[i] = hybrid.take(phi, *tr.scaled(phi, J, g, vals[3][k]), exact, hybrid.exact)
        else:
            out[i] = hybrid.take(phi, *tr.scaled(phi, J, g, H), None, False)
    return out


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
        known=tr.known,
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
