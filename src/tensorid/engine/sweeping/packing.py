"""Packed symmetric storage: a K × K symmetric matrix as its K(K+1)/2 pairs j <= k
(the diagonal first), as the second-order sweeps carry ∂²x/∂θ², and the quadratic
forms Σ c D Dᵀ they accumulate."""

from __future__ import annotations

import numpy as np


def pair_indices(K: int) -> tuple[np.ndarray, np.ndarray]:
    """Packed symmetric storage: the K diagonal pairs (j, j) first, then j < k."""
    jj = list(range(K))
    kk = list(range(K))
    for j in range(K):
        for k in range(j + 1, K):
            jj.append(j)
            kk.append(k)
    return np.array(jj, dtype=int), np.array(kk, dtype=int)


def unpack_symmetric(packed: np.ndarray, K: int) -> np.ndarray:
    """(..., K(K+1)/2) packed pairs -> (..., K, K) symmetric matrices."""
    jj, kk = pair_indices(K)
    H = np.zeros(packed.shape[:-1] + (K, K))
    H[..., jj, kk] = packed
    H[..., kk, jj] = packed
    return H


def quadratic_packed(D, c, pairs, v):
    """Σ_st c_st D_s D_tᵀ for D (K, outputs), packed (pairs (jj, kk)) or times v; c a
    matrix, or its diagonal (outputs,)."""
    if pairs is not None:
        jj, kk = pairs
        return ((D @ c)[jj] * D[kk]).sum(-1) if c.ndim == 2 else (D[jj] * D[kk]) @ c
    return D @ (c @ (v @ D)) if c.ndim == 2 else D @ (c * (v @ D))


def quadratic_full(D, c):
    """Σ_st c_st D_s D_tᵀ (K, K) for D (K, outputs); c (outputs,) a diagonal."""
    return D @ c @ D.T if c.ndim == 2 else (D * c) @ D.T
