"""Parameter uncertainty at the optimum, and identifiability.

For J = Σ w r² with n weighted residuals and K unknowns, the residual variance is
σ² = J / (n - K) and, to first order, cov(θ) = 2 σ² H⁻¹, with H the Hessian of J
(H ≈ 2 JᵀJ in the Gauss-Newton form, which gives the textbook σ² (JᵀJ)⁻¹). The exact
Hessian from transition tensors is the default; the Gauss-Newton form is available
for comparison. When H is (nearly) singular, the data cannot pin down some
combination of unknowns: the warning names the unknowns in that flat direction.

Two cases where the textbook formula would lie, and what is done instead:

* H indefinite (a saddle, or a fit stopped short): its pseudo-inverse has negative
  variances. The directions with negative curvature are named, and the intervals
  come from the Gauss-Newton form, which is positive semi-definite; each interval
  records the form it came from.
* An estimate on a bound: a symmetric Wald interval across the bound is not
  meaningful. It is flagged, and intervals are cut at the bounds.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy import stats

# relative eigenvalue below which a direction counts as not identifiable; the
# Hessian is exact to ~1e-12 relative, so this is far above its rounding
FLAT = 1e-8


@dataclass
class Uncertainty:
    """Standard errors, 95 % intervals and correlations of θ (natural units).

    ``forms`` names, per unknown, the Hessian its interval comes from ("hessian" or
    "gauss-newton"); ``at_bound`` maps an unknown that sits on a bound to "lower" or
    "upper"; ``cut`` maps an unknown whose interval was cut at a bound to the side.
    """

    names: list[str]
    theta: np.ndarray
    covariance: np.ndarray
    stderr: np.ndarray
    ci95: np.ndarray  # (K, 2)
    correlation: np.ndarray
    sigma2: float
    dof: int
    kind: str
    warnings: list[str] = field(default_factory=list)
    forms: list[str] = field(default_factory=list)
    at_bound: dict[str, str] = field(default_factory=dict)
    cut: dict[str, str] = field(default_factory=dict)

    def as_dicts(self) -> dict:
        """stderr, ci95, correlation, the form of each interval and the unknowns at a
        bound, as JSON-ready dicts keyed by unknown."""
        return {
            "stderr": dict(zip(self.names, map(float, self.stderr), strict=True)),
            "ci95": {
                n: [float(a), float(b)] for n, (a, b) in zip(self.names, self.ci95, strict=True)
            },
            "correlation": self.correlation.tolist(),
            "interval_form": dict(zip(self.names, self.forms, strict=True)),
            "at_bound": dict(self.at_bound),
            "interval_cut_at_bound": dict(self.cut),
        }


def jacobi_scale(H: np.ndarray) -> np.ndarray:
    """s with diag(s H s) = 1 where H_ii > 0: unit-free, and it takes the Silverbox
    Hessian from a condition number near 1e18 to one that eigen-solvers resolve."""
    d = np.abs(np.diag(H))
    return np.where(d > 0, 1.0 / np.sqrt(np.where(d > 0, d, 1.0)), 1.0)


def _directions(H: np.ndarray, names: list[str], keep) -> list[tuple[float, list[str]]]:
    """Eigen-directions of H in Jacobi-scaled units whose relative eigenvalue passes
    ``keep``: (relative eigenvalue, names of the unknowns that move together)."""
    s = jacobi_scale(H)
    Hs = H * np.outer(s, s)
    lam, V = np.linalg.eigh(0.5 * (Hs + Hs.T))
    top = max(np.abs(lam).max(), np.finfo(float).tiny)
    out = []
    for k in range(lam.size):
        if keep(lam[k] / top):
            v = V[:, k] / np.abs(V[:, k]).max()
            involved = [n for n, c in zip(names, v, strict=True) if abs(c) > 0.1]
            out.append((float(lam[k] / top), involved))
    return out


def flat_directions(
    H: np.ndarray, names: list[str], threshold: float = FLAT
) -> list[tuple[float, list[str]]]:
    """Directions along which the cost is (nearly) flat, in Jacobi-scaled units:
    (relative eigenvalue, names of the unknowns that move together)."""
    return _directions(H, names, lambda r: abs(r) <= threshold)


def negative_directions(
    H: np.ndarray, names: list[str], threshold: float = FLAT
) -> list[tuple[float, list[str]]]:
    """Directions of clearly negative curvature (relative eigenvalue below
    -threshold): the point is not a minimum along them."""
    return _directions(H, names, lambda r: r < -threshold)


def _variances(H: np.ndarray, sigma2: float, names: list[str], unbounded) -> tuple:
    """(covariance, variances) from the PSD part of H in Jacobi-scaled units; the
    unknowns in ``unbounded`` directions get infinite variance. Work in scaled units:
    on the raw Hessian, rounding makes the smallest eigenvalue's sign meaningless and
    a relative pinv cutoff would discard exactly the poorly determined directions."""
    sc = jacobi_scale(H)
    Hs = 0.5 * (H + H.T) * np.outer(sc, sc)
    cov = 2.0 * sigma2 * np.linalg.pinv(Hs, rcond=FLAT, hermitian=True) * np.outer(sc, sc)
    var = np.diag(cov).copy()
    for _, involved in unbounded:  # pinv would report these as zero
        for name in involved:
            var[names.index(name)] = np.inf
    var[~(var >= 0)] = np.inf  # a negative variance is no variance: never print a 0
    return cov, var


def _bounded(problem, theta, se, ci, names) -> tuple[dict, dict, list[str]]:
    """Flag estimates on a bound, cut intervals at the bounds; returns (at_bound,
    cut, warnings). An estimate is on a bound when it is within a millionth of its
    standard error of it (or within rounding)."""
    lo, hi = np.asarray(problem.lower), np.asarray(problem.upper)
    near = np.maximum(1e-12 * (1.0 + np.abs(theta)), 1e-6 * np.where(np.isfinite(se), se, 0.0))
    at_bound, cut, warnings = {}, {}, []
    for k, name in enumerate(names):
        side = (
            "lower"
            if theta[k] - lo[k] <= near[k]
            else "upper"
            if hi[k] - theta[k] <= near[k]
            else None
        )
        if side:
            at_bound[name] = side
            bound = lo[k] if side == "lower" else hi[k]
            warnings.append(
                f"{name} sits on its {side} bound {bound:g}: the data would move it further "
                "if allowed, so its interval is one-sided and only indicative (the Wald "
                "approximation does not hold at a bound); check whether the bound is physical "
                "or the model is missing something"
            )
        if ci[k, 0] < lo[k] or ci[k, 1] > hi[k]:
            cut[name] = "lower" if ci[k, 0] < lo[k] else "upper"
            ci[k] = np.clip(ci[k], lo[k], hi[k])
    return at_bound, cut, warnings


def uncertainty(
    problem, theta: np.ndarray, J: float, H: np.ndarray, kind: str = "hessian", gauss_newton=None
) -> Uncertainty:
    """Uncertainty of θ at an optimum with cost J and Hessian H (exact or
    Gauss-Newton, as ``kind`` says). ``gauss_newton``: the Gauss-Newton Hessian (or a
    function returning it) to fall back on where H is indefinite."""
    names = problem.theta_names
    K = theta.size
    n = sum(e.P for e in problem.experiments) * int((problem.weights > 0).sum())
    dof = max(n - K, 1)
    sigma2 = J / dof
    warnings, form, unbounded = [], kind, []
    negative = negative_directions(H, names)
    if negative:
        where = "; ".join(
            f"a direction that moves {', '.join(inv)} (relative curvature {rel:.1e})"
            for rel, inv in negative
        )
        if kind == "hessian" and gauss_newton is not None:
            H = gauss_newton() if callable(gauss_newton) else gauss_newton
            form = "gauss-newton"
            then = (
                "the standard errors and intervals below come from the Gauss-Newton "
                "form (the expected information) instead"
            )
        else:
            unbounded = negative
            then = "the unknowns in those directions get unbounded intervals"
        warnings.append(
            f"the Hessian is indefinite here: the cost curves downward along {where}, so "
            f"this is not a strict local minimum; {then}"
        )
    flat = flat_directions(H, names)
    for rel, involved in flat:
        warnings.append(
            f"not identifiable from these data: the cost is flat (relative curvature "
            f"{rel:.1e}) along a direction that moves {', '.join(involved)} together; "
            "fix one of them, add data that excites them differently, or reparametrise"
        )
    cov, var = _variances(H, sigma2, names, flat + unbounded)
    se = np.sqrt(var)
    q = stats.t.ppf(0.975, dof)
    ci = np.stack([theta - q * se, theta + q * se], axis=1)
    at_bound, cut, bound_warnings = _bounded(problem, theta, se, ci, names)
    with np.errstate(divide="ignore", invalid="ignore"):
        corr = cov / np.outer(se, se)
    corr = np.where(np.isfinite(corr), corr, np.nan)
    np.fill_diagonal(corr, 1.0)
    return Uncertainty(
        names,
        theta,
        cov,
        se,
        ci,
        corr,
        float(sigma2),
        dof,
        kind,
        warnings + bound_warnings,
        [form] * K,
        at_bound,
        cut,
    )
