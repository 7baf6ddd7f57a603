"""fit() and fit_batch(): estimate θ with the exact-derivative trust-region methods,
or with the finite-difference baselines the paper compares against, from one start,
a batch of starts in lock-step, or many starts on workers (the best refined).

The checks of the user's arguments live here; the iterations in driver.py. Every
method works on scaled variables (see scaling.py); whatever a method does, the
result holds the best finite point it evaluated: a fit never returns NaN.
"""

from __future__ import annotations

import functools
import os
import time

import numpy as np

from ..engine.compilation import compile_clock
from ..engine.problem import Problem
from ..engine.status import Status
from .baselines import BASELINES
from .driver import failed, fit_many
from .multistart import SAMPLINGS, StartsStopped, draw_starts, ranked_starts, run_starts
from .options import FitOptions
from .priors import weigh_priors, weighed
from .results import FitInterrupted, FitResult
from .robust import fit_robust
from .shooting import fit_shooting

METHODS = ("auto", "newton", "newton-cg", "gauss-newton", *BASELINES)
LOCKSTEP = ("auto", "newton", "gauss-newton")  # methods whose starts can share vmapped calls


def fit(
    problem: Problem,
    method: str = "auto",
    *,
    theta0=None,
    starts: int | None = None,
    spread: float | None = None,
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
    timeout: float | None = None,
    polish: bool = True,
) -> FitResult:
    """Estimate the free initial states and parameters of ``problem``.

    method:
      "auto"          (default) Gauss-Newton while it converges fast, the exact
                      Hessian where it does not or at a saddle (see hybrid.py)
      "newton"        trust-region Newton with the exact Hessian from transition tensors
      "newton-cg"     trust-region Newton with truncated CG on exact Hessian-vector
                      products (one sweep of 2K + 1 state copies each, against
                      1 + K + K(K+1)/2 for the full Hessian): for many unknowns
      "gauss-newton"  trust-region Gauss-Newton (Levenberg-Marquardt) with the exact
                      Jacobian from first-order sensitivities
      "fd-bfgs"       BFGS (L-BFGS-B with bounds) with a finite-difference gradient
      "fd-lsq"        scipy least_squares (trf) with a finite-difference Jacobian, as
                      MATLAB's grey-box toolbox does
    theta0 : start (K,), natural units; default ``problem.theta0``.
    x_scale, maxiter, gtol, ftol, xtol, callback : see :class:`FitOptions` (or options=).
    starts : with N > 1, fit from theta0 and N - 1 further starts (inside the bounds,
        within ``spread`` of theta0 or across the box: see ``draw_starts``; Latin
        hypercube or uniform ``sampling``, seeded), in parallel through ``executor`` (any
        concurrent.futures.Executor, e.g. a Dask ``client.get_executor()``) or a local
        process pool of ``workers``; the best is refined and returned, with every start
        ranked in ``result.starts``. The local pool spawns fresh processes, which
        re-import the calling script: guard a script's top level with
        ``if __name__ == "__main__":``.
    batch : with starts, fit this many starts per task in lock-step, evaluated in one
        jax.vmap call (see fit_batch; auto, newton, gauss-newton; 1.5x the throughput on
        Silverbox). Default: the starts shared evenly over the local workers (at most
        16 per task) for those methods, one start per task otherwise.
    timeout : seconds to wait for the next start to finish on workers; then the best
        finished start is returned, status ``WORKERS_LOST``. Default: wait.
    polish : with segments (multiple shooting: "auto", "newton" and "newton-cg" by
        the exact Lagrangian Hessian, or "gauss-newton"), end with single shooting
        from its solution (default); ``result.shooting`` reports the stage.
    Ctrl-C stops the fit at once, workers included, raising :class:`FitInterrupted`
    (a KeyboardInterrupt) whose ``result`` is the best point so far.
    """
    started = time.perf_counter()
    _check_method(problem, method)
    options = _options(options, x_scale, maxiter, gtol, ftol, xtol, callback, polish)
    theta0 = _check_start(problem, problem.theta0 if theta0 is None else theta0, "theta0")
    if starts is not None:
        _check_count("starts", starts)
    n = 1 if starts is None else int(starts)
    if n > 1:
        batch = _check_batch(method, batch, n, executor, workers)
        _check_multistart(spread, sampling, workers, timeout)
    with compile_clock() as clock:  # this process's compilations (not the workers')
        if n > 1:
            lo, hi = problem.lower, problem.upper
            thetas = draw_starts(theta0, lo, hi, n, spread=spread, sampling=sampling, seed=seed)
            where = (executor, workers, int(batch or 1), timeout)
        else:
            thetas, where = theta0[None, :], None
        res = _starts(problem, method, thetas, options, where, started)
    res.compile_seconds = clock[0]
    if res.status is Status.INTERRUPTED:
        raise FitInterrupted(res)
    return res


