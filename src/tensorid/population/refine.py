"""The substeps check of a population fit. A fixed-step scheme's substeps are per
sample interval, and a fleet's intervals differ (a quarter of an hour after a dose,
twelve hours later): where doubling them moves a unit's prediction by more than a tenth
of its output's residual SD, the answer is the scheme's, not the model's. Before the fit
the default substeps are raised fourfold while that holds at its start
(:func:`presized`); after it, :func:`coarse_steps` measures it at the estimates
(estimate.py refits, or warns where the user chose them). Every prediction compared
comes from one program, whatever the substeps (Objective.predict_all)."""

from __future__ import annotations

import numpy as np

from .objective import Objective
from .result import PopulationResult
from .start import start_point

# where a population fit's check finds the default substeps too coarse, it raises them
# fourfold and fits again, up to this many per sample interval
MAX_SUBSTEPS = 64


def _sd_at(obj: Objective, psi, etas, yhat) -> np.ndarray:
    """The residual SD at (ψ, η) of a fit with a residual-error model, whose predictions
    are ``yhat``: per output where constant, else per sample; on each error model's
    scale (log y for an exponential one)."""
    if obj.plain:
        return obj.error.constant_sd(obj.split(psi)[3])
    return obj.residual_sd(psi, etas, yhat)


def coarse_steps(obj: Objective, res: PopulationResult, etas) -> float | None:
    """The largest move, in residual SDs, of a unit's prediction at the estimates when
    the substeps double; None where it is at most a tenth of one (or cannot be
    measured)."""
    if not np.isfinite(res.objective):
        return None
    sd = np.array(list(res.residual_sd.values())) if obj.joint else None  # (per output)
    return _moved(obj, res.x, etas, sd)


def _moved(obj: Objective, x, etas, sigma=None) -> float | None:
    """The largest move of a prediction at (ψ, η) when the substeps double, in the
    residual SDs ``sigma`` (None: the fit's error model's there); None where it is at
    most a tenth (or cannot be measured). Both predictions come from the one program
    that serves every substeps."""
    d = obj.problem.discretisation
    if not d.fixed_steps:
        return None  # adaptive steps control their own error; a discrete map is exact
    mask = obj.units.mask
    # the model's own predictions, read where measured (−∞ elsewhere for log c at a dose)
    coarse, finer = (np.where(mask > 0, obj.predict_all(x, etas, s), 0.0)
                     for s in (None, 2 * d.substeps))  # fmt: skip
    sigma = _sd_at(obj, x, etas, coarse) if sigma is None else sigma
    moved = np.asarray(obj.error.scaled(finer, mask)) - np.asarray(obj.error.scaled(coarse, mask))
    moved = np.where(mask > 0, np.abs(moved) / np.maximum(sigma, 1e-300), 0.0)
    worst = float(np.max(np.where(np.isfinite(moved), moved, np.inf)))  # (a blow-up: inf)
    return worst if worst > 0.1 else None


def presized(obj: Objective) -> tuple[Objective, list[str]]:
    """The default substeps raised fourfold before the fit while, at its start, doubling
    them moves a prediction by more than a tenth of the start's residual SD, for the
    typical unit and for units 2ω either side of it (the fleet's span; theophylline's
    fastest absorbers are what 4 substeps cannot follow): one fit at the substeps the
    check after it would ask for, not a fit and a refit (which compiled every program
    twice). That check stays."""
    notes: list[str] = []
    while not (obj.joint or obj.problem.discretisation.chosen):
        d = obj.problem.discretisation
        if d.substeps >= MAX_SUBSTEPS:
            break
        psi, etas = start_point(obj), obj.start_etas()
        omega = np.exp(psi[obj.qp : 2 * obj.qp]) if not obj.full else 0.0  # (full: typical)
        moves = []
        for side in (0.0, 2.0, -2.0):
            probe = etas.copy()
            probe[:, : obj.qp] = side * omega
            moves.append(_moved(obj, psi, probe) or 0.0)
        worst = max(moves) or None
        if worst is None:
            break
        notes.append(
            f"the substeps were raised from {d.substeps} to {4 * d.substeps} before the "
            f"fit: at its start the predictions (of units 2ω either side of the typical "
            f"one too) moved by {worst:.2g} residual SDs when the substeps doubled "
            "(--substeps on the command line, substeps= in Python, chooses them)"
        )
        obj = Objective(obj.problem.with_substeps(4 * d.substeps), obj.method)
    return obj, notes


def unrefined(finer: Objective, s: int) -> str:
    """The note of a fit kept at ``s`` substeps whose refit at ``finer``'s could not start."""
    units = finer.unfinite + [n for n in finer.unconverged if n not in finer.unfinite]
    more = " ..." if len(units) > 10 else ""
    why = f"the inner problems of {len(units)} unit(s) {units[:10]}{more} did not converge"
    why = f"{why} or were not finite there" if units else "its objective was not finite there"
    return (f"the fit could not be repeated at {4 * s} substeps from its estimates at {s} "
            f"({why}): these are the estimates at {s}; a fit given --substeps {4 * s} "
            "(substeps= in Python) starts there afresh")  # fmt: skip


def raised_note(s: int, worst: float) -> str:
    """The note of a fit repeated at 4 × ``s`` substeps (a fleet's or one system's)."""
    return (
        f"the substeps were raised from {s} to {4 * s} and the fit repeated from its "
        f"estimates: at {s} the predictions moved by {worst:.2g} residual SDs when the "
        "substeps doubled (--substeps on the command line, substeps= in Python, "
        "chooses them)"
    )


def coarse_note(d, worst: float) -> str:
    return (
        f"the predictions at the estimates move by {worst:.2g} residual SDs when the "
        f"substeps per sample interval go from {d.substeps} to {2 * d.substeps}: the "
        "longest intervals are integrated too coarsely and the estimates are the "
        f"scheme's, not the model's; raise the substeps (--substeps {4 * d.substeps} on "
        f"the command line, substeps={4 * d.substeps} in Python)"
    )
