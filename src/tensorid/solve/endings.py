"""How a run ends, in one place: the loop that steps every run of a method (one start,
a lock-step batch, the inner solves of multiple shooting) and decides how each ends,
and the Solution of each ending, built once.

A run ends when its method says so (``terminate``: converged, or given up for a
reason its status names), or here:

- its step raised what the method may raise (``method.raises``; for every method a
  ``LinAlgError`` from an eigen-solver at the edge of overflow): SOLVER_FAILED, at
  the best point it saw. Anything else is a bug and is not hidden;
- Ctrl-C: every unfinished run INTERRUPTED at its best point, at once (nothing
  more is evaluated, so the user is not kept waiting);
- workers lost, or Ctrl-C while starts ran on workers: :func:`stopped`, the best
  of the starts that finished.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..engine.schemes.status import Status
from .solution import Solution
from .stats import Stats


@dataclass
class Outcome:
    """Where a run ended (``x``, in its own units) and how."""

    x: np.ndarray
    nit: int
    status: Status
    detail: str = ""
    nhev: int = 0


@dataclass
class Run:
    """One run: its method (init / step / terminate / result / best), the method's
    state (``state.point``: the next point it needs evaluated, None when it evaluates
    for itself), and once it has ended, its ``ending`` and ``result``."""

    method: Any
    state: Any
    ending: Outcome | None = None
    result: Any = None
    done: bool = False


class OwnRun:
    """The base of a run that is its own method and state (``Run(r, r)``): a solve
    that is not a fit's method (shooting's augmented Lagrangian, minimize.py's, the
    design's searches). It has ended once it has set ``outcome``."""

    raises: tuple = ()
    outcome: Outcome | None = None

    def terminate(self, state) -> bool:
        return self.outcome is not None

    def result(self, state) -> Outcome:
        assert self.outcome is not None
        return self.outcome


def run_alone(run: OwnRun) -> Outcome:
    """``run`` (its own method and state, its values from its own ``evaluate()``)
    through the loop, alone; how it ended."""
    ran = Run(run, run)
    iterate([ran], lambda runs: [run.evaluate()])  # type: ignore[attr-defined]
    assert ran.ending is not None
    return ran.ending


def iterate(runs: list[Run], evaluate: Callable, finish: Callable | None = None) -> None:
    """Step every run until each has ended: the points pending are evaluated
    together (``evaluate(runs) -> values``, one per run), and each run is handed its
    value; ``finish(run)``, where given, makes each run's ``result`` as it ends (a
    Ctrl-C while it does so interrupts that run too)."""
    try:
        while live := [r for r in runs if not r.done]:
            values = _evaluated([r for r in live if r.state.point is not None], evaluate)
            for run in live:
                if run.ending is None:
                    _step(run, values.get(id(run)))
                if run.ending is not None:
                    run.result = finish(run) if finish else None
                    run.done = True
    except KeyboardInterrupt:
        for run in runs:
            if not run.done:
                x, nit = run.method.best(run.state)
                run.ending = Outcome(x, nit, Status.INTERRUPTED)
                run.result = finish(run) if finish else None  # evaluates nothing
                run.done = True


def _raises(runs: list[Run]) -> tuple:
    """What the runs' steps may raise and end with SOLVER_FAILED."""
    return (np.linalg.LinAlgError, *(e for r in runs for e in r.method.raises))


def _failed(run: Run, e: BaseException) -> Outcome:
    x, nit = run.method.best(run.state)
    why = f"{run.method.name} raised {type(e).__name__}: {e}"
    return Outcome(x, nit, Status.SOLVER_FAILED, why)


def _evaluated(asking: list[Run], evaluate) -> dict:
    if not asking:
        return {}
    try:
        return {id(r): v for r, v in zip(asking, evaluate(asking), strict=True)}
    except _raises(asking) as e:
        for run in asking:
            run.ending = _failed(run, e)
        return {}


def _step(run: Run, value) -> None:
    try:
        run.method.step(run.state, value)
        if run.method.terminate(run.state):
            run.ending = run.method.result(run.state)
    except _raises([run]) as e:
        run.ending = _failed(run, e)


# -- the Solution of each ending -------------------------------------------------------
def _result(problem, method: str, theta, status: Status, started, **fields) -> Solution:
    """The one place a Solution is made: every ending below comes here."""
    fields.setdefault("scale", np.ones(problem.K))
    return Solution.at(problem, method, theta, fields.pop("scale"), status, started=started,
                        **fields)  # fmt: skip


