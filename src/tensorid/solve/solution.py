"""What a solver returns: a plain record of where a run ended and how, in
scipy.optimize.OptimizeResult's vocabulary (x, fun, jac, hess, nit, nfev, status,
history), built once where the run ends (endings.py).

It knows nothing of statistics: :class:`tensorid.FitResult` (analysis/results.py) is
this record with the statistics' methods (uncertainty, summary, plot, ...), made from
it by the composition layer (``FitResult.of``) once the solver has returned.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field, replace
from typing import Any, Self

import numpy as np

from ..engine.assembly.problem import Problem
from ..engine.modelling.metrics import gof
from ..engine.schemes.status import Status
from .stats import Stats


def _measured_gof(e, y_sim: np.ndarray):
    """GOF of each output of the record ``e`` at its measured samples (not its gaps,
    nor a row holding only a dose): a float for one output, else (S,); NaN for an
    output measured fewer than twice."""
    seen = e.seen
    v = np.array([gof(e.measured[seen[:, j], j], y_sim[seen[:, j], j])
                  if seen[:, j].sum() > 1 else np.nan for j in range(seen.shape[1])])  # fmt: skip
    return float(v[0]) if v.size == 1 else v


@dataclass(frozen=True)
class Solution:
    """A solver's outcome; its fields are :class:`tensorid.FitResult`'s (whose docstring
    says what each holds)."""

    problem: Problem  # None only on its way back from a worker (see detached)
    method: str
    theta: np.ndarray
    params: dict[str, float]
    x0: np.ndarray
    cost: float
    jac: np.ndarray
    hess: np.ndarray
    grad_norm: float
    status: Status
    message: str
    seconds: float
    scale: np.ndarray
    history: list[dict] = field(default_factory=list)
    starts: list[dict] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)
    stats: Stats = field(default_factory=Stats)
    compile_seconds: float = 0.0
    derivatives: bool = True  # jac and hess hold the exact derivatives at theta
    shooting: dict | None = None  # multiple shooting: segments, defects, its own counts
    hybrid: dict | None = None  # method "auto": evaluations of each kind, mode switches
    # priors: their noise variance against the residuals (an analysis.prior_effects.NoiseCheck)
    noise_check: Any = None
    # Problem(constraints=...): values, activity, multipliers (a ConstraintOutcome of
    # solve/constrained.py; in a FitResult an analysis.constraint_report.ConstraintReport)
    constraints: Any = None
    # the summary, the warnings, fit.json and report.md all read the same uncertainty;
    # keyed on what it depends on, so a result made by replace shares it (but not
    # across Problems: detached and attached start afresh)
    _uncertainty: dict = field(default_factory=dict, repr=False, compare=False)

    @classmethod
    def at(
        cls,
        problem: Problem,
        method: str,
        theta: np.ndarray,
        scale: np.ndarray,
        status: Status,
        *,
        message: str | None = None,
        stats: Stats | None = None,
        started: float | None = None,
        history: list | None = None,
        evaluate: bool = True,
        cost: float = np.inf,
        known: tuple | None = None,
        **more,
    ) -> Self:
        """The result at θ, with the exact gradient and Hessian there. A point whose
        simulation is not finite gets cost inf and zero derivatives, never NaN.
        Without ``evaluate`` nothing is computed (an interrupted fit must end at
        once): the result holds the ``cost`` already known and no derivatives.
        ``known`` = (θ, J, g, H) spares the evaluation when it was at this θ;
        ``stats`` defaults to one evaluation; ``more``: the other fields (notes,
        hybrid, shooting, starts)."""
        K = theta.size
        if evaluate and known is not None and np.array_equal(known[0], theta):
            J, g, H = known[1:]
        else:
            J, g, H = problem.cost_grad_hess(theta) if evaluate else (cost, None, None)
        if np.isfinite(J) and g is not None and H is not None:
            phi = theta / scale
            pg = np.clip(phi - g * scale, problem.lower / scale, problem.upper / scale) - phi
            grad_norm = float(np.linalg.norm(pg, np.inf))
        else:
            J = J if not evaluate and np.isfinite(J) else np.inf
            g, H, grad_norm = np.zeros(K), np.zeros((K, K)), np.inf
        p, x0 = problem.unpack(theta)
        return cls(
            problem=problem,
            method=method,
            theta=theta,
            params=dict(zip(problem.model.params, map(float, p), strict=True)),
            x0=x0[0] if len(problem.experiments) == 1 else x0,
            cost=float(J),
            jac=g,
            hess=H,
            grad_norm=grad_norm,
            status=status,
            message=status.message if message is None else message,
            seconds=0.0 if started is None else time.perf_counter() - started,
            scale=scale,
            history=history or [],
            stats=Stats(nfev=1) if stats is None else stats,
            derivatives=evaluate,
            **more,
        )

    def detached(self) -> Self:
        """This result without its Problem, to travel back from a worker process (a
        Problem holds compiled code); :meth:`attached` gives it one again."""
        return replace(self, problem=None, _uncertainty={})  # type: ignore[arg-type]

    def attached(self, problem: Problem) -> Self:
        return replace(self, problem=problem, _uncertainty={})

    def history_then(self, more: list[dict]) -> list[dict]:
        """This history followed by ``more`` (a run from this end point), whose
        iterations are numbered on from its last (or from ``nit`` without one);
        ``more``'s iteration 0, this end point again, is left out where it is here."""
        own = self.history
        offset = own[-1]["iteration"] if own else self.nit
        return own + [dict(h, iteration=h["iteration"] + offset) for h in more
                      if h["iteration"] or not own]  # fmt: skip

    def followed_by(self, after: Self, **more) -> Self:
        """``after`` (a run from this one's end point: a refit, the next outer
        iteration) counting both runs: history, counters and ``auto``'s evaluations of
        each kind; ``more``: other fields as the caller joins them."""
        hybrid = after.hybrid
        if self.hybrid and after.hybrid:
            hybrid = {k: self.hybrid[k] + after.hybrid[k] for k in after.hybrid}
        return replace(
            after, history=self.history_then(after.history),
            stats=self.stats.then(after.stats), hybrid=hybrid, **more,
        )  # fmt: skip

    # the counters, read-only (public names since the first release)
    nit = property(lambda self: self.stats.nit, doc="Iterations (``stats['nit']``).")
    nfev = property(lambda self: self.stats.nfev, doc="Cost evaluations (``stats['nfev']``).")
    nhev = property(lambda self: self.stats.nhev, doc="Hessian-vector products.")
    nit_total = property(lambda self: self.stats.nit_total, doc="Every start's iterations.")
    nfev_best = property(lambda self: self.stats.nfev_best, doc="The best start's evaluations.")

    @property
    def has_uncertainty(self) -> bool:
        """Whether error bars can be given: a finite cost with the exact derivatives
        there (an interrupted fit keeps its best point but not its derivatives)."""
        return bool(np.isfinite(self.cost)) and self.derivatives

    @property
    def success(self) -> bool:
        """Whether the fit converged (``status.success``)."""
        return self.status.success

    @property
    def x(self) -> np.ndarray:
        """Alias of theta (scipy.optimize.OptimizeResult's name)."""
        return self.theta

    @property
    def fun(self) -> float:
        """Alias of cost (scipy.optimize.OptimizeResult's name)."""
        return self.cost

    def simulate(self):
        """Simulations of every experiment at the estimate."""
        return self.problem.simulate(self.theta)

    def gof(self) -> list:
        """Goodness of fit per experiment (per output for several outputs): a list with
        a float per experiment, or an (S,) array for S outputs, in the order of
        ``problem.experiments``. (``validate()`` instead returns Scores, whose ``gof``
        is a dict keyed by output; ``training_scores`` in
        :mod:`tensorid.analysis.validation` gives the training records that way.)"""
        sims = self.simulate()
        return [_measured_gof(e, s.y) for e, s in zip(self.problem.experiments, sims, strict=True)]

    @property
    def convergence_warnings(self) -> list[str]:
        """The warnings that need no statistics: how the fit ended, if not converged, and
        a multiple-shooting stage that left defects before a polish that converged."""
        out = [] if self.success else [f"the fit did not converge: {self.message}", *self.notes]
        sh = self.shooting or {}
        if self.success and sh.get("status") == str(Status.DEFECTS_REMAIN):
            out.append(
                f"the multiple-shooting stage ended with a continuity defect of "
                f"{sh['max_defect']:.1e} (tolerance {sh['defect_tol']:.0e}), so the single-"
                "shooting polish started from a discontinuous trajectory; it converged, but "
                "compare with a fit of fewer segments or more iterations"
            )
        return out

    def __repr__(self) -> str:
        ps = ", ".join(f"{k}={v:.6g}" for k, v in self.params.items())
        return (
            f"{type(self).__name__}(method={self.method!r}, status={self.status}, "
            f"cost={self.cost:.6g}, nit={self.nit}, params={{{ps}}}, message={self.message!r})"
        )


class FitInterrupted(KeyboardInterrupt):
    """Ctrl-C during :func:`tensorid.fit`. Still a KeyboardInterrupt (a script stops
    as it always did), but ``result`` holds the best point found so far, with status
    ``INTERRUPTED``; its ``starts`` list the starts that had finished. From
    :func:`tensorid.fit_batch`, ``results`` holds every start's result."""

    def __init__(self, result, results: list | None = None):
        super().__init__(result.message)
        self.result = result
        self.results = [result] if results is None else results
