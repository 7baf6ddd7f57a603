"""The accuracy levels of the paper study: RK4 with a number of substeps per sample
("rk4x16"), or the adaptive dopri5 at a tolerance ("dopri5-1e-12"), named once and
turned into Problem/simulate options here."""

from __future__ import annotations

from ..engine.schemes.integrators import RTOL_FLOOR

# the accuracy levels of the robustness study: RK4 with 4, 16 and 64 substeps per
# sample (a smooth simulator, "rk4x4" ...), and the paper's own levels, the adaptive
# dopri5 at rtol = atol = 1e-10, 1e-12, 1e-14 ("dopri5-1e-10" ...), where step-size
# control reacts to every change of θ, finite differences included, as in MATLAB
ACCURACY_LEVELS = (4, 16, 64)
ADAPTIVE_TOLERANCES = (1e-10, 1e-12, 1e-14)


QUICK_LEVELS = (4,)


def level_name(level) -> str:
    """ "rk4x16" for 16 substeps; a name passes through."""
    return level if isinstance(level, str) else f"rk4x{int(level)}"


def level_options(level) -> dict:
    """The Problem/simulate options of a level: {"substeps": n} or the adaptive
    scheme with its tolerances."""
    name = level_name(level)
    if name.startswith("rk4x") and name[4:].isdigit():
        return {"substeps": int(name[4:])}
    if name.startswith("dopri5-"):
        tol = float(name[7:])
        # rtol below 100 eps is raised to it, as MATLAB's ode45 does with RelTol 1e-14
        return {"scheme": "dopri5", "rtol": max(tol, RTOL_FLOOR), "atol": tol}
    raise ValueError(f"unknown accuracy level {name!r}: use rk4xN (N substeps) or dopri5-TOL")


def all_levels() -> tuple[str, ...]:
    """Every level of the full study, fixed-step first."""
    return tuple(map(level_name, ACCURACY_LEVELS)) + tuple(
        f"dopri5-{t:g}" for t in ADAPTIVE_TOLERANCES
    )
