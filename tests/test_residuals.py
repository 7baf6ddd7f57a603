"""Residual analysis (MATLAB's resid) and information criteria: a correct model on
white-noise data passes at the stated level, a model missing a dynamic fails, and AIC
and BIC prefer the right structure."""

from __future__ import annotations

import json
import re
from pathlib import Path

import jax.numpy as jnp
import numpy as np
import pytest

import tensorid as ti
from tensorid import cli

SECOND = ti.Model(
    rhs=lambda x, p, u: jnp.stack([x[1], -p[0] * x[0] - p[1] * x[1] + p[2] * u[0]]),
    states=["x", "v"], params=["k", "c", "g"], inputs=["u"],
    output=lambda x, p: x[:1], outputs=["y"], name="second-order",
)  # fmt: skip
FIRST = ti.Model(
    rhs=lambda x, p, u: -p[0] * x + p[1] * u[0], states=["x"], params=["a", "b"],
    inputs=["u"], output=lambda x, p: x, outputs=["y"], name="first-order",
)  # fmt: skip
T = np.arange(600) * 0.05


def _record(seed: int) -> ti.Experiment:
    rng = np.random.default_rng(seed)
    u = rng.standard_normal(T.size)
    y = ti.simulate(SECOND, {"k": 4.0, "c": 0.8, "g": 1.0}, [0, 0], ti.Experiment(T, u)).y
    return ti.Experiment(T, u, y + 0.01 * rng.standard_normal(y.shape))


@pytest.mark.slow  # compile-bound; keeps the default run under five minutes
def test_a_correct_model_is_white_and_a_missing_dynamic_is_not():
    seeds = range(20)
    white = missing = 0
    for seed in seeds:
        e = _record(seed)
        right = ti.fit(ti.Problem(SECOND, e, p0={"k": 3.0, "c": 0.5, "g": 1.2}))
        tests = right.residual_tests()
        white += tests.whiteness[0].passed and tests.independence[0].passed
        wrong = ti.fit(ti.Problem(FIRST, e, p0={"a": 1.0, "b": 1.0}))
        missing += not wrong.residual_tests().whiteness[0].passed
        if seed == 0:
            assert right.criteria()["aic"] < wrong.criteria()["aic"]
            assert right.criteria()["bic"] < wrong.criteria()["bic"]
    assert white / len(seeds) >= 0.9
    assert missing == len(seeds)


def test_the_statistics_are_those_of_the_textbook():
    e = _record(1)
    res = ti.fit(ti.Problem(SECOND, e, p0={"k": 3.0, "c": 0.5, "g": 1.2}))
    tests = res.residual_tests(max_lag=10, level=0.95)
    err = (e.y - res.simulate()[0].y)[:, 0]
    err = err - err.mean()
    r = np.array([err[k:] @ err[: err.size - k] for k in range(11)]) / (err @ err)
    np.testing.assert_allclose(tests.whiteness[0].values, r, rtol=1e-10)
    assert tests.whiteness[0].statistic == pytest.approx(600 * np.sum(r[1:] ** 2))
    assert tests.bound == pytest.approx(1.959964 / np.sqrt(600), rel=1e-6)
    # the negative lags: the residual against later inputs (feedback), shown, not tested
    u = e.u[:, 0] - e.u[:, 0].mean()
    back = np.array([err[: err.size - k] @ u[k:] for k in range(1, 11)])
    back /= np.sqrt((err @ err) * (u @ u))
    indep = tests.independence[0]
    np.testing.assert_allclose(indep.feedback, back, rtol=1e-10, atol=1e-15)
    saved = tests.as_dict()["independence"][0]
    assert saved["correlation_negative_lags"] == indep.feedback.tolist()
    assert "at negative lags (feedback)" in indep.line()
    c = res.criteria()
    J, n, K = res.cost, 600, 3
    assert c["aic"] == pytest.approx(n * (np.log(2 * np.pi * J / n) + 1) + 2 * K)
    assert c["bic"] == pytest.approx(n * (np.log(2 * np.pi * J / n) + 1) + K * np.log(n))
    with pytest.raises(ValueError, match="max_lag"):
        res.residual_tests(max_lag=0)
    # more lags than a quarter of the samples: no verdict, a reason instead
    assert res.residual_tests(max_lag=150).not_available is None
    many = res.residual_tests(max_lag=10000)
    assert many.passed is None and not many.whiteness and many.figure() is None
    assert many.lines() == [f"tests {many.not_available}"]
    assert "10000 lags on 600 samples" in many.not_available and "150 or fewer" in many.lines()[0]


