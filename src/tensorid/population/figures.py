"""A population fit's figures, built in memory (the app writes them): every unit's data
with its own fit and the typical unit's (a grid of small panels), observed against
predicted (population and individual), and a visual predictive check (the observed
percentiles over time beside those of fleets simulated from the fitted population)."""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np

GRID_MAX = 36  # units shown in the grid; the rest are in fit.json


DENSE = 240  # points of a record with events drawn between its first and last rows


def _predictions(res, dense: bool = False):
    """(units, the typical unit's predictions, each unit's own): the typical unit is
    η = 0, with the median of the units' values for individual parameters. With
    ``dense``, for records with events: on each unit's grid and DENSE more times, so
    that a curve goes through its doses rather than straight between samples."""
    obj = res.objective_function
    if dense and getattr(obj.problem, "dosing", None) is not None:
        obj = _densely(obj)
    middle = np.median(res.etas, axis=0)
    middle[: obj.qp] = 0.0
    typical = np.asarray(obj.predict_all(res.x, np.broadcast_to(middle, res.etas.shape)))
    own = np.asarray(obj.predict_all(res.x, res.etas))
    return obj.units, typical, own


def _densely(obj):
    """``obj`` on its units' records with DENSE unobserved times more each."""
    import copy

    from ..engine.modelling.data import Experiment
    from ..engine.modelling.events import regrid
    from .units import Units

    records = []
    for e in obj.problem.experiments:  # its samples stay, with their values
        dense = regrid(e.t, e.u, e.y, e.observed, np.linspace(e.t[0], e.t[-1], DENSE))
        records.append(Experiment(*dense[:3], e.name, None, e.events, dense[3]))
    out = copy.copy(obj)
    out.units = Units.of(obj.problem, records)
    out.data = (*out.units.arrays(), obj.data[5])
    if obj.censored:  # the curves' times: none is a censored sample
        out.data += (jnp.zeros_like(out.data[2]),)
    return out


def units_figure(res, output: int = 0):
    """Each unit's observations, its own prediction (η̂) and the typical unit's (η = 0)."""
    import matplotlib.pyplot as plt

    units, typical, own = _predictions(res, dense=True)
    n = min(len(units.names), GRID_MAX)
    cols = int(np.ceil(np.sqrt(n)))
    rows = int(np.ceil(n / cols))
    fig, axes = plt.subplots(rows, cols, figsize=(2.4 * cols, 1.9 * rows), squeeze=False,
                             sharex=True, sharey=True)  # fmt: skip
    name = res.problem.model.outputs[output]
    for i, ax in enumerate(axes.flat):
        if i >= n:
            ax.set_visible(False)
            continue
        k = int(units.samples[i])
        t = units.t[i, :k]
        seen = units.mask[i, :k, output] > 0  # rows of a dose alone are not observations
        ax.plot(t[seen], units.y[i, :k, output][seen], "o", ms=3, color="k", label="observed")
        ax.plot(t, own[i, :k, output], "-", color="C0", label="individual")
        ax.plot(t, typical[i, :k, output], "--", color="C1", label="population")
        ax.set_title(f"unit {units.names[i]}", fontsize=8)
        ax.tick_params(labelsize=7)
    axes.flat[0].legend(fontsize=6)
    more = "" if len(units.names) <= n else f" (first {n} of {len(units.names)} units)"
    fig.suptitle(f"{name}: data and fits{more}", fontsize=10)
    fig.supxlabel("time", fontsize=9)
    fig.tight_layout()
    return fig


def observed_predicted_figure(res, output: int = 0):
    """Observed against population (η = 0) and individual (η̂) predictions."""
    import matplotlib.pyplot as plt

    units, typical, own = _predictions(res)
    seen = units.mask[..., output] > 0
    y = units.y[..., output][seen]
    fig, axes = plt.subplots(1, 2, figsize=(8, 3.8))
    for ax, pred, what in ((axes[0], typical, "population"), (axes[1], own, "individual")):
        p = pred[..., output][seen]
        ax.plot(p, y, "o", ms=3, alpha=0.7)
        lo, hi = float(min(p.min(), y.min())), float(max(p.max(), y.max()))
        ax.plot([lo, hi], [lo, hi], "k-", lw=0.8, label="observed = predicted")
        ax.set_xlabel(f"{what} prediction")
        ax.set_ylabel("observed")
        ax.set_title(f"{what} (η {'= 0' if what == 'population' else '= η̂'})")
        ax.legend(fontsize=7)
    fig.tight_layout()
    return fig


