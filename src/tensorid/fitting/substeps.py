"""The substeps check of a fit of one system's records (a fleet's is
population/refine.py). A fixed-step scheme's substeps are per sample interval, and
where the intervals differ (an event table: a quarter of an hour after a dose, twelve
hours later; a record sampled unevenly) one number cannot suit them all. Where
doubling them moves a prediction at the estimates by more than a tenth of its
output's residual SD, the answer is the scheme's, not the model's: the default
substeps are raised fourfold and the fit repeated from its estimates (up to
MAX_SUBSTEPS), and a user's own choice is kept with a note saying so."""

from __future__ import annotations

import time
from dataclasses import replace

import numpy as np

from ..analysis.results import FitInterrupted, FitResult
from ..engine.schemes.status import Status
from ..population.refine import MAX_SUBSTEPS, coarse_note, raised_note

MOVE = 0.1  # of a residual SD: the largest move of a prediction that is no move


def uneven(problem) -> bool:
    """Whether one substeps count may be too coarse for some intervals: events, or a
    record whose longest sample interval is over twice its shortest (an evenly sampled
    record's substeps were chosen for its one interval)."""
    if problem.dosing is not None:
        return True
    dts = [np.diff(e.t) for e in problem.experiments]
    return any(dt.size and dt.max() > 2 * dt.min() for dt in dts)


def coarse_move(problem, theta) -> float | None:
    """The largest move, in residual SDs of its output, of a prediction at a measured
    sample when the substeps double at θ; None where at most MOVE, where the check does
    not apply (an adaptive or discrete scheme, a filter, multiple shooting, an even
    record) or where the simulation is not finite at θ."""
    d = problem.discretisation
    if not d.fixed_steps or problem.predictor.filters or problem.shooting or not uneven(problem):
        return None
    coarse = problem.simulate(theta)
    if any(s.status is not Status.OK for s in coarse):
        return None
    finer = problem.with_substeps(2 * d.substeps).simulate(theta)
    exps = problem.experiments
    seen = [e.seen for e in exps]
    r = np.concatenate([np.where(k, e.measured - s.y, np.nan)
                        for k, e, s in zip(seen, exps, coarse, strict=True)])  # fmt: skip
    with np.errstate(invalid="ignore"):
        n = (~np.isnan(r)).sum(axis=0)
        sd = np.sqrt(np.nansum(r**2, axis=0) / np.where(n > 0, n, np.nan))  # (NaN: nowhere)
        moved = np.concatenate([np.where(k, np.abs(b.y - a.y), 0.0)
                                for k, a, b in zip(seen, coarse, finer, strict=True)])  # fmt: skip
        moved = np.where(np.isnan(sd), 0.0, moved / np.maximum(np.nan_to_num(sd), 1e-300))
    worst = float(np.max(np.where(np.isfinite(moved), moved, np.inf)))  # (a blow-up: inf)
    return worst if worst > MOVE else None


def refined(problem, res: FitResult, refit, started: float) -> FitResult:
    """``res`` after the substeps check: the default substeps, where too coarse at the
    estimates, raised fourfold and the fit repeated from them (``refit(problem,
    theta0)``), while the check asks and MAX_SUBSTEPS allows; a note says what was done
    (or, for the user's own substeps, that they are too coarse). Ctrl-C in the check
    keeps the fit it checks (FitInterrupted)."""
    notes: list[str] = []
    worst = None
    while res.success and np.isfinite(res.cost):
        try:
            worst = coarse_move(problem, res.theta)
        except KeyboardInterrupt:
            why = (
                f"interrupted during the check of the substeps ({problem.discretisation.substeps})"
            )
            raise FitInterrupted(replace(res, notes=[*res.notes, *notes, why])) from None
        d = problem.discretisation
        if worst is None or d.chosen or d.substeps >= MAX_SUBSTEPS:
            break
        s, finer = d.substeps, problem.with_substeps(4 * d.substeps)
        again = refit(finer, res.theta)
        if again.status is Status.INTERRUPTED:  # the fit it refines is finished: kept
            why = f"interrupted in the refit at {4 * s} substeps: these are the estimates at {s}"
            raise FitInterrupted(replace(res, notes=[*res.notes, *notes, why]))
        if not np.isfinite(again.cost):
            notes.append(f"the fit could not be repeated at {4 * s} substeps from its "
                         f"estimates at {s}: these are the estimates at {s}")  # fmt: skip
            break
        again = replace(again, starts=again.starts or res.starts)  # (the starts' ranking)
        notes.append(raised_note(s, worst))
        problem, res, worst = finer, again, None
    if worst is not None:
        notes.append(coarse_note(problem.discretisation, worst))
    if not notes:
        return res
    return replace(res, notes=[*res.notes, *notes], seconds=time.perf_counter() - started)
