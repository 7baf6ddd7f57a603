"""The outer fit of a population: ψ by the trust region with the exact gradient and
Hessian of the marginal likelihood (objective.py), each evaluation first solving every
unit's inner problem from the last point's η̂; then the standard errors from the outer
curvature, each unit's empirical Bayes estimates with their own error bars, and η
shrinkage."""

from __future__ import annotations

import time
import warnings
from dataclasses import replace
from typing import Any

import numpy as np

from ..engine.schemes.status import Status
from ..solve.minimize import interrupted, minimize_trust_region
from ..solve.solution import FitInterrupted
from ..solve.trust_region import TRResult
from .ahead import compile_ahead, joined, preload
from .boundary import (
    Collapsed,
    bounds,
    collapse_note,
    collapsing,
    flat_directions,
    no_effect_note,
    without,
)
from .distributed import UnitMap, evaluate_chunk
from .objective import Objective
from .refine import MAX_SUBSTEPS, coarse_note, coarse_steps, presized, raised_note, unrefined
from .result import PopulationResult
from .start import drawn_starts, start_point


def _a_fleet(problem, executor):
    """``problem``, refused in one line unless it is a fleet's (and ``executor``
    unless it is one)."""
    if not (getattr(problem, "population", None) or getattr(problem, "individual", None)):
        raise ValueError(
            "fit_population needs a Problem with population= or individual= parameters; "
            "this one has neither: fit it with ti.fit"
        )
    if problem.population and len(problem.experiments) < 2:  # (a Problem of one unit
        # describes a new unit to estimate η̂ of: validation.py; a fit needs a fleet)
        raise ValueError(
            "population parameters need at least 2 units (one experiment each): with one, "
            "its variation from unit to unit cannot be told from its own value; fit it "
            "without population (its parameters shared), or give more units"
        )
    check_executor(executor)
    return problem


def check_executor(executor) -> None:
    """One line for an executor that is none (it failed at its first submit)."""
    if executor is not None and not callable(getattr(executor, "submit", None)):
        raise TypeError(
            "executor must be a concurrent.futures executor (with submit), e.g. a Dask "
            f"client's client.get_executor(); got {executor!r}"
        )


def _estimate(obj: Objective, executor, workers, timeout, began, start=None, **options):
    """(PopulationResult, η̂) of the outer fit from ``start`` (see _outer), the units'
    work spread where asked; Ctrl-C: FitInterrupted with the best point so far."""
    obj.unconverged, obj.unfinite = [], []
    spread = executor is not None or (workers or 1) > 1
    units = UnitMap(obj, executor, workers, timeout) if spread else None
    complete, state = False, dict[str, Any]()  # state: the best point so far
    try:
        r, etas = _outer(obj, units, state, start, **options)
        complete = True
        # the converged point's η̂ and error bars: a Ctrl-C here keeps that point too
        etas, ok = obj.solve_inner(r.x, etas)
        status = r.status if ok else Status.SOLVER_FAILED
        flat = state.get("flat", np.zeros(obj.size, bool))
        res = PopulationResult.build(obj, r, etas, status, time.perf_counter() - began, flat)
        note = no_effect_note(obj, flat)
        return (replace(res, notes=[note]) if note else res), etas
    except KeyboardInterrupt:  # Ctrl-C: the best point so far, kept and handed up
        if units is not None and not complete:
            units.close(False)
        raise FitInterrupted(_interrupted(obj, state, began)) from None  # type: ignore[arg-type]
    except Collapsed:
        if units is not None:
            units.close(True)
        raise
    finally:
        if units is not None and complete:
            units.close(True)


