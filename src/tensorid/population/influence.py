"""Which unit moves a population's estimates most: the fleet's data sensitivity.

The objective is a sum over units, O(ψ) = Σ_i O_i(ψ) (each at its own η̂). Without unit
i the optimum moves to where ∇(O − O_i) = 0; one exact Newton step from ψ̂ gives it,

    ψ̂_(−i) − ψ̂ ≈ −(H − H_i)⁻¹ (g − g_i),      g = Σ g_i ≈ 0 at ψ̂,

with every unit's g_i and H_i the fit's own exact derivatives (objective.py): one
evaluation ranks every unit. A step is not the refit where O is far from quadratic
(theophylline's most influential unit: −1.41 SE for log ka by the step, −0.73 by the
refit), so the ``refits`` units ranked first are then refitted without their data, from
ψ̂ (the trust region on the exact derivatives, a few iterations), and their shifts are
the refits'.
Reported per unit as each estimate's shift in its standard errors and as Cook's
distance D_i = Δψᵀ cov⁻¹ Δψ / k, the squared shift of all estimates together in the
metric of their covariance (about 1 or more: a unit the estimates lean on). A fit
with individual parameters gets the steps, not the refits (a unit without data has
no value of its own parameters to fit).
"""

from __future__ import annotations

import copy
import dataclasses

import jax.numpy as jnp
import numpy as np

from ..solve.minimize import interrupted, minimize_trust_region
from .profiles import Marginal


def unit_influence(res, refits: int = 5) -> list[dict]:
    """Each unit's pull on the fit ``res`` (PopulationResult), largest first.

    Arguments:
        res: the fit. refits: how many of the units ranked first are refitted without
            their data (0: the Newton step alone for every unit).

    Returns:
        [{"id", "cook" (Cook's distance), "shift" ({ψ name: the estimate's move without
        the unit, in its standard errors}), "largest" (the name it moves most),
        "refitted" (whether by a refit, else by the step)}].
    """
    obj = res.objective_function
    if not res.success:
        raise ValueError(f"unit influence needs a fit that converged; this one {res.message}")
    psi, etas = np.asarray(res.x), np.asarray(res.etas)
    _, g, H, _ = obj.evaluation(psi, etas)
    G, Htot = g.sum(0), H.sum(0)
    cov = np.where(np.isfinite(res.cov), res.cov, 0.0)  # (NaN: a direction not measured)
    se, info = np.sqrt(np.abs(np.diag(cov))), np.linalg.pinv(cov, hermitian=True)
    out = []
    for i, uid in enumerate(obj.units.names):
        step = -np.linalg.lstsq(Htot - H[i], G - g[i], rcond=1e-12)[0]
        out.append(_entry(res, uid, step, se, info, False) | {"index": i})
    out.sort(key=lambda d: -d["cook"])
    for d in out[:refits] if len(out) > 2 and obj.q == obj.qp else []:
        moved = _refit(obj, psi, etas, d["index"])
        if moved is not None:
            d.update(_entry(res, d["id"], moved, se, info, True))
    for d in out:
        del d["index"]
    return sorted(out, key=lambda d: -d["cook"])


def _entry(res, uid, step, se, info, refitted: bool) -> dict:
    """One unit's record: its shift ``step`` of ψ in SEs and as Cook's distance
    (``info``: the pseudo-inverse of the estimates' covariance)."""
    with np.errstate(invalid="ignore", divide="ignore"):
        shift = np.where(se > 0, step / se, np.nan)
    measured = np.where(np.isfinite(shift), np.abs(shift), -1.0)
    return {"id": uid, "cook": float(step @ info @ step / len(step)),
            "shift": {n: float(v) for n, v in zip(res.names, shift, strict=True)},
            "largest": res.names[int(np.argmax(measured))], "refitted": refitted}  # fmt: skip


def _refit(obj, psi, etas, i: int):
    """ψ̂ without unit i less ψ̂, by the fit's own outer loop from ψ̂; None where that
    refit does not converge (the step stands)."""
    held = Marginal(without_data(obj, i), etas)
    r = minimize_trust_region(held.cost_grad_hess, psi, held.lower, held.upper, radius=1.0,
                              fatol=-np.inf, maxiter=50)  # fmt: skip
    return np.asarray(r.x) - psi if interrupted(r).status.success else None


def without_data(obj, i: int):
    """``obj`` with unit i's observations masked out. A unit without data has
    marginal likelihood 1 whatever ψ (its η integrates to 1; the Laplace approximation
    is exact for the Gaussian prior it is left with), so this is the fit without the
    unit, on the programs already compiled for the fleet's size (a fleet one unit
    smaller would compile every program again)."""
    new = copy.copy(obj)
    u = obj.units
    mask = u.mask.copy()
    mask[i] = 0.0
    cens = None if u.cens is None else u.cens.copy()
    data = list(obj.data)
    data[3] = jnp.asarray(mask)  # (t, u, y, mask, x0, p[, cens]): Objective.data
    if cens is not None:
        cens[i] = 0.0
        data[6] = jnp.asarray(cens)
    new.units = dataclasses.replace(u, mask=mask, cens=cens)
    new.data, new.unconverged, new.unfinite = tuple(data), [], []
    return new


def influence_lines(influence: list[dict], shown: int = 5) -> list[str]:
    """The console's lines: the units that move the estimates most."""
    if not influence:
        return []
    lines = [
        f"Units that move the estimates most (Cook's distance, and the estimate each "
        f"moves most, in SEs, if left out; all {len(influence)} in fit.json unit_influence):"
    ]
    for d in influence[:shown]:
        n = d["largest"]
        how = "refit" if d["refitted"] else "one Newton step"
        lines.append(f"  unit {str(d['id']):<10} D = {d['cook']:.3g}   {n} {d['shift'][n]:+.2f} SE "
                     f"({how})")  # fmt: skip
    return lines