def test_a_record_with_gaps_is_tested_and_drawn_on_its_measured_samples():
    """A sample not measured holds y = 0, not a measurement: its "residual" −ŷ had
    entered the tests (the right model's input correlation failed, Q = 337 on a
    record whose every third sample was missing) and the figure (a line to 0). The
    tests and the figure now take each output's measured samples."""
    from tensorid.analysis.figures import compare_figure, figure_jobs

    e = _record(3)
    seen = np.ones((T.size, 1), dtype=bool)
    seen[::3] = False
    data = ti.Experiment(T, e.u, e.y, observed=seen)
    res = ti.fit(ti.Problem(SECOND, data, p0={"k": 3.0, "c": 0.5, "g": 1.2}))
    tests = res.residual_tests(max_lag=10)
    assert tests.samples == seen.sum() and tests.passed
    err = (data.y - res.simulate()[0].y)[seen[:, 0], 0]
    err = err - err.mean()
    r = np.array([err[k:] @ err[: err.size - k] for k in range(11)]) / (err @ err)
    np.testing.assert_allclose(tests.whiteness[0].values, r, rtol=1e-10)
    assert tests.whiteness[0].statistic == pytest.approx(seen.sum() * np.sum(r[1:] ** 2))
    [job] = [j for j in figure_jobs(res, convergence=False) if j[1] == "compare"]
    assert np.isnan(job[2]["y_meas"][~seen[:, 0]]).all()
    fig = compare_figure(**job[2])
    measured, residual = fig.axes[0].lines[0], fig.axes[1].lines[0]
    assert measured.get_xdata().size == residual.get_xdata().size == seen.sum()


def test_the_sandwich_of_a_record_with_gaps_counts_its_measured_samples():
    """The robust error bars' scores are those of the samples that hold a measurement:
    a gap's row (score 0) had counted in n and spread the Newey-West lags across it."""
    from tensorid.analysis.sandwich import score_covariance, scores

    e = _record(4)
    seen = np.ones((T.size, 1), dtype=bool)
    seen[::3] = False
    data = ti.Experiment(T, e.u, e.y, observed=seen)
    pb = ti.Problem(SECOND, data, p0={"k": 4.0, "c": 0.8, "g": 1.0})
    theta = pb.theta0
    [s] = scores(pb, theta)
    assert not s[~seen[:, 0]].any()  # (0 where nothing was measured)
    kept, n, K = s[seen[:, 0]], int(seen.sum()), pb.K
    B, _ = score_covariance(pb, theta, 0)
    np.testing.assert_allclose(B, kept.T @ kept * n / (n - K), rtol=1e-12)
    B2, L = score_covariance(pb, theta, 2)
    nw = kept.T @ kept
    for lag in (1, 2):
        G = kept[lag:].T @ kept[:-lag]
        nw += (1 - lag / 3) * (G + G.T)
    assert L == 2
    np.testing.assert_allclose(B2, nw * n / (n - K), rtol=1e-12)


def test_feedback_shows_at_negative_lags_only():
    from tensorid.analysis.residuals import _correlation

    rng = np.random.default_rng(0)
    e = rng.standard_normal(2000)
    u = np.roll(e, 2) + 0.1 * rng.standard_normal(2000)  # u[k] = e[k-2]: a loop closed
    ahead, back = _correlation([e], [u], 5), _correlation([u], [e], 5)
    assert np.abs(ahead).max() < 0.1 and back[2] > 0.9  # at lag -2, not at +2


def test_the_command_line_reports_the_tests(tmp_path, capsys):
    example = Path(__file__).resolve().parents[1] / "examples" / "silverbox"
    out = tmp_path / "fit"
    args = ["fit", str(example / "model.py"), str(example / "train.csv"), "--out", str(out)]
    assert cli.main(args + ["--no-progress", "--residual-lags", "10"]) == 0
    data = json.loads((out / "fit.json").read_text())
    assert data["residual_tests"]["max_lag"] == 10 and len(data["residual_tests"]["whiteness"]) == 1
    assert {"aic", "aicc", "bic"} <= set(data)
    report = (out / "report.md").read_text()
    assert "## Residual analysis" in report and "whiteness of y" in report
    assert (out / "residual_tests.png").is_file()
    assert "residuals: whiteness of y" in capsys.readouterr().out


