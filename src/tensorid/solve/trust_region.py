"""Trust-region minimisation with an exact subproblem solver and simple bounds.

K (the number of unknowns) is small in grey-box identification, so each
subproblem  min g·s + ½ sᵀHs, ||s|| <= Δ  is solved exactly through an eigen-
decomposition of H (Moré–Sorensen's conditions, hard case included): indefinite
Hessians far from the optimum are handled, and near it the step is the Newton
step, so convergence is quadratic. Bounds are handled by an active set (variables
on a bound with the gradient pushing outward are held) and a projected step.

With Hessian-vector products only (H a function v -> Hv), the subproblem is solved
approximately by Steihaug-Toint truncated CG instead, to the forcing tolerance
||r|| <= min(0.5, sqrt||g||) ||g||, which keeps convergence superlinear.

A trial point where the cost is not finite (the simulation blew up) is an ordinary
rejected step: ρ = -inf, the radius shrinks, and the iterate stays where it was.
"""

from __future__ import annotations

from collections.abc import Callable, Generator
from dataclasses import dataclass, field

import numpy as np

from ..engine.schemes.status import Status
from .curvature import negative_curvature
from .projected import held_newton_steps, projected_cauchy, subspace_steps


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
        if l_hi - l_lo <= 1e-15 * l_hi:  # relative: H may be 1e-3 (J0 >> J), see curvature.py
            break
    s = -Q @ (a / (lam + l))
    n = np.linalg.norm(s)
    if n > radius:  # numerical overshoot: keep strictly inside
        s *= radius / n
    return s, True


def steihaug_cg(
    g: np.ndarray, hessp: Callable[[np.ndarray], np.ndarray], radius: float, maxiter: int
) -> tuple[np.ndarray, np.ndarray, float]:
    """Approximate minimiser of g·s + ½ sᵀHs over ||s|| <= radius by truncated CG.

    Returns (s, Hs, gᵀHg): the step, H times it (for the model value without another
    product) and the curvature along -g (for the Cauchy step), the latter from the
    first CG product."""
    s, Hs = np.zeros_like(g), np.zeros_like(g)
    r, d = g.copy(), -g
    rr = float(r @ r)
    tol = min(0.5, np.sqrt(np.sqrt(rr))) * np.sqrt(rr)
    gHg = np.nan

    def to_boundary(d, Hd):
        # τ > 0 with ||s + τ d|| = Δ
        a, b, c = d @ d, 2.0 * (s @ d), s @ s - radius**2
        tau = (-b + np.sqrt(max(b * b - 4.0 * a * c, 0.0))) / (2.0 * a)
        return s + tau * d, Hs + tau * Hd

    for i in range(maxiter):
        Hd = hessp(d)
        dHd = float(d @ Hd)
        if i == 0:
            gHg = dHd
        if not dHd > 0:  # negative curvature (or a failed product): go to the boundary
            return (*to_boundary(d, Hd), gHg)
        alpha = rr / dHd
        if np.linalg.norm(s + alpha * d) >= radius:
            return (*to_boundary(d, Hd), gHg)
        s, Hs = s + alpha * d, Hs + alpha * Hd
        r = r + alpha * Hd
        rr_new = float(r @ r)
        if np.sqrt(rr_new) <= tol:
            break
        d = -r + (rr_new / rr) * d
        rr = rr_new
    return s, Hs, gHg


@dataclass
class TRResult:
    """How a trust-region run ended; ``success`` and ``message`` derive from ``status``
    (``detail`` is appended to the message, e.g. the iteration limit)."""

    x: np.ndarray
    fun: float
    jac: np.ndarray
    hess: np.ndarray | None  # None when only Hessian-vector products were used
    nit: int
    nfev: int
    status: Status
    history: list[dict] = field(default_factory=list)
    nhev: int = 0  # Hessian-vector products
    detail: str = ""

    @property
    def success(self) -> bool:
        return self.status.success

    @property
    def message(self) -> str:
        return self.status.describe(self.detail)


def _projected_gradient(x, g, lo, hi):
    return np.clip(x - g, lo, hi) - x


