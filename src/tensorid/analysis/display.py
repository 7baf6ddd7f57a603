"""A fit's display, as ``print(res)``, ``res.summary()`` and ``tensorid fit``'s console
show it: the headline, the estimates with their error bars, the metric table, the
residual tests' verdicts and, where the residuals are not shown to be white, the
robust (sandwich) error bars beside the white ones and what to trust: the
model-error check's verdict where it was made (:mod:`tensorid.analysis.model_check`).
The same text in Python and on the command line: a notebook user sees what the CLI
would have warned about."""

from __future__ import annotations

import math

import numpy as np

from .model_check import REPEATED
from .residuals import default_lags
from .summary import (
    Table,
    as_text,
    criteria_text,
    estimates_table,
    headline,
    metric_rows,
    noise_intensities,
    noise_text,
    score_notes,
)


def summary_table(res, scores=None, residual=None, check=None) -> str:
    """The estimates of a FitResult as a plain-text table, the residual verdicts, then
    the warnings and, with ``scores`` (see tensorid.analysis.validation), the metric
    table. ``residual``: the residual tests already made (else made here with the
    default lags); ``check``: the model-error check already made (else the one the
    result holds, if any)."""
    return as_text(fit_blocks(res, scores, residual, check))


def fit_blocks(res, scores=None, residual=None, check=None) -> list:
    """A FitResult's display: the headline, the estimates (with the robust standard
    errors beside the white ones where the residuals are not shown white), the metric
    table (with ``scores``), noise intensities, information, criteria, the residual
    verdicts, notes, warnings."""
    u = res.uncertainty() if res.has_uncertainty else None
    if residual is None and math.isfinite(res.cost) and res.derivatives:
        residual = _tests(res)  # not for an interrupted fit: it must end at once
    robust = _robust(res) if u is not None and _doubtful(residual) else None
    title = f"{res.problem.model.name}: {'converged' if res.success else 'NOT converged'}"
    names = res.problem.theta_names
    blocks: list = [headline(res), estimates_table(names, res.theta, u, title, robust)]
    if scores:
        blocks.append(Table(None, *metric_rows(scores)))
        blocks += score_notes(scores)
    if res.constraints is not None:  # values, activity, multipliers; the bars' meaning
        blocks += res.constraints.blocks()
    noise = noise_intensities(res, u)
    if noise:
        blocks.append(noise_text(noise, res.problem.model.discrete))
    if u is not None:
        blocks.append("information: " + res.information().describe())
        c = res.criteria()
        shown = any(c.get(k) is not None and math.isfinite(c[k]) for k in ("aic", "aicc", "bic"))
        better = "; lower is better, for models of the same data" if shown else ""
        blocks.append(criteria_text(c) + f" (n = {c['n']}, K = {c['K']}{better})")
    blocks += residual_lines(res, residual, check, robust)
    # what happened on the way (a robust loss's stages, rejected trial points); a fit
    # that did not converge has them among its warnings already
    notes = [f"note: {n}" for n in res.notes] if res.success else []
    return blocks + notes + [f"warning: {w}" for w in res.warnings]


def residual_lines(res, residual, check=None, robust=None) -> list[str]:
    """The residual tests' verdicts, one line each, and where the residuals are not
    shown white, :func:`coloured_residuals_line` (and the model-error check's line
    where one was made)."""
    if residual is None:
        return []
    out = [f"residuals: {line}" for line in residual.lines()]
    check = check if check is not None else res.cached_model_check()
    if check is not None:
        out.append(f"model-error check: {check.line()}")
    if res.has_uncertainty and _doubtful(residual):
        out.append(f"residuals: {coloured_residuals_line(res, residual, check, robust)}")
    return out


