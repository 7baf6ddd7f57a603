"""Quantiles of the normal, χ², Student t and F(1, d) distributions, in plain Python.

The statistics need a handful of quantiles per fit (confidence intervals, the
residual tests' thresholds, a profile's rise). ``scipy.special`` has them, but
importing it takes 0.12 s of a 1.7 s command (it brings SciPy's array-API layer),
and ``scipy.stats`` 0.3-1 s. These agree with ``scipy.special`` to 1e-11 relative
or better (tests/test_quantiles.py compares them on a grid of levels from 1e-17 and
degrees of freedom from 1 to 1e6, and 1e9 for t, which beyond 1e5 is the
Cornish-Fisher expansion). Each is found by Newton's method on the distribution
function, kept inside a bracket by bisection, so it cannot leave the support or
cycle; where it does not settle, it says so.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from statistics import NormalDist

__all__ = ["chi2", "f1", "normal", "student_t"]

_TINY = 1e-300
_EPS = 1e-16
_CONVERGED = 1e-15  # a continued fraction's step this close to 1 changes nothing


def normal(p: float) -> float:
    """The standard normal quantile: x with Φ(x) = p, 0 < p < 1."""
    return NormalDist().inv_cdf(p)


def chi2(dof: float, p: float) -> float:
    """The χ² quantile: x with P(χ²_dof ≤ x) = p (scipy: 2·gammaincinv(dof/2, p))."""
    _check(dof, p)
    a = dof / 2
    z = normal(p)
    guess = max(a * (1 - 1 / (9 * a) + z * math.sqrt(1 / (9 * a))) ** 3, 1e-8)  # Wilson-Hilferty

    def density(x: float) -> float:  # dP(a, x)/dx
        return math.exp(_log_gamma_lead(a, x)) / x if x > 0 else 0.0

    if p <= 0.5:
        return 2 * _invert(lambda x: _gamma_pq(a, x)[0], density, p, guess)
    # the upper tail through Q = 1 − P, which keeps the digits that 1 − Q would lose
    return 2 * _invert(lambda x: -_gamma_pq(a, x)[1], density, p - 1, guess)


def student_t(dof: float, p: float) -> float:
    """The Student t quantile: t with P(T_dof ≤ t) = p (scipy: stdtrit(dof, p))."""
    _check(dof, p)
    if p == 0.5:
        return 0.0
    if dof > 1e5:  # Cornish-Fisher: the next term is below 1e-14 relative here, where
        z = normal(p)  # the incomplete beta's fraction would lose digits
        return z + (z**3 + z) / (4 * dof) + (5 * z**5 + 16 * z**3 + 3 * z) / (96 * dof**2)
    tail = p if p < 0.5 else 1 - p  # the smaller tail's area, with the digits p has
    log_c = _log_gamma_ratio(dof / 2, 0.5) - 0.5 * math.log(dof * math.pi)

    def density(t: float) -> float:
        return math.exp(log_c - (dof + 1) / 2 * math.log1p(t * t / dof))

    def minus_tail(t: float) -> float:  # −P(T > t) = −I_{dof/(dof+t²)}(dof/2, 1/2) / 2
        return -0.5 * _beta_i(dof / (dof + t * t), t * t / (dof + t * t), dof / 2, 0.5)

    t = _invert(minus_tail, density, -tail, max(-normal(tail), 1e-8))
    return t if p > 0.5 else -t


def f1(dof: float, p: float) -> float:
    """The quantile of F(1, dof), the square of a t with dof degrees of freedom
    (scipy: fdtri(1, dof, p))."""
    return student_t(dof, (1 + p) / 2) ** 2


def _check(dof: float, p: float) -> None:
    # beyond 1e12 degrees of freedom the series would take minutes: use the normal
    if not (0 < dof <= 1e12 and 0 < p < 1):
        raise ValueError(f"a quantile needs 0 < dof <= 1e12 and 0 < p < 1, not dof={dof}, p={p}")


def _invert(
    cdf: Callable[[float], float], density: Callable[[float], float], p: float, x: float
) -> float:
    """x > 0 with cdf(x) = p: Newton's steps from ``x``, a bisection wherever a step
    would leave the bracket that the steps have narrowed so far. ValueError where
    that does not settle (quantiles far below 1e-100, which no caller asks for)."""
    lo, hi = 0.0, math.inf
    for _ in range(400):
        f = cdf(x) - p
        if f == 0:
            return x
        if f < 0:
            lo = x
        else:
            hi = x
        d = density(x)
        step = x - f / d if d > 0 else math.nan
        if not lo < step < hi:  # also NaN
            step = 2 * x if hi == math.inf else (lo + hi) / 2
        if abs(step - x) <= 4 * _EPS * abs(x):
            return step
        x = step
    raise ValueError(f"the quantile for p={p} did not settle (last {x})")


def _gamma_pq(a: float, x: float) -> tuple[float, float]:
    """The regularized incomplete gamma functions P(a, x) and Q = 1 − P: P by its
    series below x = a + 1, Q by its continued fraction above (Numerical Recipes
    §6.2), the other as one minus it."""
    if x <= 0:
        return 0.0, 1.0
    lead = math.exp(_log_gamma_lead(a, x))
    if x < a + 1:
        n, term = a, 1 / a
        total = term
        while abs(term) > abs(total) * _EPS:
            n += 1
            term *= x / n
            total += term
        return total * lead, 1 - total * lead
    b = x + 1 - a
    c, d = 1 / _TINY, 1 / b
    h = d
    for i in range(1, 100_000):
        an = -i * (i - a)
        b += 2
        d = _nonzero(an * d + b)
        c = _nonzero(b + an / c)
        d = 1 / d
        h *= d * c
        if abs(d * c - 1) < _CONVERGED:
            break
    return 1 - lead * h, lead * h


def _log_gamma_lead(a: float, x: float) -> float:
    """log(x^a e^(−x) / Γ(a)); for large a, with u = x/a − 1, a(log1p(u) − u) +
    ½ log(a/2π) − Stirling's tail: each term ~a log a would cost that many digits."""
    if a < 30:
        return a * math.log(x) - x - math.lgamma(a)
    u = (x - a) / a
    return a * (math.log1p(u) - u) + 0.5 * math.log(a / (2 * math.pi)) - _stirling_tail(a)


