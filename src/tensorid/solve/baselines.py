"""The finite-difference baselines the paper compares against: BFGS with a
finite-difference gradient, and SciPy's least_squares with a finite-difference
Jacobian (as MATLAB's grey-box toolbox does). They see the same simulator and the
same scaled variables as the exact-derivative methods; SciPy drives its own
evaluations, so each asks the driver for no point and runs whole in one step."""

from __future__ import annotations

import warnings

import numpy as np

from ..engine.schemes.status import Status
from .endings import Outcome
from .options import FitOptions
from .scaling import Tracker
from .solvers import Method, State, Values


class Baseline(Method):
    """A SciPy minimiser on finite differences (see the module docstring)."""

    exact_derivatives = False
    supports_segments = False
    raises = (ValueError, ArithmeticError)  # SciPy's ways of giving up

    def step(self, state: State, values: Values | None) -> None:
        """Minimise from φ0; ``state.record`` receives one entry per iteration."""
        tr, options = state.tr, state.options
        lo, hi = tr.box()
        it = [0]

        # SciPy passes its OptimizeResult only to a parameter named intermediate_result
        def cb(intermediate_result):
            it[0] += 1
            nan = float("nan")
            state.record(
                {
                    "iteration": it[0],
                    "cost": float(self.cost(intermediate_result)),
                    "grad_norm": nan,
                    "radius": nan,
                    "step_norm": nan,
                    "rho": nan,
                    "accepted": True,
                    "nfev": tr.nfev,
                }
            )

        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            res, nit = self.minimize(tr, tr.phi(tr.theta0), lo, hi, options, cb)
        status = Status.BASELINE_CONVERGED if res.success else Status.BASELINE_STOPPED
        state.outcome = Outcome(res.x, nit, status, str(res.message))

    def cost(self, r) -> float:
        """J (scaled) from SciPy's intermediate result."""
        raise NotImplementedError

    def minimize(self, tr: Tracker, phi0, lo, hi, options: FitOptions, cb):
        """(SciPy's OptimizeResult, iterations)."""
        raise NotImplementedError


class FdBfgs(Baseline):
    """BFGS (L-BFGS-B with bounds) with a finite-difference gradient."""

    name = "fd-bfgs"

    def cost(self, r) -> float:
        return r.fun

    def minimize(self, tr: Tracker, phi0, lo, hi, options: FitOptions, cb):
        import scipy.optimize  # here, not at the top: keeps `import tensorid` cheap

        bounded = bool(np.isfinite(lo).any() or np.isfinite(hi).any())
        res = scipy.optimize.minimize(
            tr.cost,
            phi0,
            method="L-BFGS-B" if bounded else "BFGS",
            jac="2-point",
            bounds=list(zip(lo, hi, strict=True)) if bounded else None,
            options={"maxiter": options.maxiter, "gtol": options.gtol},
            callback=cb,
        )
        return res, int(res.nit)


class FdLsq(Baseline):
    """scipy's least_squares (trf) with a finite-difference Jacobian."""

    name = "fd-lsq"
    supports_likelihood = False  # it minimises Σ r², which a filter's J is not

    def cost(self, r) -> float:
        return 2.0 * r.cost  # least_squares: ½ Σ r²

    def minimize(self, tr: Tracker, phi0, lo, hi, options: FitOptions, cb):
        import scipy.optimize

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
        return res, int(res.njev or res.nfev)