def coloured_residuals_line(res, residual=None, check=None, robust=None) -> str:
    """One line for residuals (a filter's innovations) that fail whiteness or cannot be
    tested for it: the standard errors robust to that (Newey-West,
    tensorid.analysis.sandwich) beside the white ones, and which to trust: the robust
    ones only where the model-error check (``check``) passed."""
    filt = res.problem.loss.likelihood
    what = "the filter's innovations" if filt else "the residuals"
    if residual is not None and False not in residual.whiteness_passed:
        head = (
            f"the whiteness of {what} cannot be trusted (see above), so the white-noise "
            "standard errors are unproven"
        )
    else:
        why = (
            ": the model or its noise misses something (process noise on another state, "
            "or the model's structure)"
            if filt
            else ""
        )
        head = (
            f"{what} are not white{why}, so the white-noise standard errors are not to be trusted"
        )
    white = res.uncertainty()
    robust = robust if robust is not None else res.uncertainty("robust")
    with np.errstate(divide="ignore", invalid="ignore"):  # inf/inf: a flat direction
        ratio = robust.stderr / white.stderr
    finite = ratio[np.isfinite(ratio)]
    if not finite.size:
        return f"{head}; no finite standard error to compare"
    pairs = ", ".join(
        f"{n} ±{w:.3g} → ±{r:.3g}"
        for n, w, r in zip(white.names, white.stderr, robust.stderr, strict=True)
    )
    how = "Newey-West on the scores of −2 log L" if filt else "Newey-West"
    return (
        f"{head}; those robust to coloured {'innovations' if filt else 'residuals'} ({how}, "
        f"{robust.lags} lags) are {finite.min():.2g} to {finite.max():.2g} times them: "
        f"{pairs} (fit.json stderr_robust). {trust_advice(check, residual)}"
    )


def trust_advice(check, residual=None) -> str:
    """Which error bars to trust, from the model-error check (None: not made) and,
    where its parts repeat one excitation (it cannot see model error then), what the
    residual tests against the inputs show."""
    if check is not None and check.passed and check.repeated:
        failing = [c for c in getattr(residual, "independence", []) if c.passed is False]
        if failing:
            c = failing[0]
            lag = int(c.lags[int(np.argmax(np.abs(c.values)))])
            return (
                f"The model-error check cannot see model error here: {REPEATED}. And "
                f"the residuals' test {c.what} FAILS (Q = {c.statistic:.0f}, largest |r| "
                f"{c.largest:.2f} at lag {lag}): that is model error, which no error bars "
                "here cover. Trust neither; try a richer model, the input's intersample "
                "setting (interpolation), or process noise (--predictor ekf)"
            )
        return (
            f"The model-error check passes, but {REPEATED}: trust the robust ones only as "
            "far as the model is right; a record with another excitation (as a separate "
            "record) would test it"
        )
    if check is None:
        return (
            "They cover coloured noise, not a wrong model: res.model_check() (made by "
            "tensorid fit when the residuals are not white) tests whether separate parts "
            "of the record agree"
        )
    if check.passed and check.left_out:
        return (
            f"The model-error check passes for {', '.join(check.names)}: trust their robust "
            f"ones, or model the disturbance; {', '.join(check.left_out)} could not be "
            "checked (a part of the record alone cannot determine them)"
        )
    if check.passed:
        return "The model-error check passes: trust the robust ones, or model the disturbance"
    if check.passed is None:
        return (
            "They cover coloured noise, not a wrong model, and the model-error check could "
            f"not be made ({check.not_available})"
        )
    return check.advice()


def _doubtful(residual) -> bool:
    return residual is not None and residual.not_available is None and residual.not_shown_white


def _tests(res):
    """The residual tests with the default lags; None where they cannot be made."""
    try:
        return res.residual_tests(default_lags(res.problem))
    except (ValueError, ArithmeticError):  # LinAlgError is a ValueError
        return None


def _robust(res):
    """The robust error bars; None where they cannot be computed."""
    try:
        return res.uncertainty("robust")
    except (ValueError, ArithmeticError):
        return None