def fit_population(
    problem,
    method: str = "focei",
    *,
    maxiter: int = 100,
    gtol: float = 1e-8,
    ftol: float = 1e-12,
    xtol: float = 1e-10,
    callback=None,
    executor=None,
    workers: int | None = None,
    timeout: float | None = None,
    starts: int = 1,
    spread: float | None = None,
    sampling: str = "lhs",
    seed: int = 0,
) -> PopulationResult:
    """Estimate a fleet's population (see :mod:`tensorid.population`).

    Arguments:
        problem: a :class:`tensorid.Problem` with ``population`` (random effects) or
            ``individual`` (each unit its own value, no distribution) set, one
            experiment per unit. Individual parameters are estimated jointly with the
            shared ones by least squares, reduced to the shared ones: each evaluation
            fits every unit's own parameters (exact Newton steps) and steps the shared
            ones by the Schur complement of the block-arrow Hessian, Σ_i (H_ss − H_sb
            H_bb⁻¹ H_bs), so an iteration costs time linear in the number of units.
        method: "focei" (default) or "laplace" (see objective.py for the difference).
        maxiter, gtol, ftol, xtol: the outer trust region's limits.
        callback: called with each outer iteration's record (dict).
        executor, workers: the units' work (inner solves, their shares of O, ∇O, ∇²O)
            in chunks on ``executor`` (e.g. a Dask ``client.get_executor()``) or a local
            pool of ``workers`` processes (distributed.py); default: here, one
            vectorised call. ``timeout``: seconds before a chunk's worker counts as
            lost (its chunk is sent again once, then computed here).
        starts, spread, sampling, seed: fits from ``starts`` points (the first p0's
            and the given ω; the others drawn around them: start.py), the lowest −2 log
            L kept; ``result.starts`` says how each ended.

    Returns:
        :class:`PopulationResult`.
    """
    began = time.perf_counter()
    obj = Objective(_a_fleet(problem, executor), method)
    fit = dict(executor=executor, workers=workers, timeout=timeout, began=began,
               maxiter=maxiter, gtol=gtol, ftol=ftol, xtol=xtol, callback=callback)  # fmt: skip
    collapsed: list[tuple[list[str], float]] = []
    loading = preload(obj, MAX_SUBSTEPS)  # read while the substeps are checked
    try:
        obj, raised = presized(obj)
        obj, res, etas = _best_start(obj, fit, collapsed, (starts, spread, sampling, seed))
    finally:
        joined(loading)
    ran = res.starts
    obj, res, etas, notes = _refined(obj, res, etas, fit, collapsed)
    res = replace(res, starts=ran)  # (a refinement's refit from the best keeps them)
    notes = raised + notes
    notes = [collapse_note(n, v, res.objective) for n, v in collapsed] + notes
    notes += _near_singular(res)
    if obj.unfinite:
        names = obj.unfinite
        notes.append(
            f"the simulation of {len(names)} unit(s) {names[:10]}"
            f"{' ...' if len(names) > 10 else ''} is not finite at these parameters: "
            "check those units' data, or start closer (p0)"
        )
    if obj.unconverged:
        names = obj.unconverged
        notes.append(
            f"the inner problems of {len(names)} unit(s) {names[:10]}"
            f"{' ...' if len(names) > 10 else ''} did not converge from their starts (a "
            "plateau or a point that is not a minimum of their own parameters): start "
            "them closer (p0), or leave those units out"
        )
    for n in notes:
        warnings.warn(n, UserWarning, stacklevel=2)
    return replace(res, notes=notes)


def _dropping(obj: Objective, fit: dict, collapsed: list, start=None):
    """(objective, result, η̂) of ``_estimate``, a random effect that collapses to 0
    dropped and the fit repeated from where it had got (boundary.py); each drop
    appended to ``collapsed`` as (names, −2 log L as they collapsed)."""
    while True:
        try:
            res, etas = _estimate(obj, start=start, **fit)
            return obj, res, etas
        except Collapsed as gone:
            collapsed.append((gone.names, gone.value))
            obj, start = Objective(without(obj, gone.names, gone.psi), obj.method), None


def _best_start(obj: Objective, fit: dict, collapsed: list, draw: tuple):
    """``_dropping`` from each start ``draw`` = (n, spread, sampling, seed) asks for
    (start.py), the lowest −2 log L kept with its drops, each start's ending in its
    ``starts``; Ctrl-C in a later start keeps the best finished one."""
    if draw[0] <= 1:
        return _dropping(obj, fit, collapsed)
    best, ran = None, []
    for k, psi0 in enumerate(drawn_starts(obj, *draw)):
        drops: list = []
        try:
            o, r, e = _dropping(obj, fit, drops, start=(psi0, obj.start_etas()))
        except FitInterrupted:
            if best is None:
                raise
            why = f"interrupted in start {k + 1} of {draw[0]}: the best of the {k} finished"
            kept = replace(best[1], notes=[*best[1].notes, why], starts=ran)
            raise FitInterrupted(kept) from None  # type: ignore[arg-type]
        ran.append({"start": k, "objective": r.objective, "status": r.status.name.lower(),
                    "nit": r.nit})  # fmt: skip
        if best is None or r.objective < best[1].objective:
            best = (o, r, e, drops)
    assert best is not None
    collapsed += best[3]
    ran.sort(key=lambda d: d["objective"])
    return best[0], replace(best[1], starts=ran), best[2]


def _refined(obj: Objective, res: PopulationResult, etas, fit: dict, collapsed: list):
    """(objective, result, η̂, notes) after the substeps check: the default substeps,
    where too coarse, raised fourfold and the fit repeated from its estimates, so that
    the answer is the model's (a user's own choice is kept, and warned about). Ctrl-C
    in a check keeps the fit it checks, with a note."""
    notes: list[str] = list(res.notes)
    steps = obj.problem.discretisation
    while True:
        try:
            worst = coarse_steps(obj, res, etas)
        except KeyboardInterrupt:
            why = f"interrupted during the check of the substeps ({steps.substeps}), unfinished"
            raise FitInterrupted(replace(res, notes=[*notes, why])) from None  # type: ignore[arg-type]
        if worst is None or steps.chosen or steps.substeps >= MAX_SUBSTEPS:
            break
        s = steps.substeps
        finer = Objective(obj.problem.with_substeps(4 * s), obj.method)
        dropped = len(collapsed)
        try:
            refit = _dropping(finer, fit, collapsed, start=(res.x, etas))
        except KeyboardInterrupt:  # Ctrl-C in the refit: the fit it refines is finished
            del collapsed[dropped:]
            why = f"interrupted in the refit at {4 * s} substeps: these are the estimates at {s}"
            raise FitInterrupted(replace(res, notes=[*notes, why])) from None  # type: ignore[arg-type]
        if not np.isfinite(refit[1].objective):  # it could not even start: this fit stands
            del collapsed[dropped:]  # (nothing the refit dropped is this fit's)
            notes.append(unrefined(refit[0], s))
            res = replace(res, seconds=time.perf_counter() - fit["began"])  # (the refit too)
            break
        notes.append(raised_note(s, worst))
        obj, res, etas = refit
        notes += [n for n in res.notes if n not in notes]
        steps = obj.problem.discretisation
    if worst is not None:
        notes.append(coarse_note(steps, worst))
    return obj, res, etas, notes


