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


def jacobi_scale(H: np.ndarray) -> np.ndarray:
    """s with diag(s H s) = 1 where H_ii > 0: unit-free, and it takes the Silverbox
    Hessian from a condition number near 1e18 to one that eigen-solvers resolve."""
    d = np.abs(np.diag(H))
    return np.where(d > 0, 1.0 / np.sqrt(np.where(d > 0, d, 1.0)), 1.0)


def jacobi_scaled(H: np.ndarray) -> np.ndarray:
    """D^-1/2 H D^-1/2 with D = |diag H|, symmetrised, over the unknowns whose row is
    finite (a non-finite entry says nothing either way). An unknown with a zero
    diagonal entry keeps the units it has, as in the error bars' Jacobi scaling
    (uncertainty.py): alone it is a direction of no curvature, not of negative
    curvature, but coupled to another unknown it makes H indefinite whatever the units
    ([[0, b], [b, c]] has determinant -b²): the saddle of J = c + a·b at a = b = 0,
    where a fit from zero starts, has nothing but such couplings. Scaled row by row
    and then column by column, so that a subnormal diagonal entry does not overflow."""
    H = 0.5 * (H + H.T)
    keep = np.isfinite(H).all(axis=1)
    H = H[np.ix_(keep, keep)]
    s = jacobi_scale(H)
    return (H * s[:, None]) * s[None, :]


def negative_curvature(H: np.ndarray) -> bool:
    """Does H curve downward beyond rounding, in units in which that means the same
    whatever the units of the unknowns?

    A = D^-1/2 H D^-1/2 (D = |diag H|, :func:`jacobi_scaled`) is H in the units that
    make each unknown's own curvature ±1. It does not change when the unknowns are
    rescaled (S H S has diagonal S²D, so the same A): the verdict cannot depend on the
    scales chosen at the start, as a test on H in the trust region's units did. A has
    ±1 on its diagonal (0 where H_ii = 0, in the units given), so its largest eigenvalue
    in magnitude is at least 1 (and at most n when H is semi-definite) unless every
    H_ii is 0. Rounding in H's entries of up to η √(|H_ii H_jj|)
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
