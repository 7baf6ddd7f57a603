"""fit() and fit_batch(): estimate θ with the exact-derivative trust-region methods,
or with the finite-difference baselines the paper compares against, from one start,
a batch of starts in lock-step, or many starts on workers (the best refined).

The checks of the user's arguments live here; the iterations in driver.py. A
Problem's ``constraints`` ("Fs >= Fc") are kept around an exact-derivative
trust-region method by an augmented Lagrangian (constrained.py), every start
included; the result's ``constraints`` gives their values and multipliers. Every
method works on scaled variables (see scaling.py); whatever a method does, the
result holds the best finite point it evaluated: a fit never returns NaN.
"""

from __future__ import annotations

import os
import time
from dataclasses import replace

import numpy as np

from ..analysis.results import FitInterrupted, FitResult
from ..engine.assembly.problem import Problem
from ..engine.compiling.compilation import compile_clock
from ..engine.modelling.checks import did_you_mean
from ..engine.schemes.status import Status
from ..population import fit_population
from ..population.approximations import APPROXIMATIONS
from ..population.estimate import check_executor
from ..solve.multistart import SAMPLINGS, draw_starts
from ..solve.options import FitOptions
from ..solve.registry import LOCKSTEP, METHODS, listed, resolve
from ..solve.solvers import Method, TrustRegion
from ..solve.starts import fit_task, fits, many_starts
from .priors import weigh_priors, weighed
from .robust import fit_robust
from .substeps import refined

__all__ = ["LOCKSTEP", "METHODS", "fit", "fit_batch", "fit_task"]


def fit(
    problem: Problem,
    method: str | Method = "auto",
    *,
    theta0=None,
    starts: int | None = None,
    spread: float | None = None,
    sampling: str = "lhs",
    seed: int = 0,
    executor=None,
    workers: int | None = None,
    batch: int | None = None,
    x_scale="auto",
    maxiter: int = 200,
    gtol: float = 1e-10,
    ftol: float = 1e-12,
    xtol: float = 1e-12,
    callback=None,
    options: FitOptions | None = None,
    timeout: float | None = None,
    polish: bool = True,
) -> FitResult:
    """Estimate the free initial states and parameters of ``problem``. method:
      "auto"          (default) Gauss-Newton while it converges fast, the exact
                      Hessian where it does not or at a saddle (see hybrid.py)
      "newton"        trust-region Newton with the exact Hessian from transition tensors
      "newton-cg"     trust-region Newton with truncated CG on exact Hessian-vector
                      products (one sweep of 2K + 1 state copies each, against
                      1 + K + K(K+1)/2 for the full Hessian): for many unknowns
      "gauss-newton"  trust-region Gauss-Newton (Levenberg-Marquardt) with the exact
                      Jacobian from first-order sensitivities
      "fd-bfgs"       BFGS (L-BFGS-B with bounds) with a finite-difference gradient
      "fd-lsq"        scipy least_squares (trf) with a finite-difference Jacobian, as
                      MATLAB's grey-box toolbox does
      or a method object (a ``tensorid.solve.solvers.Method``: architecture.md)
    theta0 : start (K,), natural units; default ``problem.theta0``.
    x_scale, maxiter, gtol, ftol, xtol, callback : see :class:`FitOptions` (or options=).
    starts : with N > 1, fit from theta0 and N - 1 further starts (inside the bounds,
        within ``spread`` of theta0 or across the box: see ``draw_starts``; Latin
        hypercube or uniform ``sampling``, seeded), in parallel through ``executor`` (any
        concurrent.futures.Executor, e.g. a Dask ``client.get_executor()``) or a local
        process pool of ``workers``; the best is refined and returned, with every start
        ranked in ``result.starts``. The local pool spawns fresh processes, which
        re-import the calling script: guard a script's top level with
        ``if __name__ == "__main__":``.
    batch : with starts, this many per task in lock-step, in one jax.vmap call (see
        fit_batch); default: shared evenly over the local workers, at most 16 per task.
    timeout : seconds to wait for the next start to finish on workers; then the best
        finished start is returned, status ``WORKERS_LOST``. Default: wait.
    polish : with segments (multiple shooting: "auto", "newton" and "newton-cg" by
        the exact Lagrangian Hessian, or "gauss-newton"), end with single shooting
        from its solution (default); ``result.shooting`` reports the stage.
    Ctrl-C stops the fit at once, workers included, raising :class:`FitInterrupted`
    (a KeyboardInterrupt) whose ``result`` is the best point so far.
    A fleet's Problem (``population``, ``individual``) goes to :func:`fit_population`.
    """
    started = time.perf_counter()
    if getattr(problem, "population", None) or getattr(problem, "individual", None):
        return _fleet(problem, method, maxiter, callback, executor, workers, timeout, locals())
    solver = check_method(problem, method)
    options = _options(options, x_scale, maxiter, gtol, ftol, xtol, callback, polish)
    theta0 = _check_start(problem, problem.theta0 if theta0 is None else theta0, "theta0")
    n = 1 if starts is None else _check_count("starts", starts)
    _check_multistart(spread, sampling, workers, timeout, seed, executor)
    if n > 1:
        batch = _check_batch(solver, batch, n, executor, workers)
    with compile_clock() as clock:  # this process's compilations (not the workers')
        if n > 1:
            lo, hi = problem.lower, problem.upper
            thetas = draw_starts(theta0, lo, hi, n, spread=spread, sampling=sampling, seed=seed)
            where = (executor, workers, int(batch or 1), timeout)
        else:
            thetas, where = theta0[None, :], None
        res = _starts(problem, solver, thetas, options, where, started)
        res = refined(problem, res, _refit(solver, options, started), started)  # substeps
    res = replace(res, compile_seconds=clock[0])
    if res.status is Status.INTERRUPTED:
        raise FitInterrupted(res)
    return res


