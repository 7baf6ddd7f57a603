"""method="auto": Gauss-Newton while it works, the exact Hessian where it does not.

The exact Hessian is the Gauss-Newton one plus a residual term,

    ∇²J = H_GN − 2 Σ w r ∂²ỹ/∂θ²,    H_GN = 2 Σ w (∂ỹ/∂θ)ᵀ(∂ỹ/∂θ),

and H_GN costs one first-order sweep where ∇²J costs a second-order one (2-4× more
at the paper's sizes). The residual term pays where residuals are large, the model
is strongly nonlinear, or the cost curves downward; elsewhere it only costs. So a fit
by ``Hybrid`` goes in two modes:

- **Gauss-Newton mode** (the start): (J, g, H_GN) at each point. Where the residual
  term is small Gauss-Newton converges quadratically, and where it matters it stalls:
  it converges only linearly, or its model mispredicts so that the trust region
  keeps its steps short. Either way its iterations stop lowering the cost: each
  lowers it by less than STALL (1e-3) of itself, rejected steps included; but a
  step whose actual decrease was within a factor FAIR (2) of H_GN's prediction
  neither counts nor ends a run (nor does the rejected step right after one, which
  only tried the radius that step doubled): H_GN's curvature held along it, so the
  residual term, all that the exact Hessian adds, did not matter there. Such slow
  steps are a radius still doubling towards a point far off in scaled units (a
  Silverbox start whose initial velocity is 1e-4 where the optimum's is -1.3), or
  steps the radius keeps short where the cost is not quadratic (the two-tank
  problem): counting them
  made auto 1.45x and 1.2-1.6x Gauss-Newton's time on seeded ±20 % starts there
  (7-25 exact evaluations per fit for no fewer iterations; bench_start_panel.py),
  where on Lotka-Volterra Gauss-Newton's predictions fail (ρ 0.2-0.6 at radii of
  1e-3) and the exact Hessian ends a crawl of 100-200 iterations in 20-40. After
  a run of such iterations that has cost as much as one exact evaluation (the
  ski-rental rule: rent until the rent paid equals the price, then buy; an exact
  evaluation costs about (K + 2)/2 Gauss-Newton ones by the transition tensors, the
  ratio of the columns the two sweeps carry, and the run is at least STALL_RUN long),
  exact mode. Second-order adjoints make an exact evaluation cost only about 3
  Gauss-Newton ones, but pricing it so made auto 1.24x and 1.67x slower than
  Gauss-Newton on the chains of 5 and 32 masses in one bench_methods run (8 and 6
  exact evaluations for no fewer iterations), so the price stays (K + 2)/2 whichever
  path computes it. A quadratically converging run crosses from 1e-3 to ftol in two
  or three iterations and never gets there. The cost model is fixed, not timed, so
  that a fit is the same fit on every machine and every run (to rounding: the Hessian
  path, which engine/sweeping/adjoint.py also picks by the cores, moves the last digits only).
  (Mispredicted steps far from the
  optimum, where the cost still falls fast, are no such sign: switching on them made
  fits of the mass chain twice as slow for no fewer iterations.)
- **Exact mode**: one second-order sweep gives both ∇²J and H_GN (the latter is a
  term of the former). The next step uses whichever model predicted the last
  step's actual decrease better (the rule of Dennis, Gay and Welsch's NL2SOL), so
  negative curvature of ∇²J is followed when it is real, and a Hessian that
  mispredicts is not trusted. After three steps running where H_GN predicted
  better, back to Gauss-Newton mode and its cheaper sweeps.

Method "newton" is exact mode throughout (``locked``): the exact Hessian from every
sweep, with the same choice of model per step, and H_GN for the first step (as in
NL2SOL: there is no step yet to judge the models by). The pure exact model, far
from the optimum, follows the residual term's negative curvature to the trust
region's boundary, where the cost does not follow: on a chain of 5 masses with cubic
springs (benchmarks/bench_chain_cubic.py, starts 1 and 6) most such steps were
rejected, the radius stayed at 0.003-0.8 for a hundred iterations, and both runs
ended in a worse local minimum (cost 559.6, three dampers at their bound) after 150
and 118 iterations; now they reach 1.8952 in 21 and 14. (Without H_GN's first step,
start 6 still went to 559.6, in 105 iterations.)

A run that converges in Gauss-Newton mode is checked with ∇²J (which the error bars
need anyway); if ∇²J has negative curvature there (a saddle, invisible to H_GN,
which is never indefinite) the fit continues in exact mode (see driver.py).
"""

from __future__ import annotations

import numpy as np

