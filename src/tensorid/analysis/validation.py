"""Scoring a fitted model on records: the training records at the estimate, and new
records with the initial states re-estimated (MATLAB's compare; the nonlinear
benchmarks' protocol with an initialisation window).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from ..engine.assembly.problem import Problem
from ..engine.assembly.simulate import Simulation, run_simulation
from ..engine.compiling.compiled import on_device
from ..engine.modelling.checks import same_step, step
from ..engine.modelling.data import Experiment
from ..engine.modelling.metrics import gof, nrmse, r2, rmse
from ..engine.schemes.status import Status
from ..engine.sweeping.dosing import dosing_of, measured
from ..engine.sweeping.predictions import check_horizon
from ..engine.sweeping.sweeps import shared_sweeps
from ..solve.minimize import interrupted, minimize_trust_region
from ..solve.scaling import Tracker
from .summary import Table, Tabular, metric_rows, score_notes


@dataclass(frozen=True, eq=False, repr=False)
class Score(Tabular):
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
    horizon: int | None = None  # k: scored as k-step-ahead prediction, not simulation
    filtered: bool = False  # the model of a filter fit (predictor="ekf")
    # how the fit of the initial states ended (None: none fitted); where it stopped
    # short, a note says the scores may be pessimistic
    x0_status: Status | None = None

    @property
    def label(self) -> str:
        """The kind, with the record's name where it tells records apart (and the
        prediction horizon, where scored as prediction; "simulation" for a filter
        fit's record scored without one, beside rows scored as prediction)."""
        label = record_label(self.kind, self.experiment.name, self.alone)
        if self.horizon is None:
            return f"{label}, simulation" if self.filtered else label
        return f"{label}, {self.horizon}-step prediction"

    @property
    def x0_fit(self) -> str | None:
        """How the fit of the initial states ended ("gtol", "maxiter", ...; None
        where none was fitted), as fit.json and compare.json say it."""
        return self.x0_status.name.lower() if self.x0_status else None

    def _pairs(self):
        """Per output, (measured, simulated) at its scored samples: from ``start`` on,
        where it was measured (not at a gap, nor at a row holding only a dose, whose
        y is a placeholder 0 and whose prediction may not even be finite: log c)."""
        seen = self.experiment.seen[self.start :]
        y, s = self.experiment.measured[self.start :], self.simulation.y[self.start :]
        return [(y[seen[:, j], j], s[seen[:, j], j]) for j in range(y.shape[1])]

    @property
    def samples(self) -> int:
        """The scored samples: from ``start`` on, those holding a measurement."""
        return int(self.experiment.seen_rows[self.start :].sum())

    @property
    def scored(self) -> dict[str, int]:
        """{output: the number of its scored samples}."""
        outs = self.simulation.model.outputs
        return {o: int(a.size) for o, (a, _) in zip(outs, self._pairs(), strict=True)}

    def _per_output(self, metric) -> dict[str, float]:
        """{output: metric}; NaN where fewer than two samples of it are scored."""
        outs = self.simulation.model.outputs
        return {o: float(metric(a, b)) if a.size > 1 else float("nan")
                for o, (a, b) in zip(outs, self._pairs(), strict=True)}  # fmt: skip

    @property
    def gof(self) -> dict[str, float]:
        """1 - ‖y - ŷ‖ / ‖y - mean y‖ per output (MATLAB's FitPercent / 100)."""
        return self._per_output(gof)

    @property
    def rmse(self) -> dict[str, float]:
        return self._per_output(rmse)

    @property
    def constant(self) -> dict[str, float]:
        """{output: value} for each output the record holds constant over its scored
        samples, where GOF, NRMSE, R² and fit percent (which divide by its spread)
        are undefined unless the simulation matches it exactly."""
        outs = self.simulation.model.outputs
        pairs = zip(outs, self._pairs(), strict=True)
        return {o: float(a[0]) for o, (a, _) in pairs if a.size and np.ptp(a) == 0}

    @property
    def nrmse(self) -> dict[str, float]:
        return self._per_output(nrmse)

    @property
    def r2(self) -> dict[str, float]:
        """1 - ‖y - ŷ‖² / ‖y - mean y‖² per output (the coefficient of determination)."""
        return self._per_output(r2)

    @property
    def fit_percent(self) -> dict[str, float]:
        """100 · GOF per output (MATLAB's compare, the benchmarks' fit index)."""
        return {o: 100.0 * v for o, v in self.gof.items()}

    def metrics(self) -> dict[str, dict[str, float]]:
        """{output: {"rmse", "nrmse", "r2", "fit_percent", "gof"}} (compare.json's)."""
        names = ("rmse", "nrmse", "r2", "fit_percent", "gof")
        values = {n: getattr(self, n) for n in names}
        return {o: {n: values[n][o] for n in names} for o in self.simulation.model.outputs}

    def blocks(self) -> list:
        """The metric table of the summary and report.md, for this record."""
        return [Table(None, *metric_rows([self])), *score_notes([self])]

    def __repr__(self) -> str:
        fits = ", ".join(f"{o}: {v:.4f}" for o, v in self.gof.items())
        after = f" after {self.start}" if self.start else ""
        return f"Score({self.label}, gof={{{fits}}}, {self.samples} samples{after})"


