"""The units' inner problems, every unit's η̂ at once, through the one loop
(solve/endings.iterate): one run whose step is a vectorised damped-Newton step of
every unit (Objective's compiled ``steps``), so that its ending is a fit's —
converged, the iteration limit, Ctrl-C (INTERRUPTED, then KeyboardInterrupt again for
the population fit, which keeps its best outer point) or a failing solver."""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np

from ..engine.schemes.status import Status
from ..solve.endings import Outcome, OwnRun, run_alone


def solve_units(
    obj, psi, etas, maxiter: int, tol: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Each unit's η̂ from ``etas`` at ψ by damped Newton steps until each unit's step
    is below ``tol`` (relative) or its simulation is not finite.

    Returns:
        (η̂ (E, q), converged (E,), not finite (E,)).
    """
    run = _Newton(obj, psi, etas, maxiter, tol)
    if run_alone(run).status is Status.INTERRUPTED:
        raise KeyboardInterrupt
    return np.asarray(run.eta), run.done, run.failed


class _Newton(OwnRun):
    """Both the method and the state of the run (``point``: the units' η while there
    is a step to take); it ends by its own test, not by an outcome set."""

    name = "the units' inner Newton"

    def __init__(self, obj, psi, etas, maxiter: int, tol: float):
        self.obj, self.psi, self.maxiter, self.tol = obj, jnp.asarray(psi), maxiter, tol
        self.eta = jnp.asarray(etas)
        self.lam = jnp.zeros(self.eta.shape[0])  # each unit's damping
        self.done = self.failed = np.zeros(self.eta.shape[0], dtype=bool)
        self.nit = 0
        self.point = self.eta if maxiter > 0 else None

    def evaluate(self):
        obj = self.obj
        return obj._blocked("steps", self.eta, self.lam, self.psi, obj.data, units=(0, 1, 3))

    def step(self, state, value) -> None:
        if value is None:  # maxiter 0: no step asked for
            return
        self.eta, self.lam, f, size = value
        self.nit += 1
        self.failed = ~np.isfinite(np.asarray(f))  # its simulation: not finite
        self.done = ~self.failed & (np.asarray(size) < self.tol)  # its step negligible
        self.point = None if self.terminate(state) else self.eta

    def terminate(self, state) -> bool:
        return bool((self.done | self.failed).all()) or self.nit >= self.maxiter

    def result(self, state) -> Outcome:
        if self.done.all():
            status = Status.GTOL
        else:  # some units' simulations not finite, or the iteration limit
            status = Status.NONFINITE_STATE if (self.done | self.failed).all() else Status.MAXITER
        return Outcome(np.asarray(self.eta), self.nit, status)

    def best(self, state) -> tuple:
        return np.asarray(self.eta), self.nit
