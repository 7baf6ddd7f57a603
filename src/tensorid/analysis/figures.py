"""Figures of a fit: measured against simulated outputs with residuals, and the
convergence history. They are built in memory as matplotlib Figure objects, outside
pyplot (so nothing changes the user's backend and nothing leaks); writing them is the
caller's choice."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np


def new_figure(**kwargs):
    """A matplotlib Figure that no pyplot window manager knows of."""
    from matplotlib.figure import Figure

    return Figure(**kwargs)


# inches, for 10 pt text: a tick label's line, an axis label's, a title's
_LINE, _TICKS, _LABEL, _TITLE = 0.17, 0.27, 0.25, 0.3


def fixed_layout(fig, *, top: float = _TITLE, gap: float = 0.12, wide_gap: bool = False) -> None:
    """Margins of a figure's grid of axes, in inches, set from what its labels need
    rather than by ``tight_layout``, which lays out every tick label's text and took
    a third of the time of the figures a fit command writes (0.24 of 0.69 s). The
    left margin (and between columns the gap) is made as wide as the widest y tick
    label, its characters counted: tick labels are digits, signs and points, whose
    widths the estimate bounds; an axis's offset text ("1e-7" above it) gets a line
    above each row. ``top``: room above the grid (titles); ``gap``: between rows
    (axes sharing x: only the lower one is labelled), or with ``wide_gap`` room for a
    row's x tick labels, its x label and the next row's title."""
    width, height = fig.get_size_inches()
    axes = fig.axes
    ticks = [_tick_text(a) for a in axes]
    cols = {a.get_subplotspec().colspan.start for a in axes}
    rows = {a.get_subplotspec().rowspan.start for a in axes}
    y_room = max(w for w, _ in ticks) + _TICKS / 2 + _LABEL
    offset = _LINE if any(o for _, o in ticks) else 0.0
    left, right = y_room + 0.12, 0.2
    bottom, top = _TICKS + _LABEL + 0.05, top + offset
    hgap = (_TICKS + _LABEL + _TITLE if wide_gap else gap) + offset
    wgap = y_room + 0.25  # the next column's y tick labels and axis label
    # subplots_adjust's spaces are fractions of the mean axes' width and height
    axes_w = (width - left - right - wgap * (len(cols) - 1)) / len(cols)
    axes_h = (height - top - bottom - hgap * (len(rows) - 1)) / len(rows)
    fig.subplots_adjust(
        left=left / width,
        right=1 - right / width,
        bottom=bottom / height,
        top=1 - top / height,
        wspace=wgap / axes_w,
        hspace=hgap / axes_h,
    )


def _tick_text(ax) -> tuple[float, bool]:
    """Inches that the y tick labels of ``ax`` take, from their characters, and
    whether the axis writes an offset text: what its formatter makes of the ticks
    its locator places in the current limits (no text is laid out)."""
    import matplotlib as mpl

    axis = ax.yaxis
    lo, hi = sorted(ax.get_ylim())
    locs = [v for v in axis.get_major_locator()() if lo <= v <= hi]
    formatter = axis.get_major_formatter()
    labels = formatter.format_ticks(locs) if locs else [""]
    # a log axis spanning less than a decade labels its minor ticks ("2×10⁻³")
    minor = [v for v in axis.get_minor_locator()() if lo <= v <= hi]
    labels += axis.get_minor_formatter().format_ticks(minor) if minor else []
    chars = max(_characters(t) for t in labels)
    size = mpl.font_manager.FontProperties(size=mpl.rcParams["ytick.labelsize"]).get_size()
    # DejaVu Sans: digits 0.64 em, a minus 0.84, a point 0.32
    return chars * 0.64 * size / 72, bool(formatter.get_offset())


def _characters(label: str) -> float:
    """A tick label's width in characters; mathtext (a log axis's 10 to a power)
    counts its exponent at the superscript's 0.7 size."""
    if not label.startswith("$"):
        return len(label)
    text = label.strip("$").replace("\\mathdefault", "").replace("{", "").replace("}", "")
    base, _, exponent = text.partition("^")
    return len(base.replace("\\times", "x")) + 0.7 * len(exponent) + 0.5


_SUPERSCRIPT = str.maketrans("-0123456789", "⁻⁰¹²³⁴⁵⁶⁷⁸⁹")