FLEET_METHODS = tuple(APPROXIMATIONS)  # a population fit's (population/approximations.py)


def check_fleet_method(problem, method) -> str:
    """The approximation a fleet's fit uses for ``method``: "auto" is FOCEI; individual
    parameters alone are least squares, which "auto" names."""
    if problem.population and method in ("auto", *FLEET_METHODS):
        return "focei" if method == "auto" else method
    if not problem.population and method == "auto":
        return "focei"  # (unused: individual parameters are fitted by least squares)
    which = "'auto', 'focei' or 'laplace'" if problem.population else "'auto'"
    raise ValueError(
        f"method {method!r} is not one for a fit with "
        f"{'population' if problem.population else 'individual'} parameters: use {which}"
    )


# fit's options that a fleet's fit does not take yet: one given other than its default
# (fit's signature) is refused in one line (they were dropped without a word)
_NOT_FOR_FLEETS = ("theta0", "batch", "x_scale", "options", "polish")
# the outer trust region's limits, passed on where given (left at fit's defaults, the
# population's own apply: fit_population's), and the starts (population/start.py)
_FLEET_LIMITS = ("gtol", "ftol", "xtol", "starts", "spread", "sampling", "seed")


def _fleet_options(given: dict) -> None:
    """One line naming the first option a fleet's fit would drop."""
    import inspect

    defaults = inspect.signature(fit).parameters
    for name in _NOT_FOR_FLEETS:
        value, default = given[name], defaults[name].default
        same = value is default or (
            value is not None and default is not None and np.ndim(value) == 0 and value == default
        )
        if not same:
            raise ValueError(
                f"{name}={value!r} is not taken by a fit with population or individual "
                "parameters yet (it would be dropped): leave it out; maxiter, gtol, ftol, "
                "xtol, starts, spread, sampling, seed, callback, executor, workers and "
                "timeout apply"
            )


def _fleet(problem, method, maxiter, callback, executor, workers, timeout, given) -> FitResult:
    import inspect

    _fleet_options(given)
    kind = check_fleet_method(problem, method)
    if given["starts"] is not None:
        _check_count("starts", given["starts"])
    _check_multistart(given["spread"], given["sampling"], workers, timeout, given["seed"], executor)
    where = dict(executor=executor, workers=workers, timeout=timeout)
    defaults = inspect.signature(fit).parameters
    where |= {k: given[k] for k in _FLEET_LIMITS if given[k] != defaults[k].default}
    # a PopulationResult: a FitResult with the population's part (population/result.py)
    with compile_clock() as clock:  # this process's compilations, as a single fit's
        res = fit_population(problem, kind, maxiter=maxiter, callback=callback, **where)
    return replace(res, compile_seconds=clock[0])


def _check_enough_data(problem) -> None:
    """Fewer residuals than unknowns (and no priors to make up for them): refused
    before any iteration. A fit ran to a "converged" point of many equally good
    ones (176 iterations of a filter on 3 samples) before saying it had no error bars."""
    from ..analysis.residuals import residual_count

    n, K = residual_count(problem), problem.K
    if n >= K or problem.priors:
        return
    filt = problem.loss.likelihood and len(problem.free_x0)
    lost = " (a filter leaves each record's first sample out)" if filt else ""
    raise ValueError(
        f"{n} residuals{lost} for {K} unknowns {problem.theta_names}: fewer data than "
        "unknowns, so many estimates fit them equally well; fix some unknowns (fixed=, "
        "--fix), give priors, or fit a longer record"
    )


