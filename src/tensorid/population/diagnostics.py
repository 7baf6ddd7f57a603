r"""A population fit's per-observation diagnostics, in a population modeller's words
(NONMEM's table, nlmixr2/xpose's columns), one row per observation:

    PRED   the typical unit's prediction (η = 0; individual parameters at their median)
    IPRED  the unit's own prediction (η̂, its empirical Bayes estimate)
    RES    DV − PRED,   IRES  DV − IPRED
    IWRES  (h(DV) − h(IPRED)) / σ(IPRED): the individual residual over its SD, on the
           error model's scale h (log for an exponential error; errors.py)
    CWRES  conditional weighted residuals (Hooker et al. 2007): with A = ∂h(ŷ)/∂η at
           η̂, the unit's observations linearised about η̂ have mean
           h(ŷ(η̂)) − A η̂ and covariance C = A Ω Aᵀ + diag σ²(η̂); CWRES = L⁻¹(h(DV) −
           mean) with C = L Lᵀ (time order within the unit)
    NPDE   normalised prediction distribution errors (Brendel et al. 2006): the unit's
           observations and SIMULATIONS of it simulated under the fitted model (η ~
           N(0, Ω), the residual error) decorrelated by the simulations' own mean and
           Cholesky factor; pde the share of simulated values below the observed one
           (kept in [1/2K, 1 − 1/2K]), NPDE = Φ⁻¹(pde)

Each is ~N(0, 1) where the model holds; a trend against time or PRED is model error.
"""

from __future__ import annotations

from statistics import NormalDist

import jax.numpy as jnp
import numpy as np

SIMULATIONS = 200  # replicate fleets behind NPDE (as the visual predictive check's)
COLUMNS = ("ID", "TIME", "OUTPUT", "DV", "PRED", "IPRED", "RES", "IRES", "IWRES", "CWRES",
           "NPDE")  # fmt: skip


def predictions(res) -> tuple[np.ndarray, np.ndarray]:
    """(PRED, IPRED) (E, P, S) of every unit at the fit's estimates."""
    obj = res.objective_function
    middle = np.median(res.etas, axis=0)
    middle[: obj.qp] = 0.0
    pred = np.asarray(obj.predict_all(res.x, np.broadcast_to(middle, res.etas.shape)))
    return pred, np.asarray(obj.predict_all(res.x, res.etas))


def table(res, simulations: int = SIMULATIONS, seed: int = 0) -> dict[str, np.ndarray]:
    """The per-observation table (the module docstring's columns), one entry per
    observed sample (censored ones are not in it), units in their order, each unit's
    samples in time order, outputs within a time.

    Arguments:
        res: a population fit's result (random effects; not individual values alone).
        simulations: replicate fleets behind NPDE.
        seed: their random seed.

    Returns:
        {column: array (N,)}: ID and OUTPUT as strings, the rest floats."""
    obj = res.objective_function
    if obj.joint:
        raise ValueError("the diagnostics table is a population fit's: this fit has no "
                         "random effects (individual parameters alone)")  # fmt: skip
    u, err = obj.units, obj.error
    pred, ipred = predictions(res)
    seen = u.mask > 0
    h = lambda v: np.asarray(err.scaled(v, u.mask))  # noqa: E731
    sd = obj.residual_sd(res.x, res.etas, ipred)
    cwres = _cwres(obj, res, h(u.y), h(ipred), sd**2)
    npde = _npde(obj, res, h(u.y), simulations, np.random.default_rng(seed))
    E, P, S = u.y.shape
    ids = np.broadcast_to(np.array(u.names, dtype=object)[:, None, None], (E, P, S))
    outs = np.broadcast_to(np.array(obj.problem.model.outputs, dtype=object), (E, P, S))
    cols = {
        "ID": ids, "TIME": np.broadcast_to(u.t[..., None], (E, P, S)), "OUTPUT": outs,
        "DV": u.y, "PRED": pred, "IPRED": ipred, "RES": u.y - pred, "IRES": u.y - ipred,
        "IWRES": (h(u.y) - h(ipred)) / np.where(seen, sd, 1.0), "CWRES": cwres, "NPDE": npde,
    }  # fmt: skip
    return {k: np.asarray(v)[seen] for k, v in cols.items()}


def _omega(obj, psi) -> np.ndarray:
    L = np.asarray(obj.effects.cholesky(jnp.asarray(psi[obj.qp : obj.first_shared])))
    return L @ L.T


def _cwres(obj, res, hy, hipred, var) -> np.ndarray:
    """CWRES (E, P, S), NaN where not observed."""
    A = obj.slopes(res.x, res.etas)  # ∂h(ŷ)/∂η at η̂ (E, P, S, qp)
    omega, seen = _omega(obj, res.x), obj.units.mask > 0
    out = np.full(hy.shape, np.nan)
    for i in range(hy.shape[0]):
        k = seen[i]
        Ai = A[i][k]  # (n, qp)
        mean = hipred[i][k] - Ai @ res.etas[i, : obj.qp]
        C = Ai @ omega @ Ai.T + np.diag(var[i][k])
        try:
            out[i][k] = np.linalg.solve(np.linalg.cholesky(C), hy[i][k] - mean)
        except np.linalg.LinAlgError:  # (σ² = 0 somewhere: no residual to weigh)
            pass
    return out


def _npde(obj, res, hy, K: int, rng) -> np.ndarray:
    """NPDE (E, P, S) from K fleets simulated at the estimates, NaN where not observed."""
    qp, seen = obj.qp, obj.units.mask > 0
    L = np.linalg.cholesky(_omega(obj, res.x))
    sims = np.empty((K, *hy.shape))
    for k in range(K):
        etas = np.array(res.etas)  # individual values: each unit's own
        etas[:, :qp] = rng.standard_normal((len(etas), qp)) @ L.T
        pred = np.asarray(obj.predict_all(res.x, etas))
        sd = obj.residual_sd(res.x, etas, pred)
        z = rng.standard_normal(pred.shape)
        y = np.stack([obj.error.sample(pred[..., g], sd[..., g], z[..., g], g)
                      for g in range(pred.shape[-1])], axis=-1)  # fmt: skip
        sims[k] = np.asarray(obj.error.scaled(y, obj.units.mask))
    inv = np.vectorize(NormalDist().inv_cdf)
    out = np.full(hy.shape, np.nan)
    for i in range(hy.shape[0]):
        k = seen[i]
        s = sims[:, i][:, k]  # (K, n)
        with np.errstate(all="ignore"):  # (a unit whose simulations overflow: no warning)
            out[i][k] = inv(_pde(s, hy[i][k], K))
    return out


def _pde(s: np.ndarray, obs: np.ndarray, K: int) -> np.ndarray:
    """The prediction discrepancies of one unit's observations ``obs`` (n,) among its
    K simulations ``s`` (K, n), decorrelated; NaN where a simulation is not finite
    (its discrepancies would mean nothing)."""
    if not np.isfinite(s).all():
        return np.full(obs.shape, np.nan)
    centred = s - s.mean(0)
    try:  # decorrelated by the simulations' own covariance
        Li = np.linalg.cholesky(centred.T @ centred / (K - 1))
        z = np.linalg.solve(Li, obs - s.mean(0))
        dec = np.linalg.solve(Li, centred.T).T
    except np.linalg.LinAlgError:  # more samples than replicates: standardised only
        scale = np.maximum(centred.std(0, ddof=1), 1e-300)
        z, dec = (obs - s.mean(0)) / scale, centred / scale
    return np.clip((dec < z).mean(0), 1 / (2 * K), 1 - 1 / (2 * K))