def plain_log_labels(axis) -> None:
    """A log axis labelled in plain text ("10⁻³", "2×10⁻³") instead of Matplotlib's
    mathtext, whose parser took a third of the convergence figure's time (each label
    parsed anew in each process that draws). A linear axis is left as it is."""
    from matplotlib import ticker

    if axis.get_scale() != "log":
        return

    class Plain(ticker.LogFormatterSciNotation):
        def __call__(self, x, pos=None):
            return plain_power(super().__call__(x, pos))

    axis.set_major_formatter(Plain())
    axis.set_minor_formatter(Plain(labelOnlyBase=False))


def plain_power(label: str) -> str:
    """``$\\mathdefault{2\\times10^{-3}}$`` as ``2×10⁻³``; a label that is not such a
    power of ten, as it is."""
    if not (label.startswith("$\\mathdefault{") and label.endswith("}$")):
        return label
    text = label[len("$\\mathdefault{") : -2].replace("\\times", "×")
    base, _, exponent = text.partition("^")
    exponent = exponent.removeprefix("{").removesuffix("}")
    if not exponent.lstrip("-").isdigit() or not base.replace("×", "").replace(".", "").isdigit():
        return label
    return base + exponent.translate(_SUPERSCRIPT)


def save_png(fig, path: Path) -> Path:
    """Write ``fig`` as PNG to ``path`` (whatever its suffix)."""
    # 100 dpi and light compression: a fifth less time than 120 dpi at zlib's
    # default, for files of about the same size (the CLI writes 4+ after every fit)
    fig.savefig(path, dpi=100, format="png", pil_kwargs={"compress_level": 1})
    return path


def compare_figure(
    t: np.ndarray,
    y_meas: np.ndarray,
    y_sim: np.ndarray,
    *,
    title: str,
    ylabel: str = "y",
    xlabel: str = "t [s]",
    labels: tuple[str, str] = ("measured", "model"),
    window: float | None = None,
):
    """Measured against simulated output, with the residual below (one output);
    ``window``: the end of an initialisation window, shaded (not scored). A NaN in
    ``y_meas`` is a sample not measured: the measurements and residuals are drawn
    on the measured samples alone, each marked (a record with gaps or events' rows)."""
    fig = new_figure(figsize=(9, 5.5))
    ax, axr = fig.subplots(2, 1, sharex=True, gridspec_kw={"height_ratios": [3, 1]})
    if window is not None:
        for a in (ax, axr):
            a.axvspan(t[0], window, color="0.85", zorder=0)
    seen = np.isfinite(y_meas)
    dots = {} if seen.all() else {"marker": ".", "ms": 4}
    ax.plot(t[seen], y_meas[seen], color="0.2", lw=1.0, label=labels[0], **dots)
    ax.plot(t, y_sim, color="tab:red", lw=0.9, ls="--", label=labels[1])
    ax.set_ylabel(ylabel)
    titled_with_legend(ax, title)
    ax.grid(alpha=0.3)
    axr.plot(t[seen], (y_meas - y_sim)[seen], color="tab:blue", lw=0.8, **dots)
    axr.set_ylabel(f"residual [units of {ylabel}]")
    axr.set_xlabel(xlabel)
    axr.grid(alpha=0.3)
    fixed_layout(fig, top=_TITLE + _LEGEND)
    return fig


_LEGEND = 0.22  # inches: a row of legend entries at 8 pt between the title and the axes


def titled_with_legend(ax, title: str) -> None:
    """The legend in one row above the axes, under the title: inside them, in any
    corner, it covered the data's peaks (an oscillating record fills every corner)."""
    handles, _ = ax.get_legend_handles_labels()
    ax.legend(
        loc="lower right", bbox_to_anchor=(1.0, 1.0), ncol=len(handles), fontsize=8,
        frameon=False, borderaxespad=0.1, handlelength=1.8, columnspacing=1.2,
    )  # fmt: skip
    ax.set_title(title, fontsize=10, pad=6 + 72 * _LEGEND)


def compare_plot(path: Path, *args, **kwargs) -> Path:
    """:func:`compare_figure`, written to ``path``."""
    return save_png(compare_figure(*args, **kwargs), path)


