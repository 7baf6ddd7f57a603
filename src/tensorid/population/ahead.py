"""A population fit's biggest program, the outer evaluation's (value, gradient, outer
and inner Hessians: objective.py), made ready beside the fit's own work instead of
before it: read from disk while the substeps are checked (:func:`preload`), or traced
and then compiled by XLA, without the GIL, while the inner steps compile and the
inner problems are solved (:func:`compile_ahead`). On two cores a fit then waits for
the longest of these rather than their sum."""

from __future__ import annotations

import threading

import numpy as np

from ..engine.compiling.compilation import clocks_here, counted_by
from .objective import Objective
from .units import BLOCK

_AHEAD: set = set()  # (structure, units per call) whose evaluation was compiled ahead


def compile_ahead(obj: Objective, psi, etas) -> threading.Thread | None:
    """The outer evaluation's program traced here, then compiled (or read) in a second
    thread while this one compiles the inner steps and solves. The fit's own call
    waits for it (the Program's lock); its compiling counts in the fit's
    compile_seconds. Once per structure (a refit, a further start, has it); the
    caller joins the thread before it returns."""
    shape = (obj.key, min(len(obj.units.names), BLOCK))  # (a program per shape)
    if shape in _AHEAD:
        return None
    _AHEAD.add(shape)
    program, args = obj.evaluation_program(psi, etas)
    program.trace_ahead(*args)  # traced here: the thread then runs XLA alone
    clocks = clocks_here()

    def run() -> None:
        with counted_by(clocks):
            try:
                obj.evaluation(psi, etas)
            except Exception:  # the fit's own call meets it, and says so
                pass

    return _started(run, "tensorid-compile-ahead")


def preload(obj: Objective, most: int) -> threading.Thread | None:
    """The outer evaluation's executables an earlier process kept for this structure,
    read in a second thread (reading does not hold the GIL: 0.7 s for theophylline's)
    while this one checks the substeps (refine.presized), at each substeps the check
    may settle on (fourfold steps up to ``most``; the given ones alone where the user
    chose them). A program no process kept is left to the fit (nothing is compiled
    here); None where the fit has no outer evaluation of this kind."""
    if obj.joint or not obj.size:
        return None
    problem, d = obj.problem, obj.problem.discretisation
    steps = [d.substeps]
    while d.fixed_steps and not d.chosen and steps[-1] < most:  # (as the check may raise them)
        steps.append(4 * steps[-1])
    clocks = clocks_here()

    def run() -> None:
        with counted_by(clocks):
            for s in steps:
                try:
                    at = obj if s == d.substeps else Objective(problem.with_substeps(s), obj.method)
                    program, args = at.evaluation_program(np.zeros(at.size), at.start_etas())
                    program.load_kept(*args)
                except Exception:  # the fit's own call reads or compiles it
                    pass

    return _started(run, "tensorid-preload")


def _started(run, name: str) -> threading.Thread:
    thread = threading.Thread(target=run, name=name, daemon=True)
    thread.start()
    return thread


def joined(*threads: threading.Thread | None) -> None:
    """Each thread that was started, waited for (none is left inside XLA when the
    process ends)."""
    for t in threads:
        if t is not None:
            t.join()