def _room(x, v, lo, hi) -> float:
    """Largest α with lo <= x + αv <= hi."""
    with np.errstate(divide="ignore", invalid="ignore"):
        r = np.where(v > 0, (hi - x) / v, np.where(v < 0, (lo - x) / v, np.inf))
    return max(float(r.min()), 0.0)


def _cauchy_step(x, g, curv, lo, hi, free, radius):
    """Minimiser of the model along the steepest-descent direction v of the free
    variables (curv = vᵀHv), within the radius and the bounds: a step with guaranteed
    decrease whenever the projected gradient is not zero, whatever the Newton step
    does. Returns (step, model value)."""
    v = np.where(free, -g, 0.0)
    vv = float(v @ v)
    if vv == 0.0:
        return v, 0.0
    alpha = min(radius / np.sqrt(vv), _room(x, v, lo, hi))
    if curv > 0:
        alpha = min(alpha, vv / curv)
    return alpha * v, float(-alpha * vv + 0.5 * alpha**2 * curv)


def _newton_step(g, H, free, radius, nhev, subproblem=None):
    """(s, Hs, vᵀHv) for the free variables, v = -g: exactly from a matrix H (by
    ``subproblem(g, H, radius, free)`` where given: a structured solver), or by
    truncated CG from a product function H(v)."""
    s, Hs = np.zeros_like(g), np.zeros_like(g)
    if callable(H):

        def hessp(d):
            nhev[0] += 1
            full = np.zeros_like(g)
            full[free] = d
            return H(full)[free]

        s[free], Hs[free], curv = steihaug_cg(g[free], hessp, radius, 2 * int(free.sum()) + 2)
        return s, Hs, curv
    Hf = H[np.ix_(free, free)]
    if subproblem is None:
        s[free], _ = solve_subproblem(g[free], Hf, radius)
    else:
        s[free], _ = subproblem(g[free], Hf, radius, free)
    Hs[free] = Hf @ s[free]
    return s, Hs, float(g[free] @ Hf @ g[free])


def _candidate_step(x, g, H, lo, hi, free, radius, nhev, sub=None) -> tuple[np.ndarray, float]:
    """The best feasible step by the model's prediction among: the Newton (or CG) step
    projected onto the box, and truncated at the box; the Cauchy step; and, for a
    matrix H, the generalised Cauchy point along the projected path and the subspace
    Newton steps from it (projected.py). Returns (step, predicted decrease)."""
    s, Hs, curv = _newton_step(g, H, free, radius, nhev, sub)
    d_proj = np.clip(x + s, lo, hi) - x
    beta = min(1.0, _room(x, s, lo, hi))
    d_trunc = beta * s
    m_s = float(g @ s + 0.5 * s @ Hs)
    if np.array_equal(d_proj, s):
        m_proj = m_s
    else:
        nhev[0] += callable(H)
        m_proj = float(g @ d_proj + 0.5 * d_proj @ (H(d_proj) if callable(H) else H @ d_proj))
    m_trunc = float(beta * (g @ s) + 0.5 * beta**2 * (s @ Hs))
    steps, values = [d_proj, d_trunc], [m_proj, m_trunc]
    if callable(H):
        d_cauchy, m_cauchy = _cauchy_step(x, g, curv, lo, hi, free, radius)
        steps.append(d_cauchy)
        values.append(m_cauchy)
    else:
        d_cauchy, m_cauchy = projected_cauchy(x, g, H, lo, hi, free, radius)
        steps.append(d_cauchy)
        values.append(m_cauchy)
        solve = sub or (lambda g_, H_, r_, _mask: solve_subproblem(g_, H_, r_))
        for d in subspace_steps(x, g, H, lo, hi, free, radius, d_cauchy, solve) + (
            held_newton_steps(x, g, H, lo, hi, free, radius, s, solve)
        ):
            steps.append(d)
            values.append(float(g @ d + 0.5 * d @ H @ d))
    best = int(np.argmin(values))
    return steps[best], -values[best]


RADIUS_BOUND = 0.99  # a step at least this fraction of the radius is held back by it


