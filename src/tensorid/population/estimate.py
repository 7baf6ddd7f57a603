"""The outer fit of a population: ψ by the trust region with the exact gradient and
Hessian of the marginal likelihood (objective.py), each evaluation first solving every
unit's inner problem from the last point's η̂; then the standard errors from the outer
curvature, each unit's empirical Bayes estimates with their own error bars, and η
shrinkage."""

from __future__ import annotations

import time

import numpy as np

from ..engine.status import Status
from ..fitting.trust_region import minimize_trust_region
from .objective import Objective
from .result import PopulationResult


def _start(obj: Objective) -> np.ndarray:
    """ψ0: the typical values from p0, ω as given, the shared parameters from p0, and
    each output's σ from the residuals of the typical unit."""
    pr, m = obj.problem, obj.problem.model
    mu = [np.log(pr.p0[m.params.index(n)]) for n in obj.pop]
    logw = [np.log(pr.population[n]) for n in obj.pop]
    s = [pr.p0[m.params.index(n)] for n in obj.shared]
    psi = np.array(mu + logw + s + [0.0] * obj.S, dtype=float)
    u = obj.units
    yhat = np.asarray(obj.predict_all(psi, np.zeros((len(u.names), obj.q))))
    n = np.maximum(u.mask.sum((0, 1)), 1)
    sig = np.sqrt((((u.y - yhat) * u.mask) ** 2).sum((0, 1)) / n)
    scale = np.sqrt((u.y**2 * u.mask).sum((0, 1)) / n)
    typical = np.isfinite(sig) & (sig > 1e-8 * scale)
    psi[-obj.S :] = np.log(np.where(typical, sig, np.maximum(0.1 * scale, 1e-12)))
    return psi


def _bounds(obj: Objective) -> tuple[np.ndarray, np.ndarray]:
    pr = obj.problem
    lo, hi = np.full(obj.size, -np.inf), np.full(obj.size, np.inf)
    for j, n in enumerate(obj.shared):
        i = pr.theta_names.index(n)
        lo[2 * obj.q + j], hi[2 * obj.q + j] = pr.lower[i], pr.upper[i]
    for k, n in enumerate(obj.pop):
        i = pr.theta_names.index(n)
        lo[k] = np.log(pr.lower[i]) if pr.lower[i] > 0 else -np.inf
        hi[k] = np.log(pr.upper[i]) if np.isfinite(pr.upper[i]) and pr.upper[i] > 0 else np.inf
    return lo, hi


def fit_population(
    problem,
    method: str = "focei",
    *,
    maxiter: int = 100,
    gtol: float = 1e-8,
    ftol: float = 1e-12,
    xtol: float = 1e-10,
    callback=None,
) -> PopulationResult:
    """Estimate a fleet's population (see :mod:`tensorid.population`).

    Arguments:
        problem: a :class:`tensorid.Problem` with ``population`` set, one experiment
            per unit.
        method: "focei" (default) or "laplace" (see objective.py for the difference).
        maxiter, gtol, ftol, xtol: the outer trust region's limits.
        callback: called with each outer iteration's record (dict).

    Returns:
        :class:`PopulationResult`.
    """
    began = time.perf_counter()
    obj = Objective(problem, method)
    psi0 = _start(obj)
    lo, hi = _bounds(obj)
    state = {"etas": np.zeros((len(obj.units.names), obj.q)), "inner": 0}

    def fun(psi):
        etas, ok = obj.solve_inner(psi, state["etas"])
        if not ok:
            return np.inf, np.zeros(obj.size), np.eye(obj.size)
        O, g = obj.value_grad(psi, etas)
        J, grad = float(O.sum()), g.sum(0)
        if not (np.isfinite(J) and np.isfinite(grad).all()):
            return np.inf, np.zeros(obj.size), np.eye(obj.size)
        H = obj.hessian(psi, etas)
        if not np.isfinite(H).all():
            return np.inf, np.zeros(obj.size), np.eye(obj.size)
        state["etas"] = etas
        return J, grad, H

    try:
        r = minimize_trust_region(
            fun, psi0, lo, hi, maxiter=maxiter, gtol=gtol, ftol=ftol, xtol=xtol,
            callback=callback, radius=1.0,
        )  # fmt: skip
    except KeyboardInterrupt:
        raise
    etas, ok = obj.solve_inner(r.x, state["etas"])
    status = r.status if ok else Status.SOLVER_FAILED
    return PopulationResult.build(obj, r, etas, status, time.perf_counter() - began)