def record_label(kind: str, name: str, alone: bool = True) -> str:
    """ "training", or "training 'exp2'": the record's name, unless it is the only
    record of its kind and its name only repeats the kind (train.csv for training,
    validate.csv for validation)."""
    plain = name.lower()
    if not plain or (alone and plain in _KIND_WORDS[kind]):
        return kind
    return f"{kind} '{name}'"


def repeats_kind(kind: str, name: str) -> bool:
    """Whether a record's name only repeats its kind ("train" for training)."""
    return name.lower() in _KIND_WORDS[kind]


_KIND_WORDS = {
    "training": ("training", "train", "estimation", "est"),
    "validation": ("validation", "validate", "valid", "test"),
}


def training_scores(res) -> list[Score]:
    """The training records at the estimate."""
    x0 = np.atleast_2d(res.x0)
    exps = res.problem.experiments
    filtered = res.problem.predictor.update is not None  # scored as its simulation
    return [
        Score("training", e, s, x0[i], alone=len(exps) == 1, filtered=filtered)
        for i, (e, s) in enumerate(zip(exps, res.simulate(), strict=True))
    ]


def estimate_x0(
    model, params, x0, free: list[str], record: Experiment, discretisation, events=None
) -> tuple[np.ndarray, Status]:
    """The initial state (N,) for ``record``, and how its fit ended: the states named
    in ``free`` estimated by
    trust-region Gauss-Newton with the parameters held (MATLAB's compare), the others
    as in ``x0``; ``x0`` itself where the simulation from it is not finite. (Gauss-Newton:
    a few initial states are fitted in a few steps, and a second-order sweep would
    cost the command line its compilation.)"""
    if record.censored is not None:  # a least-squares fit of x0: the measured samples alone
        record = replace(record, censored=None)
    problem = Problem(
        model,
        record,
        p0=params,
        x0=x0,
        free_x0=free,
        fixed=list(model.params),
        discretisation=discretisation,
        **(events or {}),  # doses=, lags=: what the fit's events did
    )
    theta, status = _free_x0(problem)
    return problem.unpack(theta)[1][0], status


def _free_x0(problem: Problem) -> tuple[np.ndarray, Status]:
    theta0 = problem.theta0
    J0, _, H0 = problem.cost_grad_gn(theta0)
    if not np.isfinite(J0):
        return theta0, Status.NONFINITE_START
    tr = Tracker.start(problem, theta0, J0, H0, "auto")
    lo, hi = tr.box()
    r = minimize_trust_region(
        tr.derivs(problem.cost_grad_gn), tr.phi(theta0), lo, hi, fatol=tr.fatol
    )
    # the tracker saw every evaluation, the end point included: its best is never worse
    return tr.theta(r.x if tr.best_phi is None else tr.best_phi), interrupted(r).status


def check_init_window(init_window: int | None, record: Experiment) -> None:
    """An initialisation window, a whole number of samples, leaves at least two
    samples of ``record`` to score (2.5 was cut to 2 and "20" read as 20, silently),
    and on a record with unmeasured rows holds a measurement and leaves two."""
    whole = isinstance(init_window, int | np.integer) and not isinstance(init_window, bool)
    if init_window is not None and not whole:
        raise ValueError(f"init_window must be a whole number of samples, got {init_window!r}")
    if init_window is not None and not (2 <= int(init_window) < record.P - 1):
        raise ValueError(
            f"init_window must be between 2 and {record.P - 2} samples (the record "
            f"{record.name!r} has {record.P}, and at least 2 are scored), got {init_window}"
        )
    if init_window is None or record.y is None or record.observed is None:
        return
    # a window counts rows, as the record's time axis does; on an event record (rows
    # holding only a dose) or one with gaps, both of its sides must hold measurements
    seen = record.seen_rows
    inside, after = int(seen[: int(init_window)].sum()), int(seen[int(init_window) :].sum())
    if inside < 1 or after < 2:
        raise ValueError(
            f"init_window {init_window} leaves {inside} measured sample(s) of the record "
            f"{record.name!r} to estimate its initial states on and {after} to score (it "
            f"has {record.P} samples, {int(seen.sum())} of them measured; rows holding "
            "only a dose or a gap count as samples, not as measurements): the window must "
            "hold at least 1 and leave at least 2; give another window"
        )


