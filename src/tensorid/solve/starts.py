"""Fits from several starts: one after another or in lock-step here (:func:`fits`), or
on workers (:func:`many_starts`), whose results are the same Solutions, ranked, the
best refined here. multistart.py runs the workers and knows nothing of the methods.
"""

from __future__ import annotations

import functools
import time
from dataclasses import replace

import numpy as np

from ..engine.schemes.status import Status
from .constrained import keep_constraints
from .driver import fit_many
from .endings import failed, not_run, stopped
from .multistart import StartsStopped, ranked_starts, run_starts
from .options import FitOptions
from .registry import resolve
from .shooting import fit_shooting
from .solution import Solution
from .stats import Stats


def fits(problem, method, thetas, options: FitOptions, started) -> list[Solution]:
    """Fits from every row of ``thetas``: by multiple shooting (one after another) when
    the problem has segments, else by the driver (lock-step for several); with
    constraints, each by the augmented Lagrangian around them (constrained.py)."""
    if problem.constraints and problem.penalty is None:
        return [keep_constraints(problem, fits, method, th, options, started) for th in thetas]
    if problem.shooting is None:
        return fit_many(problem, method, thetas, options, started)
    out: list[Solution] = []
    for th in thetas:
        if out and out[-1].status is Status.INTERRUPTED:  # Ctrl-C ends the batch
            out.append(not_run(problem, method.name, th, started))
        else:
            out.append(fit_shooting(problem, method, th, options, started))
    return out


def fit_task(method, options: FitOptions):
    """The task that multistart.run_starts sends to workers: fit each start of a
    chunk with ``method`` (a name or a method; the caller's callback stays behind)."""
    return functools.partial(_fit_chunk, method=resolve(method), options=options.without_callback())


def _fit_chunk(problem, thetas, *, method, options: FitOptions) -> list[Solution]:
    """Worker side: fit from each row of ``thetas`` (in lock-step when several); the
    results travel back without their Problem."""
    thetas = np.asarray(thetas, dtype=float)
    return [r.detached() for r in fits(problem, method, thetas, options, time.perf_counter())]


def start_record(start: int, theta0, res: Solution) -> dict:
    """One start as ``FitResult.starts`` (and fit.json) list it."""
    return {
        "theta0": list(map(float, theta0)),
        "theta": res.theta.tolist(),
        "cost": float(res.cost),
        "success": res.success,
        "status": str(res.status),
        "nit": res.nit,
        "nfev": res.nfev,
        "seconds": res.seconds,
        "message": res.message,
        "shooting": res.shooting,
        "start": start,
    }


def many_starts(problem, method, thetas, options: FitOptions, where: tuple, started):
    """Fits from every row of ``thetas`` on workers (``where``: executor, workers,
    batch, timeout), the best refined; or, if they cannot all finish, the best of
    those that did (its status says which: the priors' check, a later stage in
    fitting/, leaves such a result as it is)."""
    try:
        done = run_starts(problem, fit_task(method, options), thetas, *where)
    except StartsStopped as stop:
        ranked = ranked_starts([start_record(i, thetas[i], r) for i, r in stop.runs.items()])
        best = ranked[0] if ranked and np.isfinite(ranked[0]["cost"]) else None
        best = stop.runs[best["start"]] if best else None
        return stopped(problem, method.name, thetas[0], stop, ranked, best, started)
    return _best_of(problem, method, thetas, done, options, started)


def _best_of(problem, method, thetas, done: list[Solution], options: FitOptions, started):
    """Rank the starts, refine the best here (where the caller's callback can watch
    it), and report the best start's own run (nit, nfev_best, history) beside the
    totals of all of them (nit_total, nfev)."""
    ranked = ranked_starts(
        [start_record(i, th, r) for i, (th, r) in enumerate(zip(thetas, done, strict=True))]
    )
    best = done[ranked[0]["start"]]
    nit_all, nfev_all = sum(r.nit for r in done), sum(r.nfev for r in done)
    if not np.isfinite(best.cost):
        status = Status.ALL_STARTS_FAILED
        stats = Stats(nit=0, nfev=nfev_all, nit_total=nit_all, nfev_best=0)
        res = failed(problem, method.name, thetas[0], started, status.message, status, stats)
    else:
        res = _refined(problem, method, best, options, started)
        starts = Stats(nit=best.nit, nfev=nfev_all, nit_total=nit_all, nfev_best=best.nfev)
        res = replace(
            res,
            history=best.history_then(res.history),
            stats=starts.then(res.stats),
        )
    return replace(res, starts=ranked, seconds=time.perf_counter() - started)


def _refined(problem, method, best: Solution, options: FitOptions, started) -> Solution:
    """The best start refined by single shooting; with segments and no polish, the
    best start's own multiple-shooting solution as it is (refining it would polish)."""
    if problem.shooting is not None and not options.polish:
        return replace(best.attached(problem), history=[], stats=Stats(nfev=0))
    res = (fits if problem.constraints else fit_many)(
        problem, method, best.theta[None, :], options, started
    )[0]
    return replace(res, shooting=best.shooting)


def fit_counts(res) -> dict:
    """fit.json's counts, one meaning each (docs/your-own-model.md): ``iterations`` and
    ``function_evaluations`` the best start's run, its refinement included (what
    ``history`` shows); ``*_total`` every start's; equal for one start."""
    return {
        "iterations": res.nit,
        "function_evaluations": res.nfev_best,
        "iterations_total": res.nit_total,
        "function_evaluations_total": res.nfev,
        "function_evaluations_best_start": res.nfev_best,
        **after_starts(res),
    }


def after_starts(res) -> dict:
    """With several starts, what the best start's counts in ``res`` (nit and nfev_best)
    hold beyond its own entry in ``res.starts``: the refinement here (and the priors'
    refits): fit.json's iterations_after_starts, function_evaluations_after_starts.
    Empty for one start, and for a robust loss (its starts ranked the least-squares
    stage, whose counts are not the robust fit's)."""
    if not res.starts or res.problem.loss.robust:
        return {}
    best = res.starts[0]
    more = {"iterations": res.nit - best["nit"]}
    more["function_evaluations"] = res.nfev_best - best["nfev"]
    if min(more.values()) < 0:  # no best start to count from (every start failed)
        return {}
    return {f"{k}_after_starts": v for k, v in more.items()}
