"""fit(): estimate θ with the exact-derivative trust-region methods, or with the
finite-difference baselines the paper compares against; one driver for a single
start, a batch of starts in lock-step, and many starts on workers.

Every method works on scaled variables (see scaling.py); whatever a method does, the
result holds the best finite point it evaluated: a fit never returns NaN.
"""

from __future__ import annotations

import functools
import os
import time

import numpy as np

from ..engine.problem import Problem
from ..engine.status import Status
from .baselines import BASELINES, run_baseline
from .multistart import SAMPLINGS, draw_starts, run_starts
from .options import FitOptions
from .results import FitResult, describe
from .scaling import Tracker
from .trust_region import minimize_trust_region, trust_region_steps

METHODS = ("newton", "newton-cg", "gauss-newton", *BASELINES)
LOCKSTEP = ("newton", "gauss-newton")  # methods whose starts can share vmapped calls


def fit(
    problem: Problem,
    method: str = "newton",
    *,
    theta0=None,
    starts: int | None = None,
    spread: float = 0.2,
    sampling: str = "lhs",
    seed: int = 0,
    executor=None,
    workers: int | None = None,
    batch: int | None = None,
    x_scale="auto",
    maxiter: int = 200,
    gtol: float = 1e-10,
    ftol: float = 1e-12,
    xtol: float = 1e-12,
    callback=None,
    options: FitOptions | None = None,
) -> FitResult:
    """Estimate the free initial states and parameters of ``problem``.

    method:
      "newton"        trust-region Newton with the exact Hessian from transition tensors
      "newton-cg"     trust-region Newton with truncated conjugate gradients on exact
                      Hessian-vector products (one forward-over-forward sweep of 2K + 1
                      state copies each, against 1 + K + K(K+1)/2 for the full
                      Hessian): for many unknowns; the final Hessian for the error
                      bars is still computed once
      "gauss-newton"  trust-region Gauss-Newton (Levenberg-Marquardt) with the exact
                      Jacobian from first-order sensitivities
      "fd-bfgs"       BFGS (L-BFGS-B with bounds) with a finite-difference gradient
      "fd-lsq"        scipy least_squares (trf) with a finite-difference Jacobian, as
                      MATLAB's grey-box toolbox does
    theta0 : start (K,), natural units; default ``problem.theta0``.
    x_scale, maxiter, gtol, ftol, xtol, callback : see :class:`FitOptions`; or pass
        ``options=FitOptions(...)`` (which then replaces them all).
    starts : with N > 1, fit from theta0 and N - 1 further starts (within the bounds
        where both are finite, else within ±spread of theta0; Latin hypercube or
        uniform ``sampling``, seeded), in parallel through ``executor`` (any
        concurrent.futures.Executor, e.g. a Dask ``client.get_executor()``) or a local
        process pool of ``workers``; the best is refined and returned, with every start
        ranked in ``result.starts``. The local pool spawns fresh processes, which
        re-import the calling script: guard a script's top level with
        ``if __name__ == "__main__":``.
    batch : with starts, fit this many starts together in each task, in lock-step,
        their evaluations vectorised into one jax.vmap call (see fit_batch; methods
        "newton" and "gauss-newton"). On a CPU this raises the throughput of each
        worker (benchmarks/bench_multistart.py: 1.5x on Silverbox). Default: the
        starts shared evenly over the local workers (at most 16 per task) for those
        methods, one start per task for the others or with an ``executor``.
    """
    started = time.perf_counter()
    _check_method(problem, method)
    if options is None:
        options = FitOptions(x_scale, maxiter, gtol, ftol, xtol, callback=callback)
    theta0 = _check_start(problem, problem.theta0 if theta0 is None else theta0, "theta0")
    if starts is not None:
        _check_count("starts", starts)
    if starts is None or starts == 1:
        return _fit_many(problem, method, theta0[None, :], options, started)[0]
    batch = _check_batch(method, batch, starts, executor, workers)
    if not (isinstance(spread, int | float) and np.isfinite(spread) and spread >= 0):
        raise ValueError(f"spread must be a finite number >= 0, got {spread!r}")
    if sampling not in SAMPLINGS:
        raise ValueError(f"sampling must be one of {SAMPLINGS}, got {sampling!r}")
    if workers is not None:
        _check_count("workers", workers)
    thetas = draw_starts(
        theta0, problem.lower, problem.upper, starts, spread=spread, sampling=sampling, seed=seed
    )
    runs = run_starts(problem, fit_task(method, options), thetas, executor, workers, batch)
    return _best_of(problem, method, runs, options, started)


