"""The engine: the model, the measured data, the integrators and the sweeps that
carry x, dx = ∂x/∂θ and d2x = ∂²x/∂θ² (the paper's Φ, Θ, Φ¹, Θ¹, χ¹, χ²), and the
Problem that assembles them into J, ∇J and ∇²J over θ.

Its modules live in five subpackages, lowest first; a module imports its own
subpackage or a lower one, never a higher one (tests/test_architecture.py):

    compiling/   compiled entry points, programs kept across processes, compile time
    modelling/   the model, its equations, the records, their events, the checks
    schemes/     the Runge-Kutta schemes, the discretisation and its march, Status
    sweeping/    the sweeps (x, dx, d2x; J, ∇J, ∇²J), adjoints, losses, predictors, doses
    assembly/    Problem, θ's layout, priors, constraints, start, simulate

Every module keeps its old import path: ``tensorid.engine.problem`` is
``tensorid.engine.assembly.problem`` (the same module object, registered in
``sys.modules`` below), so that ``from tensorid.engine.X import Y`` and a test's
monkeypatch of it still work."""

import importlib as _importlib
import sys as _sys

# the modules that moved, by their old name here: their new subpackage (a plain literal:
# tests/test_architecture.py reads it to resolve the old paths)
MOVED = {
    "compilation": "compiling",
    "compiled": "compiling",
    "executables": "compiling",
    "programs": "compiling",
    "model": "modelling",
    "equations": "modelling",
    "initial": "modelling",
    "events": "modelling",
    "data": "modelling",
    "checks": "modelling",
    "fleet": "modelling",
    "metrics": "modelling",
    "tableau": "schemes",
    "adaptive": "schemes",
    "implicit": "schemes",
    "integrators": "schemes",
    "intersample": "schemes",
    "discretisation": "schemes",
    "status": "schemes",
    "dosing": "sweeping",
    "moving": "sweeping",
    "steady": "sweeping",
    "losses": "sweeping",
    "predictors": "sweeping",
    "packing": "sweeping",
    "output_sensitivity": "sweeping",
    "second_order": "sweeping",
    "adjoint": "sweeping",
    "hessians": "sweeping",
    "sweeps": "sweeping",
    "shooting": "sweeping",
    "problem": "assembly",
    "problem_loss": "assembly",
    "layout": "assembly",
    "priors": "assembly",
    "constraints": "assembly",
    "start": "assembly",
    "simulate": "assembly",
    "diagnostics": "assembly",
}

for _name, _home in MOVED.items():
    _module = _importlib.import_module(f"{__name__}.{_home}.{_name}")
    _sys.modules[f"{__name__}.{_name}"] = _module
    globals()[_name] = _module

from .assembly.problem import Problem  # noqa: E402
from .assembly.simulate import Simulation, simulate  # noqa: E402
from .modelling.data import Experiment  # noqa: E402
from .modelling.metrics import gof, nrmse, rmse  # noqa: E402
from .modelling.model import Model  # noqa: E402
from .schemes.discretisation import INTERPOLATIONS, Discretisation, march  # noqa: E402
from .schemes.integrators import (  # noqa: E402
    SCHEMES,
    AdaptiveRungeKutta,
    DiagonallyImplicitRungeKutta,
    ExplicitRungeKutta,
    Scheme,
    get_scheme,
)
from .schemes.status import Status  # noqa: E402
from .sweeping.sweeps import Sweeps  # noqa: E402

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
