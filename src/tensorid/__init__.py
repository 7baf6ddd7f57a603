"""tensorid: grey-box system identification with exact gradients and Hessians from
state/parameter transition tensors."""

from . import _config  # noqa: F401  (float64 before anything else touches JAX)
from .data import Experiment
from .integrate import SCHEMES, ExplicitRungeKutta
from .metrics import gof, nrmse, rmse
from .model import Model
from .optimize import METHODS, FitResult, fit
from .problem import Problem
from .simulate import Simulation, simulate

__version__ = "0.1.0"

__all__ = [
    "METHODS",
    "SCHEMES",
    "Experiment",
    "ExplicitRungeKutta",
    "FitResult",
    "Model",
    "Problem",
    "Simulation",
    "fit",
    "gof",
    "nrmse",
    "rmse",
    "simulate",
]
