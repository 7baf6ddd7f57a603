"""Plain-text presentation of a fit: the estimates table and the metric tables, with
numbers printed to as many digits as they need and no more."""

from __future__ import annotations

import io
import math

import numpy as np


def plural(n: int, word: str) -> str:
    """'1 iteration', '2 iterations'."""
    return f"{n} {word}" if n == 1 else f"{n} {word}s"


def significant(value: float, stderr: float | None = None, digits: int = 6) -> str:
    """``value`` with enough significant digits that a change of one standard error is
    visible (two digits of the error), at least ``digits``."""
    if not math.isfinite(value):
        return str(value)
    if stderr is not None and math.isfinite(stderr) and stderr > 0 and value != 0:
        digits = max(
            digits,
            int(math.floor(math.log10(abs(value)))) - int(math.floor(math.log10(stderr))) + 2,
        )
    return f"{value:.{min(digits, 17)}g}"


def interval(lo: float, hi: float, digits: int = 6) -> str:
    """[lo, hi] with enough significant digits that the two ends differ when printed."""
    if math.isnan(lo) or math.isnan(hi):
        return "–"  # no interval (error bars not available)
    if not (math.isfinite(lo) and math.isfinite(hi)):
        return f"[{lo:.{digits}g}, {hi:.{digits}g}]"
    d = digits
    while d < 17 and f"{lo:.{d}g}" == f"{hi:.{d}g}" and lo != hi:
        d += 1
    width = hi - lo
    if width > 0:  # two digits of the width
        scale = max(abs(lo), abs(hi))
        need = int(math.floor(math.log10(scale))) - int(math.floor(math.log10(width))) + 2
        d = max(d, min(need, 17))
    return f"[{lo:.{d}g}, {hi:.{d}g}]"


def stderr_text(se: float) -> str:
    """A standard error to two significant digits; 'inf' for a flat direction."""
    if not math.isfinite(se):
        return "inf" if se > 0 else "–"
    text = f"{se:#.2g}"  # '#' keeps the second digit of 4.0e-09
    return text[:-1] if text.endswith(".") else text


def interval_note(u, name: str) -> str:
    """What a reader must know about one interval: an estimate on a bound, an interval
    cut at a bound, or one from the Gauss-Newton form."""
    notes = []
    if name in u.at_bound:
        notes.append(f"on {u.at_bound[name]} bound")
    elif name in u.cut:
        notes.append(f"cut at {u.cut[name]} bound")
    k = u.names.index(name)
    if u.forms and u.forms[k] != u.kind:
        notes.append(f"{u.forms[k]} form")
    return ", ".join(notes)


METRICS = ("gof", "rmse", "nrmse")


def metric_rows(scores) -> tuple[list[str], list[list[str]]]:
    """(header, rows) of GOF, RMSE and NRMSE per record and output, for every
    Score: the one table that the summary, report.md and the CLI print."""
    header = ["record", "output", "GOF", "RMSE", "NRMSE", "scored samples"]
    rows = []
    for s in scores:
        n = s.experiment.P - s.start
        scored = f"{n}" if not s.start else f"{n} (after {s.start})"
        for o in s.simulation.model.outputs:
            rows.append(
                [s.label, o, f"{s.gof[o]:.4f}", f"{s.rmse[o]:.4g}", f"{s.nrmse[o]:.4g}", scored]
            )
    return header, rows


_CRITERIA = (("AIC", "aic"), ("AICc", "aicc"), ("BIC", "bic"))


def criteria_text(c: dict) -> str:
    """AIC, AICc and BIC in one line, a number only where the record supports it, else
    why not (``c``: information_criteria's dict, or fit.json's keys)."""
    given = {label: c.get(key) for label, key in _CRITERIA}
    ok = {k: v for k, v in given.items() if v is not None and math.isfinite(v)}
    text = ", ".join(f"{label} {v:.6g}" for label, v in ok.items())
    missing = [label for label in given if label not in ok]
    if missing:
        why = c.get("not_available") or c.get("criteria_not_available") or "not available"
        text += ("; " if text else "") + f"{', '.join(missing)} {why}"
    return text


