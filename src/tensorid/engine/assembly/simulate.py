"""Simulate a model for given parameters and initial state on an experiment's inputs."""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np

from ... import _config  # noqa: F401
from ..compiling.compiled import on_device
from ..modelling.data import Experiment
from ..modelling.model import Model
from ..schemes.discretisation import Discretisation
from ..schemes.integrators import Scheme
from ..schemes.status import Status
from ..sweeping.dosing import covering, dosing_of
from ..sweeping.sweeps import Sweeps, shared_sweeps


@dataclass(frozen=True, eq=False)
class Simulation:
    """A simulated trajectory: ``x`` (P, N) states and ``y`` (P, S) outputs at the
    experiment's sample times ``t``.

    ``status`` says how the integration ended (``Status.OK``, or the integrator's
    failure: non-finite state, step limit, step underflow, Newton stage failure,
    non-finite outputs) and ``failed_at`` the first sample that was not reached
    finitely (None when OK).
    """

    model: Model
    experiment: Experiment
    x: np.ndarray
    y: np.ndarray
    status: Status = Status.OK
    failed_at: int | None = None

    @property
    def t(self) -> np.ndarray:
        """Sample times (P,)."""
        return self.experiment.t

    @property
    def finite(self) -> bool:
        """False when the simulation blew up (non-finite states or outputs)."""
        return bool(np.isfinite(self.x).all() and np.isfinite(self.y).all())


def run_simulation(sweeps: Sweeps, data: Experiment, x0, p) -> Simulation:
    """Simulate with compiled ``sweeps`` and read the integrator's failure code (a
    record's events through the sweeps' ``dosing``, widened to the states they act on)."""
    d = sweeps.discretisation
    u = d.inputs(sweeps.model, data.t, data.inputs_held(d.interpolation))
    dosing = covering(sweeps.dosing, sweeps.model, data)
    if dosing is not None:
        if dosing != sweeps.dosing:
            sw = sweeps
            sweeps = shared_sweeps(
                sw.model, sw.free_states, sw.free_params, sw.discretisation, sw.loss,
                sw.predictor, dosing,
            )  # fmt: skip
    t, u = (data.t, u) if dosing is None else dosing.arrays(data, u)
    xs, ys, code, at = sweeps.simulate(on_device(x0), on_device(p), on_device(t), on_device(u))
    xs, ys = np.asarray(xs)[: data.P], np.asarray(ys)[: data.P]  # a lagged event's nodes: out
    status = Status.from_code(int(code))
    failed_at: int | None = None if status is Status.OK else int(at)
    # an output not finite where it was not measured (log c at a dose's own row) is the
    # model's value there, not a failure; the states must be finite everywhere
    bad_y = ~np.isfinite(ys) & (True if data.observed is None else data.observed)
    bad_y = bad_y.any(axis=1)
    first_y = int(np.argmax(bad_y)) if bad_y.any() else None
    # outputs that fail while the states are still finite fail first
    if first_y is not None and (failed_at is None or first_y < failed_at):
        status, failed_at = Status.NONFINITE_OUTPUT, first_y
    return Simulation(sweeps.model, data, xs, ys, status, failed_at)


def simulate(
    model: Model,
    params,
    x0,
    data: Experiment,
    *,
    substeps: int = 4,
    interpolation: str = "linear",
    scheme: str | Scheme = "rk4",
    rtol: float | None = None,
    atol: float | None = None,
    discretisation: Discretisation | None = None,
    doses: dict | None = None,
    lags: dict | None = None,
    durations: dict | None = None,
) -> Simulation:
    """Simulate ``model`` with ``params`` (dict or array (M,)) from ``x0`` (dict or
    array (N,)) on the inputs and sample times of ``data``, and through its events
    (``doses``: what a dose puts into a state, ``lags``: how long after its time,
    ``durations``: how long a modelled infusion lasts, as ``Problem(doses=...)``).

    Pass the fit's ``discretisation`` (``problem.discretisation``), or its scheme,
    substeps and interpolation, to reproduce its reported cost exactly.
    """
    if not isinstance(model, Model):
        raise TypeError(f"model must be a tensorid.Model, got {type(model).__name__}")
    if not isinstance(data, Experiment):
        raise TypeError(f"data must be a tensorid.Experiment, got {type(data).__name__}")
    if data.u.shape[1] != model.U:
        raise ValueError(
            f"data has {data.u.shape[1]} input column(s) but the model has "
            f"{model.U} inputs {list(model.inputs)}"
        )
    discretisation = Discretisation.resolve(
        discretisation, scheme, substeps, interpolation, rtol, atol
    ).for_model(model)
    p = model.params_array(params, "params")
    x = model.states_array(x0, "x0")
    dosing = dosing_of(model, [data], doses, lags, durations)
    sim = run_simulation(shared_sweeps(model, (), (), discretisation, dosing=dosing), data, x, p)
    if sim.status is not Status.OK:
        h = sim.failed_at or 0
        where = f"sample {h} (t = {data.t[h]:.6g})"
        n = int((~np.isfinite(sim.y)).any(axis=1).sum())
        said = (  # the states finite: no blow-up, the output's own value (log c at c = 0)
            f"the outputs are not finite at {n} of the {data.P} samples, first at {where}, "
            "where the states are finite: the output's own value there (such as log c "
            "at c = 0), not a blow-up"
            if sim.status is Status.NONFINITE_OUTPUT and np.isfinite(sim.x).all()
            else f"the simulation stops being finite at {where}: {sim.status.message}"
        )
        warnings.warn(
            f"{said}; Simulation.status and failed_at say so too", RuntimeWarning, stacklevel=2
        )
    return sim
