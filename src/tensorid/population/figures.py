"""A population fit's figures, as the arrays they plot (analysis/fleet_figures.py draws
them, in the command's renderer or here): every unit's data with its own fit and the
typical unit's (a grid of small panels), observed against predicted (population and
individual), a visual predictive check (the observed percentiles over time beside
those of fleets simulated from the fitted population) and the residual panels."""

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


def units_arguments(res, output: int = 0) -> dict:
    """The units figure's arrays: each unit's observations, its own prediction (η̂)
    and the typical unit's (η = 0), the first GRID_MAX units."""
    units, typical, own = _predictions(res, dense=True)
    n = min(len(units.names), GRID_MAX)
    panels = []
    for i in range(n):
        k = int(units.samples[i])
        t = units.t[i, :k]
        seen = units.mask[i, :k, output] > 0  # rows of a dose alone are not observations
        panels.append({"name": str(units.names[i]), "t": t, "t_seen": t[seen],
                       "y_seen": units.y[i, :k, output][seen], "own": own[i, :k, output],
                       "typical": typical[i, :k, output]})  # fmt: skip
    more = "" if len(units.names) <= n else f" (first {n} of {len(units.names)} units)"
    return {"units": panels, "output": res.problem.model.outputs[output], "more": more}


def observed_predicted_arguments(res, output: int = 0) -> dict:
    """Observed against population (η = 0) and individual (η̂) predictions."""
    units, typical, own = _predictions(res)
    seen = units.mask[..., output] > 0
    return {"observed": units.y[..., output][seen], "population": typical[..., output][seen],
            "individual": own[..., output][seen]}  # fmt: skip


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
    L = np.asarray(obj.effects.cholesky(res.x[obj.qp : obj.first_shared])) if obj.full else None
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
        every = np.asarray(obj.predict_all(res.x, etas))  # (E, P, S)
        pred = every[..., output]
        sd = _noise_sd(res, obj, etas, every, output)
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


def _noise_sd(res, obj, etas, pred, output: int) -> np.ndarray:
    """The residual SD of each simulated sample of ``output``, the fleet's predictions
    ``pred`` (E, P, S)."""
    if obj.plain:  # the output's one term: σ on its scale
        return np.full(pred.shape[:-1], obj.error.constant_sd(obj.split(res.x)[3])[output])
    return obj.residual_sd(res.x, etas, pred)[..., output]


def figure_jobs(res) -> list[tuple]:
    """(file stem, kind, arguments builder) of each figure a population fit draws: the
    units and observed against predicted, and where there is an Ω to simulate from and
    a finite fit, the visual predictive check and the residuals. The builder computes
    the arrays (here, with JAX); the kind draws them (analysis/fleet_figures.py: in
    the command's renderer, while the command goes on)."""
    kinds = [("units", "units"), ("observed_predicted", "observed_predicted")]
    if res.population and np.isfinite(res.objective):
        kinds += [("vpc", "vpc"), ("residuals", "population_residuals")]
    return [(stem, kind, ARGUMENTS[kind]) for stem, kind in kinds]


def vpc_arguments(res, output: int = 0, replicates: int = 200) -> dict:
    v = vpc(res, replicates=replicates, output=output)
    return {**v, "output": res.problem.model.outputs[output], "replicates": replicates}


def residuals_arguments(res, output: int = 0) -> dict:
    """The table's columns of ``output`` the residual panels plot."""
    tab = res.table()
    name = res.problem.model.outputs[output]
    keep = tab["OUTPUT"] == name
    wanted = ("TIME", "PRED", "IPRED", "CWRES", "IWRES", "NPDE")
    return {"columns": {k: np.asarray(tab[k][keep], dtype=float) for k in wanted},
            "output": name}  # fmt: skip


# each kind of figure (analysis/fleet_figures.py) and the builder of its arrays
ARGUMENTS = {"units": units_arguments, "observed_predicted": observed_predicted_arguments,
             "vpc": vpc_arguments, "population_residuals": residuals_arguments}  # fmt: skip


def figure(res, kind: str, output: int = 0):
    """One of :func:`figure_jobs`' kinds of figure of ``res``, drawn here."""
    from ..analysis.figures import draw

    return draw(kind, ARGUMENTS[kind](res, output))


def units_figure(res, output: int = 0):
    """Each unit's observations, its own prediction (η̂) and the typical unit's (η = 0)."""
    return figure(res, "units", output)


def observed_predicted_figure(res, output: int = 0):
    """Observed against population (η = 0) and individual (η̂) predictions."""
    return figure(res, "observed_predicted", output)


def vpc_figure(res, output: int = 0):
    """The visual predictive check of 200 fleets simulated from the fit."""
    return figure(res, "vpc", output)


def residuals_figure(res, output: int = 0):
    """CWRES against time and PRED, IWRES against IPRED, and the QQ panel."""
    return figure(res, "population_residuals", output)
