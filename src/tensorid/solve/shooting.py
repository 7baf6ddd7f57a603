"""Fitting a multiple-shooting problem: an augmented Lagrangian whose inner problems
are solved by the trust-region Newton method with the exact Hessian of the
Lagrangian, then (by default) a single-shooting polish from its solution.

In scaled units (z = scale·φ, J relative to its value at the start, defects
ĉ = c / (state scale)) the k-th inner problem is

    min_φ  L_A(φ) = Ĵ + λᵀĉ + ½ μ ‖ĉ‖²,
    ∇²L_A = ∇²Ĵ + Σ_k (λ + μ ĉ)_k ∇²ĉ_k + μ ÂᵀÂ,

where ∇²ĉ_k comes from the segments' end transition tensors (``Shooting.curvature``)
and Â = ∂ĉ/∂φ from their end transition matrices. After each inner solve the
multipliers take the first-order update λ ← λ + μ ĉ, and μ grows tenfold when the
largest defect fell by less than a factor of four. "gauss-newton" drops the
second-order terms (∇²Ĵ by its Gauss-Newton form, no ∇²ĉ): the cheaper variant.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import replace

import numpy as np

from ..engine.schemes.status import Status
from .arrow import ArrowSolver
from .driver import fit_many
from .endings import Outcome, OwnRun, failed, run_alone, segments_result
from .options import FitOptions
from .solution import Solution
from .stats import Stats
from .trust_region import trust_region_steps

MU0 = 10.0  # first penalty, in units of the starting cost per (defect / state scale)²
MAX_OUTER = 12
ARROW_FROM = 100  # unknowns from which the block-arrow solver beats the dense one


def fit_shooting(problem, method, theta0, options: FitOptions, started) -> Solution:
    """Fit ``problem`` (which has segments) from θ0 by ``method`` (a registry method)
    by multiple shooting, then polish by single shooting unless ``options.polish`` is
    False."""
    sh = problem.shooting
    z0 = sh.start(theta0)
    first = sh.evaluate(z0, exact=False)
    if not first.finite:  # a segment blows up from the measured states: simulate instead
        z0 = sh.start(theta0, from_data=False)
        first = sh.evaluate(z0, exact=False)
    if not first.finite:
        why = problem.diagnose(theta0) or (
            "a segment's simulation is not finite at the start, although the whole "
            "record's is; try more segments or another initial guess"
        )
        return failed(problem, method.name, theta0, started, why + " Choose another initial guess.")
    run = _Run(problem, method, z0, first.J, options)
    ending = run_alone(run)  # the one loop: endings.py
    z, status = ending.x, ending.status
    theta = sh.to_theta(z)
    if status is Status.INTERRUPTED and problem.cost(theta0) < problem.cost(theta):
        theta = np.asarray(theta0, dtype=float)  # stopped before the segments beat the start
    info = dict(
        segments=list(sh.counts),
        nit=run.nit,
        outer=run.outer,
        nfev=run.nfev,
        cost=float(run.J),
        max_defect=float(run.defect),
        defect_tol=run.ctol,
        status=str(status),
        seconds=time.perf_counter() - started,
        polished=False,
    )
    notes = []
    if run.defect > run.ctol and np.isfinite(run.defect):
        notes.append(
            f"multiple shooting stopped with a continuity defect of {run.defect:.1e} "
            f"(relative to the state scale; tolerance {run.ctol:.0e})"
            + (": the polish started from a discontinuous trajectory" if options.polish else "")
        )
    if status is Status.INTERRUPTED or not options.polish:
        stopped = status is Status.INTERRUPTED
        return segments_result(
            problem, method.name, theta, status, started,
            message=status.describe(ending.detail), stats=Stats(nit=run.nit, nfev=run.nfev),
            history=run.history, cost=problem.cost(theta) if stopped else np.inf,
            shooting=info, notes=notes,
        )  # fmt: skip
    res = fit_many(problem, method, theta[None, :], options, started)[0]
    info.update(polished=True, polish_nit=res.nit)
    history = run.history + [
        dict(h, iteration=h["iteration"] + run.nit, stage="polish") for h in res.history
    ]
    stats = Stats(nit=run.nit, nfev=run.nfev).then(res.stats)
    return replace(res, history=history, stats=stats, shooting=info, notes=res.notes + notes)


class _Run(OwnRun):
    """One augmented-Lagrangian solve in scaled units; keeps the counts and history.
    It is both the method and the state of a run of endings.iterate: ``point`` is the
    next φ to evaluate by ``fun`` (the Lagrangian of the inner solve under way)."""

    def __init__(self, problem, method, z0, J0, options: FitOptions):
        sh = self.sh = problem.shooting
        self.problem, self.options, self.name = problem, options, method.name
        self.exact = method.needs_hessian  # the exact Lagrangian Hessian, or Gauss-Newton
        self.J_ref = J0 if J0 > 0 else 1.0
        states = sh.state_scale(z0)
        self.cscale = np.tile(states, len(sh.defect_rows))
        self.scale = self._z_scale(z0, states)
        self.lo, self.hi = self._box()
        self.ctol = options.defect_tol
        self.nit = self.nfev = self.outer = 0
        self.history: list[dict] = []
        self.best_z = z0
        self.J, self.defect = J0, np.inf
        self.costs_seen: dict[float, float] = {}
        # the state unknowns come first in z: the banded block of the arrow
        self.subproblem = ArrowSolver(sh.nz_states) if sh.nz >= ARROW_FROM else None
        self.fun: Callable | None = None  # the Lagrangian of the inner solve under way
        self.steps = self.solve()
        self.point = next(self.steps)

    # -- as a method of endings.iterate
    def evaluate(self):
        """(L_A, ∇L_A, ∇²L_A) at the pending point."""
        assert self.fun is not None
        return self.fun(self.point)

    def step(self, state, value) -> None:
        try:
            self.point = self.steps.send(value)
        except StopIteration as done:
            self.point, self.outcome = None, done.value

    def best(self, state) -> tuple:
        return self.best_z, self.nit

    def _z_scale(self, z0, states) -> np.ndarray:
        sh, pr = self.sh, self.problem
        scale = np.abs(z0)
        for e, n in enumerate(sh.counts):
            free = [pr.model.states.index(s) for s in pr.free_x0]
            scale[sh.state_slice(e, 0)] = np.maximum(scale[sh.state_slice(e, 0)], states[free])
            for i in range(1, n):
                scale[sh.state_slice(e, i)] = states
        return np.where(scale > 0, scale, 1.0)

    def _box(self):
        sh, pr = self.sh, self.problem
        lo, hi = np.full(sh.nz, -np.inf), np.full(sh.nz, np.inf)
        lo[sh.theta_index], hi[sh.theta_index] = pr.lower, pr.upper
        return lo / self.scale, hi / self.scale

    def lagrangian(self, lam, mu):
        """φ -> (L_A, ∇L_A, ∇²L_A) in scaled units; L_A = inf where a segment blows up."""
        sh, s = self.sh, self.scale

        def fun(phi):
            z = np.clip(phi * s, self.lo * s, self.hi * s)
            L = sh.evaluate(z, exact=self.exact)
            self.nfev += 1
            rejected = np.inf, np.zeros_like(phi), np.eye(phi.size)
            if not L.finite:
                return rejected
            # defects far beyond a tiny state scale overflow in scaled units: such a
            # trial point is rejected as a blow-up is, not a raw RuntimeWarning
            with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
                c = L.c / self.cscale
                A = L.A / self.cscale[:, None] * s
                w = lam + mu * c
                val = L.J / self.J_ref + w @ c - 0.5 * mu * c @ c
                grad = L.g * s / self.J_ref + A.T @ w
                H = L.H * np.outer(s, s) / self.J_ref + mu * A.T @ A
                if self.exact and w.size:
                    H += sh.curvature(L, w / self.cscale) * np.outer(s, s)
            if not (np.isfinite(val) and np.isfinite(grad).all() and np.isfinite(H).all()):
                return rejected
            self.costs_seen[float(val)] = L.J  # the history reports J beside L_A
            return val, grad, H

        return fun

    def solve(self):
        """Outer iterations until the defects are below ctol: a generator that yields
        the inner solves' points and returns the Outcome (z, status)."""
        sh, opts = self.sh, self.options
        phi = self.best_z / self.scale
        lam, mu = np.zeros(self.cscale.size), MU0
        status, detail, previous = Status.MAXITER, "", np.inf
        for outer in range(1, MAX_OUTER + 1):
            budget = opts.maxiter - self.nit
            if budget <= 0:
                break
            self.outer = outer
            gtol = max(opts.gtol, 1e-3 * 10.0 ** (1 - self.outer))
            self.fun = self.lagrangian(lam, mu)
            r = yield from trust_region_steps(
                phi,
                self.lo,
                self.hi,
                callback=self._record(lam, mu),
                subproblem=self.subproblem,
                **dict(opts.trust_region(), maxiter=budget, gtol=gtol),
            )
            phi, self.nit = r.x, self.nit + r.nit
            z = np.clip(phi * self.scale, self.lo * self.scale, self.hi * self.scale)
            L = sh.evaluate(z, exact=False)
            with np.errstate(over="ignore"):  # an overflow is an infinite defect
                c = L.c / self.cscale
            self.best_z, self.J = z, L.J
            self.defect = float(np.abs(c).max()) if c.size else 0.0
            if self.defect <= self.ctol and r.status.success:
                return Outcome(z, self.nit, r.status)
            lam = lam + mu * c
            if self.defect > 0.25 * previous:
                mu *= 10.0
            previous = self.defect
            status, detail = r.status, ""
        if self.defect > self.ctol:
            status = Status.DEFECTS_REMAIN
            detail = f"largest defect {self.defect:.1e} after {self.outer} outer iterations"
        return Outcome(self.best_z, self.nit, status, detail)

    def _record(self, lam, mu):
        """History entries in the user's units: ``cost`` is J, ``lagrangian`` the
        augmented Lagrangian the inner solve minimises; each inner solve's iteration
        0 (the previous one's end point) is recorded once."""
        seen = self.costs_seen

        def record(entry):
            if entry["iteration"] == 0 and self.history:
                return
            scaled = entry["cost"]
            self.history.append(
                dict(
                    entry,
                    iteration=entry["iteration"] + self.nit,
                    cost=seen.get(float(scaled), np.nan),
                    lagrangian=scaled * self.J_ref,
                    grad_norm=entry["grad_norm"] * self.J_ref,
                    penalty=float(mu),
                    stage="multiple shooting",
                )
            )
            if self.options.callback is not None:
                self.options.callback(self.history[-1])

        return record
