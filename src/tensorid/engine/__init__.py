"""The engine: the model, the measured data, the integrators and the sweeps that
carry x, dx = ∂x/∂θ and d2x = ∂²x/∂θ² (the paper's Φ, Θ, Φ¹, Θ¹, χ¹, χ²), and the
Problem that assembles them into J, ∇J and ∇²J over θ."""

from .data import Experiment
from .discretisation import INTERPOLATIONS, Discretisation, march
from .integrators import (
    SCHEMES,
    AdaptiveRungeKutta,
    DiagonallyImplicitRungeKutta,
    ExplicitRungeKutta,
    Scheme,
    get_scheme,
)
from .metrics import gof, nrmse, rmse
from .model import Model
from .problem import Problem
from .simulate import Simulation, simulate
from .status import Status
from .sweeps import Sweeps

__all__ = [
    "INTERPOLATIONS",
    "SCHEMES",
    "AdaptiveRungeKutta",
    "DiagonallyImplicitRungeKutta",
    "Discretisation",
    "Experiment",
    "ExplicitRungeKutta",
    "Model",
    "Problem",
    "Scheme",
    "Simulation",
    "Status",
    "Sweeps",
    "get_scheme",
    "gof",
    "march",
    "nrmse",
    "rmse",
    "simulate",
]
