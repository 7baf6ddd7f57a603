"""Saddle or minimum: does a Hessian curve downward, beyond rounding, whatever the
units of the unknowns?

The trust region works in the units chosen at the start (scaling.py), and those may
no longer fit where it stops: a filter fit started at σ_e = 1e-7 stopped
"converged" at cost −2185 (the minimum is −2546) with σ_e gone to 1e-10, where the
cost's curvature along log σ_e is −3e-15 beside 1.7e3 along the initial position.
The eigenvalues of that Hessian in the trust region's units were −9e-17 to 4e-6, so
a test relative to the largest (−1e-8 λmax) took the negative one for rounding; yet
it is the exact second derivative of a term that does not cancel, and the cost does
fall that way. The test here is made in Jacobi-scaled units, in which the answer does
not depend on the units at all.
"""

from __future__ import annotations

import numpy as np

ROUNDING = 1e-8  # relative eigenvalue of the Jacobi-scaled Hessian below which it is noise


def jacobi_scaled(H: np.ndarray) -> np.ndarray:
    """D^-1/2 H D^-1/2 with D = |diag H|, symmetrised, over the unknowns whose diagonal
    entry is finite and not zero and whose row is finite. An unknown with a zero
    diagonal entry is left out: a direction of no curvature is not one of negative
    curvature (a coupling to it would be, but its size relative to the diagonal has
    no scale-free meaning), and a non-finite entry says nothing either way."""
    H = 0.5 * (H + H.T)
    d = np.abs(np.diag(H))
    keep = np.isfinite(d) & (d > 0) & np.isfinite(H).all(axis=1)
    s = 1.0 / np.sqrt(d[keep])
    return H[np.ix_(keep, keep)] * np.outer(s, s)


def negative_curvature(H: np.ndarray) -> bool:
    """Does H curve downward beyond rounding, in units in which that means the same
    whatever the units of the unknowns?

    A = D^-1/2 H D^-1/2 (D = |diag H|, :func:`jacobi_scaled`) is H in the units that
    make each unknown's own curvature ±1. It does not change when the unknowns are
    rescaled (S H S has diagonal S²D, so the same A): the verdict cannot depend on the
    scales chosen at the start, as a test on H in the trust region's units did. A has
    ±1 on its diagonal, so its largest eigenvalue in magnitude is at least 1 (and at
    most n when H is semi-definite). Rounding in H's entries of up to η √(|H_ii H_jj|)
    each (relative to the curvatures they couple: the sweeps compute each entry as a
    sum of terms of about its own size or less) perturbs A by a matrix E with
    |E_ij| <= η, whose norm is at most n η, and by Weyl's inequality no eigenvalue of A
    moves further. The threshold ROUNDING · max|λ(A)| >= 1e-8 covers n η for η up to
    2e-11, 1e5 units of double rounding, at the n <= 500 free unknowns at which the
    trust region factorises H: an eigenvalue below it is not rounding. It is the
    threshold by which the error bars call a Hessian indefinite (uncertainty.py, in the
    same Jacobi units), so a fit is not called converged where its own error bars
    would say that the point is not a minimum. (A diagonal entry that is itself the
    remainder of a cancellation breaks the error model; the exact derivatives' sums
    do not cancel so along one unknown in the fits measured, and a valley across
    unknowns is a small eigenvalue of A, not a small diagonal entry.)"""
    if not H.size:
        return False
    A = jacobi_scaled(H)
    if not A.size:
        return False
    lam = np.linalg.eigvalsh(A)
    return bool(lam[0] < -ROUNDING * max(np.abs(lam).max(), np.finfo(float).tiny))