def starts_outcome(starts: list[dict]) -> str:
    """ ", 5 at the best cost (to 1e-9 relative), 3 failed: 2 nonfinite start, 1
    maxiter": how many starts reached the best cost, how many failed and why."""
    from collections import Counter

    from .multistart import SAME_COST, at_best

    best = min((s["cost"] for s in starts), default=math.inf)
    if not math.isfinite(best):
        return ""
    same = sum(at_best(s["cost"], best) for s in starts)
    text = f", {same} at the best cost (to {SAME_COST:g} relative)"
    failed = Counter(str(s.get("status", "")) for s in starts if not s.get("success", True))
    if failed:
        why = ", ".join(f"{n} {k.replace('_', ' ')}" for k, n in failed.most_common())
        text += f", {sum(failed.values())} failed: {why}"
    return text


def headline(res) -> str:
    """One line: method, how it ended, iterations, evaluations, cost."""
    line = (
        f"{res.method}: {res.message}; {plural(res.nit, 'iteration')}, "
        f"{plural(res.nfev_best, 'cost evaluation')}"
    )
    if res.starts:
        line += (
            f" (best of {len(res.starts)} starts{starts_outcome(res.starts)}; all starts: "
            f"{plural(res.nit_total, 'iteration')}, {plural(res.nfev, 'cost evaluation')})"
        )
    line += f"; cost {res.cost:.6g}"
    if res.hybrid and not res.starts:
        h = res.hybrid
        line += (
            f"; {h['gauss_newton_evaluations']} Gauss-Newton and "
            f"{plural(h['exact_evaluations'], 'exact-Hessian evaluation')}"
            + (", past a saddle" if h["saddles_left"] else "")
        )
    if res.shooting:
        sh = res.shooting
        line += (
            f"; multiple shooting over {sum(sh['segments'])} segments: "
            f"{plural(sh['nit'], 'iteration')} in {sh['outer']} outer, largest defect "
            f"{sh['max_defect']:.1e}" + (", then single-shooting polish" if sh["polished"] else "")
        )
    return line


def summary_table(res, scores=None) -> str:
    """The estimates of a FitResult as a plain-text table, then the warnings and, with
    ``scores`` (see tensorid.fitting.validation), the metric table."""
    from rich.console import Console
    from rich.table import Table

    u = res.uncertainty() if res.has_uncertainty else None
    tab = Table(
        title=f"{res.problem.model.name}: {'converged' if res.success else 'NOT converged'}"
    )
    names = res.problem.theta_names
    notes = [interval_note(u, n) for n in names] if u else [""] * len(names)
    columns = ["unknown", "estimate", "std. error", "95 % interval"]
    for col in columns + (["note"] if any(notes) else []):
        tab.add_column(col, justify="left" if col in ("unknown", "note") else "right")
    for k, name in enumerate(names):
        se = float(u.stderr[k]) if u else math.nan
        ci = interval(*u.ci95[k]) if u else "–"
        row = [name, significant(res.theta[k], se), stderr_text(se), ci]
        tab.add_row(*row, *([notes[k]] if any(notes) else []))
    console = Console(width=110, record=True, file=io.StringIO())
    console.print(headline(res), soft_wrap=True)
    console.print(tab)
    if scores:
        header, rows = metric_rows(scores)
        mt = Table(show_edge=False)
        for c in header:
            mt.add_column(c, justify="left" if c in ("record", "output") else "right")
        for r in rows:
            mt.add_row(*r)
        console.print(mt)
    if u is not None:
        console.print("information: " + res.information().describe(), soft_wrap=True)
        c = res.criteria()
        console.print(
            criteria_text(c) + f" (n = {c['n']}, K = {c['K']}; lower is better, for models "
            "of the same data)",
            soft_wrap=True,
        )
    for w in res.warnings:
        console.print(f"warning: {w}", soft_wrap=True)
    return console.export_text()


def coloured_residuals_line(res) -> str:
    """One line for residuals that fail whiteness: the standard errors robust to that
    (Newey-West, tensorid.fitting.sandwich) beside the white ones, and which to trust."""
    white, robust = res.uncertainty(), res.uncertainty("robust")
    ratio = robust.stderr / white.stderr
    finite = ratio[np.isfinite(ratio)]
    if not finite.size:
        return "the residuals are not white; no finite standard error to compare"
    pairs = ", ".join(
        f"{n} ±{w:.3g} → ±{r:.3g}"
        for n, w, r in zip(white.names, white.stderr, robust.stderr, strict=True)
    )
    return (
        f"the residuals are not white, so the white-noise standard errors are not to be "
        f"trusted; those robust to coloured residuals (Newey-West, {robust.lags} lags) are "
        f"{finite.min():.2g} to {finite.max():.2g} times them: {pairs} (fit.json "
        "stderr_robust). Trust the robust ones, or model the disturbance"
    )