def fit_batch(problem: Problem, method: str, thetas, **options) -> list[FitResult]:
    """Fits from every row of ``thetas`` (B, K) in lock-step: at each iteration the
    points of all unfinished starts are evaluated in one vectorised (jax.vmap) call,
    which costs far less than B separate calls on a CPU. Methods "newton" and
    "gauss-newton"; options as for :func:`fit` (x_scale, maxiter, gtol, ftol,
    xtol, or options=FitOptions(...)). Each result is what
    ``fit(problem, method, theta0=row)`` returns; its ``seconds`` is the wall time of
    the whole batch."""
    started = time.perf_counter()
    if method not in LOCKSTEP:
        raise ValueError(
            f"batched starts work with 'newton' and 'gauss-newton', not {method!r}; use batch=1"
        )
    opts = options.pop("options", None)
    if opts is None:
        allowed = {"x_scale", "maxiter", "gtol", "ftol", "xtol"}
        if set(options) - allowed:
            raise TypeError(f"fit_batch got unexpected options {sorted(set(options) - allowed)}")
        opts = FitOptions(**options)
    elif options:
        raise TypeError("pass either options=FitOptions(...) or keyword options, not both")
    thetas = np.atleast_2d(np.asarray(thetas, dtype=float))
    thetas = np.stack([_check_start(problem, th, "a start") for th in thetas])
    return _fit_many(problem, method, thetas, opts, started)


# -- checks -----------------------------------------------------------------------------
def _check_method(problem, method) -> None:
    if not isinstance(problem, Problem):
        raise TypeError(f"fit needs a tensorid.Problem, got {type(problem).__name__}")
    if method not in METHODS:
        raise ValueError(f"unknown method {method!r}; choose one of {list(METHODS)}")


def _check_start(problem: Problem, theta, what: str) -> np.ndarray:
    theta = problem.check_theta(theta)
    if ((theta < problem.lower) | (theta > problem.upper)).any():
        raise ValueError(f"{what} lies outside the bounds")
    return theta


def _check_count(name: str, n) -> None:
    if isinstance(n, bool) or not isinstance(n, int | np.integer) or n < 1:
        raise ValueError(f"{name} must be a positive integer, got {n!r}")