def _fits(problem, method, thetas, options, started) -> list[FitResult]:
    """The solver's fits from every row of ``thetas`` (solve/starts.py), as FitResults."""
    return [FitResult.of(r) for r in fits(problem, method, thetas, options, started)]


def _starts(problem, method, thetas, options, where, started) -> FitResult:
    """One start (``where`` None) or many on workers, the best refined; a robust loss
    in stages, from the least-squares estimate (robust.py); with priors, their noise
    level checked against the residuals and refitted where it was estimated (priors.py)."""
    if problem.loss.robust:
        first = _starts(problem.with_loss("squared"), method, thetas, options, where, started)
        return fit_robust(
            problem,
            first,
            lambda p, th: weighed(_fits)(p, method, th[None, :], options, time.perf_counter())[0],
        )
    if where is None:
        return weighed(_fits)(problem, method, thetas, options, started)[0]
    res = FitResult.of(many_starts(problem, method, thetas, options, where, started))
    return weigh_priors(res, _fits, method, options, started)


def _refit(method, options, started):
    """``(problem, theta0) -> FitResult``: the fit repeated from θ0 (a finer problem's)."""
    return lambda problem, theta: _starts(problem, method, theta[None, :], options, None, started)


def fit_batch(problem: Problem, method: str | Method, thetas, **options) -> list[FitResult]:
    """Fits from every row of ``thetas`` (B, K) in lock-step: at each iteration the
    points of all unfinished starts are evaluated in one vectorised (jax.vmap) call,
    which costs far less than B separate calls on a CPU. Methods "auto", "newton"
    and "gauss-newton"; options as for :func:`fit` (x_scale, maxiter, gtol, ftol,
    xtol, or options=FitOptions(...)). Each result is what
    ``fit(problem, method, theta0=row)`` returns; its ``seconds`` and
    ``compile_seconds`` are those of the whole batch — except for a robust loss,
    which is fitted as given here (no least-squares stage, no scale check: use
    :func:`fit` for those). Ctrl-C raises :class:`FitInterrupted` with every start's
    best point so far."""
    started = time.perf_counter()
    solver = check_method(problem, method)
    fleet = [k for k in ("population", "individual") if getattr(problem, k, None)]
    if fleet:  # its starts would be plain shared least squares, the random effects dropped
        raise ValueError(
            f"fit_batch fits one shared parameter set per start, and this problem has "
            f"{' and '.join(fleet)} parameters (a fleet): fit it with tensorid.fit"
        )
    if not solver.supports_batch:
        raise ValueError(
            f"batched starts work with {listed('supports_batch', 'and')}, not "
            f"{solver.name!r}; use batch=1"
        )
    opts = options.pop("options", None)
    if opts is None:
        allowed = {"x_scale", "maxiter", "gtol", "ftol", "xtol", "polish"}
        if set(options) - allowed:
            raise TypeError(f"fit_batch got unexpected options {sorted(set(options) - allowed)}")
        opts = FitOptions(**options)
    elif options:
        raise ValueError("pass either options=FitOptions(...) or keyword options, not both")
    thetas = np.atleast_2d(np.asarray(thetas, dtype=float))
    thetas = np.stack([_check_start(problem, th, "a start") for th in thetas])
    with compile_clock() as clock:
        results = weighed(_fits)(problem, solver, thetas, opts, started)
    results = [replace(r, compile_seconds=clock[0]) for r in results]
    if any(r.status is Status.INTERRUPTED for r in results):
        best = min(results, key=lambda r: (not np.isfinite(r.cost), r.cost))
        raise FitInterrupted(best, results)
    return results


# -- checks -----------------------------------------------------------------------------
def _options(options, x_scale, maxiter, gtol, ftol, xtol, callback, polish=True) -> FitOptions:
    """``options``, or the keywords as FitOptions; both at once is an error (one of them
    would be silently ignored)."""
    if options is None:
        return FitOptions(x_scale, maxiter, gtol, ftol, xtol, callback=callback, polish=polish)
    d = FitOptions()
    changed = not (isinstance(x_scale, str) and x_scale == d.x_scale) or callback is not None
    changed |= polish is not True
    changed |= (maxiter, gtol, ftol, xtol) != (d.maxiter, d.gtol, d.ftol, d.xtol)
    if changed:
        raise ValueError(
            "give either options=FitOptions(...) or x_scale/maxiter/gtol/ftol/xtol/"
            "callback/polish, not both"
        )
    if not isinstance(options, FitOptions):
        raise TypeError(f"options must be a tensorid.FitOptions, got {type(options).__name__}")
    return options