def convergence_figure(history: list[dict], title: str):
    """Cost and gradient norm per iteration."""
    it = [h["iteration"] for h in history]
    fig = new_figure(figsize=(9, 3.5))
    a1, a2 = fig.subplots(1, 2)
    costs = [h["cost"] for h in history]
    # a likelihood's J (a filter's fit) may be negative: then a linear axis
    (a1.semilogy if min(costs) > 0 else a1.plot)(it, costs, "o-", ms=3)
    a1.set_xlabel("iteration")
    a1.set_ylabel("cost J")
    grads = [h["grad_norm"] for h in history]
    a2.semilogy(it, [g if np.isfinite(g) and g > 0 else np.nan for g in grads], "o-", ms=3)
    for a in (a1, a2):
        plain_log_labels(a.yaxis)
    a2.set_xlabel("iteration")
    a2.set_ylabel("gradient norm (scaled)")
    for a in (a1, a2):
        a.grid(alpha=0.3)
    fig.suptitle(title, fontsize=10)
    fixed_layout(fig, top=_TITLE + 0.05)
    return fig


def profile_figure(prof, sigma2: float, stderr: float):
    """The profile of one unknown: the rise of the cost in units of σ² against its
    value, the threshold and the interval, beside the Wald parabola (what the
    standard error alone would say)."""
    fig = new_figure(figsize=(6, 4))
    ax = fig.subplots()
    rise = (prof.costs - prof.costs.min()) / sigma2
    # the curve runs through the interval's ends (found by root-finding between the
    # traced points), so it crosses the threshold where the interval ends
    sides = zip(prof.interval, ("lower", "upper"), strict=True)
    crossings = [e for e, k in sides if prof.ends.get(k) == "crossed"]
    x = np.concatenate([prof.values, crossings])
    y = np.concatenate([rise, np.full(len(crossings), prof.threshold / sigma2)])
    order = np.argsort(x, kind="stable")
    ax.plot(x[order], y[order], "-", color="C0", label="profile")
    ax.plot(prof.values, rise, "o", ms=3, color="C0")
    if np.isfinite(stderr) and stderr > 0:
        c = np.linspace(prof.values.min(), prof.values.max(), 200)
        ax.plot(c, ((c - prof.estimate) / stderr) ** 2, "--", lw=1, label="Wald (quadratic)")
    ax.axhline(prof.threshold / sigma2, color="k", lw=0.8, label=f"{prof.level:.0%} threshold")
    for end in prof.interval:
        if np.isfinite(end):
            ax.axvline(end, color="C3", lw=0.8)
    ax.set_xlabel(prof.name)
    # a likelihood's cost is −2 log L, σ² = 1: its rise is read as it is
    ax.set_ylabel("PL − Ĵ  (−2 log L)" if sigma2 == 1.0 else "(PL − Ĵ) / σ²")
    ax.set_title(prof.describe(), fontsize=8)
    ax.set_ylim(bottom=0, top=max(2 * prof.threshold / sigma2, 1.0))
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    return fig


def prediction_figure(t, measured, simulated, predicted, sd, innovations, *, title, ylabel):
    """A filter's fit on one output: measured, simulated and predicted one step ahead
    (with the ±2σ band of the innovation covariance, sd its standard deviation), and
    the standardised innovations below, which should look like white noise inside ±2."""
    fig = new_figure(figsize=(9, 5.5))
    ax, axr = fig.subplots(2, 1, sharex=True, gridspec_kw={"height_ratios": [3, 1]})
    ax.plot(t, measured, color="0.2", lw=1.0, label="measured")
    ax.plot(t, simulated, color="tab:red", lw=0.9, ls="--", label="simulated")
    ax.plot(t, predicted, color="tab:green", lw=0.9, label="predicted one step ahead")
    if sd is not None:
        lo, hi = predicted - 2 * sd, predicted + 2 * sd
        ax.fill_between(t, lo, hi, color="tab:green", alpha=0.15, lw=0, label="±2σ")
    ax.set_ylabel(ylabel)
    titled_with_legend(ax, title)
    ax.grid(alpha=0.3)
    # the axes are the data's: a filter's first steps (x0 far off) can predict −3e151,
    # which drew every other sample as a flat line at 0
    seen = np.concatenate([np.ravel(measured), np.ravel(simulated)])
    seen = seen[np.isfinite(seen)]
    if seen.size:
        span = max(float(np.ptp(seen)), 1e-12 * max(1.0, float(np.abs(seen).max())))
        ax.set_ylim(seen.min() - 0.25 * span, seen.max() + 0.25 * span)
    axr.plot(t, innovations, color="tab:blue", lw=0.6)
    _beyond(axr, np.asarray(t), np.asarray(innovations, dtype=float))
    for level in (-2, 2):
        axr.axhline(level, color="k", lw=0.6, ls=":")
    # the dotted lines named here: a legend in so short a panel covered the innovations
    axr.set_ylabel("innovation / σ\n(dotted: ±2, 95 %\nof white ones)", fontsize=8)
    axr.set_xlabel("t [s]")
    axr.grid(alpha=0.3)
    fixed_layout(fig, top=_TITLE + _LEGEND)
    return fig


