"""The trust-region subproblem for a block-arrow Hessian, in time linear in the number
of shooting segments.

In multiple shooting the unknowns are z = (segment states, parameters). Segment i's
state couples only with its neighbours' (through its cost and its defects), so the
state block B of the Hessian is banded, of half-bandwidth below 2N; the parameters
couple with everything, through the dense border C and the small block D:

    H = [[B, C], [Cᵀ, D]],   n_b states (banded), n_p parameters.

(H + λI) s = −g is solved by a banded Cholesky factor of B + λI and the Schur
complement D + λI − Cᵀ(B + λI)⁻¹C: O(n_b·w² + n_b·w·n_p + n_p³) for bandwidth w,
against O(n³) for the eigendecomposition of the dense solver. The multiplier λ of
the boundary solution is found by Moré and Sorensen's safeguarded Newton iteration on
1/‖s(λ)‖ − 1/Δ, using only factorizations; where it does not settle (the hard case,
g nearly orthogonal to the lowest eigenvector) the dense solver takes over.
"""

from __future__ import annotations

import numpy as np

from .trust_region import solve_subproblem


class ArrowSolver:
    """``subproblem(g, H, radius, free)`` for the trust region, when the first
    ``n_banded`` unknowns of the full vector are the banded block."""

    def __init__(self, n_banded: int, tol: float = 1e-3):
        self.n_banded, self.tol = n_banded, tol
        self.fallbacks = 0

    def __call__(self, g, H, radius, free) -> tuple[np.ndarray, bool]:
        nb = int(np.count_nonzero(free[: self.n_banded]))
        if nb == 0 or nb == g.size:
            return solve_subproblem(g, H, radius)
        w = _bandwidth(H[:nb, :nb])
        ab = np.stack([np.pad(np.diagonal(H[:nb, :nb], -k), (0, k)) for k in range(w + 1)])
        solve = _Shifted(ab, H[:nb, nb:], H[nb:, nb:], nb)
        s = solve(0.0, g)
        if s is not None and np.linalg.norm(s) <= radius:
            return s, False
        found = _boundary(solve, g, H, radius, self.tol)
        if found is None:
            self.fallbacks += 1
            return solve_subproblem(g, H, radius)
        return found, True


def _bandwidth(B: np.ndarray) -> int:
    rows, cols = np.nonzero(B)
    return int(np.abs(rows - cols).max()) if rows.size else 0


class _Shifted:
    """s = −(H + λI)⁻¹ g by banded Cholesky and the Schur complement; None when
    H + λI is not positive definite."""

    def __init__(self, ab, C, D, nb):
        self.ab, self.C, self.D, self.nb = ab, C, D, nb
        self.last = None

    def __call__(self, lam: float, g: np.ndarray):
        # scipy is imported where it is used: `import tensorid` stays cheap
        from scipy.linalg import cho_factor, cho_solve, cho_solve_banded, cholesky_banded

        nb = self.nb
        ab = self.ab.copy()
        ab[0] += lam
        try:
            L = cholesky_banded(ab, lower=True)
            X = cho_solve_banded((L, True), np.column_stack([self.C, g[:nb]]))
            Sch = self.D + lam * np.eye(self.D.shape[0]) - self.C.T @ X[:, :-1]
            F = cho_factor(Sch, lower=True)
        except np.linalg.LinAlgError:
            return None
        s_p = cho_solve(F, -g[nb:] + self.C.T @ X[:, -1])
        s_b = -X[:, -1] - X[:, :-1] @ s_p
        self.last = (L, X[:, :-1], F)
        return np.concatenate([s_b, s_p])

    def inverse_norm2(self, s: np.ndarray) -> float:
        """sᵀ(H + λI)⁻¹s for the λ of the last successful call."""
        from scipy.linalg import cho_solve, cho_solve_banded

        L, X, F = self.last
        nb = self.nb
        y_b = cho_solve_banded((L, True), s[:nb])
        y_p = cho_solve(F, s[nb:] - self.C.T @ y_b)
        y = np.concatenate([y_b - X @ y_p, y_p])
        return float(s @ y)


def _boundary(solve: _Shifted, g, H, radius, tol):
    """s with ‖s‖ = Δ (to ``tol``) and H + λI positive definite, λ >= 0; None if the
    iteration does not settle in 60 factorizations."""
    # bounds on λ (Moré and Sorensen): λ_min <= min H_ii, and ‖s(λ)‖ < Δ beyond
    # ‖g‖/Δ + ‖H‖_∞
    lo = max(0.0, float(-np.diag(H).min()))
    hi = np.linalg.norm(g) / radius + float(np.abs(H).sum(axis=1).max())
    lam = lo
    for _ in range(60):
        s = solve(lam, g)
        if s is None:  # not positive definite: λ is below −λ_min
            lo = lam
            lam = max(np.sqrt(max(lo, 1e-300) * hi), lo + 0.01 * (hi - lo))
            continue
        n = np.linalg.norm(s)
        if abs(n - radius) <= tol * radius:
            return s * min(1.0, radius / n)
        if n < radius:
            hi = lam
        else:
            lo = lam
        step = (n / radius - 1.0) * n**2 / solve.inverse_norm2(s)
        new = lam + step
        lam = new if lo < new < hi else 0.5 * (lo + hi)
        if hi - lo <= 1e-14 * max(1.0, hi):
            return None
    return None
