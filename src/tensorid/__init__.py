"""tensorid: grey-box system identification with exact gradients and Hessians from
state/parameter transition tensors."""

from . import _config  # noqa: F401  (float64 before anything else touches JAX)
from ._config import enable_compilation_cache
from .data import Experiment
from .equations import model_from_equations
from .functions import safe_sqrt
from .integrate import (
    SCHEMES,
    AdaptiveRungeKutta,
    DiagonallyImplicitRungeKutta,
    ExplicitRungeKutta,
)
from .loaders import ModelSpec, load_data, load_model
from .metrics import gof, nrmse, rmse
from .model import Model
from .optimize import METHODS, FitResult, fit, fit_batch
from .problem import Problem
from .simulate import Simulation, simulate
from .uncertainty import Uncertainty

__version__ = "0.1.0"

__all__ = [
    "METHODS",
    "SCHEMES",
    "AdaptiveRungeKutta",
    "DiagonallyImplicitRungeKutta",
    "Experiment",
    "ExplicitRungeKutta",
    "FitResult",
    "Model",
    "ModelSpec",
    "Problem",
    "Simulation",
    "Uncertainty",
    "enable_compilation_cache",
    "fit",
    "fit_batch",
    "gof",
    "load_data",
    "load_model",
    "model_from_equations",
    "nrmse",
    "rmse",
    "safe_sqrt",
    "simulate",
]