def score_record(
    model,
    params,
    x0,
    free_x0: list[str],
    record: Experiment,
    discretisation,
    init_window: int | None = None,
    *,
    kind: str = "validation",
    alone: bool = True,
    horizon: int | None = None,
    predictor=None,
    events: dict | None = None,
) -> Score:
    """``model`` with ``params`` held, simulated on ``record`` (MATLAB's compare): the
    initial states named in ``free_x0`` estimated on the first ``init_window`` samples
    (the whole record when None; not at all without measured outputs), the others as
    in ``x0``; scored after the window. With ``horizon`` k, scored as k-step-ahead
    prediction by ``predictor`` (a Sweeps' predictor and loss, (loss, predictor));
    by output error (the default), whose prediction at every horizon is the
    simulation, scored and labelled as the simulation.
    The one routine behind ``FitResult.validate``, ``tensorid simulate`` and
    ``tensorid compare``."""
    check_init_window(init_window, record)
    x0 = np.asarray(x0, dtype=float)
    disc = discretisation.for_model(model)
    x0_status = None
    if free_x0 and record.y is not None:
        window = record if init_window is None else record.window(0, int(init_window))
        x0, x0_status = estimate_x0(model, params, x0, list(free_x0), window, disc, events)
    dosing = dosing_of(model, [record], **(events or {}))  # the fit's doses= and lags=
    sweeps = shared_sweeps(model, (), (), disc, dosing=dosing)
    sim = run_simulation(sweeps, record, x0, model.params_array(params))
    if horizon is not None and (predictor is None or predictor[1].update is None):
        check_horizon(horizon, record.P)  # a bad one is refused all the same
        horizon = None  # output error: every horizon's prediction is the simulation
    if horizon is not None:
        sim = _predicted(sim, model, params, x0, record, disc, horizon, predictor)
    start = 0 if init_window is None else int(init_window)
    filtered = predictor is not None and predictor[1].update is not None
    return Score(kind, record, sim, x0, start, init_window, alone=alone, horizon=horizon,
                 filtered=filtered, x0_status=x0_status)  # fmt: skip


def _predicted(sim, model, params, x0, record, disc, horizon, predictor) -> Simulation:
    """``sim`` with its outputs replaced by the k-step-ahead predictions."""
    if record.y is None:
        raise ValueError(f"a prediction horizon needs measured outputs; {record.name!r} has none")
    check_horizon(horizon, record.P)
    sw = shared_sweeps(model, (), (), disc, *(predictor or ()))
    u = disc.inputs(model, record.t, record.inputs_held(disc.interpolation))
    args = (on_device(a) for a in (x0, model.params_array(params), record.t, u))
    y = measured(record, record.P)  # with its mask where it has gaps: no update there
    y = np.asarray(sw.k_step(on_device(np.zeros(0)), *args, y, k=int(horizon)))
    return Simulation(model, record, sim.x, y, sim.status, sim.failed_at)


def validate(res, data, init_window: int | None = None, horizon: int | None = None) -> list[Score]:
    """See FitResult.validate."""
    exps = [data] if isinstance(data, Experiment) else list(data)
    prob = res.problem
    x0_fit = np.atleast_2d(res.x0)[0]
    windows = []
    for i, e in enumerate(exps):
        if not isinstance(e, Experiment):
            raise TypeError(f"validation record {i} is a {type(e).__name__}, not an Experiment")
        if e.y is None:
            raise ValueError(f"validation record {i} ({e.name!r}) has no measured outputs")
        windows.append(e.init_window if init_window is None else init_window)
        check_init_window(windows[-1], e)
        same_step(prob.model, e, step(prob.experiments[0]), f"validation record {e.name!r}")
    return [
        score_record(
            prob.model,
            res.params,
            x0_fit,
            prob.free_x0,
            e,
            prob.discretisation,
            w,
            alone=len(exps) == 1,
            horizon=horizon,
            predictor=(prob.loss, prob.predictor),
            events=None if prob.dosing is None else prob.dosing.expressions(),
        )  # fmt: skip
        for e, w in zip(exps, windows, strict=True)
    ]
