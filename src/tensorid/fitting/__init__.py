"""Fitting: the composition of the solvers (``tensorid.solve``) and the statistics
(``tensorid.analysis``): ``fit`` and ``fit_batch`` (methods.py), the staged pipelines
(a robust loss's stages, robust.py; the priors' noise re-check, priors.py), experiment
design (design.py, which fits); ``FitResult``, the solver's record with the
statistics' methods, is in ``tensorid.analysis.results`` (``tensorid.fitting.results``
is the same module), below ``tensorid.population``, whose result is one.

The modules that moved to ``tensorid.solve`` and ``tensorid.analysis`` keep their
old import paths: ``tensorid.fitting.trust_region`` is ``tensorid.solve.trust_region``
(the same module object, registered in ``sys.modules`` below), so that
``from tensorid.fitting.X import Y`` and a test's monkeypatch of it still work."""

import importlib as _importlib
import sys as _sys

# the modules that moved, by their old name here: their new package (a plain literal:
# tests/test_architecture.py reads it to resolve the old paths)
MOVED = {
    "arrow": "solve",
    "baselines": "solve",
    "curvature": "solve",
    "driver": "solve",
    "endings": "solve",
    "hybrid": "solve",
    "multistart": "solve",
    "options": "solve",
    "projected": "solve",
    "registry": "solve",
    "scaling": "solve",
    "shooting": "solve",
    "solvers": "solve",
    "starts": "solve",
    "stats": "solve",
    "trust_region": "solve",
    "display": "analysis",
    "figures": "analysis",
    "influence": "analysis",
    "model_check": "analysis",
    "profiles": "analysis",
    "quantiles": "analysis",
    "residuals": "analysis",
    "sandwich": "analysis",
    "summary": "analysis",
    "uncertainty": "analysis",
    "validation": "analysis",
    "results": "analysis",
}

for _name, _home in MOVED.items():
    _module = _importlib.import_module(f"tensorid.{_home}.{_name}")
    _sys.modules[f"{__name__}.{_name}"] = _module
    globals()[_name] = _module

from ..analysis.profiles import Profile, profile  # noqa: E402
from ..analysis.results import FitInterrupted, FitResult  # noqa: E402
from ..analysis.uncertainty import Uncertainty  # noqa: E402
from ..analysis.validation import Score  # noqa: E402
from ..solve.options import FitOptions  # noqa: E402
from .methods import LOCKSTEP, METHODS, fit, fit_batch  # noqa: E402

__all__ = [
    "LOCKSTEP",
    "METHODS",
    "FitInterrupted",
    "FitOptions",
    "FitResult",
    "Profile",
    "Score",
    "Uncertainty",
    "fit",
    "fit_batch",
    "profile",
]
