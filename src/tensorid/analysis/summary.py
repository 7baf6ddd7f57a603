"""Plain-text presentation of a fit: the estimates table and the metric tables, with
numbers printed to as many digits as they need and no more."""

from __future__ import annotations

import io
import math
from abc import ABC, abstractmethod
from typing import NamedTuple

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


def interval_text(u, name: str, ci) -> str:
    """The 95 % interval as a table prints it; one cut at both bounds is the box
    itself, not an interval, and says so ("wider than [lo, hi]")."""
    text = interval(*ci)
    return f"wider than {text}" if u is not None and u.cut.get(name) == "both" else text


def interval_note(u, name: str) -> str:
    """What a reader must know about one interval: an estimate on a bound, an interval
    cut at a bound, or one from the Gauss-Newton form."""
    notes = []
    if name in u.at_bound:
        notes.append(f"on {u.at_bound[name]} bound")
    if u.cut.get(name) == "both":  # the box, not the data, is what bounds it
        notes.append("the data do not bound it within its bounds")
    elif name in u.cut and name not in u.at_bound:
        notes.append(f"cut at {u.cut[name]} bound")
    k = u.names.index(name)
    kind = "hessian" if u.kind == "robust" else u.kind  # a sandwich on the exact Hessian
    if u.forms and u.forms[k] != kind:
        notes.append(f"{u.forms[k]} form")
    return ", ".join(notes)


METRICS = ("gof", "rmse", "nrmse")


def metric_rows(scores) -> tuple[list[str], list[list[str]]]:
    """(header, rows) of GOF, RMSE and NRMSE per record and output, for every
    Score: the one table that the summary, report.md and the CLI print."""
    header = ["record", "output", "GOF", "RMSE", "NRMSE", "scored samples"]
    rows = []
    for s in scores:
        undefined, counts = undefined_gof(s), s.scored  # (measured samples, per output)
        for o in s.simulation.model.outputs:
            cells = [finite(s.gof[o], ".4f"), finite(s.rmse[o], ".4g"), finite(s.nrmse[o], ".4g")]
            if o in undefined:  # not a blow-up: no spread to divide by
                cells[0] = cells[2] = "undefined"
            n = counts[o]
            rows.append([s.label, o, *cells, f"{n}" if not s.start else f"{n} (after {s.start})"])
    return header, rows


def undefined_gof(score) -> dict[str, float]:
    """{output: value} where GOF is not finite because the record holds the output
    constant (the simulation is finite at its scored samples but not exactly that value)."""
    seen = score.experiment.seen[score.start :]
    if not np.isfinite(score.simulation.y[score.start :][seen]).all():
        return {}
    flat = getattr(score, "constant", {})
    return {o: v for o, v in flat.items() if not math.isfinite(score.gof[o])}


def gof_text(score, output: str) -> str:
    """A record's GOF for one output as the figures' titles and lines show it:
    "0.9811", "undefined" (a constant record) or "not finite" (a blow-up)."""
    if output in undefined_gof(score):
        return "undefined"
    return finite(score.gof[output], ".4f")


def metric_notes(scores) -> list[str]:
    """One line per output whose GOF and NRMSE are undefined (constant in its record),
    saying why: a bare "not finite" read as a simulation that blew up."""
    return [
        f"note: {s.label}, {o}: GOF (fit percent), NRMSE and R² are undefined: {o} is "
        f"constant in the record ({v:g} at every scored sample) and they divide by its "
        f"spread about the mean; its RMSE, {s.rmse[o]:.4g}, is the score"
        for s in scores
        for o, v in undefined_gof(s).items()
    ]


def score_notes(scores) -> list[str]:
    """The scores' notes wherever they are shown: metric_notes's, and one line per
    record whose initial states' fit stopped before converging (fit.json's gof_notes
    keep metric_notes's alone)."""
    short = [s for s in scores if s.x0_status is not None and not s.x0_status.success]
    return metric_notes(scores) + [
        f"note: {s.label}: the fit of its initial states stopped before converging "
        f"({s.x0_status.describe()}): its scores may be worse than the model's"
        for s in short
    ]


def finite(value: float, spec: str) -> str:
    """``value`` formatted, or "not finite" (a record whose simulation blew up was
    shown as GOF -inf, RMSE nan)."""
    return format(value, spec) if math.isfinite(value) else "not finite"


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

    from ..solve.multistart import SAME_COST, at_best

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


