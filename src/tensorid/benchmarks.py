"""The paper's two benchmark problems, Silverbox and two-tank (models, start values,
the paper's estimates), a Lotka–Volterra record where single shooting has local
minima, and a chain of masses whose size sets N and K: ``tensorid.benchmarks`` is
the documented name of ``tensorid.paper.problems``."""

from .paper.problems import (
    LOTKA_VOLTERRA_TRUE,
    LOTKA_VOLTERRA_X0,
    SILVERBOX_GUESS,
    SILVERBOX_PAPER,
    SILVERBOX_PAPER_VAL_GOF,
    SILVERBOX_PAPER_VDOT0,
    TWO_TANK_GUESS,
    TWO_TANK_PAPER,
    TWO_TANK_PAPER_GOF,
    lotka_volterra_model,
    lotka_volterra_problem,
    mass_chain_model,
    mass_chain_problem,
    mass_chain_truth,
    silverbox_model,
    silverbox_offset_model,
    silverbox_problem,
    two_tank_model,
    two_tank_problem,
)

__all__ = [
    "LOTKA_VOLTERRA_TRUE",
    "LOTKA_VOLTERRA_X0",
    "SILVERBOX_GUESS",
    "SILVERBOX_PAPER",
    "SILVERBOX_PAPER_VAL_GOF",
    "SILVERBOX_PAPER_VDOT0",
    "TWO_TANK_GUESS",
    "TWO_TANK_PAPER",
    "TWO_TANK_PAPER_GOF",
    "lotka_volterra_model",
    "lotka_volterra_problem",
    "mass_chain_model",
    "mass_chain_problem",
    "mass_chain_truth",
    "silverbox_model",
    "silverbox_offset_model",
    "silverbox_problem",
    "two_tank_model",
    "two_tank_problem",
]
