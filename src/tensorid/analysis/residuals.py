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

The tests use the samples the likelihood uses: a filter (predictor="ekf") with
estimated initial states leaves each record's first sample out of its likelihood
(its standardised innovation divides by √R alone and may be anything), so the tests
leave it out too; and each output's series is its measured samples (a record with
gaps or events' rows: a sample not measured holds no residual), N its count. A
verdict is only given where the series can carry one; otherwise the test "cannot be
trusted" (``passed`` None) and ``untrusted`` says why:

* a swamped series: when the largest 1 % of the samples (at least one) hold more
  than half of its sum of squares, r(τ) = Σ e_k e_{k−τ} / Σ e² is the correlation
  of those few samples with their neighbours over their own squares, ≈ 0 at every
  lag whatever the rest does, and Q ≈ 0 "passes" any model. For white Gaussian
  residuals that share is about 10 % (one sample of twenty holding half is a
  1-in-100 event); a constant or non-finite series is untrusted the same way.
* a filter whose measurement noise σ_e went to its floor (below 10⁻⁶ of the output's
  spread, see :func:`tensorid.analysis.summary.collapsed_outputs`): the filter then
  follows the output exactly, its innovations' covariance comes from the process
  noise alone, and the likelihood sits in a corner, not at a noise model the test
  could check; fix σ_e at the sensor's noise and fit again.

Information criteria, with Gaussian residuals of unknown variance: for n residuals
and K unknowns, −2 log L = n (log(2π J/n) + 1), AIC = −2 log L + 2K,
AICc = AIC + 2K(K + 1)/(n − K − 1), BIC = −2 log L + K log n. Lower is better; only
differences between models fitted to the same data mean anything.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from . import quantiles
from .summary import Table, Tabular, collapsed_outputs

# a series whose largest 1 % of samples (at least one) hold more than this share of
# its sum of squares is swamped by them (white Gaussian: about 0.1)
SWAMPED = 0.5


