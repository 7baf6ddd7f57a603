"""Inequality constraints c(θ) >= 0 ("Fs >= Fc") kept by the exact-derivative
trust-region methods: an augmented Lagrangian (the method of multipliers, as in
LANCELOT, Conn, Gould and Toint) around the ordinary fit.

Each outer iteration fits the cost plus the Powell-Hestenes-Rockafellar terms of
engine/assembly/constraints.py (multiplier estimates λ, penalties μ) with the method the user
chose, from the last solution, with the exact ∇ and ∇² of the penalised cost: its
Hessian is the Lagrangian's, ∇²J − Σ λ̂ ∇²c, plus μ ∇c ∇cᵀ on the constraints that
bind, so each solve converges as fast as an unconstrained one. Then λ ← max(0, λ − μc),
and μ grows tenfold for a constraint whose violation did not fall by 4. The loop ends
when every |min(c, λ/μ)| (violation and complementarity together) is within ``TOL``
of the constraint's size. A start that violates a constraint is allowed: the first
penalty pulls the fit over. A constraint that does not bind costs nothing: λ stays 0,
its term is 0 where c >= 0, and the fit is the unconstrained one, in one outer iteration.

At the end, a solution still outside a constraint by its tolerance (1e-10 of its size)
is moved onto it by a minimum-norm step in the scaled unknowns, so that every
constraint holds; the result is the ordinary Solution of the Problem at that point
(J, ∇J, ∇²J of the cost alone), with ``constraints`` (a :class:`ConstraintOutcome`)
saying each constraint's value, whether it binds, and its multiplier: λ >= 0 with
∇J = Σ λ ∇c at the solution, the rise of the optimal J per unit the constraint's
margin c >= 0 is tightened. The error bars with the active constraints held are
statistics: tensorid.analysis.constraint_report adds them where the fit's result is
made (``FitResult.of``).
"""

from __future__ import annotations

import copy
from dataclasses import dataclass, replace

import numpy as np

from ..engine.schemes.status import Status
from .solution import Solution

MAX_OUTER = 30
TOL = 1e-10  # violation and complementarity, relative to each constraint's size
ACTIVE = 1e-8  # a constraint within this of its size from 0 binds (or λ > 0)
MU0 = 10.0  # the first penalty: μ c² = MU0·|J0| for c of the constraint's size
GROW, SHRINK = 10.0, 0.25


@dataclass(frozen=True)
class ConstraintOutcome:
    """How a constrained solve ended. ``items``: per constraint ``expr`` (as written),
    ``c`` (the function kept >= 0), ``value`` (c at the solution), ``active`` and
    ``multiplier`` (λ >= 0); ``converged``: every constraint met within its tolerance;
    ``outer``: augmented-Lagrangian iterations; ``second_order``: whether ∇²L > 0 on
    the active constraints' tangent space (None where none binds)."""

    items: list[dict]
    converged: bool
    outer: int
    second_order: bool | None = None


def keep_constraints(problem, fits, method, theta0, options, started) -> Solution:
    """The fit of ``problem`` from ``theta0`` with its constraints kept; ``fits``
    (problem, method, thetas, options, started -> results) fits a penalised copy."""
    cons = problem.constraints
    c, A, _ = cons.evaluate(theta0)
    size = _sizes(c, A, theta0)
    J0 = problem.cost(theta0)
    lam = np.zeros(len(cons))
    mu = MU0 * max(abs(J0) if np.isfinite(J0) else 1.0, 1e-300) / size**2
    theta, done, before, converged, outer = theta0, None, np.full(len(cons), np.inf), False, 0
    while outer < MAX_OUTER:
        outer += 1
        res = fits(_penalised(problem, lam, mu), method, theta[None, :], options, started)[0]
        done = res if done is None else done.followed_by(res, notes=_notes(done, res))
        if res.status is Status.INTERRUPTED or not np.isfinite(res.cost):
            break
        theta, c = res.theta, cons.values(res.theta)
        violation = np.abs(np.minimum(c, lam / mu)) / size
        lam = np.maximum(lam - mu * c, 0.0)
        converged = bool(violation.max() <= TOL)
        if converged and res.success:
            break
        mu = np.where((violation > SHRINK * before) & (violation > TOL), GROW * mu, mu)
        before = violation
    assert done is not None
    if converged:
        theta = _onto(problem, theta, size, done.scale)
    return _result(problem, done, theta, lam, size, converged, outer, started)