def vpc(res, replicates: int = 200, seed: int = 0, bins: int = 8, output: int = 0):
    """The visual predictive check's numbers: per time bin, the observed 5/50/95 %
    percentiles and the 5/50/95 % range of each over ``replicates`` fleets simulated at
    the observed times (η ~ N(0, Ω), individual parameters drawn from the fitted units'
    values, noise of the fitted residual error). Returns a dict of arrays: centre (B,),
    observed (B, 3), simulated (B, 3, 3) [percentile, range]."""
    obj = res.objective_function
    units = obj.units
    rng = np.random.default_rng(seed)
    omega = np.array([v["omega"] for v in res.population.values()])
    L = np.asarray(obj.cholesky(res.x[obj.qp : obj.first_shared])) if obj.full else None
    qp, E = obj.qp, len(res.etas)
    seen = units.mask[..., output] > 0
    t = units.t[seen]
    edges = np.unique(np.quantile(t, np.linspace(0, 1, bins + 1)))
    which = np.clip(np.searchsorted(edges, t, side="right") - 1, 0, len(edges) - 2)
    levels = (5, 50, 95)

    def percentiles(values):
        return np.array(
            [np.percentile(values[which == b], levels) if (which == b).any() else [np.nan] * 3
             for b in range(len(edges) - 1)]
        )  # fmt: skip

    sims = []
    for _ in range(replicates):
        etas = np.array(res.etas)
        if obj.q > qp:  # individual values: drawn from the fitted units'
            etas = etas[rng.integers(0, E, E)]
        z = rng.standard_normal((E, qp))
        etas[:, :qp] = z * omega if L is None else z @ L.T  # η ~ N(0, Ω)
        pred = np.asarray(obj.predict_all(res.x, etas))[..., output]
        sd = _noise_sd(res, obj, etas, pred.shape, output)
        pred = pred[seen]
        z = rng.standard_normal(pred.shape)
        sims.append(percentiles(obj.error.sample(pred, sd[seen], z, output)))
    sims_a = np.stack(sims)  # (R, B, 3)
    centre = np.array([t[which == b].mean() if (which == b).any() else np.nan
                       for b in range(len(edges) - 1)])  # fmt: skip
    return {
        "centre": centre,
        "observed": percentiles(units.y[..., output][seen]),
        "simulated": np.percentile(sims_a, levels, axis=0).transpose(1, 2, 0),
    }


def _noise_sd(res, obj, etas, shape, output: int) -> np.ndarray:
    """The residual SD of each simulated sample of ``output``."""
    if obj.plain:  # the output's one term: σ on its scale
        return np.full(shape, obj.error.constant_sd(obj.split(res.x)[3])[output])
    return obj.residual_sd(res.x, etas)[..., output]


def drawn(res) -> list[tuple]:
    """(file stem, figure builder) of each figure a population fit draws: the units and
    observed against predicted, and where there is an Ω to simulate from and a
    finite fit, the visual predictive check and the residuals."""
    out = [("units", units_figure), ("observed_predicted", observed_predicted_figure)]
    if res.population and np.isfinite(res.objective):
        out += [("vpc", vpc_figure), ("residuals", residuals_figure)]
    return out


def vpc_figure(res, output: int = 0):
    import matplotlib.pyplot as plt

    v = vpc(res, output=output)
    fig, ax = plt.subplots(figsize=(6.5, 4))
    c = v["centre"]
    for j, (level, colour) in enumerate(((5, "C0"), (50, "C3"), (95, "C0"))):
        band = v["simulated"][:, j]
        ax.fill_between(c, band[:, 0], band[:, 2], color=colour, alpha=0.2,
                        label=f"simulated {level} % (90 % range)")  # fmt: skip
        ax.plot(c, v["observed"][:, j], "-o", color=colour, ms=3, label=f"observed {level} %")
    name = res.problem.model.outputs[output]
    ax.set_xlabel("time (bin mean)")
    ax.set_ylabel(name)
    ax.set_title("visual predictive check (200 simulated fleets)")
    ax.legend(fontsize=6, ncol=2)
    fig.tight_layout()
    return fig


def residuals_figure(res, output: int = 0):
    """The population modeller's four residual panels of ``output``: CWRES against
    time and against PRED, IWRES against IPRED, and CWRES and NPDE against the normal
    quantiles (each should scatter evenly about 0, within ±2, without a trend)."""
    import matplotlib.pyplot as plt

    from ..analysis.quantiles import normal

    tab = res.table()
    name = res.problem.model.outputs[output]
    keep = tab["OUTPUT"] == name
    col = {k: np.asarray(v[keep], dtype=float) for k, v in tab.items() if k not in ("ID", "OUTPUT")}
    fig, axes = plt.subplots(2, 2, figsize=(8, 6.4))
    panels = (("TIME", "CWRES", "time"), ("PRED", "CWRES", "population prediction"),
              ("IPRED", "IWRES", "individual prediction"))  # fmt: skip
    for ax, (x, y, label) in zip(axes.flat, panels, strict=False):
        ax.plot(col[x], col[y], "o", ms=3, alpha=0.6)
        for level, style in ((0.0, "-"), (2.0, ":"), (-2.0, ":")):
            ax.axhline(level, color="k", lw=0.8, ls=style)
        ax.set_xlabel(label)
        ax.set_ylabel(y)
    ax = axes.flat[3]
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
    fig.suptitle(f"{name}: residuals ({int(keep.sum())} observations)", fontsize=10)
    fig.tight_layout()
    return fig