def _next_radius(radius: float, rho: float, step: float, max_radius: float) -> float:
    if rho < 0.25:
        return 0.25 * step
    if rho > 0.75 and step >= 0.8 * radius:
        return min(2.0 * radius, max_radius)
    return radius


def _held(x, g, lo, hi) -> np.ndarray:
    """Variables on a bound with the gradient pushing outward: held this iteration."""
    tol_b = 1e-12 * (1.0 + np.abs(x))
    return ((x <= lo + tol_b) & (g > 0)) | ((x >= hi - tol_b) & (g < 0))


def _downhill(H, free) -> bool:
    return not callable(H) and free.sum() <= 500 and negative_curvature(H[np.ix_(free, free)])


def _newton_decrease(g: np.ndarray, H, free: np.ndarray, J: float) -> float:
    """½ gᵀH⁻¹g over the free variables (H's directions of no curvature left out),
    relative to |J| (at least 1e-20: a likelihood's J may pass through 0): the
    decrease a Newton step predicts, which, unlike the gradient, does not depend on how
    θ and J were scaled. The gradient test alone trusts the scales chosen at the start:
    from a filter started at tiny noise intensities (J0 = 3.5e18, the scales of the
    noise parameters 1e-9 of their later values) fits were "converged" with 7.8 of
    their cost still to go by this measure (and at 7.7e6 where the optimum is -2516).
    0 where H is a function or too large to factorise."""
    if callable(H) or free.sum() > 500 or not free.any():
        return 0.0
    mu, V = np.linalg.eigh(0.5 * (H + H.T)[np.ix_(free, free)])
    keep = mu > 1e-12 * max(mu[-1], 0.0)
    c = V[:, keep].T @ g[free]
    return float(0.5 * np.sum(c**2 / mu[keep])) / max(abs(J), 1e-20)


def _collapsed(J: float, pred: float, pg_norm: float, gtol: float) -> Status:
    """The radius fell below xtol with every step rejected: a genuine rounding floor
    (rejected steps of length r mean |g| r is below the cost's rounding noise, so the
    gradient must be small too), or a collapse."""
    tiny = max(abs(J), np.finfo(float).tiny)  # |J|: a likelihood's may be negative
    ok = pred <= 1e-8 * tiny and pg_norm <= max(np.sqrt(gtol), 1e-3 * tiny)
    return Status.MACHINE_PRECISION if ok else Status.RADIUS_COLLAPSED


def _unless_saddle(ended, H, free):
    """``ended`` (from :func:`_ended`), unless it would call a point where H curves
    downward (curvature.py) converged: a saddle's negative curvature is a way down, so
    small steps there (FTOL, XTOL) go on (None), and a radius that collapsed under
    rejected steps there (False) is a collapse, not a rounding floor."""
    if ended not in (Status.FTOL, Status.XTOL, False) or not _downhill(H, free):
        return ended
    return None if ended else Status.RADIUS_COLLAPSED


def _detail(status: Status, maxiter: int, radius: float, history: list, H, free) -> str:
    """What the status's message leaves out: the iteration limit, or what was seen
    where the radius collapsed (a cost curving downward there: a saddle, or a flat
    valley of points as good, where the general reasons the message gives mislead)."""
    if status is Status.MAXITER:
        return f"maxiter={maxiter}"
    if status is not Status.RADIUS_COLLAPSED:
        return ""
    if _downhill(H, free):
        return (
            f"radius {radius:.1e}, where the cost curves downward: a saddle, or a flat "
            "valley of points as good (an unknown the data cannot tell); try other starts"
        )
    if history and history[-1]["accepted"]:
        return f"radius {radius:.1e}; its last steps were accepted, on tiny decreases"
    return ""


