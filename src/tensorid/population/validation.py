"""Held-out units: a fitted population predicting units it was not fitted to.

Each new unit gets its empirical Bayes estimate η̂ (the mode of its η given its own
data and the fitted ψ: the inner problem of objective.py with ψ held) and two
predictions scored against its observations: the individual one (IPRED, at η̂: how
well the model follows the unit once its own data have spoken) and the population one
(PRED, at η = 0: the typical unit, what the fit predicts before any of the unit's
data). Scores are goodness of fit (MATLAB's FitPercent / 100) and RMS per output, on
the observed samples alone.
"""

from __future__ import annotations

import copy
from collections.abc import Mapping

import numpy as np

from ..engine.modelling.metrics import gof
from .objective import Objective


def held_out(res, problem) -> list[dict]:
    """Score the fitted population ``res`` on the units of ``problem``.

    Arguments:
        res (PopulationResult): the fit.
        problem: a :class:`tensorid.Problem` over the held-out units with the fit's
            model, parameter kinds (population, individual, shared, fixed values) and
            residual-error models (build it as the fitted one, with other records).

    Returns:
        per unit {"id", "eta" (random effects), "params" (its values at η̂), "gof"
        and "rmse" of IPRED, "gof_pred" and "rmse_pred" of PRED (per output, or one
        number for one output; PRED is None where there are individual parameters,
        which have no typical value), "observations", "converged"}.
    """
    fitted = res.objective_function
    obj = Objective(_as_fitted(problem, fitted), fitted.method)
    if not res.success:
        raise ValueError(f"held-out units need a fit that converged; this one {res.message}")
    if list(obj.names) != list(fitted.names) or obj.pop != fitted.pop:
        raise ValueError(
            "the held-out units' problem does not have the fit's unknowns "
            f"({list(obj.names)} against {list(fitted.names)}): build it with the same "
            "model, population, individual, fixed and residual_error settings"
        )
    psi = np.asarray(res.x)
    out, etas = _estimates(obj, psi)
    own = np.asarray(obj.predict_all(psi, etas))
    typical = None
    if obj.q == obj.qp:  # random effects alone: η = 0 is the typical unit
        typical = np.asarray(obj.predict_all(psi, np.zeros_like(etas)))
    for i, entry in enumerate(out):
        entry.update(_scores(obj.units, i, own, ""))
        entry.update(_scores(obj.units, i, typical, "_pred"))
    return out


def empirical_bayes(problem, unknowns: Mapping[str, float], method: str = "focei") -> list[dict]:
    """Each unit's empirical Bayes estimate with the population ψ held: the mode of its
    η given its own data, and its parameter values there (IPRED's parameters).

    Arguments:
        problem: a :class:`tensorid.Problem` over the units, with the fit's model and
            parameter kinds (population, individual, shared, fixed values), residual-
            error models and discretisation.
        unknowns: the fit's ψ by name (a fit.json's ``unknowns``); they must be the
            unknowns of ``problem``'s population objective, in its order.
        method: the fit's approximation ("focei", "laplace"): the inner problem is the
            same for both.

    Returns:
        per unit {"id", "eta", "params" (the population and individual parameters at
        η̂), "converged", "observations"}.
    """
    obj = Objective(problem, method)
    if list(unknowns) != list(obj.names):
        raise ValueError(
            f"the fit's unknowns {list(unknowns)} are not those of this model and these "
            f"settings {list(obj.names)}: give the model file it was fitted with"
        )
    return _estimates(obj, np.asarray(list(unknowns.values()), dtype=float))[0]


def _estimates(obj, psi) -> tuple[list[dict], np.ndarray]:
    """(per unit {"id", "eta", "params", "converged", "observations"}, η̂ (E, q))."""
    etas, _ = obj.solve_inner(psi, obj.start_etas())
    u, out = obj.units, []
    lost = set(obj.unconverged) | set(obj.unfinite)
    for i, uid in enumerate(u.names):
        eta = {n: float(etas[i, k]) for k, n in enumerate(obj.pop[: obj.qp])}
        params = {
            n: float(np.exp(psi[k] + etas[i, k]) if k < obj.qp else etas[i, k])
            for k, n in enumerate(obj.pop)
        }
        out.append({"id": uid, "eta": eta, "params": params, "converged": uid not in lost,
                    "observations": int(u.mask[i].sum())})  # fmt: skip
    return out, np.asarray(etas)


def _as_fitted(problem, fitted):
    """``problem`` as the fit ended: the random effects it dropped (collapsed to 0,
    made shared: boundary.py) dropped here too, and the default substeps raised as
    the fit raised them (a user's own are kept)."""
    dropped = [n for n in problem.population if n not in fitted.pop]
    if dropped:
        problem = copy.copy(problem)
        problem.population = {n: w for n, w in problem.population.items() if n not in dropped}
    d, fit = problem.discretisation, fitted.problem.discretisation
    if not d.chosen and d.substeps != fit.substeps:
        problem = problem.with_substeps(fit.substeps)
    return problem


def _scores(u, i: int, yhat, suffix: str) -> dict:
    """{"gof" + suffix, "rmse" + suffix} of unit i's observed samples (per output)."""
    if yhat is None:
        return {f"gof{suffix}": None, f"rmse{suffix}": None}
    g, r = [], []
    for s in range(yhat.shape[-1]):
        seen = u.mask[i, :, s] > 0
        y, f = u.y[i, seen, s], yhat[i, seen, s]
        g.append(float(gof(y, f)) if seen.sum() >= 2 else float("nan"))
        r.append(float(np.sqrt(np.mean((y - f) ** 2))) if seen.any() else float("nan"))
    one = len(g) == 1
    return {f"gof{suffix}": g[0] if one else g, f"rmse{suffix}": r[0] if one else r}


def held_out_lines(scores: list[dict], outputs) -> list[str]:
    """The console's table of held-out units: each unit's fit % of IPRED and PRED."""
    if not scores:
        return []
    lines = [
        f"Held-out units ({len(scores)}): fit % of the individual prediction (IPRED, η̂ "
        "from the unit's data) and of the population one (PRED, the typical unit)"
    ]
    lines.append(f"  {'unit':<12} {'output':<8} {'IPRED %':>9} {'PRED %':>9} {'RMS':>10}")
    for s in scores:
        for k, name in enumerate(outputs):
            pick = lambda v, k=k: v if np.ndim(v) == 0 else v[k]  # noqa: E731
            ip, pr = pick(s["gof"]), s["gof_pred"]
            pr_text = "" if pr is None else f"{100 * pick(pr):9.1f}"
            lines.append(f"  {str(s['id']):<12} {name:<8} {100 * ip:9.1f} {pr_text:>9} "
                         f"{pick(s['rmse']):10.4g}")  # fmt: skip
    return lines