def _starts(problem, method, thetas, options, where, started) -> FitResult:
    """One start (``where`` None) or many on workers, the best refined; a robust loss
    in stages, from the least-squares estimate (robust.py)."""
    if problem.loss.robust:
        first = _starts(problem.with_loss("squared"), method, thetas, options, where, started)
        return fit_robust(
            problem,
            first,
            lambda p, th: weighed(_fits)(p, method, th[None, :], options, time.perf_counter())[0],
        )
    if where is None:
        return weighed(_fits)(problem, method, thetas, options, started)[0]
    return _many_starts(problem, method, thetas, options, where, started)


def fit_batch(problem: Problem, method: str, thetas, **options) -> list[FitResult]:
    """Fits from every row of ``thetas`` (B, K) in lock-step: at each iteration the
    points of all unfinished starts are evaluated in one vectorised (jax.vmap) call,
    which costs far less than B separate calls on a CPU. Methods "auto", "newton"
    and "gauss-newton"; options as for :func:`fit` (x_scale, maxiter, gtol, ftol,
    xtol, or options=FitOptions(...)). Each result is what
    ``fit(problem, method, theta0=row)`` returns; its ``seconds`` and
    ``compile_seconds`` are those of the whole batch — except for a robust loss,
    which is fitted as given here (no least-squares stage, no scale check: use
    :func:`fit` for those). Ctrl-C raises :class:`FitInterrupted` with every start's
    best point so far."""
    started = time.perf_counter()
    if method not in LOCKSTEP:
        raise ValueError(
            f"batched starts work with 'auto', 'newton' and 'gauss-newton', not {method!r}; "
            "use batch=1"
        )
    opts = options.pop("options", None)
    if opts is None:
        allowed = {"x_scale", "maxiter", "gtol", "ftol", "xtol", "polish"}
        if set(options) - allowed:
            raise TypeError(f"fit_batch got unexpected options {sorted(set(options) - allowed)}")
        opts = FitOptions(**options)
    elif options:
        raise ValueError("pass either options=FitOptions(...) or keyword options, not both")
    thetas = np.atleast_2d(np.asarray(thetas, dtype=float))
    thetas = np.stack([_check_start(problem, th, "a start") for th in thetas])
    with compile_clock() as clock:
        results = weighed(_fits)(problem, method, thetas, opts, started)
    for r in results:
        r.compile_seconds = clock[0]
    if any(r.status is Status.INTERRUPTED for r in results):
        best = min(results, key=lambda r: (not np.isfinite(r.cost), r.cost))
        raise FitInterrupted(best, results)
    return results


