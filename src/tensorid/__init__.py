"""tensorid: grey-box system identification with exact gradients and Hessians from
state/parameter transition tensors.

The package in layers, lowest first (an import only goes downward; see
docs/architecture.md): ``engine`` (model, data, integrators, sweeps, problem),
``solve`` (trust region, methods, multiple shooting, multi-start: plain records out),
``analysis`` (uncertainty, residual tests, profiles, tables and figures) beside
``population``, ``fitting`` (``fit`` and ``FitResult``: the solvers and the
statistics composed), ``app`` (files, command line, reports, progress) and ``paper``
(the paper study). Everything a user needs is re-exported here.
"""

# first, before NumPy and JAX: the commands that draw start their figure process there
from . import _early  # noqa: F401
from ._config import __version__, disable_compilation_cache, enable_compilation_cache
from .analysis.profiles import Profile, profile
from .analysis.results import FitInterrupted, FitResult
from .analysis.uncertainty import Uncertainty
from .analysis.validation import Score
from .app.files import ModelSpec, load_data, load_model
from .engine.assembly.problem import Problem
from .engine.assembly.simulate import Simulation, simulate
from .engine.assembly.start import Start
from .engine.modelling.data import Experiment
from .engine.modelling.equations import model_from_equations
from .engine.modelling.events import Events
from .engine.modelling.metrics import gof, nrmse, rmse
from .engine.modelling.model import Model
from .engine.schemes.discretisation import Discretisation
from .engine.schemes.integrators import (
    SCHEMES,
    AdaptiveRungeKutta,
    DiagonallyImplicitRungeKutta,
    ExplicitRungeKutta,
)
from .engine.schemes.status import Status
from .fitting.design import InputDesign, design_input
from .fitting.methods import METHODS, fit, fit_batch
from .functions import (
    coulomb_friction,
    dead_zone,
    safe_sqrt,
    saturation,
    smooth_abs,
    smooth_max,
    smooth_min,
    smooth_sign,
    stribeck_friction,
)
from .population import PopulationResult, fit_population
from .solve.options import FitOptions

__all__ = [
    "METHODS",
    "SCHEMES",
    "AdaptiveRungeKutta",
    "DiagonallyImplicitRungeKutta",
    "Discretisation",
    "Events",
    "Experiment",
    "ExplicitRungeKutta",
    "FitInterrupted",
    "InputDesign",
    "FitOptions",
    "FitResult",
    "Model",
    "ModelSpec",
    "Problem",
    "Profile",
    "Score",
    "Start",
    "Simulation",
    "Status",
    "Uncertainty",
    "__version__",
    "enable_compilation_cache",
    "disable_compilation_cache",
    "design_input",
    "fit",
    "fit_batch",
    "fit_population",
    "PopulationResult",
    "profile",
    "gof",
    "load_data",
    "load_model",
    "model_from_equations",
    "nrmse",
    "rmse",
    "safe_sqrt",
    "smooth_abs",
    "smooth_sign",
    "smooth_max",
    "smooth_min",
    "saturation",
    "dead_zone",
    "coulomb_friction",
    "stribeck_friction",
    "simulate",
]
