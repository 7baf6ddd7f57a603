"""What a constrained fit reports beside its estimates (solve/constrained.py keeps
the constraints): each constraint's value, whether it binds, its Lagrange multiplier,
and what the error bars mean at a binding constraint."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ..solve.curvature import jacobi_scale
from .summary import Table, Tabular, stderr_text
from .uncertainty import FLAT


@dataclass(repr=False)
class ConstraintReport(Tabular):
    """The constraints of a fit at its solution. ``items``: per constraint, ``expr``
    (as written), ``c`` (the function kept >= 0), ``value`` (c at the solution),
    ``active`` and ``multiplier`` (λ >= 0, ∇J = Σ λ ∇c: how much the optimal cost
    would rise per unit the margin c >= 0 is tightened; 0 for a constraint that does
    not bind). ``converged``: every constraint met within its tolerance; ``outer``:
    augmented-Lagrangian iterations. ``restricted_stderr``: with a constraint that
    binds, each unknown's standard error with the binding constraints held as
    equalities (on their tangent space), beside the data's own in the estimates."""

    items: list[dict]
    converged: bool
    outer: int
    restricted_stderr: dict[str, float] = field(default_factory=dict)
    second_order: bool | None = None  # ∇²L > 0 on the active constraints' tangent space
    # per constraint met with equality at λ = 0: its unknowns that sit on a box bound
    # (the bound, not the constraint, holds the estimate there), or [] for none
    unforced: dict[str, list[str]] = field(default_factory=dict)
    # directions of the tangent space along which J is flat: the unknowns each moves
    flat: list[list[str]] = field(default_factory=list)

    @classmethod
    def of(cls, res) -> ConstraintReport:
        """The report of a fit's result whose solve kept constraints (``res.constraints``
        a solve.constrained.ConstraintOutcome), with the restricted error bars."""
        out = res.constraints
        active = np.array([d["active"] for d in out.items], dtype=bool)
        A = res.problem.constraints.evaluate(res.theta)[1][active] if active.any() else None
        tangent, flat, held = None, None, {}
        if A is not None and np.isfinite(res.hess).all():  # J on the tangent space, once
            tangent = _tangent(res, A)
            flat = tangent_flat(res, A, tangent)
            held = restricted_stderr(res, A, tangent, flat) if out.converged else {}
        flat = flat or []
        return cls(out.items, out.converged, out.outer, held, out.second_order, _unforced(res),
                   flat)  # fmt: skip

    def as_dict(self) -> dict:
        return {
            "constraints": self.items,
            "converged": self.converged,
            "outer_iterations": self.outer,
            "restricted_stderr": self.restricted_stderr or None,
            "second_order": self.second_order,
        }

    def blocks(self) -> list:
        rows = [
            [
                d["expr"],
                f"{d['value']:.6g}",
                ("yes, λ = 0" if d["multiplier"] == 0 else "yes") if d["active"] else "no",
                f"{d['multiplier']:.6g}",
            ]
            for d in self.items
        ]
        head = ["constraint", "value of c (>= 0)", "active", "multiplier λ"]
        title = f"constraints ({self.outer} augmented-Lagrangian iterations)"
        out: list = [Table(title, head, rows)]
        return out + self.lines()

    def lines(self) -> list[str]:
        """What the estimates' error bars mean here (the warnings are the result's)."""
        out = []
        for expr, bounded in self.unforced.items():  # active, yet no multiplier: say why
            out.append(
                f"{expr!r} holds with equality but carries no multiplier (λ = 0): "
                + (
                    f"the bound on {', '.join(bounded)} holds the estimate there, not the "
                    "constraint (a bound switched the term off)"
                    if bounded
                    else "the data's own optimum lies on it, so it changes nothing"
                )
            )
        if self.flat:  # flat, not curving down: rounding decides the sign there
            moved = "; ".join(", ".join(f) for f in self.flat)
            out.append(
                "the solution minimises J on the active constraints, not J itself, and J is "
                f"flat on their tangent space along a direction that moves {moved}: the "
                "constraints do not make those unknowns identifiable (any point along it "
                "fits as well; their error bars with the constraints held are unbounded)"
            )
        elif self.second_order is not None:
            out.append(
                "the solution minimises J on the active constraints, not J itself: "
                + (
                    "the Lagrangian's Hessian ∇²J − Σ λ ∇²c is positive definite on their "
                    "tangent space (a strict constrained minimum), whatever ∇²J alone does"
                    if self.second_order
                    else "the Lagrangian's Hessian curves downward on their tangent space "
                    "(not a strict constrained minimum); try other starts"
                )
            )
        if self.restricted_stderr:
            held = ", ".join(f"{n} {stderr_text(v)}" for n, v in self.restricted_stderr.items())
            out.append(
                "error bars: the estimates' are the data's alone (the Hessian of J, as if "
                "there were no constraint), so an interval may reach past an active "
                "constraint into values it excludes; with the active constraints held "
                f"as equalities (their tangent space) the standard errors are {held}"
            )
        return out

    def warnings(self) -> list[str]:
        if self.converged:
            return []
        worst = min(self.items, key=lambda d: d["value"])
        return [
            f"constraint {worst['expr']!r} is not met to tolerance after {self.outer} "
            f"augmented-Lagrangian iterations (c = {worst['value']:.3g}); fit again from "
            "result.theta, or check that the constraints can hold together"
        ]