# -- checks -----------------------------------------------------------------------------
def _options(options, x_scale, maxiter, gtol, ftol, xtol, callback, polish=True) -> FitOptions:
    """``options``, or the keywords as FitOptions; both at once is an error (one of them
    would be silently ignored)."""
    if options is None:
        return FitOptions(x_scale, maxiter, gtol, ftol, xtol, callback=callback, polish=polish)
    d = FitOptions()
    changed = not (isinstance(x_scale, str) and x_scale == d.x_scale) or callback is not None
    changed |= polish is not True
    changed |= (maxiter, gtol, ftol, xtol) != (d.maxiter, d.gtol, d.ftol, d.xtol)
    if changed:
        raise ValueError(
            "give either options=FitOptions(...) or x_scale/maxiter/gtol/ftol/xtol/"
            "callback/polish, not both"
        )
    if not isinstance(options, FitOptions):
        raise TypeError(f"options must be a tensorid.FitOptions, got {type(options).__name__}")
    return options


def _check_method(problem, method) -> None:
    if not isinstance(problem, Problem):
        raise TypeError(f"fit needs a tensorid.Problem, got {type(problem).__name__}")
    if method not in METHODS:
        raise ValueError(f"unknown method {method!r}; choose one of {list(METHODS)}")
    if problem.shooting is not None and method in BASELINES:
        raise ValueError(
            f"method {method!r} is single shooting only; with segments (multiple "
            "shooting) use 'auto', 'newton' or 'gauss-newton', or drop the segments"
        )


def _fits(problem, method, thetas, options: FitOptions, started) -> list[FitResult]:
    """Fits from every row of ``thetas``: by multiple shooting (one after another) when
    the problem has segments, else by the driver (lock-step for several)."""
    if problem.shooting is None:
        return fit_many(problem, method, thetas, options, started)
    out: list[FitResult] = []
    for th in thetas:
        if out and out[-1].status is Status.INTERRUPTED:  # Ctrl-C ends the batch
            out.append(
                FitResult.at(problem, method, th, np.ones(problem.K), Status.INTERRUPTED,
                             started=started, evaluate=False, cost=problem.cost(th))
            )  # fmt: skip
        else:
            out.append(fit_shooting(problem, method, th, options, started))
    return out


def _check_start(problem: Problem, theta, what: str) -> np.ndarray:
    theta = problem.check_theta(theta)
    if ((theta < problem.lower) | (theta > problem.upper)).any():
        raise ValueError(f"{what} lies outside the bounds")
    return theta


def _check_count(name: str, n) -> None:
    if isinstance(n, bool) or not isinstance(n, int | np.integer) or n < 1:
        raise ValueError(f"{name} must be a positive integer, got {n!r}")


def _check_multistart(spread, sampling, workers, timeout) -> None:
    if spread is not None and not (
        isinstance(spread, int | float) and np.isfinite(spread) and spread >= 0
    ):
        raise ValueError(f"spread must be a finite number >= 0, got {spread!r}")
    if sampling not in SAMPLINGS:
        raise ValueError(f"sampling must be one of {SAMPLINGS}, got {sampling!r}")
    if workers is not None:
        _check_count("workers", workers)
    if timeout is not None and not (
        isinstance(timeout, int | float) and not isinstance(timeout, bool) and timeout > 0
    ):
        raise ValueError(f"timeout must be a number of seconds > 0, got {timeout!r}")


def _check_batch(method, batch, starts, executor, workers) -> int:
    if batch is None:
        if method in LOCKSTEP and executor is None:
            return min(16, -(-starts // (workers or os.cpu_count() or 1)))
        return 1
    _check_count("batch", batch)
    if batch > 1 and method not in LOCKSTEP:
        raise ValueError(
            f"batch > 1 works with 'auto', 'newton' and 'gauss-newton', not {method!r}; use batch=1"
        )
    return int(batch)


# -- many starts --------------------------------------------------------------------------
def fit_task(method: str, options: FitOptions):
    """The task that multistart.run_starts sends to workers: fit each start of a
    chunk with ``method`` (the caller's callback stays behind)."""
    return functools.partial(_fit_chunk, method=method, options=options.without_callback())


def _many_starts(problem, method, thetas, options: FitOptions, where: tuple, started):
    """Fits from every row of ``thetas`` on workers (``where``: executor, workers,
    batch, timeout), the best refined; or, if they cannot all finish, the best of
    those that did."""
    try:
        runs = run_starts(problem, fit_task(method, options), thetas, *where)
    except StartsStopped as stop:
        return _stopped(problem, method, thetas[0], stop, started)
    res = _best_of(problem, method, thetas[0], runs, options, started)
    return weigh_priors(res, _fits, method, options, started)


def _fit_chunk(problem, thetas, *, method: str, options: FitOptions) -> list[dict]:
    """Worker side: fit from each row of ``thetas`` (in lock-step when several)."""
    thetas = np.asarray(thetas, dtype=float)
    results = _fits(problem, method, thetas, options, time.perf_counter())
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
            "shooting": res.shooting,
        }
        for th, res in zip(thetas, results, strict=True)
    ]


