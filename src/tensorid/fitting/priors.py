"""Priors that weigh what they should.

A prior adds σ² Σ((θᵢ − mean)/sd)² to J, σ² the noise variance of a unit-weight
residual: ``noise=``² when given, else estimated from the outputs' second differences,
which holds only where the noise, not the signal, dominates them. A wrong σ² weighs
every prior by the same wrong factor (1,770× on the README's oscillator at 1 kHz).

After a MAP fit, :func:`weigh_priors` compares that σ² with the residual variance at
the optimum. Where σ² was estimated and the two differ by more than ``TOLERANCE``,
σ² becomes the residual variance and the fit is repeated from its optimum (empirical
Bayes), until they agree (at most ``MAX_REFITS`` refits; each takes a few iterations).
A σ² the user gave is kept, and a disagreement beyond both that factor and the
residual variance's chance scatter is a warning that names both. Then
:func:`prior_moves` says how far each prior moved its estimate in standard errors of
the data alone, so that a strong or wrong prior is never silent. The measurements
behind the rule are in docs/statistics.md.
"""

from __future__ import annotations

import copy
from dataclasses import replace

import numpy as np

from ..analysis import quantiles
from ..analysis.prior_effects import (
    FIX,
    MOVED,
    STEPS,
    TOLERANCE,
    NoiseCheck,
    data_only,
    move_lines,
    prior_moves,
)
from ..analysis.residuals import residual_count, too_few
from ..engine.schemes.status import Status
from .robust import residual_noise

# NoiseCheck, prior_moves, data_only and move_lines read a result (analysis/
# prior_effects.py); here, the stage that re-checks the noise level and refits
__all__ = [
    "FIX",
    "MAX_REFITS",
    "MOVED",
    "STEPS",
    "TOLERANCE",
    "NoiseCheck",
    "data_only",
    "move_lines",
    "prior_moves",
    "weigh_priors",
    "weighed",
]

MAX_REFITS = 10  # from the README example's 1,770×, 4 refits reach the tolerance


def weighed(fits):
    """``fits`` (problem, method, thetas, options, started -> results) with every
    result then passed through :func:`weigh_priors`, its refits made by ``fits``."""

    def run(problem, method, thetas, options, started):
        done = fits(problem, method, thetas, options, started)
        return [weigh_priors(r, fits, method, options, started) for r in done]

    return run


def _residual_variance(res) -> float:
    """The variance of a unit-weight residual at the fit: the data's share of J over
    n − K for the squared loss; for a robust loss, whose J is not Σ w r², each counted
    output's weighted residuals' median absolute deviation (× 1.4826, squared),
    averaged, so that the outliers it is robust to do not inflate it either."""
    if res.problem.loss.squared:
        return res.uncertainty().sigma2
    w = res.problem.weights
    return float(np.mean((w * residual_noise(res) ** 2)[w > 0]))


def weigh_priors(res, fits, method, options, started):
    """``res`` after the check of its priors' noise variance, refitted where it was
    estimated and disagrees with the residuals: by ``fits(problem, method, thetas,
    options, started)``, from the optimum, on a copy of the problem with σ² changed.
    The result's ``problem`` is that copy; the caller's Problem is left as it was."""
    problem = res.problem
    if not problem.priors or not res.success or not res.has_uncertainty:
        return res
    if problem.loss.likelihood:  # J is −2 log L: the priors' weight 1 is exact, no σ²
        return res
    first, done, refits = problem.noise_variance, res, 0
    residual = _residual_variance(done)
    floor = problem.rounding_floor / max(done.uncertainty().dof, 1)
    # no more residuals than unknowns: the residuals say nothing of the noise (a
    # robust loss's spread of them is a number all the same), so no refit and no check
    few = too_few(residual_count(problem), done.theta.size, what="a residual variance")
    while (
        problem.noise_estimated
        and not few
        and not _agree(done.problem.noise_variance, residual)
        and refits < MAX_REFITS
        and residual > 0
    ):
        again = fits(
            _with_noise(done.problem, max(residual, floor)),
            method,
            done.theta[None, :],
            options,
            started,
        )[0]
        refits += 1
        if again.status is Status.INTERRUPTED:  # Ctrl-C: fit() raises with this point
            return _chained(done, again)
        if not again.success or not again.has_uncertainty:
            break  # keep the last fit that converged, and say the check did not settle
        done = _chained(done, again)
        residual = _residual_variance(done)
    used = done.problem.noise_variance
    if problem.noise_estimated:
        source, agree = "second differences", _agree(used, residual)
    else:  # the user's word: only a clear disagreement is worth a warning
        dof = done.uncertainty().dof
        source, agree = "given", _agree(used, residual) or _chance(used, residual, dof)
    agree = agree and not few  # nothing to agree with: said, never passed as agreement
    check = NoiseCheck(source, first, used, residual, refits, agree, _per_output(done), few)
    return replace(done, noise_check=check)


def _agree(a: float, b: float) -> bool:
    return bool(b > 0 and a > 0 and max(a / b, b / a) <= TOLERANCE)


def _chance(variance: float, residual: float, dof: int) -> bool:
    """Whether noise of ``variance`` leaves a residual variance like ``residual`` one
    time in a hundred or more (χ² with ``dof`` degrees of freedom): a short record's
    residual variance scatters by √(2/dof), 23 % at 40 samples."""
    lo, hi = quantiles.chi2(dof, 0.005) / dof, quantiles.chi2(dof, 0.995) / dof
    return bool(lo <= residual / variance <= hi)


def _with_noise(problem, variance: float):
    """A shallow copy of ``problem`` whose priors are weighed by ``variance`` (its
    compiled sweeps shared; a multiple-shooting layout pointed at the copy)."""
    out = copy.copy(problem)
    out.noise_variance = float(variance)
    if problem.shooting is not None:
        out.shooting = copy.copy(problem.shooting)
        out.shooting.problem = out
    return out


def _chained(before, after):
    """``after`` (a refit from ``before``'s optimum) counting both runs (see
    Solution.followed_by), with ``before``'s starts."""
    return before.followed_by(
        after, starts=before.starts, shooting=after.shooting or before.shooting,
        notes=before.notes + after.notes,
    )  # fmt: skip


def _per_output(res) -> dict[str, dict[str, float]]:
    """Per output, all experiments together: the weighted second-difference variance
    (/6, as the estimate), the weighted residual variance and the second differences'
    lag-1 correlation."""
    problem, out = res.problem, {}
    sims, exps = res.simulate(), problem.experiments
    for s, name in enumerate(problem.model.outputs):
        w = float(problem.weights[s])
        seen = [e.seen[:, s] for e in exps]  # (not a gap, nor a dose's row)
        d2 = [np.diff(e.measured[m, s], n=2) for e, m in zip(exps, seen, strict=True)]
        r = [e.measured[m, s] - sim.y[m, s] for e, sim, m in zip(exps, sims, seen, strict=True)]
        ss = sum(float(d @ d) for d in d2)
        lag = sum(float(d[1:] @ d[:-1]) for d in d2)
        out[name] = {
            "second_difference_variance": w * ss / 6.0 / max(sum(d.size for d in d2), 1),
            "residual_variance": w * sum(float(x @ x) for x in r) / max(sum(x.size for x in r), 1),
            "second_difference_lag1": lag / ss if ss > 0 else float("nan"),
        }
    return out