def restricted_stderr(res, A: np.ndarray, tangent=None, flat=None) -> dict[str, float]:
    """Each unknown's standard error with the rows of A (active constraints' ∇c) held
    as equalities: 2σ² Z (Zᵀ H Z)⁻¹ Zᵀ with Z the null space of A (their tangent
    space), which is C − C Aᵀ (A C Aᵀ)⁻¹ A C where H is invertible (a robust loss's
    sandwich C is restricted by that formula itself). A direction of the
    tangent space along which J is flat (as the error bars judge flat) leaves its
    unknowns unbounded (inf): C alone has dropped such directions, and gave them 0.
    ``tangent`` (:func:`_tangent`) and ``flat`` (:func:`tangent_flat`): where already
    computed."""
    if tangent is None and np.isfinite(res.hess).all():
        tangent = _tangent(res, A)
    flat = tangent_flat(res, A, tangent) if flat is None and tangent is not None else flat
    if not len(A) or not res.success or flat is None:
        return {}
    try:
        u = res.uncertainty()
    except ValueError:
        return {}
    if res.problem.loss.robust:  # the sandwich's covariance, restricted as it stands
        C = u.covariance
        if not np.isfinite(C).all():
            return {}
        var = np.diag(C - C @ A.T @ np.linalg.pinv(A @ C @ A.T) @ A @ C).copy()
    else:
        D, Z, lam, V, keep = tangent
        inv = Z @ ((V[:, keep] / lam[keep]) @ V[:, keep].T) @ Z.T
        var = np.diag(2.0 * u.sigma2 * inv) * D**2
    names = res.problem.theta_names
    for involved in flat:
        for name in involved:
            var[names.index(name)] = np.inf
    se = np.sqrt(np.clip(var, 0.0, None))
    return {n: float(v) for n, v in zip(names, se, strict=True) if not math.isnan(v)}


def _tangent(res, A: np.ndarray):
    """J's exact Hessian on the tangent space of the rows of A, in the Jacobi-scaled
    unknowns of the whole Hessian (θ = D φ; scaled on the tangent space instead, a
    flat direction's own tiny diagonal would be scaled up to 1): (D, Z an orthonormal
    basis of the null space of A D, the eigenvalues and vectors of Zᵀ (D H D) Z, and
    which of them the error bars keep: relative curvature above FLAT)."""
    H = np.asarray(res.hess)
    D = jacobi_scale(H)
    _, sv, Vt = np.linalg.svd(A * D)
    rank = int((sv > 1e-12 * max(sv.max(), 1e-300)).sum())
    Z = Vt[rank:].T
    Hz = Z.T @ (0.5 * (H + H.T) * np.outer(D, D)) @ Z
    lam, V = np.linalg.eigh(Hz)
    keep = lam > FLAT * max(np.abs(lam).max() if lam.size else 0.0, np.finfo(float).tiny)
    return D, Z, lam, V, keep


def tangent_flat(res, A: np.ndarray, tangent=None) -> list[list[str]] | None:
    """The directions of the active constraints' tangent space along which J is flat
    (as uncertainty.flat_directions judges flat), each as the unknowns it moves; None
    where J's Hessian is not finite. ``tangent``: :func:`_tangent`'s, where computed."""
    if not np.isfinite(res.hess).all():
        return None
    D, Z, lam, V, keep = _tangent(res, A) if tangent is None else tangent
    top = max(np.abs(lam).max() if lam.size else 0.0, np.finfo(float).tiny)
    out = []
    for k in np.flatnonzero(np.abs(lam) <= FLAT * top):
        w = D * (Z @ V[:, k])  # the direction in the unknowns
        w = w / np.abs(w).max()
        out.append([n for n, c in zip(res.problem.theta_names, w, strict=True) if abs(c) > 0.1])
    return out


def _unforced(res) -> dict[str, list[str]]:
    """{constraint: its unknowns on a box bound} for each constraint met with
    equality whose multiplier is 0."""
    pr, theta = res.problem, np.asarray(res.theta)
    rows = pr.constraints.evaluate(theta)[1]
    span = np.maximum(np.abs(theta), 1e-12)
    on = (np.abs(theta - pr.lower) <= 1e-9 * span) | (np.abs(theta - pr.upper) <= 1e-9 * span)
    out = {}
    for d, row in zip(res.constraints.items, rows, strict=True):
        if d["active"] and d["multiplier"] == 0:
            involved = np.abs(row) > 0
            out[d["expr"]] = [pr.theta_names[k] for k in np.flatnonzero(involved & on)]
    return out