def _check_batch(method, batch, starts, executor, workers) -> int:
    if batch is None:
        if method in LOCKSTEP and executor is None:
            return min(16, -(-starts // (workers or os.cpu_count() or 1)))
        return 1
    _check_count("batch", batch)
    if batch > 1 and method not in LOCKSTEP:
        raise ValueError(
            f"batch > 1 works with 'newton' and 'gauss-newton', not {method!r}; use batch=1"
        )
    return int(batch)


# -- the driver ---------------------------------------------------------------------------
def _fit_many(problem, method, thetas, options: FitOptions, started) -> list[FitResult]:
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
    try:
        if method in BASELINES:
            phi, nit, status, detail = run_baseline(method, tr, phi0, options, record)
        else:
            if method == "newton-cg":
                fn = tr.derivs_hessp
            else:
                fn = tr.derivs(
                    problem.cost_grad_hess if method == "newton" else problem.cost_grad_gn
                )
            r = minimize_trust_region(
                fn, phi0, lo, hi, fatol=tr.fatol, callback=record, **options.trust_region()
            )
            phi, nit, status, detail, nhev = r.x, r.nit, r.status, r.detail, r.nhev
    except (ValueError, ArithmeticError, np.linalg.LinAlgError) as e:
        # SciPy's baselines give up in their own ways; an eigen-solver may fail to
        # converge on a Hessian at the edge of overflow
        if tr.best_phi is None:
            return _failed(problem, method, theta0, started, f"{type(e).__name__}: {e}")
        phi, nit, status = tr.best_phi, len(history), Status.BASELINE_STOPPED
        detail = f"{method} stopped with {type(e).__name__}: {e}"
    res = _finish(tr, method, phi, nit, status, detail, started, history)
    res.nhev = nhev
    return res


def _lockstep(problem, method, trackers: dict, options, started, results) -> list:
    """The trust-region runs of several starts, their points evaluated together."""
    gn = method == "gauss-newton"
    B = len(results)
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
                del pending[i]
                results[i] = _finish(tr, method, r.x, r.nit, r.status, r.detail, started, history)
    return results


def _finish(tr: Tracker, method, phi, nit, status, detail, started, history) -> FitResult:
    """The result at the end point, or at the best point seen if that is better."""
    problem = tr.problem
    if tr.best_phi is not None and tr.best_J < problem.cost(tr.theta(phi)):
        phi = tr.best_phi
    message = describe(status, detail)
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


def _failed_start(problem, method, theta0, started) -> FitResult:
    """The result for a start where the simulation already blows up, saying where."""
    why = problem.diagnose(theta0) or "the simulation is not finite at the start"
    return _failed(problem, method, theta0, started, why + " Choose another initial guess.")


def _failed(problem, method, theta0, started, message, status=Status.NONFINITE_START):
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


# -- many starts --------------------------------------------------------------------------
def fit_task(method: str, options: FitOptions):
    """The task that multistart.run_starts sends to workers: fit each start of a
    chunk with ``method`` (the caller's callback stays behind)."""
    return functools.partial(_fit_chunk, method=method, options=options.without_callback())


def _fit_chunk(problem, thetas, *, method: str, options: FitOptions) -> list[dict]:
    """Worker side: fit from each row of ``thetas`` (in lock-step when several)."""
    thetas = np.asarray(thetas, dtype=float)
    results = _fit_many(problem, method, thetas, options, time.perf_counter())
    return [
        {
            "theta0": list(map(float, th)),
            "theta": res.theta.tolist(),
            "cost": float(res.cost),
            "success": res.success,
            "status": str(res.status),
            "nit": res.nit,
            "nfev": res.nfev,
            "seconds": res.seconds,
            "message": res.message,
            "history": res.history,
        }
        for th, res in zip(thetas, results, strict=True)
    ]


def _best_of(problem, method, runs: list[dict], options: FitOptions, started) -> FitResult:
    """Rank the starts, refine the best here (where the caller's callback can watch
    it), and report the best start's own run beside the totals of all of them."""
    for i, r in enumerate(runs):
        r["start"] = i
    ranked = sorted(runs, key=lambda r: (not np.isfinite(r["cost"]), r["cost"]))
    best = ranked[0]
    histories = {r["start"]: r.pop("history") for r in runs}
    nit_all, nfev_all = sum(r["nit"] for r in runs), sum(r["nfev"] for r in runs)
    if not np.isfinite(best["cost"]):
        msg = describe(
            Status.ALL_STARTS_FAILED, f"none of the {len(runs)} starts gave a finite cost"
        )
        res = _failed(problem, method, problem.theta0, started, msg, Status.ALL_STARTS_FAILED)
        res.nit_total, res.nfev_total = nit_all, nfev_all
    else:
        res = _fit_many(problem, method, np.asarray(best["theta"])[None, :], options, started)[0]
        res.nit_total, res.nfev_total = nit_all + res.nit, nfev_all + res.nfev
        more = [dict(h, iteration=h["iteration"] + best["nit"]) for h in res.history[1:]]
        res.history = histories[best["start"]] + more
        res.nit += best["nit"]
        res.nfev += best["nfev"]
    res.starts = ranked
    res.seconds = time.perf_counter() - started
    return res
