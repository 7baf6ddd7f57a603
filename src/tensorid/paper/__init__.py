"""The paper reproduced: its Silverbox and two-tank studies, the robustness
comparison of its Table 1, their report, and the benchmark problems, on top of
everything else (``tensorid paper``).

The names below are imported when first used: the command line registers
``tensorid paper`` from this package, and a ``tensorid fit`` should not wait for the
study's imports."""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from . import problems
    from .study import (
        ACCURACY_LEVELS,
        COMPARED,
        CONVERGED_RTOL,
        QUICK_LEVELS,
        SPREAD,
        draw_starts,
        integration_errors,
        robustness_study,
        robustness_task,
        run,
        silverbox_study,
        summarise,
        two_tank_study,
    )

__all__ = [
    "ACCURACY_LEVELS",
    "COMPARED",
    "CONVERGED_RTOL",
    "QUICK_LEVELS",
    "SPREAD",
    "draw_starts",
    "integration_errors",
    "problems",
    "robustness_study",
    "robustness_task",
    "run",
    "silverbox_study",
    "summarise",
    "two_tank_study",
]


def __getattr__(name: str):
    if name == "problems":
        return importlib.import_module(".problems", __name__)
    if name in __all__:
        return getattr(importlib.import_module(".study", __name__), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))
