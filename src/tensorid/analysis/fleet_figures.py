"""A population fit's figures drawn from plain arrays (population/figures.py computes
them): every unit's data with its own and the typical unit's prediction, observed
against predicted, the visual predictive check's bands and the residual panels.

Like figures.py, this file imports only NumPy, Matplotlib and the standard library,
and is loaded by path (figures.py's ``draw``), so that the command's renderer, which
imports neither tensorid nor JAX, draws these too while the command writes its
files. Figures are built outside pyplot (nothing changes the user's backend)."""

from __future__ import annotations

from statistics import NormalDist

import numpy as np


def _figure(rows: int, cols: int, size: tuple[float, float], **kw):
    from matplotlib.figure import Figure

    fig = Figure(figsize=size)
    return fig, fig.subplots(rows, cols, squeeze=False, **kw)


def units_grid(units: list[dict], output: str, more: str):
    """Each unit's observations (``t_seen``, ``y_seen``), its own prediction (``own``)
    and the typical unit's (``typical``) on its grid ``t``, a panel per unit."""
    n = len(units)
    cols = int(np.ceil(np.sqrt(n)))
    rows = int(np.ceil(n / cols))
    fig, axes = _figure(rows, cols, (2.4 * cols, 1.9 * rows), sharex=True, sharey=True)
    for i, ax in enumerate(axes.flat):
        if i >= n:
            ax.set_visible(False)
            continue
        u = units[i]
        ax.plot(u["t_seen"], u["y_seen"], "o", ms=3, color="k", label="observed")
        ax.plot(u["t"], u["own"], "-", color="C0", label="individual")
        ax.plot(u["t"], u["typical"], "--", color="C1", label="population")
        ax.set_title(f"unit {u['name']}", fontsize=8)
        ax.tick_params(labelsize=7)
    axes.flat[0].legend(fontsize=6)
    fig.suptitle(f"{output}: data and fits{more}", fontsize=10)
    fig.supxlabel("time", fontsize=9)
    fig.tight_layout()
    return fig


def observed_predicted(observed, population, individual):
    """Observed against the population (η = 0) and individual (η̂) predictions."""
    fig, axes = _figure(1, 2, (8, 3.8))
    y = np.asarray(observed)
    for ax, p, what in ((axes[0, 0], population, "population"),
                        (axes[0, 1], individual, "individual")):  # fmt: skip
        p = np.asarray(p)
        ax.plot(p, y, "o", ms=3, alpha=0.7)
        lo, hi = float(min(p.min(), y.min())), float(max(p.max(), y.max()))
        ax.plot([lo, hi], [lo, hi], "k-", lw=0.8, label="observed = predicted")
        ax.set_xlabel(f"{what} prediction")
        ax.set_ylabel("observed")
        ax.set_title(f"{what} (η {'= 0' if what == 'population' else '= η̂'})")
        ax.legend(fontsize=7)
    fig.tight_layout()
    return fig


def vpc_bands(centre, observed, simulated, output: str, replicates: int):
    """The visual predictive check: per time bin the observed 5/50/95 % percentiles
    (B, 3) over the 90 % range of each in the simulated fleets (B, 3, 3)."""
    fig, axes = _figure(1, 1, (6.5, 4))
    ax, c, simulated = axes[0, 0], np.asarray(centre), np.asarray(simulated)
    for j, (level, colour) in enumerate(((5, "C0"), (50, "C3"), (95, "C0"))):
        band = simulated[:, j]
        ax.fill_between(c, band[:, 0], band[:, 2], color=colour, alpha=0.2,
                        label=f"simulated {level} % (90 % range)")  # fmt: skip
        ax.plot(c, np.asarray(observed)[:, j], "-o", color=colour, ms=3,
                label=f"observed {level} %")  # fmt: skip
    ax.set_xlabel("time (bin mean)")
    ax.set_ylabel(output)
    ax.set_title(f"visual predictive check ({replicates} simulated fleets)")
    ax.legend(fontsize=6, ncol=2)
    fig.tight_layout()
    return fig


def residual_panels(columns: dict, output: str):
    """The population modeller's four residual panels: CWRES against TIME and PRED,
    IWRES against IPRED, and CWRES and NPDE against the normal quantiles (each should
    scatter evenly about 0, within ±2, without a trend). ``columns``: the table's
    columns of one output, as float arrays."""
    col = {k: np.asarray(v, dtype=float) for k, v in columns.items()}
    fig, axes = _figure(2, 2, (8, 6.4))
    panels = (("TIME", "CWRES", "time"), ("PRED", "CWRES", "population prediction"),
              ("IPRED", "IWRES", "individual prediction"))  # fmt: skip
    for ax, (x, y, label) in zip(axes.flat, panels, strict=False):
        ax.plot(col[x], col[y], "o", ms=3, alpha=0.6)
        for level, style in ((0.0, "-"), (2.0, ":"), (-2.0, ":")):
            ax.axhline(level, color="k", lw=0.8, ls=style)
        ax.set_xlabel(label)
        ax.set_ylabel(y)
    ax = axes.flat[3]
    normal = NormalDist().inv_cdf
    for what, colour in (("CWRES", "C0"), ("NPDE", "C3")):
        v = np.sort(col[what][np.isfinite(col[what])])
        if v.size:
            q = [normal((k + 0.5) / v.size) for k in range(v.size)]
            ax.plot(q, v, "o", ms=3, color=colour, alpha=0.6, label=what)
    lim = 3.5
    ax.plot([-lim, lim], [-lim, lim], "k-", lw=0.8)
    ax.set_xlabel("normal quantile")
    ax.set_ylabel("residual")
    ax.legend(fontsize=7, loc="upper left")
    fig.suptitle(f"{output}: residuals ({len(col['TIME'])} observations)", fontsize=10)
    fig.tight_layout()
    return fig


MAKERS = {
    "units": units_grid,
    "observed_predicted": observed_predicted,
    "vpc": vpc_bands,
    "population_residuals": residual_panels,
}
