"""Minimising a plain function ``fun(x) -> (J, g, H)`` by the trust region, through the
one loop (endings.iterate): the inner solves that are not fits of a Problem — a
profile's corrections, validation's initial states, the model-error check's refits,
the population's outer problem — end as a fit's runs do:

- converged or given up: the trust region's own Status and detail;
- Ctrl-C: INTERRUPTED at once, at the best point evaluated (the caller decides
  whether its own work stops too: see :func:`interrupted`);
- ``fun`` or the subproblem raising ``LinAlgError`` (an eigen-solver at the edge of
  overflow): SOLVER_FAILED at the best point, the error in the detail.

The result is a :class:`~tensorid.solve.trust_region.TRResult` whatever the ending.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from ..engine.schemes.status import Status
from .endings import Outcome, OwnRun, run_alone
from .trust_region import TRResult, trust_region_steps


def minimize_trust_region(
    fun: Callable[[np.ndarray], tuple[float, np.ndarray, np.ndarray]],
    x0: np.ndarray,
    lo: np.ndarray,
    hi: np.ndarray,
    **options: Any,
) -> TRResult:
    """Minimise J with ``fun(x) -> (J, g, H)`` (J = inf marks a failed evaluation)
    within lo <= x <= hi, starting from a feasible x0.

    Arguments:
        fun: J, its gradient, and its Hessian or a function v -> Hv at x (then the
            steps are truncated CG).
        x0, lo, hi: the start and the bounds.
        options: those of :func:`~tensorid.solve.trust_region.trust_region_steps`.

    Returns:
        The TRResult: the trust region's own where it ended by itself; otherwise
        (INTERRUPTED, SOLVER_FAILED) at the best point evaluated, with its values.
    """
    run = _Plain(fun, x0, lo, hi, options)
    ending = run_alone(run)
    if run.done is not None and ending.status is not Status.INTERRUPTED:
        return run.done
    return run.stopped(ending)


def interrupted(r: TRResult) -> TRResult:
    """``r``, or KeyboardInterrupt again where Ctrl-C ended it: for callers whose own
    work (a profile's next point, the next record) must stop with it, after the loop
    has ended the run cleanly."""
    if r.status is Status.INTERRUPTED:
        raise KeyboardInterrupt
    return r


class _Plain(OwnRun):
    """One trust-region run on ``fun``: both the method and the state of a run of
    the one loop (``point``: the next x to evaluate). It keeps the best point
    evaluated, for an ending the trust region did not choose."""

    name = "trust-region"

    def __init__(self, fun, x0, lo, hi, options: dict):
        self.fun = fun
        user = options.pop("callback", None)
        self.nit = self.nfev = 0
        self.history: list[dict] = []

        def record(entry):
            self.nit = entry["iteration"]
            self.history.append(entry)
            if user is not None:
                user(entry)

        self.steps = trust_region_steps(x0, lo, hi, callback=record, **options)
        self.point: np.ndarray | None = next(self.steps)
        self.best_x: np.ndarray | None = self.point
        self.best_values: tuple | None = None
        self.done: TRResult | None = None

    # -- as a method of endings.iterate
    def evaluate(self):
        """(J, g, H) at the pending point."""
        assert self.point is not None
        return self.fun(self.point)

    def step(self, state, value) -> None:
        self.nfev += 1
        J = value[0]
        if np.isfinite(J) and (self.best_values is None or J < self.best_values[0]):
            self.best_x, self.best_values = self.point, value
        try:
            self.point = self.steps.send(value)
        except StopIteration as end:
            self.done = end.value
            self.point = None
            self.outcome = Outcome(end.value.x, end.value.nit, end.value.status, end.value.detail)

    def best(self, state) -> tuple:
        return self.best_x, self.nit

    def stopped(self, ending: Outcome) -> TRResult:
        """The TRResult of an ending the loop chose, at the best point evaluated."""
        x = np.asarray(self.best_x, dtype=float)
        if self.best_values is None:  # nothing finite evaluated: a failed run
            J, g, H = np.inf, np.zeros_like(x), None
        else:
            J, g, H = self.best_values
        hess = None if callable(H) else H
        return TRResult(x, float(J), g, hess, self.nit, self.nfev, ending.status, self.history,
                        0, ending.detail)  # fmt: skip
