"""Residual analysis as MATLAB's ``resid`` does it, and the information criteria for
comparing model structures.

Whiteness: the residuals' normalised autocorrelation r(τ), τ = 1..M, should be that
of white noise; the portmanteau statistic Q = N Σ r(τ)² is then χ² with M degrees of
freedom, and the test passes when Q is below its quantile at the stated level.
Independence: the normalised cross-correlation of the residuals with each input for
τ = 0..M (the residual now against the input τ samples earlier) should vanish: a
model missing a dynamic leaves the past input in the residual. Q = N Σ r_eu(τ)² is χ²
with M + 1 degrees of freedom. The negative lags τ = −1..−M (the residual against
later inputs) are shown and reported beside it but not tested: in a closed loop the
controller feeds the output, residual included, back into the input, so they measure
the feedback, not a flaw of the model (MATLAB's resid draws both sides too). The
figure shows r with the ±z/√N band of the level, as MATLAB draws it; the pass/fail
comes from Q, which for 25 lags holds its level (a band test on every lag would fail
a correct model one time in five). Q is χ² only for M well below N: with more than
N/4 lags (``lag_limit``) the tests are not made and ``not_available`` says so (a Q
summed over lags with almost no products under a threshold that grows with M
"passes" any model).

Information criteria, with Gaussian residuals of unknown variance: for n residuals
and K unknowns, −2 log L = n (log(2π J/n) + 1), AIC = −2 log L + 2K,
AICc = AIC + 2K(K + 1)/(n − K − 1), BIC = −2 log L + K log n. Lower is better; only
differences between models fitted to the same data mean anything.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from . import quantiles
from .summary import Table, Tabular


@dataclass
class Correlation:
    """One correlation test: the correlation per lag, its statistic and verdict."""

    what: str  # "whiteness of y" or "y against input u"
    lags: np.ndarray
    values: np.ndarray
    statistic: float
    threshold: float
    passed: bool
    # the cross-correlation at lags -1..-M (later inputs: feedback), not tested
    feedback: np.ndarray | None = None

    def line(self) -> str:
        """The test in words."""
        verdict = "passes" if self.passed else "FAILS"
        side = "below" if self.passed else "above"
        back = (
            ""
            if self.feedback is None
            else f"; at negative lags (feedback) {np.max(np.abs(self.feedback)):.3f}"
        )
        return (
            f"{self.what}: {verdict} (Q = {self.statistic:.1f}, {side} "
            f"{self.threshold:.1f}; largest |r| {self.largest:.3f}{back})"
        )

    @property
    def largest(self) -> float:
        """The largest |r| over the tested lags (lag 0 of a whiteness test is 1)."""
        shown = self.values[1:] if self.what.startswith("whiteness") else self.values
        return float(np.max(np.abs(shown)))


@dataclass(repr=False)
class ResidualTests(Tabular):
    """Whiteness per output and independence from each input, at ``level``."""

    level: float
    max_lag: int
    samples: int
    bound: float  # z/√N: the band the figure draws
    whiteness: list[Correlation]
    independence: list[Correlation]
    # inputs constant on every record: no correlation to test, so no verdict
    constant_inputs: list[str] = field(default_factory=list)
    not_available: str | None = None  # why no test was made (too many lags), or None

    @property
    def passed(self) -> bool | None:
        """Whether every test passed; None where none could be made."""
        if self.not_available:
            return None
        return all(c.passed for c in self.whiteness + self.independence)

    @property
    def whiteness_passed(self) -> list[bool | None]:
        """Per output, whether its residuals passed the whiteness test (None: not made)."""
        return [c.passed for c in self.whiteness]

    def lines(self) -> list[str]:
        """One line per test, in words."""
        if self.not_available:
            return [f"tests {self.not_available}"]
        return [c.line() for c in self.whiteness + self.independence] + [
            f"input {name}: not tested (constant on every record, so nothing to correlate)"
            for name in self.constant_inputs
        ]

    def blocks(self) -> list:
        """One row per test: Q against its threshold, the largest |r|, the verdict."""
        if self.not_available:
            return [f"residual tests {self.not_available}"]
        tests = self.whiteness + self.independence
        header = ["test", "Q", "threshold", "largest |r|", "verdict"]
        rows = [
            [c.what, f"{c.statistic:.1f}", f"{c.threshold:.1f}", f"{c.largest:.3f}"]
            + ["passes" if c.passed else "FAILS"]
            for c in tests
        ]
        if any(c.feedback is not None for c in tests):  # feedback: shown, not tested
            header.insert(4, "|r| at negative lags")
            for row, c in zip(rows, tests, strict=True):
                row.insert(4, "" if c.feedback is None else f"{np.max(np.abs(c.feedback)):.3f}")
        head = f"residual tests at the {self.level:.0%} level, up to lag {self.max_lag}"
        head += f", {self.samples} samples"
        constant = [
            f"input {n}: not tested (constant on every record)" for n in self.constant_inputs
        ]
        return [head, Table(None, header, rows), *constant]

    def __repr__(self) -> str:
        return f"ResidualTests(passed={self.passed}, level={self.level}, max_lag={self.max_lag})"

    def as_dict(self) -> dict:
        def one(c: Correlation) -> dict:
            return {
                "test": c.what,
                "passed": c.passed,
                "statistic": c.statistic,
                "threshold": c.threshold,
                "correlation": c.values.tolist(),
                "lags": c.lags.tolist(),
            } | ({} if c.feedback is None else {"correlation_negative_lags": c.feedback.tolist()})

        return {
            "level": self.level,
            "max_lag": self.max_lag,
            "samples": self.samples,
            "band": self.bound,
            "whiteness": [one(c) for c in self.whiteness],
            "independence": [one(c) for c in self.independence],
            "constant_inputs": self.constant_inputs,
            "not_available": self.not_available,
        }

    def figure_job(self) -> tuple[str, str, dict] | None:
        """The figure as plain data, (file stem, kind, arguments) for
        ``tensorid.fitting.figures.draw``; None where no test was made."""
        if self.not_available:
            return None
        panels = [
            dict(what=c.what, passed=c.passed, lags=c.lags, values=c.values, feedback=c.feedback)
            for c in self.whiteness + self.independence
        ]
        return "residual_tests", "residual", dict(bound=self.bound, panels=panels)

    def figure(self):
        """Autocorrelation and cross-correlation panels with the ±z/√N band; None where
        no test was made."""
        from .figures import draw

        job = self.figure_job()
        return None if job is None else draw(job[1], job[2])


def _correlation(a: list[np.ndarray], b: list[np.ndarray], lags: int) -> np.ndarray:
    """Σ a[k] b[k − τ] / √(Σa² Σb²) for τ = 0..lags, pooled over the records."""
    num = np.zeros(lags + 1)
    for x, y in zip(a, b, strict=True):
        x, y = x - x.mean(), y - y.mean()
        for tau in range(min(lags, x.size - 1) + 1):
            num[tau] += x[tau:] @ y[: x.size - tau]
    den = np.sqrt(
        sum((x - x.mean()) @ (x - x.mean()) for x in a)
        * sum((y - y.mean()) @ (y - y.mean()) for y in b)
    )
    return num / den if den > 0 else np.zeros(lags + 1)


def residual_tests(res, max_lag: int = 25, level: float = 0.99) -> ResidualTests:
    """Whiteness of each output's residuals and their independence from each input.

    Arguments:
      res : a FitResult with a finite cost.
      max_lag : the largest lag (MATLAB's default M = 25).
      level : the confidence level of the tests and the band (0.99 as MATLAB).

    Returns:
      :class:`ResidualTests`.
    """
    if not (isinstance(max_lag, int) and max_lag >= 1):
        raise ValueError(f"max_lag must be a whole number >= 1, got {max_lag!r}")
    if not 0 < level < 1:
        raise ValueError(f"level must be between 0 and 1, got {level!r}")
    problem = res.problem
    model = problem.model
    exps = problem.experiments
    N = sum(e.P for e in exps)
    if max_lag > lag_limit(N):
        fix = (
            f"give max_lag (--residual-lags) {lag_limit(N)} or fewer"
            if lag_limit(N)
            else "they need at least 4 samples"
        )
        why = (
            f"not available: {max_lag} lags on {N} samples (the test statistic is χ² only "
            f"for lags well below N; at most N/4); {fix}"
        )
        return ResidualTests(level, max_lag, N, np.nan, [], [], [], why)
    if problem.loss.likelihood:  # a filter's: its standardised innovations
        errors = [np.asarray(o.innovations) for o in problem.predict(res.theta)]
    else:
        errors = [e.measured - s.y for e, s in zip(exps, res.simulate(), strict=True)]
    white, indep = [], []
    constant = [
        name for i, name in enumerate(model.inputs) if all(np.ptp(e.u[:, i]) == 0 for e in exps)
    ]
    q_white = quantiles.chi2(max_lag, level)
    q_cross = quantiles.chi2(max_lag + 1, level)
    for j, out in enumerate(model.outputs):
        err = [a[:, j] for a in errors]
        r = _correlation(err, err, max_lag)
        Q = float(N * np.sum(r[1:] ** 2))
        lags = np.arange(max_lag + 1)
        out = f"{out}'s innovations" if problem.loss.likelihood else out  # what was tested
        white.append(Correlation(f"whiteness of {out}", lags, r, Q, q_white, Q <= q_white))
        for i, name in enumerate(model.inputs):
            if name in constant:
                continue
            u = [e.u[:, i] for e in exps]
            c = _correlation(err, u, max_lag)
            Qc = float(N * np.sum(c**2))
            back = _correlation(u, err, max_lag)[1:]  # Σ e[k] u[k + τ]: later inputs
            what = f"{out} against input {name}"
            indep.append(Correlation(what, lags, c, Qc, q_cross, Qc <= q_cross, back))
    bound = float(quantiles.normal(0.5 + level / 2) / np.sqrt(N))
    return ResidualTests(level, max_lag, N, bound, white, indep, constant)


def lag_limit(samples: int) -> int:
    """The most lags the residual tests take on ``samples`` samples: N/4 (Q is χ² only
    for M well below N)."""
    return samples // 4


def residual_count(problem) -> int:
    """n: the weighted residuals, samples times the outputs that carry weight; a
    filter with estimated initial states leaves each record's first sample out of its
    likelihood (tensorid.engine.sweeps, Sweeps._march)."""
    first = 1 if problem.loss.likelihood and len(problem.free_x0) else 0
    return sum(e.P - first for e in problem.experiments) * int((problem.weights > 0).sum())


def too_few(n: int, K: int, need: int = 1, what: str = "error bars") -> str | None:
    """Why a statistic cannot be given with n residuals for K unknowns (it needs
    n >= K + need), or None when it can."""
    if n >= K + need:
        return None
    return f"not available: {n} samples for {K} unknowns ({what}: at least {K + need} needed)"


def information_criteria(res) -> dict:
    """AIC, AICc and BIC of a fit (see the module's docstring), with n and K. A criterion
    the record cannot support is NaN, and ``not_available`` says why (None when all are
    given): AIC and BIC need n > K residuals and a positive cost, AICc n > K + 1."""
    problem = res.problem
    n = residual_count(problem)
    K = problem.K
    J = res.cost - problem.prior_cost(res.theta)
    out = {"aic": np.nan, "aicc": np.nan, "bic": np.nan, "n": n, "K": K, "not_available": None}
    if problem.loss.likelihood:  # J is −2 log L already (less n log 2π)
        m2logL = J + n * np.log(2 * np.pi)
        out.update(aic=float(m2logL + 2 * K), bic=float(m2logL + K * np.log(n)))
        if n > K + 1:
            out["aicc"] = float(m2logL + 2 * K + 2 * K * (K + 1) / (n - K - 1))
        return out
    if not problem.loss.squared:  # their likelihood is Gaussian: J must be Σ w r²
        out["not_available"] = (
            f"not available: they assume the squared loss, this fit's is {problem.loss.name}"
        )
        return out
    if not (np.isfinite(J) and J > 0):
        out["not_available"] = f"not available: the residual cost is {J:.3g}, not positive"
        return out
    short = too_few(n, K, 1, "information criteria")
    if short:
        out["not_available"] = short
        return out
    m2logL = n * (np.log(2 * np.pi * J / n) + 1)
    aic = m2logL + 2 * K
    out.update(aic=float(aic), bic=float(m2logL + K * np.log(n)))
    out["not_available"] = too_few(n, K, 2, "AICc")  # its correction divides by n - K - 1
    if out["not_available"] is None:
        out["aicc"] = float(aic + 2 * K * (K + 1) / (n - K - 1))
    return out
