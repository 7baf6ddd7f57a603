"""Profile likelihood: the cost along one unknown with every other re-optimised, and
the likelihood-ratio interval it gives.

For an unknown θ_i held at c, the profile is PL(c) = min over θ_{-i} of J(θ). With σ²
estimated as Ĵ/(n − K), the interval at level α is the set of c where

    (PL(c) − Ĵ) / σ̂²  <=  F⁻¹_{1, n−K}(α)

(for a linear model this is exactly the Wald interval; for a nonlinear one it follows
the curved cost surface, and it is one-sided or unbounded where the data say so).

The profile is traced by integration (Chen & Jennrich 2002; Stapor et al. 2018): along
the profile the optimality of θ_{-i} gives, with the exact Hessian H,

    dθ_{-i}/dc = −H_{-i,-i}⁻¹ H_{-i,i},

an Euler step along which predicts the next point; a few exact-Newton trust-region
iterations with θ_i held correct it. Each interval end is then found by safeguarded
Newton on c (the profile's slope at a re-optimised point is ∂J/∂θ_i, already at
hand), each evaluation corrected to convergence. ``method="refit"`` instead
re-fits θ_{-i} from the last point at each trial c (optimisation-based profiles, as
pyPESTO does): the reference the integration is measured against. Both find the
interval ends to the same precision; they differ in how they get near them.
"""

from __future__ import annotations

import time
from collections import Counter
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from ..engine.schemes.status import Status
from ..solve.minimize import interrupted, minimize_trust_region
from . import quantiles
from .summary import Table, Tabular, interval, significant

SIDES = ("lower", "upper")


@dataclass(repr=False)
class Profile(Tabular):
    """The profile of one unknown.

    values, costs : the traced points c and PL(c), sorted by c; thetas (n, K) the
        re-optimised θ at each.
    interval : (lo, hi) likelihood-ratio interval at ``level``; ±inf on a side where
        the profile never rises above the threshold (not identifiable that way).
    ends : per side, how the interval ends: "crossed" (the profile crossed the
        threshold), "bound" (θ_i reached its bound first: the interval is one-sided and
        stops there), "flat" (the profile stayed below the threshold as far as traced:
        practically not identifiable on that side) or "failed" (the model could not be
        simulated further; the interval end is at least the last point reached).
    threshold : the rise of J that bounds the interval; seconds : time taken.
    corrections : how the re-optimisations of θ_{-i} ended, {status name: count}
        ("gtol", "ftol", ... where they converged; "maxiter", "solver_failed", ...
        where not: there PL(c) is over-estimated, and a note says so).
    """

    name: str
    index: int
    estimate: float
    level: float
    threshold: float
    values: np.ndarray
    costs: np.ndarray
    thetas: np.ndarray
    interval: tuple[float, float]
    ends: dict[str, str]
    seconds: float = 0.0
    evaluations: int = 0
    notes: list[str] = field(default_factory=list)
    corrections: dict[str, int] = field(default_factory=dict)

    @property
    def identifiable(self) -> bool:
        """Whether the interval is finite on both sides (no flat side)."""
        return "flat" not in self.ends.values()

    def describe(self) -> str:
        """One line in words."""
        lo, hi = self.interval
        text = f"{self.name}: {self.level:.0%} profile interval [{lo:.6g}, {hi:.6g}]"
        why = {
            "bound": "stops at the bound",
            "flat": "not identifiable: the profile stays flat",
            "failed": "the simulation fails beyond",
        }
        sides = [f"{s} side {why[e]}" for s, e in self.ends.items() if e != "crossed"]
        return text + (f" ({'; '.join(sides)})" if sides else "")

    def blocks(self) -> list:
        """One row: the estimate, the interval and how each side of it ends."""
        how = {
            "crossed": "crossed",
            "bound": "at the bound",
            "flat": "flat (not identifiable)",
            "failed": "simulation fails",
        }
        header = ["unknown", "estimate", f"{100 * self.level:g} % profile interval"]
        header += ["lower side", "upper side", "points", "evaluations"]
        row = [self.name, significant(self.estimate), interval(*self.interval)]
        row += [how[self.ends[s]] for s in SIDES] + [str(self.values.size), str(self.evaluations)]
        return [Table(None, header, [row]), *self.notes]

    def __repr__(self) -> str:
        lo, hi = self.interval
        return f"Profile({self.name!r}, interval=({lo:.6g}, {hi:.6g}), ends={self.ends})"