def test_an_input_constant_on_every_record_is_not_tested():
    # EMPS' estimation record holds the force pulses' input at zero: a correlation
    # with it is 0/0, and a "passes" would be a verdict without a test
    rng = np.random.default_rng(3)
    u = np.stack([rng.standard_normal(T.size), np.zeros(T.size)], axis=1)
    model = ti.Model(
        rhs=lambda x, p, u: -p[0] * x + p[1] * u[0] + u[1], states=["x"], params=["a", "b"],
        inputs=["u", "pulses"], output=lambda x, p: x, outputs=["y"],
    )  # fmt: skip
    y = ti.simulate(model, {"a": 2.0, "b": 1.0}, [0.0], ti.Experiment(T, u)).y
    res = ti.fit(ti.Problem(model, ti.Experiment(T, u, y), p0={"a": 1.0, "b": 2.0}))
    tests = res.residual_tests()
    assert [c.what for c in tests.independence] == ["y against input u"]
    assert tests.constant_inputs == ["pulses"] and tests.as_dict()["constant_inputs"] == ["pulses"]
    assert "input pulses: not tested" in tests.lines()[-1]


def _short(P: int) -> ti.FitResult:
    e = _record(5)
    return ti.fit(ti.Problem(FIRST, ti.Experiment(T[:P], e.u[:P], e.y[:P]), p0={"a": 1, "b": 1}))


def test_a_record_too_short_for_its_statistics_says_not_available(tmp_path):
    res = _short(2)  # 2 samples for 2 unknowns: no residual variance
    u = res.uncertainty()
    assert (
        u.not_available == "not available: 2 samples for 2 unknowns (error bars: at least 3 needed)"
    )
    assert np.isnan(u.stderr).all() and np.isnan(u.ci95).all() and np.isnan(u.sigma2)
    assert f"error bars {u.not_available}" in res.warnings
    c = res.criteria()
    assert np.isnan([c["aic"], c["aicc"], c["bic"]]).all()
    assert c["not_available"].startswith("not available: 2 samples for 2 unknowns")
    text = res.summary()
    assert "AIC, AICc, BIC not available: 2 samples" in text and "nan" not in text
    with pytest.raises(ValueError, match="profiles need the residual variance.*not available"):
        res.profile("a")
    three = _short(3).criteria()  # AIC and BIC, but AICc divides by n - K - 1 = 0
    assert np.isfinite([three["aic"], three["bic"]]).all() and np.isnan(three["aicc"])
    assert "(AICc: at least 4 needed)" in three["not_available"]


def test_the_command_line_writes_null_and_the_reason(tmp_path, capsys):
    e = _record(5)
    rows = "".join(f"{t},{u},{y}\n" for t, u, y in zip(T, e.u[:, 0], e.y[:, 0], strict=True))
    (tmp_path / "d.csv").write_text("t,u,y\n" + rows)
    (tmp_path / "m.py").write_text(
        'rhs = {"x": "-a*x + b*u"}\noutput = {"y": "x"}\ninputs = ["u"]\nparams = ["a", "b"]\n'
        'p0 = {"a": 1.0, "b": 1.0}\n'
    )
    out = tmp_path / "fit"
    args = ["fit", str(tmp_path / "m.py"), str(tmp_path / "d.csv"), "--out", str(out)]
    assert cli.main(args + ["--no-progress", "--samples", "0:2"]) == 0
    data = json.loads((out / "fit.json").read_text())
    assert data["stderr"] == {"a": None, "b": None} and data["residual_variance"] is None
    assert data["stderr_not_available"].startswith("not available: 2 samples for 2 unknowns")
    assert data["aic"] is None and "2 samples" in data["criteria_not_available"]
    assert data["residual_tests"]["not_available"].startswith("not available: 1 lags on 2")
    report = (out / "report.md").read_text()
    assert "AIC, AICc, BIC not available" in report
    assert not re.search(r"\bnan\b", report)  # a word: "Provenance" holds the letters
    assert "residuals: tests not available" in capsys.readouterr().out
    assert not (out / "residual_tests.png").exists()
    # asked for more lags than the record supports: refused before any work
    assert cli.main(args + ["--no-progress", "--residual-lags", "151"]) == 2
    err = capsys.readouterr().err
    assert "--residual-lags 151: the training records have 600 measured samples" in err


# -- verdicts the series cannot carry (issue 40, item 2) ---------------------------------