def _near_singular(res: PopulationResult) -> list[str]:
    """A full Ω whose random effects move almost as one: say which, and what to do."""
    tight = {k: c["value"] for k, c in res.omega_correlation.items() if abs(c["value"]) > 0.95}
    if not tight:
        return []
    pairs = ", ".join(f"η_{k.replace(',', ' and η_')} ({v:.3f})" for k, v in tight.items())
    return [
        f"the random effects {pairs} are correlated nearly perfectly: Ω is close to "
        "singular and the data cannot tell those effects apart (error bars there are "
        "unreliable or absent); give the parameters one shared effect, a covariate on "
        "both, or fit with omega='diagonal'"
    ]


def _interrupted(obj: Objective, state: dict, began: float) -> PopulationResult:
    """The result at the best point evaluated before Ctrl-C (status INTERRUPTED; no
    error bars: the fit had not ended)."""
    state.setdefault("etas", obj.start_etas())
    state.setdefault("best", np.inf)
    state.setdefault("n", 0)
    if "x" not in state:  # nothing evaluated yet
        psi0 = start_point(obj)
        state.update(x=psi0, g=np.full(obj.size, np.nan), H=np.full((obj.size,) * 2, np.nan))
    r = TRResult(state["x"], state["best"], state["g"], state["H"], nit=state["n"],
                 nfev=state["n"], status=Status.INTERRUPTED)  # fmt: skip
    return PopulationResult.build(obj, r, state["etas"], Status.INTERRUPTED,
                                  time.perf_counter() - began)  # fmt: skip


def _outer(obj: Objective, units: UnitMap | None, state: dict, start=None, **options):
    """The outer trust region over ψ, each evaluation starting every unit's inner
    problem from the best point's η̂; (its TRResult, that η̂). ``state`` keeps the best
    point evaluated, for an interrupt; ``start``: (ψ, η̂) to start from (default: p0's
    and the given ω's, η = 0)."""
    psi0, etas0 = (start_point(obj), obj.start_etas()) if start is None else start
    lo, hi = bounds(obj)
    state.update(etas=etas0, best=np.inf, n=0)
    ahead = None  # (spread over workers: they compile their own)
    if units is None and obj.size:
        ahead = compile_ahead(obj, np.asarray(psi0, dtype=float), np.asarray(etas0, dtype=float))

    def fun(psi):
        if units is None:
            etas, _, J, grad, H = evaluate_chunk(obj, psi, state["etas"])
        else:
            etas, _, J, grad, H = units(psi, state["etas"])
        if not (np.isfinite(J) and np.isfinite(grad).all() and np.isfinite(H).all()):
            return np.inf, np.zeros(obj.size), np.eye(obj.size)
        state["n"] += 1
        flat = flat_directions(grad, H)
        if flat.any():  # held: no step there (it would change nothing but the rounding)
            grad, H = np.where(flat, 0.0, grad), H * np.outer(~flat, ~flat)
            H[flat, flat] = np.max(np.abs(np.diag(H)), initial=1.0)
        if J < state["best"]:  # the next start: the best point's η̂ (a rejected trial
            state.update(etas=etas, best=J, x=np.array(psi), g=grad, H=H, flat=flat)
            gone = collapsing(obj, psi, grad)
            if gone:  # a random effect going to 0: refitted without it (boundary.py)
                raise Collapsed(gone, np.array(psi), etas, J)
        return J, grad, H

    if obj.size == 0:  # every parameter individual: the units' own fits are the fit
        J, g, H = fun(psi0)
        status = Status.GTOL if np.isfinite(J) else Status.NONFINITE_START
        return TRResult(psi0, J, g, H, nit=0, nfev=1, status=status), state["etas"]
    # a likelihood has no rounding floor (fatol): −2 log L may be negative
    # (Ctrl-C: the loop ends the run, then fit_population keeps the best point)
    try:
        r = minimize_trust_region(fun, psi0, lo, hi, radius=1.0, fatol=-np.inf, **options)
    finally:  # (not left inside XLA when the process ends)
        joined(ahead)
    return interrupted(r), state["etas"]