class Table(NamedTuple):
    """One table of a result's display: a title (or None), column names, rows of text."""

    title: str | None
    header: list[str]
    rows: list[list[str]]


# columns of names, read left to right; every other column holds numbers
LEFT = {"unknown", "record", "output", "note", "lower side", "upper side", "test", "verdict",
        "dataset", "accuracy", "method"}  # fmt: skip


def as_text(blocks: list) -> str:
    """``blocks`` (lines of text and Tables) as the terminal shows them."""
    from rich.console import Console
    from rich.table import Table as RichTable

    console = Console(width=110, record=True, file=io.StringIO())
    for b in blocks:
        if isinstance(b, str):
            console.print(b, soft_wrap=True, markup=False, highlight=False)
            continue
        tab = RichTable(title=b.title, highlight=False)
        for col in b.header:
            tab.add_column(col, justify="left" if col in LEFT else "right")
        for row in b.rows:
            tab.add_row(*row)
        console.print(tab)
    return console.export_text()


def as_html(blocks: list) -> str:
    """``blocks`` as a notebook shows them: plain, escaped <table>s and <p>s."""
    from html import escape

    out = []
    for b in blocks:
        if isinstance(b, str):
            out.append(f"<p>{escape(b)}</p>")
            continue
        cap = f"<caption>{escape(b.title)}</caption>" if b.title else ""
        head = "".join(f"<th>{escape(c)}</th>" for c in b.header)
        body = "".join(
            "<tr>" + "".join(f"<td>{escape(c)}</td>" for c in row) + "</tr>" for row in b.rows
        )
        out.append(f"<table>{cap}<thead><tr>{head}</tr></thead><tbody>{body}</tbody></table>")
    return "<div>" + "".join(out) + "</div>"


class Tabular(ABC):
    """``str()`` for a terminal and ``_repr_html_()`` for a notebook, both from one
    description of the result: ``blocks()``, lines of text and Tables."""

    @abstractmethod
    def blocks(self) -> list:
        """The display: lines of text and :class:`Table` s, in order."""

    def __str__(self) -> str:
        return as_text(self.blocks()).rstrip("\n")  # print() adds the last newline

    def _repr_html_(self) -> str:
        return as_html(self.blocks())


def estimates_table(
    names: list[str], theta, u=None, title: str | None = None, robust=None
) -> Table:
    """Estimate, standard error, 95 % interval and note per unknown (``u``: an
    Uncertainty, or None for a fit without error bars); with ``robust`` (the sandwich's
    Uncertainty) its standard errors beside the white ones."""
    notes = [interval_note(u, n) for n in names] if u else [""] * len(names)
    header = ["unknown", "estimate", "std. error", "95 % interval"]
    rows = []
    for k, name in enumerate(names):
        se = float(u.stderr[k]) if u else math.nan
        ci = interval_text(u, name, u.ci95[k]) if u else "–"
        rows.append([name, significant(float(theta[k]), se), stderr_text(se), ci])
        if robust is not None:
            rows[-1].insert(3, stderr_text(float(robust.stderr[k])))
    if robust is not None:
        header.insert(3, "robust std. error")
    if any(notes):
        header.append("note")
        rows = [r + [n] for r, n in zip(rows, notes, strict=True)]
    return Table(title, header, rows)


def noise_intensities(res, u=None) -> dict | None:
    """A filter's (predictor="ekf") noise intensities as standard deviations, from
    their log-scale estimates: {"process": {state: {...}}, "measurement": {output:
    {...}}}, each {"sigma", "stderr" (delta method: σ × se of log σ), "ci95" (the log
    interval's ends, exponentiated), "fixed"}; None for output error."""
    if not res.problem.loss.likelihood:
        return None
    from ..engine.sweeping.predictors import NOISE_PREFIXES

    names = res.problem.theta_names
    out: dict = {"process": {}, "measurement": {}}
    for name, value in res.params.items():
        for kind, prefix in NOISE_PREFIXES.items():
            if not name.startswith(prefix):
                continue
            entry: dict = {"sigma": float(np.exp(value)), "stderr": None, "ci95": None,
                     "fixed": name not in names}  # fmt: skip
            if u is not None and name in names:
                i = names.index(name)
                se = u.stderr[i]  # σ = 0 (log σ → −∞) with an unbounded se: unbounded
                entry["stderr"] = float(np.exp(value) * se) if np.isfinite(se) else float(se)
                with np.errstate(over="ignore"):  # an unbounded interval: its end is inf
                    entry["ci95"] = [float(np.exp(c)) for c in u.ci95[i]]
            out[kind][name[len(prefix) :]] = entry
    return out