def _beyond(ax, t: np.ndarray, z: np.ndarray, limit: float = 8.0) -> None:
    """Standardised innovations drawn within ±``limit`` (or the largest finite one if
    smaller), the samples beyond it named in the panel: one huge first innovation
    made the rest a flat line."""
    finite = np.isfinite(z)
    big = ~finite | (np.abs(z) > limit)
    if not big.any():
        return
    top = max(float(np.abs(z[finite & ~big]).max(initial=2.0)), 3.0) * 1.15
    ax.set_ylim(-top, top)
    k = int(np.argmax(np.where(finite, np.abs(z), np.inf)))
    ax.text(0.99, 0.95, f"{int(big.sum())} beyond the axis (largest {z[k]:.2g} at t = {t[k]:g})",
            transform=ax.transAxes, ha="right", va="top", fontsize=7)  # fmt: skip


def _prediction_jobs(res, training: list) -> list:
    """A filter fit's prediction figures, one per training record and output
    (``training``: its training scores, whose simulations they show)."""
    if not res.problem.loss.likelihood:
        return []
    jobs = []
    sims = [s.simulation for s in training]
    for e, pred, sim in zip(
        res.problem.experiments, res.problem.predict(res.theta), sims, strict=True
    ):
        for j, name in enumerate(res.problem.model.outputs):
            label = f"training '{e.name}'" if e.name else "training"
            sd = np.sqrt(np.maximum(pred.covariance[:, j, j], 0.0))
            arguments = dict(
                t=np.asarray(pred.t), measured=pred.measured[:, j], simulated=sim.y[:, j],
                predicted=pred.predicted[:, j], sd=sd, innovations=pred.innovations[:, j],
                title=f"{label}, output {name}: prediction and innovations", ylabel=name,
            )  # fmt: skip
            jobs.append(
                (file_name(f"prediction_{e.name or 'data'}_{name}"), "prediction", arguments)
            )
    return jobs


def file_name(s: str) -> str:
    """A label as a file stem: letters, digits, - and _ kept, the rest _."""
    return "".join(c if c.isalnum() or c in "-_" else "_" for c in s)


def _record_stem(score) -> str:
    """The record's part of a figure's file name: its name and "_", none where the name
    only repeats the kind and it is the only record of its kind (train.csv's training
    figure is train_y.png, not train_train_y.png); "data_" for a record without a name."""
    from .validation import repeats_kind

    name = score.experiment.name
    alone = getattr(score, "alone", True)  # two "validate"/"test" records keep their names
    return "" if name and alone and repeats_kind(score.kind, name) else f"{name or 'data'}_"


def figure_jobs(res, validation=None, training: bool = True, convergence: bool = True) -> list:
    """What :func:`fit_figures` draws, as plain data: (file stem, kind, arguments) per
    figure, ``draw(kind, arguments)`` making it. Plain data (arrays, strings) can be
    drawn in another process (the command line does), with the same pixels."""
    from .summary import gof_text
    from .validation import training_scores

    jobs = []
    train = training_scores(res) if training else []
    for s in train + list(validation or []):
        e = s.experiment
        for j, name in enumerate(res.problem.model.outputs):
            stem = f"{s.kind[:5] if s.kind == 'training' else s.kind}_{_record_stem(s)}{name}"
            title = f"{s.label}, output {name}: GOF {gof_text(s, name)}"
            if s.start:
                title += f" (scored after the first {s.start} samples)"
            arguments = dict(
                t=np.asarray(e.t),
                y_meas=e.measured_with_gaps[:, j],
                y_sim=np.asarray(s.simulation.y[:, j]),
                ylabel=name,
                title=title,
                window=float(e.t[s.start]) if s.start else None,
            )
            jobs.append((file_name(stem), "compare", arguments))
    jobs += _prediction_jobs(res, train) if training else []
    if convergence and len(res.history) > 1:
        what = f"best of {len(res.starts)} starts" if res.starts else res.method
        title = f"{what}: cost and gradient norm per iteration"
        history = [
            {
                "iteration": int(h["iteration"]),
                "cost": float(h["cost"]),
                "grad_norm": float(h["grad_norm"]),
            }
            for h in res.history
        ]
        jobs.append(("convergence", "convergence", dict(history=history, title=title)))
    return jobs