def _beta_i(x: float, y: float, a: float, b: float) -> float:
    """The regularized incomplete beta function I_x(a, b), y = 1 − x given as well
    (near x = 1 it has digits that 1 − x would lose), by its continued fraction on
    whichever side converges fast (Numerical Recipes §6.4)."""
    if x <= 0:
        return 0.0
    if y <= 0:
        return 1.0
    if a < b:
        log_ratio = _log_gamma_ratio(b, a) - math.lgamma(a)
    else:
        log_ratio = _log_gamma_ratio(a, b) - math.lgamma(b)
    log_x = math.log1p(-y) if y < 0.5 else math.log(x)  # the digits of the smaller
    log_y = math.log1p(-x) if x < 0.5 else math.log(y)
    front = math.exp(log_ratio + a * log_x + b * log_y)
    if x < (a + 1) / (a + b + 2):
        return front * _beta_fraction(x, a, b) / a
    return 1 - front * _beta_fraction(y, b, a) / b


def _log_gamma_ratio(a: float, b: float) -> float:
    """log Γ(a + b) − log Γ(a). For large a the two log-gammas are ~a log a each and
    their difference would lose that many digits (1e-9 relative at a = 5e5): there it
    is Stirling's series, differenced term by term, with log1p."""
    if a < 30:
        return math.lgamma(a + b) - math.lgamma(a)

    tail = _stirling_tail
    return (a - 0.5) * math.log1p(b / a) + b * math.log(a + b) - b + tail(a + b) - tail(a)


def _stirling_tail(x: float) -> float:
    """log Γ(x) − ((x − ½) log x − x + ½ log 2π): Stirling's series, < 1e-16 off
    for x ≥ 30."""
    x2 = x * x
    return (1 / 12 - (1 / 360 - (1 / 1260 - 1 / (1680 * x2)) / x2) / x2) / x


def _beta_fraction(x: float, a: float, b: float) -> float:
    """The continued fraction of I_x(a, b), evaluated by Lentz's method."""
    c, d = 1.0, 1 / _nonzero(1 - (a + b) * x / (a + 1))
    h = d
    for m in range(1, 1_000_000):
        m2 = 2 * m
        for num in (
            m * (b - m) * x / ((a + m2 - 1) * (a + m2)),
            -(a + m) * (a + b + m) * x / ((a + m2) * (a + m2 + 1)),
        ):
            d = 1 / _nonzero(1 + num * d)
            c = _nonzero(1 + num / c)
            h *= d * c
        if abs(d * c - 1) < _CONVERGED:
            break
    return h


def _nonzero(v: float) -> float:
    return v if abs(v) > _TINY else _TINY
