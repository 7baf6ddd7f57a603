"""The finite-difference baselines the paper compares against: BFGS with a
finite-difference gradient, and SciPy's least_squares with a finite-difference
Jacobian (as MATLAB's grey-box toolbox does). They see the same simulator and the
same scaled variables as the exact-derivative methods."""

from __future__ import annotations

import warnings

import numpy as np

from ..engine.status import Status
from .options import FitOptions
from .scaling import Tracker

BASELINES = ("fd-bfgs", "fd-lsq")


def run_baseline(
    method: str, tr: Tracker, phi0: np.ndarray, options: FitOptions, record
) -> tuple[np.ndarray, int, Status, str]:
    """Minimise from φ0 with a baseline; returns (φ, iterations, status, SciPy's
    message). ``record`` receives one history entry per iteration."""
    lo, hi = tr.box()
    bounded = bool(np.isfinite(lo).any() or np.isfinite(hi).any())
    it = [0]

    # SciPy passes its OptimizeResult only to a parameter named intermediate_result
    def cb(intermediate_result):
        it[0] += 1
        r = intermediate_result
        J = r.fun if method == "fd-bfgs" else 2.0 * r.cost  # least_squares: ½ Σ r²
        nan = float("nan")
        record(
            {
                "iteration": it[0],
                "cost": float(J),
                "grad_norm": nan,
                "radius": nan,
                "step_norm": nan,
                "rho": nan,
                "accepted": True,
                "nfev": tr.nfev,
            }
        )

    import scipy.optimize  # here, not at the top: keeps `import tensorid` cheap

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        if method == "fd-bfgs":
            res = scipy.optimize.minimize(
                tr.cost,
                phi0,
                method="L-BFGS-B" if bounded else "BFGS",
                jac="2-point",
                bounds=list(zip(lo, hi, strict=True)) if bounded else None,
                options={"maxiter": options.maxiter, "gtol": options.gtol},
                callback=cb,
            )
            nit = int(res.nit)
        else:
            res = scipy.optimize.least_squares(
                tr.residuals,
                phi0,
                jac="2-point",
                bounds=(lo, hi),
                method="trf",
                ftol=max(options.ftol, 1e-15),
                xtol=max(options.xtol, 1e-15),
                gtol=max(options.gtol, 1e-15),
                max_nfev=options.maxiter * (len(phi0) + 1),
                callback=cb,
            )
            nit = int(res.njev or res.nfev)
    status = Status.BASELINE_CONVERGED if res.success else Status.BASELINE_STOPPED
    return res.x, nit, status, str(res.message)