class _Held:
    """The problem with θ_i held at c: the cost, gradient and Hessian of θ_{-i} in
    scaled units, and the corrector that re-optimises them."""

    def __init__(self, problem, i: int, scale: np.ndarray, J_ref: float, fatol: float):
        self.problem, self.i, self.scale, self.J_ref = problem, i, scale, J_ref
        self.rest = np.array([k for k in range(problem.K) if k != i])
        self.fatol = fatol
        self.evaluations = 0
        self.last: tuple | None = None  # (θ, g, H) of the last evaluation
        self.endings: Counter[Status] = Counter()  # how the corrections ended

    def full(self, c: float, phi_rest: np.ndarray) -> np.ndarray:
        theta = np.empty(self.problem.K)
        theta[self.i] = c
        theta[self.rest] = phi_rest * self.scale[self.rest]
        return np.clip(theta, self.problem.lower, self.problem.upper)

    def correct(self, c: float, theta: np.ndarray, tight: bool) -> tuple[np.ndarray, float]:
        """θ with θ_i = c and θ_{-i} re-optimised from ``theta``; and its cost. Along
        the way a loose tolerance will do; where an interval end is found, not."""
        if self.rest.size == 0:
            theta = theta.copy()
            theta[self.i] = c
            return theta, self.problem.cost(theta)
        s = self.scale[self.rest]

        def fun(phi):
            self.evaluations += 1
            full = self.full(c, phi)
            J, g, H = self.problem.cost_grad_hess(full)
            self.last = (full, g, H)
            if not np.isfinite(J):
                return np.inf, g[self.rest], H[np.ix_(self.rest, self.rest)]
            sub = np.ix_(self.rest, self.rest)
            return (
                J / self.J_ref,
                g[self.rest] * s / self.J_ref,
                H[sub] * np.outer(s, s) / self.J_ref,
            )

        lo, hi = self.problem.lower[self.rest] / s, self.problem.upper[self.rest] / s
        # (loose: the trust region's default xtol, 1e-12)
        gtol, ftol, xtol = (1e-12, 1e-15, 1e-14) if tight else (1e-6, 1e-9, 1e-12)
        r = minimize_trust_region(fun, theta[self.rest] / s, lo, hi, fatol=self.fatol, maxiter=100,
                                  radius=1.0, gtol=gtol, ftol=ftol, xtol=xtol)  # fmt: skip
        self.endings[interrupted(r).status] += 1  # (Ctrl-C stops the profiles too)
        out = self.full(c, r.x)
        return out, self.problem.cost(out)

    def derivatives(self, theta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(g, H) at θ: those of the corrector's last evaluation when it ended there."""
        if self.last is not None and np.array_equal(self.last[0], theta):
            return self.last[1], self.last[2]
        self.evaluations += 1
        _, g, H = self.problem.cost_grad_hess(theta)
        self.last = (theta, g, H)
        return g, H

    def start(self, theta: np.ndarray, c: float, predict: bool) -> np.ndarray:
        """Where to correct from at c: θ moved along the profile's tangent, or, where
        the tangent overshoots (a nearly flat direction makes it huge), θ itself
        with θ_i = c, whichever has the lower cost."""
        warm = theta.copy()
        warm[self.i] = c
        warm = np.clip(warm, self.problem.lower, self.problem.upper)
        if not predict:
            return warm
        guess = np.clip(
            theta + (c - theta[self.i]) * self.slope(theta), self.problem.lower, self.problem.upper
        )
        self.evaluations += 2
        return guess if self.problem.cost(guess) <= self.problem.cost(warm) else warm

    def slope(self, theta: np.ndarray) -> np.ndarray:
        """dθ/dc along the profile at θ (θ_i's own entry is 1)."""
        _, H = self.derivatives(theta)
        d = np.zeros(self.problem.K)
        d[self.i] = 1.0
        if self.rest.size:
            A = H[np.ix_(self.rest, self.rest)]
            d[self.rest] = -np.linalg.lstsq(A, H[self.rest, self.i], rcond=1e-12)[0]
        return d


def _side(held: _Held, theta_hat, J_hat, dJ, step, sign, method, max_steps) -> tuple:
    """Trace one side: the points passed, and how the side ends with its end value."""
    i, problem = held.i, held.problem
    bound = problem.upper[i] if sign > 0 else problem.lower[i]
    points: list[tuple] = []
    theta, c = theta_hat.copy(), theta_hat[i]
    h = step
    for _ in range(max_steps):
        if c == bound:
            return points, "bound", bound
        c_new = float(np.clip(c + sign * h, problem.lower[i], problem.upper[i]))
        guess = held.start(theta, c_new, predict=method == "integrate")
        theta_new, J_new = held.correct(c_new, guess, tight=method == "refit")
        if not np.isfinite(J_new):
            if h < 1e-6 * step:
                return points, "failed", c
            h /= 4  # the simulation failed out there: approach more carefully
            continue
        rise = J_new - J_hat
        if rise > dJ:
            return points + [(c_new, J_new, theta_new)], "crossed", (c, theta, c_new, theta_new)
        points.append((c_new, J_new, theta_new))
        theta, c = theta_new, c_new
        # steps that rise less than a tenth of the threshold may grow, up to 16-fold:
        # a flat side is then traced over max_steps·16 initial steps before it is
        # called flat
        h = min(2.0 * h, 16.0 * step) if rise < 0.1 * dJ else h
    return points, "flat", c


def _end(held: _Held, bracket, J_hat: float, dJ: float, method: str) -> float:
    """The c where the profile crosses the threshold, between two traced points.

    With "integrate", safeguarded Newton on c: at a re-optimised point the slope of
    the profile is dPL/dc = ∂J/∂θ_i (the other derivatives vanish there), which the
    corrector's exact gradient already holds; each new c is also predicted along
    dθ/dc. With "refit", Brent's method, as a derivative-free re-fit would."""
    c_in, theta_in, c_out, theta_out = bracket
    lo, hi = sorted((c_in, c_out))
    tol = 1e-13 * max(abs(c_in), abs(c_out), hi - lo)
    near = {"theta": theta_in}

    def excess(c):
        guess = held.start(near["theta"], c, predict=method == "integrate")
        theta, J = held.correct(c, guess, tight=True)
        if not np.isfinite(J):
            return dJ, theta
        near["theta"] = theta
        return (J - J_hat) - dJ, theta

    if method == "refit":
        from scipy import optimize  # here, not at the top: keeps `import tensorid` cheap

        try:
            return float(optimize.brentq(lambda c: excess(c)[0], lo, hi, xtol=tol, rtol=1e-15))
        except ValueError:  # re-corrected tightly, the outer point fell below: stop there
            return float(c_out)
    below, above = c_in, c_out  # the profile is under the threshold at one, over at the other
    c = 0.5 * (below + above)
    for _ in range(100):
        f, theta = excess(c)
        if abs(f) <= 1e-12 * dJ:
            return float(c)
        if f > 0:
            above = c
        else:
            below = c
        if abs(above - below) <= tol:
            return float(0.5 * (above + below))
        slope = held.derivatives(theta)[0][held.i]
        c_new = c - f / slope if slope != 0 and np.isfinite(slope) else np.nan
        inside = min(below, above) < c_new < max(below, above)
        c = c_new if inside else 0.5 * (below + above)
    return float(c)


def profile(
    res,
    names: Sequence[str] | None = None,
    level: float = 0.95,
    *,
    method: str = "integrate",
    max_steps: int = 60,
) -> dict[str, Profile]:
    """Profile likelihood of each unknown in ``names`` (default: every free parameter)
    at the fit ``res``, and its likelihood-ratio interval at ``level``.

    Arguments:
        res (FitResult): a converged fit (its θ is the optimum the profiles start
            from).
        names: unknowns of ``res.problem.theta_names`` (initial states included).
        level: the confidence level of the intervals.
        method: "integrate" (exact-Hessian predictor–corrector, the default: a
            loose corrector along the way, a tight one at the interval ends) or "refit"
            (a full re-fit from the last point at every trial value: optimisation-based
            profiles, for comparison).
        max_steps: steps per side before a side that stays below the threshold is
            called flat.

    Returns:
      {name: :class:`Profile`}.
    """
    if getattr(res, "profiles_itself", False):  # a population fit: −2 log L over ψ
        return res.profile(names, level, method=method, max_steps=max_steps)
    problem = res.problem
    if not 0 < level < 1:
        raise ValueError(f"level must be between 0 and 1, got {level!r}")
    if method not in ("integrate", "refit"):
        raise ValueError(f"method must be 'integrate' or 'refit', got {method!r}")
    if not res.has_uncertainty:
        raise ValueError(f"profiles need a fit with a finite cost; this one ended as {res.status}")
    # the threshold is a Gaussian likelihood ratio's (least squares, or a filter's J)
    if not (problem.loss.squared or problem.loss.likelihood):
        raise ValueError(
            f"profile-likelihood intervals assume the squared loss; this fit's is "
            f"{problem.loss.name}: use its sandwich intervals (res.uncertainty())"
        )
    all_names = problem.theta_names
    if names is None:
        free_x0 = len(all_names) - len(problem.free_params)
        names = all_names[free_x0:]
    elif isinstance(names, str):
        names = [names]
    unknown = [n for n in names if n not in all_names]
    if unknown:
        raise ValueError(f"profile: unknown names {unknown}; the unknowns are {all_names}")
    u = res.uncertainty()
    if u.not_available:
        raise ValueError(f"profiles need the residual variance, and it is {u.not_available}")
    n_data = u.dof + problem.K
    if problem.loss.likelihood:  # J = −2 log L: Wilks' χ²(1) on the rise itself
        dJ = quantiles.chi2(1, level)
    else:
        dJ = u.sigma2 * quantiles.f1(max(n_data - problem.K, 1), level)  # F quantile
    out = {}
    # far along a profile the model may blow up: such trial points are rejected
    # steps (inf), so the overflow on the way is expected, not news for the user
    with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
        for name in names:
            i = all_names.index(name)
            out[name] = _one(res, i, dJ, level, u.stderr[i], method, max_steps)
    return out


def _one(res, i, dJ, level, se, method, max_steps) -> Profile:
    started = time.perf_counter()
    problem, theta_hat, J_hat = res.problem, res.theta, res.cost
    J_ref = abs(J_hat) if J_hat != 0 else 1.0  # |J|: a likelihood may be negative
    held = _Held(problem, i, res.scale, J_ref, problem.rounding_floor / J_ref)
    scale = abs(theta_hat[i]) if theta_hat[i] != 0 else res.scale[i]
    step = 0.5 * se if np.isfinite(se) and se > 0 else 0.05 * scale
    points: list[tuple] = [(theta_hat[i], J_hat, theta_hat)]
    ends, interval = {}, []
    for side, sign in zip(SIDES, (-1.0, 1.0), strict=True):
        traced, how, where = _side(held, theta_hat, J_hat, dJ, step, sign, method, max_steps)
        points += traced
        ends[side] = how
        if how == "crossed":
            interval.append(_end(held, where, J_hat, dJ, method))
        elif how == "flat":
            interval.append(sign * np.inf)
        else:
            interval.append(where)
    points.sort(key=lambda p: p[0])
    return Profile(
        name=problem.theta_names[i],
        index=i,
        estimate=float(theta_hat[i]),
        level=level,
        threshold=float(dJ),
        values=np.array([p[0] for p in points]),
        costs=np.array([p[1] for p in points]),
        thetas=np.array([p[2] for p in points]),
        interval=(float(interval[0]), float(interval[1])),
        ends=ends,
        seconds=time.perf_counter() - started,
        evaluations=held.evaluations,
        notes=_unconverged(held.endings),
        corrections={s.name.lower(): n for s, n in held.endings.items()},
    )


def _unconverged(endings: Counter) -> list[str]:
    """A note where corrections stopped short: their PL(c) is over-estimated (θ_{-i}
    not at its minimum), which can move a crossing inward."""
    short = {s: n for s, n in endings.items() if not s.success}
    if not short:
        return []
    how = ", ".join(f"{s.name.lower()} {n}" for s, n in short.items())
    return [
        f"note: {sum(short.values())} of {sum(endings.values())} re-optimisations of the "
        f"other unknowns stopped before converging ({how}): where they did the profile "
        "lies above the true one and the interval may be too narrow there"
    ]
