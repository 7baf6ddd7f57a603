"""What the priors did to a fit, read from its result: the noise level that weighed
them against the residuals (:class:`NoiseCheck`, made by the priors' re-check in
``fitting/priors.py``), where the data alone would put each estimate
(:func:`data_only`) and how far each prior moved it, in standard errors of the data
alone (:func:`prior_moves`), so that a strong or wrong prior is never silent. The
measurements behind the rule are in docs/statistics.md.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..engine.schemes.status import Status
from ..solve.endings import Outcome, OwnRun, run_alone
from .summary import Table, Tabular, significant
from .uncertainty import FLAT, _directions, _variances, negative_directions

TOLERANCE = 1.5  # the factor by which σ² and the residual variance may differ
STEPS = 5  # Gauss-Newton steps towards the data-only estimate
FIX = "noise= (a standard deviation; `noise = ...` in a model file)"
MOVED = 2.0  # a prior that moves an estimate by more data-only standard errors is named


@dataclass(repr=False)
class NoiseCheck(Tabular):
    """The noise variance that weighed the priors against the residuals of the fit.

    source : "given" (``noise=``) or "second differences" (estimated from the data).
    first : the σ² of the first fit; ``used`` the σ² of the result (they differ after
        refits); residual : the residual variance at the result's optimum.
    refits : fits repeated with σ² re-estimated from the residuals (empirical Bayes).
    agree : whether ``used`` and ``residual`` agree within TOLERANCE (for a given σ²:
        or within the residual variance's chance scatter, 99 %).
    too_few : why there is no residual variance to check against (no more residuals
        than unknowns), else None.
    outputs : per output, the second-difference variance, the residual variance and
        the second differences' lag-1 correlation (white noise gives −2/3; near +1
        the signal dominates them and the estimate is too large).
    """

    source: str
    first: float
    used: float
    residual: float
    refits: int
    agree: bool
    outputs: dict[str, dict[str, float]] = field(default_factory=dict)
    too_few: str | None = None

    def as_dict(self) -> dict:
        return {
            "source": self.source,
            "first_variance": self.first,
            "used_variance": self.used,
            "residual_variance": self.residual,
            "refits": self.refits,
            "agree": self.agree,
            "tolerance": TOLERANCE,
            "outputs": self.outputs,
            "too_few": self.too_few,
        }

    def blocks(self) -> list:
        """The variances in one line, the per-output evidence, and the warning if any."""
        refits = f"refitted {_count(self.refits)}" if self.refits else "no refits"
        head = (
            f"noise variance weighing the priors: {self.used:.4g} ({_SOURCE[self.source]}; first "
            f"{self.first:.4g}, {refits}); residual variance at the fit "
            + (
                f"none ({self.too_few.removeprefix('not available: ')})"
                if self.too_few
                else f"{self.residual:.4g}: "
                + ("they agree" if self.agree else "they disagree")
                + f" (tolerance {TOLERANCE:g}×)"
            )
        )
        header = ["output", "second-difference variance", "residual variance", "lag-1 correlation"]
        keys = ("second_difference_variance", "residual_variance", "second_difference_lag1")
        rows = [[o, *(f"{v[k]:.4g}" for k in keys)] for o, v in self.outputs.items()]
        warning = self.message()
        return [head, Table(None, header, rows)] + ([f"warning: {warning}"] if warning else [])

    def __repr__(self) -> str:
        return (
            f"NoiseCheck(source={self.source!r}, used={self.used:.4g}, "
            f"residual={self.residual:.4g}, refits={self.refits}, agree={self.agree})"
        )

    def _smooth(self) -> str:
        """Why the second differences misled, where their correlation shows it."""
        worst = max(self.outputs.items(), key=lambda kv: kv[1]["second_difference_lag1"])
        rho = worst[1]["second_difference_lag1"]
        if self.source != "second differences" or not rho > 0:
            return ""
        return (
            f" (the second differences of {worst[0]} have lag-1 correlation {rho:.2f} where "
            "white noise gives -0.67: the signal, not the noise, dominates them)"
        )

    def message(self) -> str | None:
        """A line for the warnings where σ² and the residuals disagreed, else None."""
        if self.refits == 0 and self.agree:
            return None
        how = "given as noise=" if self.source == "given" else "from the second differences"
        if self.too_few:  # not "matches exactly": there is no residual variance at all
            fix = "" if self.source == "given" else f"; give {FIX}"
            return (
                f"priors: the noise variance {how}, {self.first:.3g}, cannot be checked "
                f"against the residuals: {self.too_few.removeprefix('not available: ')}{fix}"
            )
        if not self.residual > 0:
            return (
                "priors: the fit matches the data exactly, so no noise level can be read "
                f"from its residuals to weigh the priors; give {FIX}"
            )
        ratio = _times(self.first / self.residual)
        head = (
            f"priors: the noise variance {how}, {self.first:.3g}, is {ratio} the residual "
            f"variance at the fit, {self.residual:.3g}" + self._smooth()
        )
        if self.source == "given" and self.first > self.residual:
            return head + (
                f", so the priors weigh at least {ratio} too much; check {FIX}, or leave it "
                "out to have it estimated from the residuals"
            )
        if self.source == "given":
            return head + (
                ": the model does not fit the data to that noise level, or noise= is too "
                f"small (then the priors weigh too little); check {FIX}"
            )
        redone = f"re-estimated from the residuals and refitted {_count(self.refits)}"
        if self.agree:
            return head + (
                f"; {redone} (empirical Bayes), the priors are weighed by {self.used:.3g}; "
                f"give {FIX} to weigh them by a known noise level"
            )
        if self.refits == 0:
            return head + f"; it was not re-estimated: give {FIX}"
        return head + f"; {redone}, it did not settle (last {self.used:.3g}): give {FIX}"


_SOURCE = {"given": "given as noise=", "second differences": "from the second differences"}


def _times(ratio: float) -> str:
    """1846.2 -> '1,846×', 0.25 -> '0.25×'."""
    return f"{ratio:,.0f}×" if ratio >= 10 else f"{ratio:.2g}×"


def _count(n: int) -> str:
    return "once" if n == 1 else f"{n} times"


def prior_moves(res) -> list[dict]:
    """How far the priors moved the estimates: for every unknown with a prior, and
    every other that moved by more than MOVED data-only standard errors, a dict with
    unknown, estimate, data_only (where the data alone put it, see :func:`data_only`;
    None where they do not determine it), data_stderr (its standard error from the
    data alone), standard_errors (|estimate − data_only| / data_stderr), prior (bool)
    and moved (more than MOVED)."""
    problem = res.problem
    if not problem.priors or not res.has_uncertainty:
        return []
    alone, se = data_only(res)
    out = []
    for k, name in enumerate(problem.theta_names):
        known = bool(np.isfinite(se[k]) and se[k] > 0)
        n = abs(res.theta[k] - alone[k]) / se[k] if known else 0.0
        if k in problem.priors or n > MOVED:
            out.append(
                {
                    "unknown": name,
                    "estimate": float(res.theta[k]),
                    "data_only": float(alone[k]) if known else None,
                    "data_stderr": float(se[k]),
                    "standard_errors": float(n) if known else None,
                    "prior": k in problem.priors,
                    "moved": bool(n > MOVED),
                }
            )
    return out


def data_only(res) -> tuple[np.ndarray, np.ndarray]:
    """(θ, standard errors) the data alone would give: Gauss-Newton steps on the
    data's part of J from the MAP estimate (the first with the exact Hessian where it
    is positive definite), each kept only if it lowers that cost, at most STEPS; the
    standard errors from the data's Hessian and residual variance there, infinite
    along directions the data alone leave open."""
    problem, names, dof = res.problem, res.problem.theta_names, res.uncertainty().dof
    theta = res.theta
    J, g, H = _data_part(problem, theta, res.cost, res.jac, res.hess)
    if negative_directions(H, names):  # far from the data's optimum: its convex form
        H = _data_part(problem, theta, *problem.cost_grad_gn(theta))[2]

    def sigma2(J):  # J = −2 log L has no residual variance: the covariance is 2 H⁻¹
        return 1.0 if problem.loss.likelihood else J / dof

    run = _TowardsData(problem, names, sigma2, (theta, J, g, H))
    if run_alone(run).status is Status.INTERRUPTED:  # the one loop (solve/endings.py)
        raise KeyboardInterrupt
    return run.theta, np.sqrt(2 * sigma2(run.J) * _pseudo_inverse(run.H, names)[1])


class _TowardsData(OwnRun):
    """data_only's Gauss-Newton steps, a run of the one loop: each step the
    pseudo-inverse's, kept only if it lowers the data's cost; at most STEPS, none
    once every step is below a thousandth of its standard error."""

    name = "Gauss-Newton towards the data alone"

    def __init__(self, problem, names, sigma2, start):
        self.problem, self.names, self.sigma2 = problem, names, sigma2
        self.theta, self.J, self.g, self.H = start
        self.k = 0
        self.point = self._next()

    def _next(self):
        """The next trial point, or None (and the outcome) where the steps end."""
        if self.k >= STEPS:
            return self._end(Status.MAXITER)
        inv, var = _pseudo_inverse(self.H, self.names)
        step = -inv @ self.g
        if not (np.abs(step) > 1e-3 * np.sqrt(2 * self.sigma2(self.J) * var)).any():
            return self._end(Status.XTOL)
        return np.clip(self.theta + step, self.problem.lower, self.problem.upper)

    def _end(self, status: Status) -> None:
        self.outcome = Outcome(self.theta, self.k, status)
        return None

    def evaluate(self):
        return _data_part(self.problem, self.point, *self.problem.cost_grad_gn(self.point))

    def step(self, state, value) -> None:
        if value is None:  # it ended before a trial point
            return
        J1, g1, H1 = value
        self.k += 1
        if not J1 < self.J:
            self.point = None
            self._end(Status.NO_FURTHER_DECREASE)
            return
        self.theta, self.J, self.g, self.H = self.point, J1, g1, H1
        self.point = self._next()

    def best(self, state) -> tuple:
        return self.theta, self.k


def _data_part(problem, theta, J, g, H):
    """J, ∇J and ∇²J of the data alone: the priors' terms taken out."""
    g = np.array(g, dtype=float)
    for i, (mean, sd) in problem.priors.items():
        g[i] -= 2 * problem.noise_variance * (theta[i] - mean) / sd**2
    return J - problem.prior_cost(theta), g, H - np.diag(problem.prior_curvature)