def check_method(problem, method) -> Method:
    """The method object named ``method`` (registry.py), checked against ``problem``."""
    if not isinstance(problem, Problem):
        raise TypeError(f"fit needs a tensorid.Problem, got {type(problem).__name__}")
    if not isinstance(method, str | Method):  # fit(problem, theta): a start where method goes
        raise TypeError(
            f"method must be a method's name or a tensorid Method, got "
            f"{type(method).__name__}; a start goes by keyword: fit(problem, theta0=...)"
        )
    if method in FLEET_METHODS:
        raise ValueError(
            f"method {method!r} is a population fit's (Problem(population=...)); this "
            "problem has no random effects: use 'auto' or another of tensorid.METHODS"
        )
    method = resolve(method)
    if problem.shooting is not None and not method.supports_segments:
        raise ValueError(
            f"method {method.name!r} is single shooting only; with segments (multiple "
            f"shooting) use {listed('supports_segments')}, or drop the segments"
        )
    if problem.loss.likelihood and not method.supports_likelihood:
        raise ValueError(
            f"method {method.name!r} minimises a sum of squared residuals, and a filter's "
            f"cost (predictor='ekf') is −2 log L, which is not one: use "
            f"{listed('supports_likelihood')}"
        )
    _check_enough_data(problem)
    _check_constraints(problem, method)
    return method


def _check_constraints(problem, method) -> None:
    """Constraints are kept by the exact-derivative trust-region methods on a single-
    shooting problem (their augmented Lagrangian is a term of J, ∇J and ∇²J)."""
    if not problem.constraints:
        return
    if not method.exact_derivatives or not isinstance(method, TrustRegion):
        raise ValueError(
            f"constraints are kept by the exact-derivative trust-region methods "
            f"'auto', 'newton', 'newton-cg' and 'gauss-newton', not {method.name!r}"
        )
    if problem.shooting is not None:
        raise ValueError(
            "constraints are kept in single shooting only: drop the segments "
            "(segments=, --segments) or the constraints"
        )


def _check_start(problem: Problem, theta, what: str) -> np.ndarray:
    theta = problem.check_theta(theta)
    if ((theta < problem.lower) | (theta > problem.upper)).any():
        raise ValueError(f"{what} lies outside the bounds")
    return theta


def _check_count(name: str, n) -> int:
    """``n``, a positive whole number, as an int; one line for anything else."""
    if isinstance(n, bool) or not isinstance(n, int | np.integer) or n < 1:
        raise ValueError(f"{name} must be a positive integer, got {n!r}")
    return int(n)


def _check_multistart(spread, sampling, workers, timeout, seed=0, executor=None) -> None:
    """The multi-start options, checked with one start too (spread=-1 or timeout=-1
    passed without a word there)."""
    check_executor(executor)
    if isinstance(seed, bool) or not isinstance(seed, int | np.integer):
        raise TypeError(f"seed must be a whole number, got {seed!r}")
    if spread is not None and not (
        isinstance(spread, int | float) and np.isfinite(spread) and spread >= 0
    ):
        raise ValueError(f"spread must be a finite number >= 0, got {spread!r}")
    if sampling not in SAMPLINGS:
        raise ValueError(
            f"sampling must be one of {SAMPLINGS}, got {sampling!r}"
            f"{did_you_mean(sampling, SAMPLINGS)}"
        )
    if workers is not None:
        _check_count("workers", workers)
    if timeout is not None and not (
        isinstance(timeout, int | float) and not isinstance(timeout, bool) and timeout > 0
    ):
        raise ValueError(f"timeout must be a number of seconds > 0, got {timeout!r}")


def _check_batch(method, batch, starts, executor, workers) -> int:
    if batch is None:
        if method.supports_batch and executor is None:
            return min(16, -(-starts // (workers or os.cpu_count() or 1)))
        return 1
    _check_count("batch", batch)
    if batch > 1 and not method.supports_batch:
        raise ValueError(
            f"batch > 1 works with {listed('supports_batch', 'and')}, not {method.name!r}; "
            "use batch=1"
        )
    return int(batch)