def fit_result(run: Run, started) -> Solution:
    """The result of one start's run (driver.py): at its end point, or at the best
    point it saw if that is better; an interrupted run's best point at once."""
    state, out = run.state, run.ending
    tr, name, hybrid = state.tr, run.method.name, run.method.report(state)
    assert out is not None
    if out.status is Status.INTERRUPTED:
        seen = tr.best_phi is not None
        theta = tr.theta(tr.best_phi) if seen else tr.theta0
        return _result(tr.problem, name, theta, Status.INTERRUPTED, started, scale=tr.scale,
                       stats=Stats(nit=out.nit, nfev=tr.nfev), history=state.history,
                       evaluate=False, cost=tr.best_J if seen else np.inf, notes=tr.notes(),
                       hybrid=hybrid)  # fmt: skip
    phi = tr.phi(tr.theta0) if out.x is None else out.x
    # (the end point is usually the best seen: then no simulation is needed to know it)
    better = tr.best_phi is not None and not np.array_equal(tr.best_phi, phi)
    if better and tr.best_J < tr.problem.cost(tr.theta(phi)):
        phi = tr.best_phi
    message = out.status.describe(out.detail)
    if not out.status.success and tr.nonfinite:
        message += f" ({tr.nonfinite} trial points blew up; see warnings)"
    return _result(
        tr.problem, name, tr.theta(phi), out.status, started, scale=tr.scale, message=message,
        stats=Stats(nit=out.nit, nfev=tr.nfev, nhev=out.nhev), history=state.history,
        known=tr.known, notes=tr.notes(), hybrid=hybrid,
    )  # fmt: skip


def failed(problem, method: str, theta0, started, message, status=Status.NONFINITE_START,
           stats: Stats | None = None) -> Solution:  # fmt: skip
    """A fit that could not start (or whose every start failed): θ0, nothing evaluated."""
    return _result(problem, method, theta0, status, started, message=message,
                   stats=stats, evaluate=False)  # fmt: skip


def failed_start(problem, method: str, theta0, started) -> Solution:
    """The result for a start where the simulation already blows up, saying where."""
    why = problem.diagnose(theta0)
    if why is None:  # every simulation is finite: the sum of squares overflowed
        with np.errstate(over="ignore"):
            big = max(float(np.abs(e.y).max()) for e in problem.experiments)
        why = (
            "the cost overflows at the start although the simulation is finite (the "
            f"measured outputs reach {big:.1e}): rescale the data, e.g. to units near 1, "
            "or give weights"
        )
        return failed(problem, method, theta0, started, why)
    return failed(problem, method, theta0, started, why + " Choose another initial guess.")


def not_run(problem, method: str, theta0, started) -> Solution:
    """A start of a batch that Ctrl-C stopped before it began: θ0 as it is."""
    return _result(problem, method, theta0, Status.INTERRUPTED, started, evaluate=False,
                   cost=problem.cost(theta0))  # fmt: skip


def segments_result(problem, method: str, theta, status, started, **fields) -> Solution:
    """Multiple shooting's own result (no polish, or interrupted): at θ, evaluated
    unless interrupted (then ``cost`` is given)."""
    return _result(problem, method, theta, status, started,
                   evaluate=status is not Status.INTERRUPTED, **fields)  # fmt: skip


def stopped(problem, method: str, theta0, stop, ranked: list[dict], best, started):
    """The result when the starts on workers could not all finish (``stop``, a
    multistart.StartsStopped: Ctrl-C or lost workers): the best of those that did
    (``best``, a Solution or None), not refined and not evaluated again (the user is
    waiting, or the workers are gone); ``ranked``: the finished starts' records."""
    which = ", ".join(str(i) for i in sorted(stop.runs))
    finished = f"{len(stop.runs)} of {stop.total} starts finished" + (f": {which}" if which else "")
    nfev = sum(r.nfev for r in stop.runs.values())
    stats = Stats(nit=best.nit if best else 0, nfev=nfev,
                  nit_total=sum(r.nit for r in stop.runs.values()))  # fmt: skip
    return _result(
        problem, method, best.theta if best else theta0, stop.status, started,
        message=stop.status.describe(f"{stop.detail}; {finished}"), stats=stats,
        history=best.history if best else [], evaluate=False,
        cost=best.cost if best else np.inf, starts=ranked,
    )  # fmt: skip
