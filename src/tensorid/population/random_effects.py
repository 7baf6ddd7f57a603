"""A fleet's random effects η ~ N(0, Ω): Ω diagonal (a log ω per effect) or full
(Ω = L Lᵀ, L lower triangular with log diagonal and the entries below it free), the
prior ηᵀ Ω⁻¹ η each unit's inner problem adds, and Ω⁻¹ in FOCEI's curvature. ψ
holds Ω's parameters (``lpar``) after the log typical values (objective.py)."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np


class RandomEffects:
    """The random effects of the parameters ``names`` (in ψ's order); ``full``:
    correlated (a full Ω), else independent."""

    def __init__(self, names: list[str], full: bool) -> None:
        self.names, self.full, self.q = list(names), bool(full), len(names)
        # Ω's parameters in ψ: the log diagonal, and where full the entries below it
        self.size = self.q * (self.q + 1) // 2 if self.full else self.q

    def lower_pairs(self) -> list[tuple[str, str]]:
        """The (row, column) names of L's entries below the diagonal (full Ω)."""
        if not self.full:
            return []
        rows, cols = np.tril_indices(self.q, -1)
        return [(self.names[i], self.names[j]) for i, j in zip(rows, cols, strict=True)]

    def cholesky(self, lpar):
        """L with Ω = L Lᵀ from its parameters (log diagonal, then below it)."""
        L = jnp.diag(jnp.exp(lpar[: self.q]))
        if not self.full:
            return L
        rows, cols = np.tril_indices(self.q, -1)
        return L.at[rows, cols].set(lpar[self.q :])

    def prior(self, eta, lpar):
        """ηᵀ Ω⁻¹ η."""
        if not self.full:
            return jnp.sum((eta * jnp.exp(-lpar)) ** 2)
        z = jax.scipy.linalg.solve_triangular(self.cholesky(lpar), eta, lower=True)
        return jnp.sum(z**2)

    def inverse(self, lpar):
        """Ω⁻¹."""
        if not self.full:
            return jnp.diag(jnp.exp(-2 * lpar))
        Li = jax.scipy.linalg.solve_triangular(self.cholesky(lpar), jnp.eye(self.q), lower=True)
        return Li.T @ Li
