"""method="auto": Gauss-Newton while it works, the exact Hessian where it does not.

The exact Hessian is the Gauss-Newton one plus a residual term,

    ∇²J = H_GN − 2 Σ w r ∂²ỹ/∂θ²,    H_GN = 2 Σ w (∂ỹ/∂θ)ᵀ(∂ỹ/∂θ),

and H_GN costs one first-order sweep where ∇²J costs a second-order one (2-4× more
at the paper's sizes). The residual term pays where residuals are large, the model
is strongly nonlinear, or the cost curves downward; elsewhere it only costs. So a fit
by ``Hybrid`` goes in two modes:

- **Gauss-Newton mode** (the start): (J, g, H_GN) at each point. Gauss-Newton
  converges quadratically where the residual term vanishes and only linearly where
  it does not, so the sign that the term matters is linear convergence: three
  accepted steps running, each predicted well (ρ > 3/4, so the trust region no
  longer limits them) and each lowering the cost by more than half as much as the
  one before. Then exact mode, if it pays: at the observed rate r, Gauss-Newton
  needs about log(ftol·J/ΔJ)/log r more steps to meet ftol, Newton a handful
  (NEWTON_STEPS), each costing (K + 2)/2 Gauss-Newton evaluations (the ratio of the
  columns the two sweeps carry; measured: 2-4 at K = 5, 6 at K = 11, more beyond, so
  an underestimate where it matters least). A fixed cost model, not timings, so
  that a fit is the same fit on every machine and every run. (Mispredicted steps far
  from the optimum are no sign: there the exact Hessian predicts no better, and
  switching on them made fits of the mass chain twice as slow for no fewer
  iterations.)
- **Exact mode**: one second-order sweep gives both ∇²J and H_GN (the latter is a
  term of the former). The next step uses whichever model predicted the last
  step's actual decrease better (the rule of Dennis, Gay and Welsch's NL2SOL), so
  negative curvature of ∇²J is followed when it is real, and a Hessian that
  mispredicts is not trusted. After three steps running where H_GN predicted
  better, back to Gauss-Newton mode and its cheaper sweeps.

A run that converges in Gauss-Newton mode is checked with ∇²J (which the error bars
need anyway); if ∇²J has negative curvature there (a saddle, invisible to H_GN,
which is never indefinite) the fit continues in exact mode (see driver.py).
"""

from __future__ import annotations

import numpy as np

GOOD = 0.75  # ρ above it: the model predicted the step well
SLOW_RUN = 3  # linear-rate steps running before exact mode
SLOW_RATE = 0.5  # a step lowering the cost by more than this × the previous is linear
GN_RUN = 3  # steps running where H_GN predicted better before Gauss-Newton mode
NEWTON_STEPS = 5  # what Newton takes from where Gauss-Newton turns linear (typical)


class Hybrid:
    """The mode of one start and the model its next step uses (scaled units).

    ``exact`` says which sweep the next point needs; :meth:`take` is given that
    point's (J, g, H_GN[, ∇²J]) and returns the (J, g, H) for the trust region.
    ``eta`` is the trust region's acceptance threshold, so that this class knows
    which trial points became iterates."""

    def __init__(self, K: int, eta: float = 0.1, ftol: float = 1e-12, exact: bool = False):
        self.eta, self.ftol = eta, ftol
        self.exact = exact
        self.cost_ratio = (K + 2) / 2  # an exact evaluation in Gauss-Newton ones
        # the iterate: φ, J, g, the H its step uses, H_GN, ∇²J (None in Gauss-Newton mode)
        self.current: tuple | None = None
        self.slow = self.gn_better = 0
        self.last_decrease: float | None = None
        self.evaluations = {"gauss-newton": 0, "exact": 0}
        self.switches = 0
        self.checked = False  # the end point was checked for negative curvature
        self.saddles = 0  # ... and had it

    def take(self, phi, J, g, H_gn, H_exact=None):
        """(J, g, H) for the trust region at ``phi``, and the mode for the next point."""
        self.evaluations["exact" if H_exact is not None else "gauss-newton"] += 1
        prefer_gn = H_exact is None
        if self.current is not None:
            phi0, J0, g0, H0, gn0, exact0 = self.current
            d = np.asarray(phi) - phi0
            actual = J0 - J if np.isfinite(J) else -np.inf
            pred = -(g0 @ d + 0.5 * d @ H0 @ d)
            rho = actual / pred if pred > 0 else -np.inf
            if exact0 is None:
                self._gauss_newton_mode(rho, actual)
            else:  # which model predicted this step better? (NL2SOL)
                errors = [abs(actual - -(g0 @ d + 0.5 * d @ H @ d)) for H in (gn0, exact0)]
                prefer_gn = H_exact is None or (np.isfinite(actual) and errors[0] < errors[1])
                self.gn_better = self.gn_better + 1 if prefer_gn else 0
                if self.gn_better >= GN_RUN:
                    self.exact, self.gn_better = False, 0
                    self.switches += 1
            if not rho > self.eta:  # rejected: the trust region keeps the iterate
                return J, g, H0
        elif not np.isfinite(J):
            return J, g, H_gn
        use = H_gn if prefer_gn else H_exact
        self.current = (np.array(phi, dtype=float), J, g, use, H_gn, H_exact)
        return J, g, use

    def _gauss_newton_mode(self, rho: float, actual: float) -> None:
        """Count linear-rate steps; switch to exact mode on SLOW_RUN of them when the
        steps Gauss-Newton still needs cost more than Newton's."""
        if not rho > self.eta:
            return
        last, J = self.last_decrease, self.current[1] - actual if self.current else 0.0
        slow = last is not None and rho > GOOD and actual > SLOW_RATE * last
        self.slow = self.slow + 1 if slow else 0
        self.last_decrease = actual
        if self.slow < SLOW_RUN:
            return
        rate = min(actual / last, 1 - 1e-9)
        remaining = np.log(max(self.ftol * J, 1e-300) / actual) / np.log(rate)
        if remaining > NEWTON_STEPS * self.cost_ratio:
            self.exact = True
            self.switches += 1
            self.slow = self.gn_better = 0

    def report(self) -> dict:
        """What the run used: evaluations of each kind and mode switches."""
        return {
            "gauss_newton_evaluations": self.evaluations["gauss-newton"],
            "exact_evaluations": self.evaluations["exact"],
            "switches": self.switches,
            "saddles_left": self.saddles,
        }
