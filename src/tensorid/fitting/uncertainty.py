"""Parameter uncertainty at the optimum, and identifiability.

For J = Σ w r² with n weighted residuals and K unknowns, the residual variance is
σ² = J / (n - K) and, to first order, cov(θ) = 2 σ² H⁻¹, with H the Hessian of J
(H ≈ 2 JᵀJ in the Gauss-Newton form, which gives the textbook σ² (JᵀJ)⁻¹). The exact
Hessian from transition tensors is the default; the Gauss-Newton form is available
for comparison. When H is (nearly) singular, the data cannot pin down some
combination of unknowns: the warning names the unknowns in that flat direction.
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
    """Standard errors, 95 % intervals and correlations of θ (natural units)."""

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

    def as_dicts(self) -> dict:
        """stderr, ci95 and correlation as JSON-ready dicts keyed by unknown."""
        return {
            "stderr": dict(zip(self.names, map(float, self.stderr), strict=True)),
            "ci95": {
                n: [float(a), float(b)] for n, (a, b) in zip(self.names, self.ci95, strict=True)
            },
            "correlation": self.correlation.tolist(),
        }


def jacobi_scale(H: np.ndarray) -> np.ndarray:
    """s with diag(s H s) = 1 where H_ii > 0: unit-free, and it takes the Silverbox
    Hessian from a condition number near 1e18 to one that eigen-solvers resolve."""
    d = np.abs(np.diag(H))
    return np.where(d > 0, 1.0 / np.sqrt(np.where(d > 0, d, 1.0)), 1.0)


def flat_directions(
    H: np.ndarray, names: list[str], threshold: float = FLAT
) -> list[tuple[float, list[str]]]:
    """Directions along which the cost is (nearly) flat, in Jacobi-scaled units:
    (relative eigenvalue, names of the unknowns that move together)."""
    s = jacobi_scale(H)
    Hs = H * np.outer(s, s)
    lam, V = np.linalg.eigh(0.5 * (Hs + Hs.T))
    top = max(abs(lam[-1]), np.finfo(float).tiny)
    out = []
    for k in range(lam.size):
        if lam[k] / top > threshold:
            break
        v = V[:, k] / np.abs(V[:, k]).max()
        involved = [n for n, c in zip(names, v, strict=True) if abs(c) > 0.1]
        out.append((float(lam[k] / top), involved))
    return out


def uncertainty(
    problem, theta: np.ndarray, J: float, H: np.ndarray, kind: str = "hessian"
) -> Uncertainty:
    """Uncertainty of θ at an optimum with cost J and Hessian H (exact or
    Gauss-Newton, as ``kind`` says)."""
    names = problem.theta_names
    K = theta.size
    n = sum(e.P for e in problem.experiments) * int((problem.weights > 0).sum())
    dof = max(n - K, 1)
    sigma2 = J / dof
    warnings = []
    flat = flat_directions(H, names)
    for rel, involved in flat:
        warnings.append(
            f"not identifiable from these data: the cost is flat (relative curvature "
            f"{rel:.1e}) along a direction that moves {', '.join(involved)} together; "
            "fix one of them, add data that excites them differently, or reparametrise"
        )
    # work in Jacobi-scaled units: on the raw Hessian, rounding makes the smallest
    # eigenvalue's sign meaningless and a relative pinv cutoff would discard exactly the
    # poorly determined directions, reporting tiny standard errors
    sc = jacobi_scale(H)
    Hs = 0.5 * (H + H.T) * np.outer(sc, sc)
    if not flat and np.linalg.eigvalsh(Hs)[0] <= 0:
        warnings.append(
            "the Hessian is not positive definite here: this is not a strict "
            "local minimum, so the intervals are not meaningful"
        )
    cov = 2.0 * sigma2 * np.linalg.pinv(Hs, rcond=FLAT, hermitian=True) * np.outer(sc, sc)
    var = np.diag(cov).copy()
    # a flat direction has unbounded variance; pinv would report it as zero
    for _, involved in flat:
        for nme in involved:
            var[names.index(nme)] = np.inf
    se = np.sqrt(np.clip(var, 0.0, np.inf))
    q = stats.t.ppf(0.975, dof)
    ci = np.stack([theta - q * se, theta + q * se], axis=1)
    with np.errstate(divide="ignore", invalid="ignore"):
        corr = cov / np.outer(se, se)
    corr = np.where(np.isfinite(corr), corr, np.nan)
    np.fill_diagonal(corr, 1.0)
    return Uncertainty(names, theta, cov, se, ci, corr, float(sigma2), dof, kind, warnings)
