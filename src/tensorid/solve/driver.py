"""The driver behind fit() and fit_batch(): the shared set-up (starting cost, scale,
tracker), then one loop (endings.iterate) for every method, which steps one start
with its points evaluated one at a time, or several starts in lock-step with their
points evaluated in one vectorised call; and the result at the end, which is the
best finite point seen.
"""

from __future__ import annotations

from functools import partial

import numpy as np

from .endings import Run, failed_start, fit_result, iterate
from .options import FitOptions
from .scaling import Tracker
from .solution import Solution
from .solvers import Method, Sweep, Values


def fit_many(problem, method: Method, thetas, options: FitOptions, started) -> list[Solution]:
    """Fits from every row of ``thetas``: lock-step for several starts, otherwise one
    start evaluated point by point. The set-up (cost, scale, tracker) is shared."""
    batched = len(thetas) > 1
    if batched:
        J0, _, H0 = problem.cost_grad_hess_batch(thetas, gauss_newton=True)
    else:
        J, _, H = problem.cost_grad_gn(thetas[0])
        J0, H0 = np.array([J]), H[None]
    results: list[Solution | None] = [None] * len(thetas)
    runs: dict[int, Run] = {}
    for i, th in enumerate(thetas):
        if np.isfinite(J0[i]):
            tr = Tracker.start(problem, th, J0[i], H0[i], options.x_scale)
            runs[i] = Run(method, method.init(tr, options))
        else:
            results[i] = failed_start(problem, method.name, th, started)
    evaluate = partial(_together, problem, len(thetas)) if batched else partial(_one, problem)
    iterate(list(runs.values()), evaluate, partial(fit_result, started=started))
    for i, run in runs.items():  # each made as its run ended: its seconds are its own
        results[i] = run.result  # (in lock-step, from the batch's start to its end)
    return [r for r in results if r is not None]


def _one(problem, runs: list[Run]) -> list[Values]:
    """The values at the one pending point, by the sweep its method asks for."""
    (run,) = runs
    theta, sweep = run.state.tr.theta(run.state.point), run.method.sweep(run.state)
    if sweep is Sweep.EXACT:
        J, g, H = problem.cost_grad_hess(theta)
        return [Values(J, g, H=H)]
    if sweep is Sweep.GN:
        J, g, G = problem.cost_grad_gn(theta)
        return [Values(J, g, G=G)]
    if sweep is Sweep.BOTH:
        return [Values(*problem.cost_grad_hess_gn(theta))]
    J, g = problem.cost_grad(theta)  # Sweep.HESSP
    return [Values(J, g, H=lambda v: problem.cost_grad_hessp(theta, v)[2])]


def _together(problem, B: int, runs: list[Run]) -> list[Values]:
    """The values at every pending point, in one vectorised call padded to B points
    (one compilation): the sweep they all ask for, or, where they differ (method
    "auto", some starts in exact mode), one second-order sweep for all, which gives
    the Gauss-Newton Hessian too (one sweep of B costs less than two)."""
    sweeps = {run.method.sweep(run.state) for run in runs}
    sweep = sweeps.pop() if len(sweeps) == 1 else Sweep.BOTH
    assert sweep is not Sweep.HESSP, "Hessian-vector products are not batched"
    points = [run.state.tr.theta(run.state.point) for run in runs]
    points += [points[0]] * (B - len(points))
    vals = problem.cost_grad_hess_batch(
        np.array(points), gauss_newton=sweep is Sweep.GN, both=sweep is Sweep.BOTH
    )
    if sweep is Sweep.GN:
        return [Values(vals[0][k], vals[1][k], G=vals[2][k]) for k in range(len(runs))]
    G = vals[3] if sweep is Sweep.BOTH else [None] * len(runs)
    return [Values(vals[0][k], vals[1][k], vals[2][k], G[k]) for k in range(len(runs))]