def _pseudo_inverse(H, names) -> tuple[np.ndarray, np.ndarray]:
    """(H's pseudo-inverse over its positive part, its diagonal with inf for the
    unknowns in directions H leaves flat or curves down along)."""
    weak = _directions(H, names, lambda r: r <= FLAT)
    return _variances(H, 0.5, names, weak)  # 2·0.5·H⁻¹: the pseudo-inverse itself


def move_lines(moves: list[dict]) -> list[str]:
    """'the prior on b moved it from 4.000 to 3.889, 880 standard errors of the data
    alone' for every prior that moved its unknown by more than MOVED of them, and one
    line for the other unknowns the priors moved that far, largest move first."""
    out, others = [], []
    for m in sorted(moves, key=lambda m: -(m["standard_errors"] or 0.0)):
        if not m["moved"]:
            continue
        se, count = m["data_stderr"], _standard_errors(m["standard_errors"])
        if not m["prior"]:
            others.append(f"{m['unknown']} ({count})")
            continue
        out.append(
            f"the prior on {m['unknown']} moved it from {significant(m['data_only'], se)} "
            f"to {significant(m['estimate'], se)}, {count} standard errors of the data "
            f"alone ({se:.2g}); check the prior's mean and sd, and the noise level that "
            "weighs it"
        )
    if others:
        out.append(f"the priors also moved {', '.join(others)} standard errors of the data alone")
    return out


def _standard_errors(n: float) -> str:
    return f"{n:.1f}" if n < 10 else f"{n:,.0f}"