def _ended(accepted, held_back, actual, pred, J, d, xscale, radius, ftol, xtol):
    """How the run ends after a step from cost J: a Status, False for "the radius
    collapsed under rejected steps" (a rounding floor or a collapse: _collapsed), or
    None to go on.
    ``held_back``: the step was as long as a radius that had shrunk by orders of
    magnitude (below √xtol); then its small decrease or length says that the radius
    is small, not that the iterate converged."""
    if accepted and not held_back:
        if actual <= ftol * abs(J) and pred <= ftol * abs(J):  # |J|: a likelihood's may be < 0
            return Status.FTOL
        if np.linalg.norm(d, np.inf) <= xtol * xscale:
            return Status.XTOL
    if (held_back or not accepted) and radius <= xtol * xscale:
        # an accepted step lowered the cost measurably: no rounding floor
        return Status.RADIUS_COLLAPSED if accepted else False
    return None


def trust_region_steps(
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
    fatol: float = 0.0,
    eta: float = 0.1,
    callback: Callable[[dict], None] | None = None,
    subproblem: Callable | None = None,
) -> Generator[np.ndarray, tuple, TRResult]:
    """The trust-region iteration as a generator: it yields each point x where it
    needs (J, g, H), is sent them back, and returns the TRResult. This lets a caller
    evaluate the points of many runs in one batched call (multi-start in lock-step).
    A cost at or below ``fatol`` is converged whatever the gradient: the caller's
    rounding floor (data fitted to machine precision)."""
    x = np.clip(np.asarray(x0, dtype=float), lo, hi)
    J, g, H = yield x
    nfev = 1
    nhev = [0]
    history: list[dict] = []

    def record(it, step, rho, accepted):
        pg = float(np.linalg.norm(_projected_gradient(x, g, lo, hi), np.inf))
        entry = dict(iteration=it, cost=float(J), grad_norm=pg, radius=float(radius))
        entry.update(step_norm=float(step), rho=float(rho), accepted=bool(accepted))
        entry.update(nfev=nfev, nhev=nhev[0])
        history.append(entry)
        if callback is not None:
            callback(entry)

    if not np.isfinite(J):
        return TRResult(x, np.inf, g, None if callable(H) else H, 0, nfev, Status.NONFINITE_START)
    record(0, 0.0, np.nan, True)
    status, it = Status.MAXITER, 0
    for it in range(1, maxiter + 1):
        pg_norm = float(np.linalg.norm(_projected_gradient(x, g, lo, hi), np.inf))
        free = ~_held(x, g, lo, hi)
        small = pg_norm <= gtol and _newton_decrease(g, H, free, J) <= np.sqrt(gtol)
        # a saddle is not converged: its negative curvature is a way down (dense H only)
        if J <= fatol or (small and not _downhill(H, free)):
            status = Status.GTOL if small else Status.ROUNDING_FLOOR
            it -= 1
            break
        d, pred = _candidate_step(x, g, H, lo, hi, free, radius, nhev, subproblem)
        step = float(np.linalg.norm(d))
        xscale = 1.0 + np.linalg.norm(x, np.inf)
        if not pred > 0 or step == 0.0:
            # no predicted decrease within the bounds: stationary up to rounding
            ok = pg_norm <= np.sqrt(gtol) or step <= xtol * xscale
            status = Status.NO_FURTHER_DECREASE if ok else Status.NO_PREDICTED_DECREASE
            it -= 1
            break
        x_new = np.clip(x + d, lo, hi)
        J_new, g_new, H_new = yield x_new
        nfev += 1
        actual = J - J_new if np.isfinite(J_new) else -np.inf
        rho = actual / pred
        held_back = step >= RADIUS_BOUND * radius and radius <= np.sqrt(xtol) * xscale
        radius = _next_radius(radius, rho, step, max_radius)
        accepted = rho > eta
        J_old = J
        if accepted:
            x, J, g, H = x_new, J_new, g_new, H_new
        record(it, step, rho, accepted)
        ended = _ended(accepted, held_back, actual, pred, J_old, d, xscale, radius, ftol, xtol)
        ended = _unless_saddle(ended, H, ~_held(x, g, lo, hi))
        if ended is not None:
            status = ended or _collapsed(J, pred, pg_norm, gtol)
            break
    hess = None if callable(H) else H
    detail = _detail(status, maxiter, radius, history, H, ~_held(x, g, lo, hi))
    return TRResult(x, float(J), g, hess, it, nfev, status, history, nhev[0], detail)