def draw(kind: str, arguments: dict):
    """The figure of one of :func:`figure_jobs`' (or ``ResidualTests.figure_job``'s)
    entries."""
    makers: dict[str, Callable] = {
        "compare": compare_figure,
        "convergence": convergence_figure,
        "residual": residual_figure,
        "prediction": prediction_figure,
    }
    if kind not in makers:  # a population fit's (fleet_figures.py)
        makers = _fleet_makers()
    return makers[kind](**arguments)


def _fleet_makers() -> dict[str, Callable]:
    """fleet_figures.py's kinds, that file loaded by path as the renderer loads this one
    (so it works in both: a relative import needs the package)."""
    import importlib.util
    import sys

    name = "_tensorid_fleet_figures"
    if name not in sys.modules:
        where = Path(__file__).with_name("fleet_figures.py")
        spec = importlib.util.spec_from_file_location(name, where)
        assert spec is not None and spec.loader is not None  # a .py file by path
        module = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(module)
        sys.modules[name] = module
    return sys.modules[name].MAKERS


def fit_figures(res, out=None, validation=None, named: bool = False) -> list:
    """The figures of a fit: per record and output, measured against simulated (the
    training records, then the ``validation`` scores), and the convergence history
    of the run that produced the estimate. Returns the matplotlib figures (with
    ``named``, (file stem, figure) pairs), or, with a folder ``out``, writes them
    there as PNG and returns their paths."""
    pairs = [(stem, draw(kind, a)) for stem, kind, a in figure_jobs(res, validation)]
    if out is None:
        return pairs if named else [fig for _, fig in pairs]
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    return [save_png(fig, out / f"{stem}.png") for stem, fig in pairs]


def residual_figure(bound: float, panels: list[dict]):
    """Autocorrelation and cross-correlation panels with the ±``bound`` band; a panel
    is a dict of ``what``, ``passed``, ``lags``, ``values`` and ``feedback`` (the
    negative lags, not tested, drawn grey; or None)."""
    fig = new_figure(figsize=(9, 1.2 + 2.0 * len(panels)))
    axes = fig.subplots(len(panels), 1, squeeze=False)[:, 0]
    for ax, c in zip(axes, panels, strict=True):
        ax.axhspan(-bound, bound, color="C0", alpha=0.15, lw=0,
                   label=f"±{bound:.2g}: where uncorrelated samples fall")  # fmt: skip
        if c["feedback"] is not None:  # not tested: drawn grey
            back = -np.arange(1, c["feedback"].size + 1)
            ax.vlines(back, 0, c["feedback"], color="0.6")
            ax.plot(back, c["feedback"], "o", ms=3, color="0.6",
                    label="negative lags: against later inputs (feedback; not tested)")  # fmt: skip
        colour = {True: "C0", False: "C3", None: "C1"}[c["passed"]]
        ax.vlines(c["lags"], 0, c["values"], color=colour)
        ax.plot(c["lags"], c["values"], "o", ms=3, color=colour,
                label="tested lags" + {True: "", False: " (the test fails)",
                                       None: " (no verdict)"}[c["passed"]])  # fmt: skip
        ax.axhline(0, color="k", lw=0.6)
        # the legend in one row in a band above the correlations, not over the lags
        shown = np.concatenate([[-bound, bound], c["values"],
                                [] if c["feedback"] is None else c["feedback"]])  # fmt: skip
        low, high = float(np.nanmin(shown)), float(np.nanmax(shown))
        pad = 0.1 * (high - low)
        ax.set_ylim(low - pad, high + 0.45 * (high - low))
        ax.legend(fontsize=7, loc="upper right", framealpha=0.8, ncol=3)
        verdict = {True: "passes", False: "fails", None: "cannot be trusted"}[c["passed"]]
        ax.set_title(f"{c['what']}: {verdict}", fontsize=9)
        ax.set_ylabel("r(τ)")
        ax.set_xlabel("lag τ (samples)")  # each panel has its own lags
        ax.grid(alpha=0.3)
    fixed_layout(fig, wide_gap=True)
    return fig
