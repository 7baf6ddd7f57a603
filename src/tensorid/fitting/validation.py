"""Scoring a fitted model on records: the training records at the estimate, and new
records with the initial states re-estimated (MATLAB's compare; the nonlinear
benchmarks' protocol with an initialisation window).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..engine.data import Experiment
from ..engine.metrics import gof, nrmse, rmse
from ..engine.problem import Problem
from ..engine.simulate import Simulation, run_simulation
from ..engine.sweeps import shared_sweeps
from .scaling import Tracker
from .trust_region import minimize_trust_region


@dataclass(frozen=True, eq=False)
class Score:
    """How well a simulation matches one record, per output.

    ``kind`` is "training" or "validation"; ``x0`` the initial state simulated from;
    samples before ``start`` (the initialisation window) are not scored.
    """

    kind: str
    experiment: Experiment
    simulation: Simulation
    x0: np.ndarray
    start: int = 0
    init_window: int | None = None
    alone: bool = True  # the only record of its kind

    @property
    def label(self) -> str:
        """The kind, with the record's name where it tells records apart."""
        return record_label(self.kind, self.experiment.name, self.alone)

    def _pairs(self):
        y, s = self.experiment.measured[self.start :], self.simulation.y[self.start :]
        return [(y[:, j], s[:, j]) for j in range(y.shape[1])]

    def _per_output(self, metric) -> dict[str, float]:
        outs = self.simulation.model.outputs
        return {o: float(metric(a, b)) for o, (a, b) in zip(outs, self._pairs(), strict=True)}

    @property
    def gof(self) -> dict[str, float]:
        """1 - ‖y - ŷ‖ / ‖y - mean y‖ per output (MATLAB's FitPercent / 100)."""
        return self._per_output(gof)

    @property
    def rmse(self) -> dict[str, float]:
        return self._per_output(rmse)

    @property
    def nrmse(self) -> dict[str, float]:
        return self._per_output(nrmse)


def record_label(kind: str, name: str, alone: bool = True) -> str:
    """ "training", or "training 'exp2'": the record's name, unless it is the only
    record of its kind and its name only repeats the kind (train.csv for training,
    validate.csv for validation)."""
    plain = name.lower()
    if not plain or (alone and plain in _KIND_WORDS[kind]):
        return kind
    return f"{kind} '{name}'"


_KIND_WORDS = {
    "training": ("training", "train", "estimation", "est"),
    "validation": ("validation", "validate", "valid", "test"),
}


def training_scores(res) -> list[Score]:
    """The training records at the estimate."""
    x0 = np.atleast_2d(res.x0)
    exps = res.problem.experiments
    return [
        Score("training", e, s, x0[i], alone=len(exps) == 1)
        for i, (e, s) in enumerate(zip(exps, res.simulate(), strict=True))
    ]


def estimate_x0(model, params, x0, free: list[str], record: Experiment, discretisation):
    """The initial state (N,) for ``record``: the states named in ``free`` estimated by
    trust-region Newton with the parameters held (MATLAB's compare), the others as in
    ``x0``; ``x0`` itself where the simulation from it is not finite."""
    problem = Problem(
        model,
        record,
        p0=params,
        x0=x0,
        free_x0=free,
        fixed=list(model.params),
        discretisation=discretisation,
    )
    return problem.unpack(_free_x0(problem))[1][0]


def _free_x0(problem: Problem) -> np.ndarray:
    theta0 = problem.theta0
    J0, _, H0 = problem.cost_grad_gn(theta0)
    if not np.isfinite(J0):
        return theta0
    tr = Tracker.start(problem, theta0, J0, H0, "auto")
    lo, hi = tr.box()
    r = minimize_trust_region(
        tr.derivs(problem.cost_grad_hess), tr.phi(theta0), lo, hi, fatol=tr.fatol
    )
    # the tracker saw every evaluation, the end point included: its best is never worse
    return tr.theta(r.x if tr.best_phi is None else tr.best_phi)


def validate(res, data, init_window: int | None = None) -> list[Score]:
    """See FitResult.validate."""
    exps = [data] if isinstance(data, Experiment) else list(data)
    prob = res.problem
    m = prob.model
    x0_fit = np.atleast_2d(res.x0)[0]
    out = []
    for i, e in enumerate(exps):
        if not isinstance(e, Experiment):
            raise TypeError(f"validation record {i} is a {type(e).__name__}, not an Experiment")
        if e.y is None:
            raise ValueError(f"validation record {i} ({e.name!r}) has no measured outputs")
        if init_window is not None and not (2 <= int(init_window) < e.P):
            raise ValueError(
                f"init_window must be between 2 and {e.P - 1} samples (the record "
                f"{e.name!r} has {e.P}), got {init_window}"
            )
        x0 = x0_fit.copy()
        if prob.free_x0:
            window = e if init_window is None else e.window(0, int(init_window))
            x0 = estimate_x0(m, res.params, x0_fit, prob.free_x0, window, prob.discretisation)
        sweeps = shared_sweeps(m, (), (), prob.discretisation)
        sim = run_simulation(sweeps, e, x0, m.params_array(res.params))
        start = 0 if init_window is None else int(init_window)
        out.append(Score("validation", e, sim, x0, start, init_window, alone=len(exps) == 1))
    return out
