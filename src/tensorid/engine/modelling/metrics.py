"""Fit metrics. For 2-D arrays (P, S) each returns one value per output column."""

from __future__ import annotations

import numpy as np


def _pair(y_obs, y_sim) -> tuple[np.ndarray, np.ndarray, bool]:
    a = np.asarray(y_obs, dtype=float)
    b = np.asarray(y_sim, dtype=float)
    if a.shape != b.shape:
        raise ValueError(f"y_obs has shape {a.shape} but y_sim has shape {b.shape}")
    if a.ndim not in (1, 2) or a.shape[0] < 2:
        raise ValueError(f"expected (P,) or (P, S) arrays with P >= 2, got {a.shape}")
    return (a[:, None], b[:, None], True) if a.ndim == 1 else (a, b, False)


def _out(v: np.ndarray, scalar: bool):
    return float(v[0]) if scalar else v


def nrmse(y_obs, y_sim):
    """||y_obs - y_sim|| / ||y_obs - mean(y_obs)|| (0 is perfect); inf where y_obs is
    constant (no spread to divide by) and y_sim differs from it."""
    a, b, scalar = _pair(y_obs, y_sim)
    # a simulation that blew up (1e297, inf) overflows the norms: inf, not a warning
    with np.errstate(over="ignore", invalid="ignore"):
        den = np.linalg.norm(a - a.mean(axis=0), axis=0)
        num = np.linalg.norm(a - b, axis=0)
    # a constant record has no spread, though its mean's rounding leaves ~1e-16: that
    # read as a spread made a constant 0.1 score GOF -1e15, printed as a number
    den = np.where(np.ptp(a, axis=0) == 0, 0.0, den)
    with np.errstate(divide="ignore", invalid="ignore"):
        v = np.where(den > 0, num / den, np.where(num > 0, np.inf, 0.0))
    return _out(v, scalar)


def gof(y_obs, y_sim):
    """Goodness of fit 1 - ||y_obs - y_sim|| / ||y_obs - mean(y_obs)||: the paper's GOF,
    MATLAB's FitPercent / 100. 1 is a perfect fit; 0 is no better than the mean;
    -inf when the simulation is not finite, or when y_obs is constant (undefined: no
    spread to divide by) and y_sim is not exactly it."""
    a, b, scalar = _pair(y_obs, y_sim)
    v = 1.0 - np.atleast_1d(nrmse(a, b))
    v = np.where(np.isfinite(b).all(axis=0), v, -np.inf)
    return _out(v, scalar)


def rmse(y_obs, y_sim):
    """Root-mean-square error, in the units of y."""
    a, b, scalar = _pair(y_obs, y_sim)
    with np.errstate(over="ignore", invalid="ignore"):  # a blown-up simulation: inf
        return _out(np.sqrt(np.mean((a - b) ** 2, axis=0)), scalar)


def r2(y_obs, y_sim):
    """Coefficient of determination 1 - ||y_obs - y_sim||² / ||y_obs - mean(y_obs)||²
    (the nonlinear benchmarks' R²; 1 is perfect, 0 no better than the mean)."""
    with np.errstate(over="ignore"):
        return 1.0 - np.square(nrmse(y_obs, y_sim))
