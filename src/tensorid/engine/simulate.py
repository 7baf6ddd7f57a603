"""Simulate a model for given parameters and initial state on an experiment's inputs."""

from __future__ import annotations

from dataclasses import dataclass

import jax.numpy as jnp
import numpy as np

from . import _config  # noqa: F401
from .data import Experiment
from .integrate import INTERPOLATIONS, Scheme, get_scheme
from .model import Model
from .sensitivity import Sensitivities


@dataclass(frozen=True, eq=False)
class Simulation:
    """A simulated trajectory: ``x`` (P, N) states and ``y`` (P, S) outputs at the
    experiment's sample times ``t``."""

    model: Model
    experiment: Experiment
    x: np.ndarray
    y: np.ndarray

    @property
    def t(self) -> np.ndarray:
        """Sample times (P,)."""
        return self.experiment.t

    @property
    def finite(self) -> bool:
        """False when the simulation blew up (non-finite states or outputs)."""
        return bool(np.isfinite(self.x).all() and np.isfinite(self.y).all())


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
) -> Simulation:
    """Simulate ``model`` with ``params`` (dict or array (M,)) from ``x0`` (dict or
    array (N,)) on the inputs and sample times of ``data``.

    Pass the fit's scheme (``problem.scheme``), substeps and interpolation to
    reproduce its reported cost exactly.
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
    if interpolation not in INTERPOLATIONS:
        raise ValueError(f"interpolation must be one of {INTERPOLATIONS}, got {interpolation!r}")
    p = model.params_array(params, "params")
    x = model.states_array(x0, "x0")
    if not isinstance(substeps, int | np.integer) or substeps < 1:
        raise ValueError(f"substeps must be a positive integer, got {substeps!r}")
    sens = Sensitivities(
        model, (), (), get_scheme(scheme, rtol, atol), int(substeps), interpolation
    )
    xs, ys = sens.simulate(jnp.asarray(x), jnp.asarray(p), jnp.asarray(data.t), jnp.asarray(data.u))
    return Simulation(model, data, np.asarray(xs), np.asarray(ys))
