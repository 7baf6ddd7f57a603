"""Profile likelihood of a population fit: −2 log L along one of ψ's entries (a typical
value, an ω, a shared parameter, a residual-error term) with every other re-optimised,
and the likelihood-ratio interval it gives, {c : PL(c) − min ≤ χ²₁(level)} (Wilks;
−2 log L needs no variance estimate).

The tracing is analysis/profiles.py's (predictor–corrector along the exact Hessian,
safeguarded Newton at each end), run on the marginal −2 log L of objective.py: each
evaluation solves every unit's inner problem from the last point's η̂, and its
gradient and Hessian are the fit's own exact ones. ψ holds typical values and ω on
the log scale: the interval is traced there and reported on the parameters' own
scale (a monotone map carries an interval over exactly).
"""

from __future__ import annotations

import types
from collections.abc import Sequence
from dataclasses import replace

import numpy as np

from ..analysis import quantiles
from ..analysis.profiles import Profile, _one
from .boundary import bounds
from .distributed import evaluate_chunk


class Marginal:
    """−2 log L(ψ) of a fitted population as analysis/profiles.py's problem: its K,
    bounds, names, cost and cost_grad_hess (each evaluation's inner solves start from
    the last finite one's η̂)."""

    def __init__(self, obj, etas):
        self.obj = obj
        self.K = obj.size
        self.lower, self.upper = bounds(obj)
        self.theta_names = list(obj.names)
        self.rounding_floor = -np.inf  # a likelihood has no rounding floor (as the fit)
        self.etas = np.asarray(etas)

    def _evaluate(self, psi, hessian: bool):
        psi = np.asarray(psi, dtype=float)
        etas, _, J, g, H = evaluate_chunk(self.obj, psi, self.etas, hessian)
        finite = np.isfinite(J) and np.isfinite(g).all() and (H is None or np.isfinite(H).all())
        if not finite:
            return np.inf, np.zeros(self.K), np.eye(self.K)
        self.etas = etas
        return J, g, H

    def cost(self, psi) -> float:
        return float(self._evaluate(psi, False)[0])

    def cost_grad_hess(self, psi):
        return self._evaluate(psi, True)


def names_of(res) -> dict[str, tuple[int, bool]]:
    """{the user's name (:func:`profile_names`, which follow ψ's order): (its index in
    ψ, whether ψ holds its logarithm)}: the typical values, a diagonal Ω's ω and the
    residual-error terms are logarithms in ψ; shared parameters and a full Ω's
    Cholesky entries are as they are."""
    obj = res.objective_function
    if obj.joint:
        return {n: (j, False) for j, n in enumerate(obj.shared)}
    names = profile_names(obj.problem)  # (the fitted problem: a collapsed ω is gone)
    on_log = [k < obj.qp or (k < obj.first_shared and not obj.full)
              or k >= obj.first_shared + obj.ns for k in range(obj.size)]  # fmt: skip
    return {n: (k, on_log[k]) for k, n in enumerate(names)}


def profile_names(problem) -> list[str]:
    """The names :func:`profile` takes for a fit of ``problem``, in ψ's order (also
    before the fit: the command line's check of --profile): a typical value by its
    parameter's name ("ka"), a diagonal Ω's ω as "omega_ka", a full Ω's Cholesky
    entries by their names in ψ, a shared parameter by its name, a residual-error term
    as "sigma_cp" (ψ's "log_sigma_cp")."""
    from .errors import ResidualErrors

    pop, ind = list(problem.population), list(problem.individual)
    shared = [n for n in problem.free_params if n not in pop + ind]
    if not pop:
        return []  # (individual parameters alone: profile() refuses them)
    kinds = problem.residual_error or {}
    outputs = problem.model.outputs
    kinds = {o: kinds for o in outputs} if isinstance(kinds, str) else kinds
    errors = ResidualErrors([kinds.get(o, "additive") for o in outputs], outputs)
    full = problem.omega == "full" and len(pop) > 1
    rows, cols = np.tril_indices(len(pop), -1)
    omegas = [f"log_omega_{n}" for n in pop] + [
        f"omega_chol_{pop[i]}_{pop[j]}" for i, j in zip(rows, cols, strict=True)
    ] if full else [f"omega_{n}" for n in pop]  # fmt: skip
    return pop + omegas + shared + [n.removeprefix("log_") for n in errors.names]


def default_names(res) -> list[str]:
    """What ``--profile`` alone profiles: the typical values, the ω (a diagonal Ω's)
    and the shared parameters; the residual error's terms only by name."""
    obj = res.objective_function
    if obj.joint:
        return list(obj.shared)
    typical = list(obj.pop[: obj.qp])
    omegas = [] if obj.full else [f"omega_{n}" for n in typical]
    return typical + omegas + list(obj.shared)


def profile(
    res,
    names: Sequence[str] | str | None = None,
    level: float = 0.95,
    *,
    method: str = "integrate",
    max_steps: int = 60,
) -> dict[str, Profile]:
    """Profile likelihood of each of ``names`` at the population fit ``res``.

    Arguments:
        res (PopulationResult): a fit that ended with a finite −2 log L.
        names: see :func:`names_of` (default :func:`default_names`).
        level: the intervals' confidence level (the rise of −2 log L is χ²₁(level)).
        method, max_steps: as :func:`tensorid.profile`.

    Returns:
        {name: :class:`tensorid.Profile`}: values, estimate and interval on the
        parameter's own scale (a typical value, not its log); costs are −2 log L.
    """
    if not 0 < level < 1:
        raise ValueError(f"level must be between 0 and 1, got {level!r}")
    if method not in ("integrate", "refit"):
        raise ValueError(f"method must be 'integrate' or 'refit', got {method!r}")
    if res.method == "joint":
        raise ValueError(
            "profiles of a fit with individual parameters alone (least squares over every "
            "unit's own values) are not made yet: use its error bars"
        )
    if not (res.success and np.isfinite(res.objective)):
        raise ValueError(f"profiles need a fit that converged; this one {res.message}")
    known = names_of(res)
    names = default_names(res) if names is None else [names] if isinstance(names, str) else names
    unknown = [n for n in names if n not in known]
    if unknown:
        raise ValueError(f"profile: unknown names {unknown}; a population fit's are {list(known)}")
    problem = Marginal(res.objective_function, res.etas)
    at = types.SimpleNamespace(problem=problem, theta=np.asarray(res.x), cost=res.objective,
                               scale=np.ones(problem.K))  # fmt: skip
    dJ = quantiles.chi2(1, level)
    se = np.sqrt(np.where(np.diag(res.cov) > 0, np.diag(res.cov), np.nan))
    out = {}
    with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
        for name in names:
            i, log = known[name]
            problem.etas = np.asarray(res.etas)  # (each profile from the fit's own η̂)
            traced = _one(at, i, dJ, level, se[i], method, max_steps)
            out[name] = _own_scale(traced, name, log)
    return out


def _own_scale(p: Profile, name: str, log: bool) -> Profile:
    """``p`` traced in ψ, on the parameter's scale (exp where ψ holds the log)."""
    back = np.exp if log else np.asarray
    lo, hi = (float(back(v)) for v in p.interval)
    return replace(p, name=name, estimate=float(back(p.estimate)), values=back(p.values),
                   interval=(lo, hi))  # fmt: skip
