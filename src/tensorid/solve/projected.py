"""Trust-region steps that bend at the bounds, for a Hessian given as a matrix.

A step cut off at the first bound it meets is as short as the room that variable has
left: a variable creeping towards its bound (a damping going to zero) then holds
every step to a sliver, the radius shrinks to fit those slivers, and a fit crawls
for hundreds of iterations. So, as in Moré and Toraldo's projected searches (and
TRON, L-BFGS-B):

- the **generalised Cauchy point** minimises the model along the projected
  steepest-descent path P(x − t g), which bends where a variable reaches its bound
  and goes on in the others (Conn, Gould and Toint), within the radius;
- **subspace Newton steps** hold at their bounds the variables that the Cauchy point
  put there, solve the trust-region subproblem in the others, and project the result
  onto the box; repeated while the projection puts more variables on a bound;
- **held Newton steps** do the same with the variables that the Newton step takes
  out of the box held at their bounds: where the gradient points into the box but
  the curvature out (a damping at its bound on a cubic chain, exact Newton), the
  Cauchy point holds nothing and crept 1e-4 at a radius of 0.07 for 150 iterations.

The trust region takes whichever candidate the model rates best, so each step
decreases the model at least as much as the Cauchy point (the convergence theory's
condition), and near a solution with its active set settled, the subspace step is
the Newton step on the free variables.
"""

from __future__ import annotations

import numpy as np

SUBSPACE_ROUNDS = 4  # the most subspace solves per step


def _distance(x, v, lo, hi) -> np.ndarray:
    """For each variable, the t >= 0 at which x + t v reaches its bound (inf: never)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.where(v > 0, (hi - x) / v, np.where(v < 0, (lo - x) / v, np.inf))
    return np.maximum(t, 0.0)


def _to_sphere(d, v, radius) -> float:
    """τ >= 0 with ||d + τ v|| = radius (d inside the sphere)."""
    a, b, c = v @ v, 2.0 * (d @ v), d @ d - radius**2
    return float((-b + np.sqrt(max(b * b - 4.0 * a * c, 0.0))) / (2.0 * a))


def projected_cauchy(x, g, H, lo, hi, free, radius) -> tuple[np.ndarray, float]:
    """The first local minimiser of the model m(d) = g·d + ½ dᵀHd along the projected
    path d(t) = P(x − t g) − x of the ``free`` variables, within ||d|| <= radius.
    Returns (d, m(d))."""
    v = np.where(free, -g, 0.0)
    t_hit = _distance(x, v, lo, hi)
    v[t_hit == 0.0] = 0.0
    d, Hd, m, t = np.zeros_like(x), np.zeros_like(x), 0.0, 0.0
    while v.any():
        t_next = float(t_hit[v != 0].min())
        slope, Hv = float((g + Hd) @ v), H @ v
        curv = float(v @ Hv)
        if not slope < 0:  # the model rises from here: a local minimiser
            break
        tau_r = _to_sphere(d, v, radius)
        tau = min(t_next - t, tau_r)
        if curv > 0:
            tau = min(tau, -slope / curv)
        d, Hd, m = d + tau * v, Hd + tau * Hv, m + tau * slope + 0.5 * tau**2 * curv
        if tau < min(t_next - t, tau_r):  # stopped inside the segment
            break
        if tau_r <= t_next - t:  # reached the radius
            break
        t = t_next
        hit = (v != 0) & (t_hit <= t)
        d[hit] = np.where(v[hit] > 0, hi[hit], lo[hit]) - x[hit]  # exactly on the bound
        v[hit] = 0.0
    return d, m


def subspace_steps(x, g, H, lo, hi, free, radius, d_cauchy, solve) -> list[np.ndarray]:
    """Newton steps with the variables on a bound at the Cauchy point (and those not
    ``free``) held: the subproblem in the rest by ``solve(g, H, radius, mask)``,
    projected onto the box; again with the variables that projection puts on a bound.
    Empty when the Cauchy point put no variable on a bound (the plain Newton step is
    then the same step)."""
    tol = 1e-12 * (1.0 + np.abs(x))
    end = x + d_cauchy
    held = ~free | ((end <= lo + tol) & (g > 0)) | ((end >= hi - tol) & (g < 0))
    if not (held & free).any():
        return []
    return _rounds(x, g, H, lo, hi, radius, held, np.where(held, d_cauchy, 0.0), solve)


def held_newton_steps(x, g, H, lo, hi, free, radius, s, solve) -> list[np.ndarray]:
    """Newton steps with the variables that the Newton step ``s`` takes out of the box
    held at the bound it crosses, the subproblem solved in the rest (as in
    subspace_steps). The Cauchy point cannot find these where the gradient points
    into the box but the model's curvature points out: there it moves the variable
    off its bound, so subspace_steps holds nothing, while projecting ``s`` (the other
    variables' coupled moves kept) or cutting it at that bound (a variable a hair
    from its bound) is no step. Empty when ``s`` stays in the box."""
    out = free & ((x + s < lo) | (x + s > hi))
    if not out.any():
        return []
    d = np.where(out, np.clip(x + s, lo, hi) - x, 0.0)
    return _rounds(x, g, H, lo, hi, radius, ~free | out, d, solve)


def _rounds(x, g, H, lo, hi, radius, held, d, solve) -> list[np.ndarray]:
    """Subspace Newton steps: ``held`` variables moved by ``d``, the subproblem in the
    rest, projected; again with the variables that projection puts on a bound."""
    steps = []
    for _ in range(SUBSPACE_ROUNDS):
        rest = ~held
        room = radius**2 - float(d @ d)
        if not rest.any() or room <= 0.0:
            break
        g_rest = g[rest] + H[np.ix_(rest, held)] @ d[held]
        trial = d.copy()
        trial[rest] = solve(g_rest, H[np.ix_(rest, rest)], np.sqrt(room), rest)[0]
        step = np.clip(x + trial, lo, hi) - x
        steps.append(step)
        clipped = rest & (step != trial)
        if not clipped.any():
            break
        held |= clipped
        d = np.where(held, step, 0.0)
    return steps