def collapsed_noise(res) -> list[str]:
    """A warning for each estimated measurement noise of a filter fit that went to
    (almost) zero (:func:`collapsed_outputs`). The filter then follows that output
    exactly, a corner where fits stop at a local optimum (a tester's Silverbox fit
    ended there at cost -12807, where a larger starting noise reached -13136)."""
    out = []
    for o, (sigma, spread) in collapsed_outputs(res, spread=True).items():
        out.append(
            f"the measurement noise of {o} went to σ_e = {sigma:.2g}, "
            f"{sigma / spread:.0e} of the output's spread: the filter then follows "
            f"{o} exactly, a corner of the likelihood where fits often stop at a worse "
            f"optimum; start from a sensor's noise (--measurement-noise {o}=σ, "
            f"measurement_noise= in Python) or fix it (--fix log_sigma_e_{o}=log σ)"
        )
    return out


# a filter's σ_e below this share of its output's spread sits at its floor
SIGMA_E_FLOOR = 1e-6


def collapsed_outputs(res, spread: bool = False) -> dict:
    """{output: σ_e} (with ``spread``: {output: (σ_e, the output's spread)}) for each
    estimated measurement noise of a filter fit that sits at its floor: below 1e-6 of
    its output's spread, and below a quantised sensor's own noise q/√12 (EMPS's
    encoder: 5e-8 m steps). Empty for output error."""
    noise = noise_intensities(res)
    if noise is None:
        return {}
    out: dict = {}
    model, exps = res.problem.model, res.problem.experiments
    for o, e in noise["measurement"].items():
        j = model.outputs.index(o)
        ys = np.concatenate([np.asarray(x.measured)[:, j] for x in exps])
        sd = float(np.nanstd(ys))
        if e["fixed"] or not sd > 0 or e["sigma"] >= SIGMA_E_FLOOR * sd:
            continue
        q = _resolution(ys)
        if q > 0 and e["sigma"] >= 0.5 * q / np.sqrt(12):
            continue  # a quantised sensor's own noise
        out[o] = (e["sigma"], sd) if spread else e["sigma"]
    return out


def _resolution(ys: np.ndarray) -> float:
    """The step q of a quantised record (every difference between its values a whole
    multiple of the smallest), whose rounding is noise of q/√12; 0 for a record whose
    values are not on a grid."""
    values = np.unique(ys[np.isfinite(ys)])
    if values.size < 3:
        return 0.0
    steps = np.diff(values)
    q = float(steps.min())
    ratio = steps / q
    return q if np.allclose(ratio, np.round(ratio), rtol=0, atol=1e-3) else 0.0


def noise_text(noise: dict, discrete: bool = False) -> str:
    """One line: each noise intensity with its interval; a discrete-time model's
    process noise is per step (P⁺ = A P Aᵀ + Q), a continuous one's per √time."""
    parts = []
    per = "per step" if discrete else "per √time"
    for kind, unit, letter in (("process", per, "w"), ("measurement", "", "e")):
        for name, e in noise[kind].items():
            ci = _noise_interval(e["ci95"])
            held = " (fixed)" if e["fixed"] else ""
            tail = f" {unit}" if unit else ""
            parts.append(f"σ_{letter}({name}) = {e['sigma']:.4g}{ci}{held}{tail}")
    return "noise intensities (standard deviations, 95 % intervals): " + "; ".join(parts)


def _noise_interval(ci) -> str:
    """The interval " [lo, hi]", "" for a fixed intensity, or a note where the error bars are not
    available (too few samples: NaN ends, None once read back from fit.json)."""
    if not ci:
        return ""
    if any(c is None or np.isnan(c) for c in ci):
        return " [interval not available]"
    return f" [{ci[0]:.3g}, {ci[1]:.3g}]"
