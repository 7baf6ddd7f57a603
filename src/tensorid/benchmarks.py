"""The paper's two benchmark problems, Silverbox and two-tank (models, start values,
the paper's estimates): ``tensorid.benchmarks`` is the documented name of
``tensorid.paper.problems``."""

from .paper.problems import (
    SILVERBOX_GUESS,
    SILVERBOX_PAPER,
    SILVERBOX_PAPER_VAL_GOF,
    SILVERBOX_PAPER_VDOT0,
    TWO_TANK_GUESS,
    TWO_TANK_PAPER,
    TWO_TANK_PAPER_GOF,
    silverbox_model,
    silverbox_offset_model,
    silverbox_problem,
    two_tank_model,
    two_tank_problem,
)

__all__ = [
    "SILVERBOX_GUESS",
    "SILVERBOX_PAPER",
    "SILVERBOX_PAPER_VAL_GOF",
    "SILVERBOX_PAPER_VDOT0",
    "TWO_TANK_GUESS",
    "TWO_TANK_PAPER",
    "TWO_TANK_PAPER_GOF",
    "silverbox_model",
    "silverbox_offset_model",
    "silverbox_problem",
    "two_tank_model",
    "two_tank_problem",
]
