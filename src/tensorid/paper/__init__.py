"""The paper reproduced: its Silverbox and two-tank studies, the robustness
comparison of its Table 1, their report, and the benchmark problems, on top of
everything else (``tensorid paper``)."""

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