STALL = 1e-3  # an iteration lowering the cost by less than this, relative, stalls
STALL_RUN = 5  # the shortest run of stalled iterations before exact mode
GN_RUN = 3  # steps running where H_GN predicted better before Gauss-Newton mode
FAIR = 2.0  # a step lowering the cost within this factor of H_GN's prediction


class Hybrid:
    """The mode of one start and the model its next step uses (scaled units).

    ``exact`` says which sweep the next point needs. :meth:`take` is given that
    point's (J, g, H_GN, ∇²J or None) and returns the (J, g, H) for the trust
    region; :meth:`observe` is given the trust region's record of the step (its
    callback entry, scaled units), which says whether the point became the iterate."""

    def __init__(self, K: int, exact: bool = False, locked: bool = False):
        self.exact = exact
        self.locked = locked  # method "newton": exact mode throughout
        self.cost_ratio = (K + 2) / 2  # an exact evaluation in Gauss-Newton ones
        # the iterate and the trial point: φ, J, g, the H its step uses, H_GN, ∇²J
        self.current: tuple | None = None
        self.pending: tuple | None = None
        self.stalled = self.gn_better = 0
        self.fair = False  # the last step in Gauss-Newton mode went as H_GN predicted
        self.evaluations = {"gauss-newton": 0, "exact": 0}
        self.switches = 0
        self.checked = False  # the end point was checked for negative curvature
        self.saddles = 0  # ... and had it

    def take(self, phi, J, g, H_gn, H_exact, exact: bool):
        """(J, g, H) for the trust region at ``phi``; ``exact``: the sweep run."""
        self.evaluations["exact" if exact else "gauss-newton"] += 1
        if self.current is None or not np.isfinite(J):
            # "newton" takes its first step by H_GN, as NL2SOL does (not after a saddle)
            first_gn = self.locked and not self.saddles
            use = H_gn if H_exact is None or first_gn else H_exact
            if self.current is None and np.isfinite(J):
                self.current = (np.array(phi, dtype=float), J, g, use, H_gn, H_exact)
            self.pending = None
            return J, g, use
        phi0, J0, g0, _, gn0, exact0 = self.current
        prefer_gn = H_exact is None
        if exact0 is not None and H_exact is not None:  # which model predicted better?
            d = np.asarray(phi) - phi0
            actual = J0 - J
            errors = [abs(actual + g0 @ d + 0.5 * d @ H @ d) for H in (gn0, exact0)]
            prefer_gn = errors[0] < errors[1]
            self.gn_better = self.gn_better + 1 if prefer_gn else 0
        use = H_gn if prefer_gn else H_exact
        self.pending = (np.array(phi, dtype=float), J, g, use, H_gn, H_exact)
        return J, g, use

    def observe(self, entry: dict) -> None:
        """The trust region's verdict on the last trial point; the mode for the next."""
        if entry["iteration"] == 0:
            return
        new = self.pending if entry["accepted"] else None
        J_old = self.current[1] if self.current is not None else np.inf
        if new is not None:
            self.current = new
        self.pending = None
        if self.exact:
            if self.gn_better >= GN_RUN and not self.locked:  # H_GN's sweeps suffice
                self.exact, self.gn_better = False, 0
                self.switches += 1
            return
        # |J_old|: a likelihood's J (predictor="ekf") may be negative
        decrease = (J_old - new[1]) / abs(J_old) if new is not None and J_old != 0 else 0.0
        # no sign that H_GN is wrong: a step as it predicted, or the rejected step
        # right after one (it tried the radius that step doubled)
        fair, probe = _as_predicted(entry), not entry["accepted"] and self.fair
        if decrease >= STALL:
            self.stalled = 0
        elif not (fair or probe):
            self.stalled += 1
        self.fair = fair
        if self.stalled >= max(STALL_RUN, self.cost_ratio):
            self.exact = True
            self.switches += 1
            self.stalled = self.gn_better = 0

    def restart_exact(self) -> None:
        """Go on in exact mode from the end point of a run (a saddle)."""
        self.exact, self.current, self.pending = True, None, None
        self.saddles += 1

    def report(self) -> dict | None:
        """What the run of method "auto" used: evaluations of each kind, mode switches."""
        if self.locked:
            return None
        return {
            "gauss_newton_evaluations": self.evaluations["gauss-newton"],
            "exact_evaluations": self.evaluations["exact"],
            "switches": self.switches,
            "saddles_left": self.saddles,
        }


def _as_predicted(entry: dict) -> bool:
    """Did the step lower the cost within a factor of two of what H_GN predicted?
    Then H_GN's curvature held along it, whatever the step's length: the exact
    Hessian differs from H_GN by the residual term, and only where H_GN mispredicts
    does that term matter."""
    return entry["accepted"] and 1.0 / FAIR < entry["rho"] < FAIR