def _sizes(c, A, theta) -> np.ndarray:
    """Each constraint's size: its terms' (|∂c/∂θ| |θ|) and its value's, at the start."""
    s = np.abs(A) @ np.abs(theta) + np.abs(c)
    return np.where(s > 0, s, 1.0)


def _penalised(problem, lam, mu):
    """A shallow copy of ``problem`` whose cost carries the augmented-Lagrangian terms."""
    out = copy.copy(problem)
    out.penalty = (np.array(lam, dtype=float), np.array(mu, dtype=float))
    return out


def _notes(before: Solution, after: Solution) -> list[str]:
    """The outer iterations' notes, each once."""
    return before.notes + [n for n in after.notes if n not in before.notes]


def _onto(problem, theta, size, scale, rounds: int = 3) -> np.ndarray:
    """θ moved onto the constraints it violates (by their tolerance at most) by the
    minimum-norm step in the scaled unknowns θ/scale, kept in the bounds."""
    cons = problem.constraints
    for _ in range(rounds):
        c, A, _ = cons.evaluate(theta)
        out = c < 0
        if not out.any():
            break
        As = A[out] * scale
        target = -c[out] + 4 * np.finfo(float).eps * size[out]  # clear of rounding
        step = scale * (As.T @ np.linalg.lstsq(As @ As.T, target, rcond=None)[0])
        theta = np.clip(theta + step, problem.lower, problem.upper)
    return theta


def _result(problem, done, theta, lam, size, converged, outer, started) -> Solution:
    """The Solution of ``problem`` at θ, with its constraints' outcome."""
    if done.status is Status.INTERRUPTED:  # Ctrl-C: end at once, with the best point
        return replace(done, problem=problem)
    status, message = done.status, done.message
    if not converged and status.success:
        status = Status.CONSTRAINTS_VIOLATED
        message = status.message
    res = Solution.at(
        problem, done.method, theta, done.scale, status, message=message,
        stats=done.stats.plus(nfev=1), started=started, history=done.history,
        notes=done.notes, hybrid=done.hybrid, shooting=done.shooting,
    )  # fmt: skip
    if not res.derivatives or not np.isfinite(res.cost):
        return res
    cons = problem.constraints
    c, A, _ = cons.evaluate(theta)
    active = (lam > 0) | (np.abs(c) <= ACTIVE * size)
    items = [
        {
            "expr": k.text,
            "c": k.expr,
            "value": float(c[i]),
            "active": bool(active[i]),
            "multiplier": float(lam[i]),
        }
        for i, k in enumerate(cons.items)
    ]
    # the Lagrangian's projected gradient: at an active constraint ∇J itself is not 0
    phi, gl = theta / res.scale, res.jac - A.T @ lam
    lo, hi = problem.lower / res.scale, problem.upper / res.scale
    pg = np.clip(phi - gl * res.scale, lo, hi) - phi
    ok = converged and active.any()
    second = _second_order(res, lam, A[active], cons.evaluate(theta)[2]) if ok else None
    outcome = ConstraintOutcome(items, converged, outer, second)
    return replace(res, grad_norm=float(np.linalg.norm(pg, np.inf)), constraints=outcome)


def _second_order(res: Solution, lam, A, Hc) -> bool:
    """Whether the Lagrangian's Hessian is positive definite on the null space of A
    (the active constraints' gradients), in the scaled unknowns."""
    D = res.scale
    HL = (res.hess - np.einsum("i,ijk->jk", lam, Hc)) * np.outer(D, D)
    _, sv, Vt = np.linalg.svd(A * D)
    rank = int((sv > 1e-12 * max(sv.max(), 1e-300)).sum())
    Z = Vt[rank:].T
    if Z.shape[1] == 0:
        return True
    w = np.linalg.eigvalsh(0.5 * (Z.T @ HL @ Z + (Z.T @ HL @ Z).T))
    return bool(w.min() > 1e-10 * max(np.abs(w).max(), 1e-300))
