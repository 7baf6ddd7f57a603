"""Fitting with a robust loss: from the least-squares estimate, with a scale that the
fit's own residuals check.

A robust loss treats residuals beyond its scale c as outliers (see engine/sweeping/losses.py),
and its cost is not convex there: far from the optimum, where most residuals are
beyond c, Cauchy's and Student-t's gradients fade and a trust-region method can
crawl into a wrong basin. So, as robust regression usually is (IRLS starts from
ordinary least squares), a robust fit runs in stages:

1. the same problem with the squared loss, from the given start(s) (least squares
   converges from far away, and gross outliers only pull it off by a little);
2. where the scale was estimated, it is set from that fit's residuals:
   c = TUNING × σ̂, σ̂ = 1.4826 · median |r − median r| per output (the median
   absolute deviation ignores the outliers; the data-only estimate from second
   differences overstates the noise wherever the signal is not smooth at the
   sampling rate, and a c too large makes Huber least squares);
3. the robust fit from the least-squares estimate;
4. while the scale was estimated and the robust fit's residuals imply one that
   differs by more than RESCALE, the fit is repeated with it (at most ROUNDS times),
   as MATLAB's robustfit and statsmodels' RLM re-estimate the scale.

A scale the user gave is never changed. The result's notes say what was done.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from ..engine.schemes.status import Status
from ..engine.sweeping.losses import robust_sd

RESCALE = 1.5  # a factor: closer than this, the scale is left as it is
ROUNDS = 3


def residual_noise(res) -> np.ndarray:
    """(S,) each output's noise level from the fit's residuals, by the median absolute
    deviation (robust to the outliers a robust loss is for)."""
    exps = res.problem.experiments
    r = np.concatenate([e.y - s.y for e, s in zip(exps, res.simulate(), strict=True)])
    seen = np.concatenate([e.seen for e in exps])  # (not a gap, nor a dose's row)
    # an output measured nowhere: NaN (no level; its scale stays the placeholder)
    return np.array([robust_sd(r[seen[:, j], j]) if seen[:, j].any() else np.nan
                     for j in range(r.shape[1])])  # fmt: skip


def _implied(problem, res) -> dict | None:
    """The scale the residuals of ``res`` imply, where it differs from the one
    ``problem`` uses by more than RESCALE on an output that counts (else None)."""
    implied = problem.loss.tuning * residual_noise(res)
    used = np.array(list(problem.loss_scale.values()))
    # an output of weight 0, or measured nowhere, keeps a placeholder scale
    counts = (problem.weights > 0) & ~np.isnan(implied)
    if not (implied[counts] > 0).all():
        return None
    if np.all(np.abs(np.log(implied[counts] / used[counts])) < np.log(RESCALE)):
        return None
    scale = np.where(counts & (implied > 0), implied, used)
    return dict(zip(problem.model.outputs, scale.tolist(), strict=True))


def fit_robust(problem, first, refit):
    """Stages 2-4 of the module docstring. ``first``: stage 1's result (the squared
    loss, with its priors' noise level checked); ``refit(problem, theta)`` fits a
    problem from one start."""
    if first.status is Status.INTERRUPTED:
        return first
    estimated, spent = problem.loss_scale_estimated, [first]
    # the robust problem on the least-squares one's settings (its priors' noise level
    # already checked against its residuals), with the loss and scale asked for
    given = None if estimated else problem.loss_scale
    robust = first.problem.with_loss(problem.loss, given)
    notes, source = [], "the outputs"
    if not np.isfinite(first.cost):
        notes.append(f"the least-squares stage failed ({first.message}); the "
                     f"{problem.loss.name} fit ran from the start")  # fmt: skip
    else:
        notes.append(
            f"the {problem.loss.name} fit started from the least-squares estimate (cost "
            f"{first.cost:.6g}, {first.nit} iterations, {first.status})"
        )
        scale = _implied(robust, first) if estimated else None
        robust = robust.with_loss(problem.loss, scale, estimated=True) if scale else robust
        source = "the least-squares fit's residuals" if scale else "the outputs"
    res = refit(robust, first.theta)
    for _ in range(ROUNDS if estimated else 0):
        scale = _implied(res.problem, res) if res.success else None
        if scale is None:
            break
        spent.append(res)
        res = refit(res.problem.with_loss(problem.loss, scale, estimated=True), res.theta)
        source = f"the residuals of the {problem.loss.name} fit"
    if estimated:
        scale = ", ".join(f"{k} {v:.3g}" for k, v in res.problem.loss_scale.items())
        refits = len(spent) - 1
        again = f" ({refits} refit(s) as it moved)" if refits else ""
        notes.append(f"its scale, {scale}, came from {source}{again}; give loss_scale= to fix it")
    if first.starts:
        notes.append(f"its starts were ranked by the least-squares stage ({len(first.starts)})")
    return replace(
        res,
        notes=first.notes + notes + res.notes,
        starts=first.starts,
        seconds=res.seconds + sum(r.seconds for r in spent),
        stats=res.stats.plus(
            nfev=sum(r.nfev for r in spent), nit_total=sum(r.nit_total for r in spent)
        ),
    )
