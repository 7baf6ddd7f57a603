"""FitOptions: the tolerances, limits and trust radius of a fit, as one value."""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np


@dataclass(frozen=True)
class FitOptions:
    """How a fit iterates and when it stops.

    Arguments:
        x_scale: "auto" or an array (K,) of typical magnitudes of θ; the methods work
            on φ = θ / x_scale.
        maxiter: iteration limit.
        gtol: stop when the ∞-norm of the scaled projected gradient, relative to the
            starting cost, is below this, and (with a dense Hessian) the decrease a
            Newton step still predicts, ½ gᵀH⁻¹g, is below √gtol times the cost: the
            second does not depend on the scales chosen at the start.
        ftol: stop when an accepted step lowers the cost by less than this, relative.
        xtol: stop when the scaled step is below this, relative to 1 + ‖φ‖∞.
        radius: the first trust radius, in scaled units.
        max_radius: the largest trust radius.
        callback: called with each iteration's history entry (a dict), natural units.
        polish: multiple shooting only: finish with single shooting from the
            multiple-shooting solution, so that estimates and error bars are those of
            the one continuous trajectory.
        defect_tol: multiple shooting only: the largest continuity defect allowed,
            relative to each state's scale.
    """

    x_scale: str | np.ndarray = "auto"
    maxiter: int = 200
    gtol: float = 1e-10
    ftol: float = 1e-12
    xtol: float = 1e-12
    radius: float = 0.1
    max_radius: float = 1e4
    callback: Callable[[dict], None] | None = None
    polish: bool = True
    defect_tol: float = 1e-8

    def __post_init__(self) -> None:
        if not isinstance(self.maxiter, int | np.integer) or self.maxiter < 1:
            raise ValueError(f"maxiter must be a positive integer, got {self.maxiter!r}")
        for name in ("gtol", "ftol", "xtol", "defect_tol"):
            v = getattr(self, name)
            if not (isinstance(v, int | float) and math.isfinite(v) and v >= 0):
                raise ValueError(f"{name} must be a finite number >= 0, got {v!r}")
        for name in ("radius", "max_radius"):
            v = getattr(self, name)
            if not (isinstance(v, int | float) and math.isfinite(v) and v > 0):
                raise ValueError(f"{name} must be a finite number > 0, got {v!r}")
        if isinstance(self.x_scale, str) and self.x_scale != "auto":
            raise ValueError("x_scale must be 'auto' or an array of typical magnitudes")
        if not isinstance(self.polish, bool):
            raise TypeError(f"polish must be True or False, got {self.polish!r}")
        if self.callback is not None and not callable(self.callback):
            raise TypeError(f"callback must be callable, got {type(self.callback).__name__}")

    def trust_region(self) -> dict:
        """The keyword arguments of trust_region_steps."""
        return dict(
            maxiter=int(self.maxiter),
            gtol=self.gtol,
            ftol=self.ftol,
            xtol=self.xtol,
            radius=self.radius,
            max_radius=self.max_radius,
        )

    def without_callback(self) -> FitOptions:
        """The same options for a worker process, where the caller's callback cannot go."""
        return replace(self, callback=None)