@dataclass
class Correlation:
    """One correlation test: the correlation per lag, its statistic and verdict."""

    what: str  # "whiteness of y" or "y against input u"
    lags: np.ndarray
    values: np.ndarray
    statistic: float
    threshold: float
    passed: bool | None  # None: the test cannot be trusted (``untrusted`` says why)
    # the cross-correlation at lags -1..-M (later inputs: feedback), not tested
    feedback: np.ndarray | None = None
    untrusted: str | None = None  # why the series cannot carry a verdict, or None

    @property
    def verdict(self) -> str:
        """ "passes", "FAILS" or "cannot be trusted"."""
        return {True: "passes", False: "FAILS", None: "cannot be trusted"}[self.passed]

    def line(self, said: dict[str, str] | None = None) -> str:
        """The test in words; ``said`` maps a reason already given to the test that
        gave it (then named instead of the reason again), and is filled in."""
        side = "below" if self.statistic <= self.threshold else "above"
        back = (
            ""
            if self.feedback is None
            else f"; at negative lags (feedback) {np.max(np.abs(self.feedback)):.3f}"
        )
        why = f": {self.untrusted}" if self.untrusted else ""
        if said is not None and self.untrusted:
            why = f": as {said[self.untrusted]}" if self.untrusted in said else why
            said.setdefault(self.untrusted, self.what)
        return (
            f"{self.what}: {self.verdict} (Q = {self.statistic:.1f}, {side} "
            f"{self.threshold:.1f}; largest |r| {self.largest:.3f}{back}){why}"
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
        """Whether every test passed: False where one failed, None where none could be
        made or one cannot be trusted."""
        if self.not_available:
            return None
        verdicts = [c.passed for c in self.whiteness + self.independence]
        return False if False in verdicts else (None if None in verdicts else True)

    @property
    def whiteness_passed(self) -> list[bool | None]:
        """Per output, whether its residuals passed the whiteness test (None: it cannot
        be trusted)."""
        return [c.passed for c in self.whiteness]

    @property
    def not_shown_white(self) -> bool:
        """Whether some output's residuals failed whiteness or could not be tested for
        it (swamped, σ_e at its floor): the white-noise error bars are then unproven."""
        return any(c.passed is not True for c in self.whiteness)

    def lines(self) -> list[str]:
        """One line per test, in words."""
        if self.not_available:
            return [f"tests {self.not_available}"]
        said: dict[str, str] = {}
        return [c.line(said) for c in self.whiteness + self.independence] + [
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
            [c.what, f"{c.statistic:.1f}", f"{c.threshold:.1f}", f"{c.largest:.3f}"] + [c.verdict]
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
        reasons: dict[str, list[str]] = {}
        for c in tests:
            if c.untrusted:
                reasons.setdefault(c.untrusted, []).append(c.what)
        why = [f"{', '.join(w)}: cannot be trusted: {r}" for r, w in reasons.items()]
        return [head, Table(None, header, rows), *why, *constant]

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
                "trusted": c.untrusted is None,
                "untrusted": c.untrusted,
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
        ``tensorid.analysis.figures.draw``; None where no test was made."""
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
    """Σ a[k] b[k − τ] / √(Σa² Σb²) for τ = 0..lags, pooled over the records (a record
    with no sample of a series, an output it never observed, adds nothing)."""
    pairs = [(x, y) for x, y in zip(a, b, strict=True) if x.size]
    a, b = [x for x, _ in pairs], [y for _, y in pairs]
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


def residual_tests(res, max_lag: int | None = None, level: float = 0.99) -> ResidualTests:
    """Whiteness of each output's residuals and their independence from each input, on
    the samples the likelihood uses (see the module's docstring).

    Arguments:
      res : a FitResult with a finite cost.
      max_lag : the largest lag; None: :func:`default_lags` (MATLAB's M = 25, fewer
        on a short record), as the command line's.
      level : the confidence level of the tests and the band (0.99 as MATLAB).

    Returns:
      :class:`ResidualTests`.
    """
    if max_lag is None:
        max_lag = default_lags(res.problem)
    if not (isinstance(max_lag, int) and max_lag >= 1):
        raise ValueError(f"max_lag must be a whole number >= 1, got {max_lag!r}")
    if not 0 < level < 1:
        raise ValueError(f"level must be between 0 and 1, got {level!r}")
    problem = res.problem
    model = problem.model
    first = skipped_samples(problem)
    exps = problem.experiments
    # each output's series is its observed samples (a record with gaps or events' rows)
    seen = [e.seen[first:] for e in exps]
    N = tested_samples(exps, first)
    if max_lag > lag_limit(N):
        fix = (
            f"give max_lag (--residual-lags) {lag_limit(N)} or fewer"
            if lag_limit(N)
            else "they need at least 4 samples"
        )
        missing = (
            f"not available: {max_lag} lags on {N} samples (the test statistic is χ² only "
            f"for lags well below N; at most N/4); {fix}"
        )
        return ResidualTests(level, max_lag, N, np.nan, [], [], [], missing)
    errors = [a[first:] for a in _errors(res)]
    inputs = [e.u[first:] for e in exps]
    constant = [
        name for i, name in enumerate(model.inputs) if all(np.ptp(u[:, i]) == 0 for u in inputs)
    ]
    collapsed = collapsed_outputs(res)
    white, indep = [], []
    q_white = quantiles.chi2(max_lag, level)
    q_cross = quantiles.chi2(max_lag + 1, level)
    lags = np.arange(max_lag + 1)
    for j, out in enumerate(model.outputs):
        rows = [k[:, j] for k in seen]
        err = [a[k, j] for a, k in zip(errors, rows, strict=True)]
        Nj = sum(a.size for a in err)
        if not Nj:  # measured nowhere: no series, no test (Problem warned of it)
            continue
        why: str | None = _floor_reason(out, collapsed[out]) if out in collapsed else swamped(err)
        r = _correlation(err, err, max_lag)
        Q = float(Nj * np.sum(r[1:] ** 2))
        verdict = None if why else bool(Q <= q_white)
        tested = f"{out}'s innovations" if problem.loss.likelihood else out  # what was tested
        white.append(Correlation(f"whiteness of {tested}", lags, r, Q, q_white, verdict, None, why))
        for i, name in enumerate(model.inputs):
            if name in constant:
                continue
            u = [a[k, i] for a, k in zip(inputs, rows, strict=True)]
            c = _correlation(err, u, max_lag)
            Qc = float(Nj * np.sum(c**2))
            back = _correlation(u, err, max_lag)[1:]  # Σ e[k] u[k + τ]: later inputs
            what = f"{out} against input {name}"
            verdict = None if why else bool(Qc <= q_cross)
            indep.append(Correlation(what, lags, c, Qc, q_cross, verdict, back, why))
    bound = float(quantiles.normal(0.5 + level / 2) / np.sqrt(N))
    return ResidualTests(level, max_lag, N, bound, white, indep, constant)


def _errors(res) -> list[np.ndarray]:
    """Per record (P, S): a filter's standardised innovations, or the output error's
    residuals y − ŷ."""
    problem = res.problem
    if problem.loss.likelihood:
        return [np.asarray(o.innovations) for o in problem.predict(res.theta)]
    sims = res.simulate()  # (a sample not observed: its y is 0, not a measurement)
    return [e.measured - s.y for e, s in zip(problem.experiments, sims, strict=True)]


def swamped(series: list[np.ndarray]) -> str | None:
    """Why a residual series (one per record) cannot carry a correlation test, or None:
    not finite, constant, or swamped by a few samples (the largest 1 %, at least one,
    holding more than ``SWAMPED`` of the sum of squares about each record's mean)."""
    x = np.concatenate([a - a.mean() if np.isfinite(a).all() else a for a in series])
    if not np.isfinite(x).all():
        return f"{int((~np.isfinite(x)).sum())} of its {x.size} values are not finite"
    top = np.abs(x).max()
    if not top > 0:
        return "the series is constant: there is nothing to correlate (Q = 0 is no test)"
    ss = np.sort((x / top) ** 2)  # scaled: a value of 1e200 must not overflow
    few = max(1, int(np.ceil(0.01 * x.size)))
    shares = np.cumsum(ss[::-1][:few]) / ss.sum()
    if shares[-1] <= SWAMPED:
        return None
    k = int(np.argmax(shares > SWAMPED))  # the fewest samples holding that much
    median = float(np.median(np.abs(x)))
    which = "largest sample holds" if k == 0 else f"{k + 1} largest samples hold"
    return (
        f"the series is swamped: its {which} {shares[k]:.0%} of its sum of squares "
        f"(|value| up to {top:.3g} against a median of {median:.3g}), so every r(τ) "
        "measures those samples alone and Q is no test of the rest; find what makes them "
        "(an outlier in the record, a start the model cannot follow) and fit again"
    )


def _floor_reason(output: str, sigma: float) -> str:
    return (
        f"the measurement noise σ_e({output}) = {sigma:.2g} sits at its floor: the filter "
        f"follows {output} exactly, so its innovations carry the sensor's noise twice (this "
        "sample's, and the last one's through the state) and are coloured whatever the "
        "model; the fit sits in a corner of the likelihood, not at a noise model this test "
        f"could check. Fix σ_e at the sensor's noise (--fix log_sigma_e_{output}=log σ, "
        "fixed= in Python) and fit again"
    )


def skipped_samples(problem) -> int:
    """How many samples at the start of each record the likelihood leaves out: one for
    a filter with estimated initial states (tensorid.engine.sweeps, Sweeps._march),
    else none."""
    return 1 if problem.loss.likelihood and len(problem.free_x0) else 0


DEFAULT_LAGS = 25  # MATLAB resid's


def default_lags(problem) -> int:
    """The lags the tests take unless told: MATLAB's 25, fewer on a short record (at
    most N/4, at least 1: below 4 samples the tests say not available); N is
    :func:`tested_samples`."""
    samples = tested_samples(problem.experiments, skipped_samples(problem))
    return max(min(DEFAULT_LAGS, lag_limit(samples)), 1)


def tested_samples(experiments, first: int = 0) -> int:
    """N of the residual tests: the measured samples (not a gap, nor a row holding
    only a dose) of the output measured least often, over the records, after each
    record's first ``first`` samples (outputs sampled at different times are each
    their own series; an output measured nowhere has none)."""
    S = experiments[0].seen.shape[1]
    counts = [int(sum(e.seen[first:, j].sum() for e in experiments)) for j in range(S)]
    return min([n for n in counts if n] or [0])  # an output measured nowhere is not tested


def lag_limit(samples: int) -> int:
    """The most lags the residual tests take on ``samples`` samples: N/4 (Q is χ² only
    for M well below N)."""
    return samples // 4


def residual_count(problem) -> int:
    """n: the weighted residuals, samples times the outputs that carry weight; a
    filter with estimated initial states leaves each record's first sample out of its
    likelihood (:func:`skipped_samples`)."""
    first = skipped_samples(problem)
    weighted = problem.weights > 0
    return sum(
        (e.P - first) * int(weighted.sum()) if e.observed is None
        else int(e.observed[first:, weighted].sum())  # a record with gaps: what was measured
        for e in problem.experiments
    )  # fmt: skip


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
