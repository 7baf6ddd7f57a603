"""Trust-region minimisation with an exact subproblem solver and simple bounds.

K (the number of unknowns) is small in grey-box identification, so each
subproblem  min g·s + ½ sᵀHs, ||s|| <= Δ  is solved exactly through an eigen-
decomposition of H (Moré–Sorensen's conditions, hard case included): indefinite
Hessians far from the optimum are handled, and near it the step is the Newton
step, so convergence is quadratic. Bounds are handled by an active set (variables
on a bound with the gradient pushing outward are held) and a projected step.

A trial point where the cost is not finite (the simulation blew up) is an ordinary
rejected step: ρ = -inf, the radius shrinks, and the iterate stays where it was.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np


def solve_subproblem(g: np.ndarray, H: np.ndarray, radius: float) -> tuple[np.ndarray, bool]:
    """Global minimiser of g·s + ½ sᵀHs over ||s|| <= radius; returns (s, on_boundary)."""
    lam, Q = np.linalg.eigh(0.5 * (H + H.T))
    a = Q.T @ g
    gnorm = np.linalg.norm(g)
    lmin = lam[0]
    scale = max(1.0, np.abs(lam).max())
    if lmin > 1e-14 * scale:
        s = -Q @ (a / lam)
        if np.linalg.norm(s) <= radius:
            return s, False
    elif gnorm == 0.0:
        return radius * Q[:, 0], True  # saddle point: follow negative curvature

    lo = max(0.0, -lmin)
    near = lam - lmin <= 1e-12 * scale
    if lmin <= 1e-14 * scale and np.linalg.norm(a[near]) <= 1e-12 * gnorm:
        # hard case: g is (numerically) orthogonal to the lowest eigenspace
        with np.errstate(divide="ignore", invalid="ignore"):
            coef = np.where(near, 0.0, a / (lam - lmin))
        s0 = -Q @ coef
        n0 = np.linalg.norm(s0)
        if n0 <= radius:
            v = Q[:, 0]
            tau = np.sqrt(max(float(radius**2 - n0**2), 0.0))
            return (s0 + tau * v if g @ v <= 0 else s0 - tau * v), True

    def norm_s(l):
        return np.linalg.norm(a / (lam + l))

    # secular equation φ(l) = 1/||s(l)|| - 1/Δ: increasing and concave in l
    l_lo, l_hi = lo, gnorm / radius + lo + 1e-300
    l = l_lo + 1e-12 * max(scale, l_hi)
    for _ in range(200):
        d = lam + l
        n = norm_s(l)
        phi = 1.0 / n - 1.0 / radius
        if abs(phi) * radius < 1e-12:
            break
        if phi < 0:
            l_lo = l
        else:
            l_hi = l
        dphi = np.sum(a**2 / d**3) / n**3
        l_new = l - phi / dphi if dphi > 0 else np.nan
        l = l_new if l_lo < l_new < l_hi else 0.5 * (l_lo + l_hi)
        if l_hi - l_lo <= 1e-15 * max(1.0, l_hi):
            break
    s = -Q @ (a / (lam + l))
    n = np.linalg.norm(s)
    if n > radius:  # numerical overshoot: keep strictly inside
        s *= radius / n
    return s, True


@dataclass
class TRResult:
    x: np.ndarray
    fun: float
    jac: np.ndarray
    hess: np.ndarray
    nit: int
    nfev: int
    success: bool
    message: str
    history: list[dict] = field(default_factory=list)


def _projected_gradient(x, g, lo, hi):
    return np.clip(x - g, lo, hi) - x


def _room(x, v, lo, hi) -> float:
    """Largest α with lo <= x + αv <= hi."""
    with np.errstate(divide="ignore", invalid="ignore"):
        r = np.where(v > 0, (hi - x) / v, np.where(v < 0, (lo - x) / v, np.inf))
    return max(float(r.min()), 0.0)


def _model(g, H, d) -> float:
    return float(g @ d + 0.5 * d @ H @ d)


def _cauchy_step(x, g, H, lo, hi, free, radius):
    """Minimiser of the model along the steepest-descent direction of the free
    variables, within the radius and the bounds: a step with guaranteed decrease
    whenever the projected gradient is not zero, whatever the Newton step does."""
    v = np.where(free, -g, 0.0)
    vv = float(v @ v)
    if vv == 0.0:
        return v
    alpha = min(radius / np.sqrt(vv), _room(x, v, lo, hi))
    curv = float(v @ H @ v)
    if curv > 0:
        alpha = min(alpha, vv / curv)
    return alpha * v


def minimize_trust_region(
    fun: Callable[[np.ndarray], tuple[float, np.ndarray, np.ndarray]],
    x0: np.ndarray,
    lo: np.ndarray,
    hi: np.ndarray,
    *,
    radius: float = 0.1,
    max_radius: float = 1e4,
    maxiter: int = 200,
    gtol: float = 1e-10,
    ftol: float = 1e-12,
    xtol: float = 1e-12,
    eta: float = 0.1,
    callback: Callable[[dict], None] | None = None,
) -> TRResult:
    """Minimise J with ``fun(x) -> (J, g, H)`` (J = inf marks a failed evaluation) within
    lo <= x <= hi, starting from a feasible x0."""
    x = np.clip(np.asarray(x0, dtype=float), lo, hi)
    J, g, H = fun(x)
    nfev = 1
    history: list[dict] = []

    def record(it, step, rho, accepted):
        entry = {
            "iteration": it,
            "cost": float(J),
            "grad_norm": float(np.linalg.norm(_projected_gradient(x, g, lo, hi), np.inf)),
            "radius": float(radius),
            "step_norm": float(step),
            "rho": float(rho),
            "accepted": bool(accepted),
            "nfev": nfev,
        }
        history.append(entry)
        if callback is not None:
            callback(entry)

    if not np.isfinite(J):
        return TRResult(
            x,
            np.inf,
            g,
            H,
            0,
            nfev,
            False,
            "the cost is not finite at the start: the simulation blows up there; "
            "choose another initial guess or tighter bounds",
            history,
        )
    record(0, 0.0, np.nan, True)
    success, message, it = False, f"iteration limit reached (maxiter={maxiter})", 0
    for it in range(1, maxiter + 1):
        pg = _projected_gradient(x, g, lo, hi)
        if np.linalg.norm(pg, np.inf) <= gtol:
            success, message = True, "converged: projected gradient below gtol"
            it -= 1
            break
        tol_b = 1e-12 * (1.0 + np.abs(x))
        held = ((x <= lo + tol_b) & (g > 0)) | ((x >= hi - tol_b) & (g < 0))
        free = ~held
        s = np.zeros_like(x)
        s[free], _ = solve_subproblem(g[free], H[np.ix_(free, free)], radius)
        # two feasible candidates: projection onto the box, and truncation along s
        d_proj = np.clip(x + s, lo, hi) - x
        d_trunc = min(1.0, _room(x, s, lo, hi)) * s
        d_cauchy = _cauchy_step(x, g, H, lo, hi, free, radius)

        values = [_model(g, H, c) for c in (d_proj, d_trunc, d_cauchy)]
        d = (d_proj, d_trunc, d_cauchy)[int(np.argmin(values))]
        pred = -_model(g, H, d)
        step = float(np.linalg.norm(d))
        xscale = 1.0 + np.linalg.norm(x, np.inf)
        if not pred > 0 or step == 0.0:
            # no predicted decrease within the bounds: stationary up to rounding
            ok = np.linalg.norm(pg, np.inf) <= np.sqrt(gtol) or step <= xtol * xscale
            success = bool(ok)
            message = (
                "converged: no further decrease predicted"
                if ok
                else "stopped: the model predicts no decrease, although the gradient is "
                "not small (check the problem's scaling)"
            )
            it -= 1
            break
        x_new = np.clip(x + d, lo, hi)
        J_new, g_new, H_new = fun(x_new)
        nfev += 1
        actual = J - J_new if np.isfinite(J_new) else -np.inf
        rho = actual / pred
        if rho < 0.25:
            radius = 0.25 * step
        elif rho > 0.75 and step >= 0.8 * radius:
            radius = min(2.0 * radius, max_radius)
        accepted = rho > eta
        J_old = J
        if accepted:
            x, J, g, H = x_new, J_new, g_new, H_new
        record(it, step, rho, accepted)
        if accepted and actual <= ftol * J_old and pred <= ftol * J_old:
            success, message = True, "converged: relative cost decrease below ftol"
            break
        if accepted and np.linalg.norm(d, np.inf) <= xtol * xscale:
            success, message = True, "converged: step below xtol"
            break
        if not accepted and radius <= xtol * xscale:
            # a genuine rounding floor: rejected steps of length r mean |g| r is
            # below the cost's rounding noise, so the gradient must be small too
            tiny = max(J, np.finfo(float).tiny)
            ok = pred <= 1e-8 * tiny and np.linalg.norm(pg, np.inf) <= max(
                np.sqrt(gtol), 1e-3 * tiny
            )
            success = bool(ok)
            message = (
                "converged: no further decrease possible at machine precision"
                if ok
                else "stopped: the trust region collapsed without a decrease (the "
                "cost may be noisy or the simulation fails near this point)"
            )
            break
    return TRResult(x, float(J), g, H, it, nfev, success, message, history)