def test_a_series_swamped_by_a_few_samples_cannot_pass():
    """One outlier of 1e3 among residuals of 0.01 holds all of Σe²: r(τ) ≈ 0 at every
    lag and Q ≈ 0 "passed" whatever the rest did. Now no verdict, and why."""
    from tensorid.analysis.residuals import swamped

    rng = np.random.default_rng(0)
    white = rng.standard_normal(1000)
    assert swamped([white]) is None and swamped([white[:500], white[500:]]) is None
    heavy = rng.standard_t(3, 1000)  # heavy tails are not swamping
    assert swamped([heavy]) is None
    spiked = white.copy()
    spiked[0] = -1e37  # the tanks filter's first innovation
    assert "largest sample holds 100%" in swamped([spiked])
    assert "constant" in swamped([np.zeros(50)])
    assert "not finite" in swamped([np.array([1.0, np.inf, 2.0])])
    # through a fit: a record with one wild sample
    e = _record(2)
    y = e.y.copy()
    y[300] += 1e3
    res = ti.fit(ti.Problem(SECOND, ti.Experiment(T, e.u, y), p0={"k": 3.0, "c": 0.5, "g": 1.2}))
    tests = res.residual_tests(10)
    white_y = tests.whiteness[0]
    assert white_y.statistic < 1.0 and white_y.passed is None  # was: passes, Q = 0.0
    assert tests.passed is None and tests.not_shown_white
    assert all(c.passed is None for c in tests.independence)
    assert "cannot be trusted (Q = " in white_y.line() and "swamped" in white_y.line()
    saved = tests.as_dict()["whiteness"][0]
    assert saved["passed"] is None and saved["trusted"] is False and "swamped" in saved["untrusted"]
    assert "cannot be trusted" in str(tests)
    tests.figure()  # draws a verdict of None


@pytest.mark.slow  # a whole filter fit to its σ_e floor (10 s cold)
def test_a_filter_s_tests_leave_out_the_sample_its_likelihood_leaves_out():
    """The two-tank record by a filter with process noise on the lower tank: σ_e went
    to 3.5e-10 and the first standardised innovation, left out of the likelihood but
    not of the tests, was 1.5e8: "passes, Q = 0.0". The tests now use samples 1..500,
    and σ_e at its floor makes the verdict "cannot be trusted", saying why."""
    from tensorid import benchmarks
    from tensorid.analysis.residuals import _correlation

    pr = benchmarks.two_tank_problem(
        predictor="ekf", process_noise={"x2": 0.01}, free_x0=["x1", "x2"]
    )
    res = ti.fit(pr)
    assert res.params["log_sigma_e_y"] < -15  # the floor this test is about
    innov = pr.predict(res.theta)[0].innovations[:, 0]
    assert abs(innov[0]) > 1e6  # what swamped the statistic
    tests = res.residual_tests(25)
    assert tests.samples == 500
    r = _correlation([innov[1:]], [innov[1:]], 25)
    np.testing.assert_allclose(tests.whiteness[0].values, r, rtol=1e-12)
    white_y = tests.whiteness[0]
    assert white_y.statistic > white_y.threshold  # no longer 0.0
    # σ_e's value at its floor is rounding's (3.5e-10, or 3.3e-26 under other XLA flags)
    assert white_y.passed is None
    assert re.search(r"σ_e\(y\) = \S+ sits at its floor", white_y.untrusted)
    assert "--fix log_sigma_e_y=log σ" in white_y.untrusted
    lines = tests.lines()
    assert lines[1].endswith(": as whiteness of y's innovations")  # the reason once
    assert "passes" not in str(tests)


def test_the_default_lags_are_the_command_line_s_and_fit_outputs_sampled_apart():
    """y1 measured at 20 samples, y2 at the other 20: each series has 20 samples, so at
    most 5 lags. The default counted the 40 rows holding either (10 lags: "not
    available" at the command line's own default), and the API's was MATLAB's 25 on
    any record."""
    t = np.linspace(0, 10, 40)
    m = ti.Model(rhs=lambda x, p, u: -p[0] * x, output=lambda x, p: jnp.stack([x[0], 2 * x[0]]),
                 states=["a"], params=["k"], outputs=["y1", "y2"])  # fmt: skip
    noise = np.random.default_rng(1).standard_normal((40, 2)) * 0.01
    y = np.exp(-0.3 * t)[:, None] * [1.0, 2.0] + noise
    even = np.arange(40) % 2 == 0
    e = ti.Experiment(t, None, y, observed=np.stack([even, ~even], axis=1))
    res = ti.fit(ti.Problem(m, e, p0={"k": 0.2}, x0=[1.0]))
    tests = res.residual_tests()
    assert tests.not_available is None and tests.max_lag == 5
    assert res.residual_tests(5) is tests  # the same call, cached once
    assert "not available" in res.residual_tests(6).not_available