def _best_of(problem, method, theta0, runs: list[dict], options: FitOptions, started):
    """Rank the starts, refine the best here (where the caller's callback can watch
    it), and report the best start's own run (nit, nfev_best, history) beside the
    totals of all of them (nit_total, nfev)."""
    for i, r in enumerate(runs):
        r["start"] = i
    ranked = ranked_starts(runs)
    best = ranked[0]
    histories = {r["start"]: r.pop("history") for r in runs}
    nit_all, nfev_all = sum(r["nit"] for r in runs), sum(r["nfev"] for r in runs)
    if not np.isfinite(best["cost"]):
        status = Status.ALL_STARTS_FAILED
        res = failed(problem, method, theta0, started, status.message, status)
        res.nit, res.nit_total, res.nfev, res.nfev_best = 0, nit_all, nfev_all, 0
    else:
        res = _refined(problem, method, best, options, started)
        own = histories[best["start"]]
        # the refinement restarts its count (the trust region records an iteration 0)
        offset = own[-1]["iteration"] if own else best["nit"]
        more = [h for h in res.history if not (h["iteration"] == 0 and own)]
        res.history = own + [dict(h, iteration=h["iteration"] + offset) for h in more]
        res.nit_total, res.nfev = nit_all + res.nit, nfev_all + res.nfev
        res.nfev_best = best["nfev"] + res.nfev_best
        res.nit += best["nit"]
    res.starts = ranked
    res.seconds = time.perf_counter() - started
    return res


def _refined(problem, method, best: dict, options: FitOptions, started) -> FitResult:
    """The best start refined by single shooting; with segments and no polish, the
    best start's own multiple-shooting solution as it is (refining it would polish)."""
    theta = np.asarray(best["theta"])
    if problem.shooting is not None and not options.polish:
        status = Status[best["status"].upper()]
        res = FitResult.at(problem, method, theta, np.ones(problem.K), status,
                           message=best["message"], started=started)  # fmt: skip
        res.nit = res.nfev = res.nfev_best = 0
    else:
        res = fit_many(problem, method, theta[None, :], options, started)[0]
    res.shooting = best.get("shooting")
    return res


def _stopped(problem, method, theta0, stop: StartsStopped, started) -> FitResult:
    """The result when the starts could not all finish: the best of those that did,
    not refined (the user is waiting, or the workers are gone)."""
    runs = ranked_starts(stop.runs)
    which = ", ".join(str(i) for i in sorted(r["start"] for r in runs))
    finished = f"{len(runs)} of {stop.total} starts finished" + (f": {which}" if runs else "")
    best = runs[0] if runs and np.isfinite(runs[0]["cost"]) else None
    res = FitResult.at(
        problem,
        method,
        np.asarray(best["theta"]) if best else theta0,
        np.ones(problem.K),
        stop.status,
        message=stop.status.describe(f"{stop.detail}; {finished}"),
        nit=best["nit"] if best else 0,
        nfev=sum(r["nfev"] for r in runs),
        started=started,
        history=best["history"] if best else [],
        evaluate=False,
        cost=best["cost"] if best else np.inf,
    )
    res.nit_total = sum(r["nit"] for r in runs)
    res.starts = [{k: v for k, v in r.items() if k != "history"} for r in runs]
    return res
