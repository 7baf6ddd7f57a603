"""The model-error check (issue 40, item 4): separate parts of the record fitted alone,
their estimates compared with their robust error bars. A right model with coloured
noise (residuals not white, robust bars honest) must pass; a linear model of a
hardening spring driven by a growing input (its best linear stiffness changes along
the record) must fail, and the summary must then say that no error bar covers it."""

from __future__ import annotations

import re

import jax.numpy as jnp
import numpy as np
import pytest

import tensorid as ti
from tensorid.analysis.display import trust_advice

DUFFING = ti.Model(
    rhs=lambda x, p, u: jnp.stack(
        [x[1], -p[0] * x[0] - p[1] * x[1] - p[3] * x[0] ** 3 + p[2] * u[0]]
    ),
    states=["x", "v"], params=["k", "c", "g", "a"], inputs=["u"],
    output=lambda x, p: x[:1], outputs=["y"], name="duffing",
)  # fmt: skip
LINEAR = ti.Model(
    rhs=lambda x, p, u: jnp.stack([x[1], -p[0] * x[0] - p[1] * x[1] + p[2] * u[0]]),
    states=["x", "v"], params=["k", "c", "g"], inputs=["u"],
    output=lambda x, p: x[:1], outputs=["y"], name="linear",
)  # fmt: skip
T = np.arange(1000) * 0.05
TRUTH = {"k": 4.0, "c": 0.8, "g": 1.0, "a": 4.0}


def record(seed: int, ar: float = 0.8, sd: float = 0.01) -> ti.Experiment:
    """A growing random input; the output with AR(1) coloured noise."""
    rng = np.random.default_rng(seed)
    u = rng.standard_normal(T.size) * np.linspace(0.2, 4.0, T.size)
    y = ti.simulate(DUFFING, TRUTH, [0, 0], ti.Experiment(T, u)).y[:, 0]
    e, w = np.zeros(T.size), sd * rng.standard_normal(T.size)
    for k in range(1, T.size):
        e[k] = ar * e[k - 1] + w[k]
    return ti.Experiment(T, u, y + e)


def test_a_right_model_passes_and_a_wrong_one_fails():
    data = record(1)
    right = ti.fit(ti.Problem(DUFFING, data, p0={"k": 3.0, "c": 0.5, "g": 1.2, "a": 0.5}))
    assert right.residual_tests().not_shown_white  # coloured: the robust bars are offered
    check = right.model_check()
    assert check.passed is True and check.how == "halves" and check.dof == 4
    assert check.parts == ["samples 0-499", "samples 500-999"]
    assert check.statistic < check.threshold and not check.left_out
    # its time, beside the fit's own in fit.json (issue 50 item 2: counted nowhere)
    assert check.seconds > 0 and check.as_dict()["seconds"] == check.seconds
    text = right.summary()
    assert text.rstrip() == str(right) and "residuals: whiteness of y: FAILS" in text
    assert "model-error check: passes" in text
    assert "The model-error check passes: trust the robust ones" in text
    assert "robust std. error" in text  # beside the white ones
    wrong = ti.fit(ti.Problem(LINEAR, data, p0={"k": 3.0, "c": 0.5, "g": 1.2}))
    assert "They cover coloured noise, not a wrong model" in wrong.summary()  # not made yet
    check = wrong.model_check()
    assert check.passed is False and check.statistic > 3 * check.threshold
    assert check.spread()[0][0] == "k"  # the stiffness drifts with the amplitude
    text = wrong.summary()
    assert "model-error check: FAILS" in text and "do not cover the model's error" in text
    assert "trust the robust ones" not in text.lower()
    assert "interpolation" in text and "process noise" in text
    saved = check.as_dict()
    assert saved["passed"] is False and saved["names"] == ["k", "c", "g"]


def test_the_statistic_is_the_textbook_homogeneity_test():
    """Q = dᵀ (Σ_1 + Σ_2)⁻¹ d for two parts, whatever the units (a parameter in units
    a million times smaller gives the same Q)."""
    from tensorid.analysis.model_check import _compare

    rng = np.random.default_rng(0)
    A = rng.standard_normal((3, 3))
    c1, c2 = A @ A.T + np.eye(3), 0.5 * np.eye(3) + 0.1
    e1, e2 = np.array([1.0, 2.0, 3.0]), np.array([1.5, 1.0, 3.2])
    se = np.sqrt(np.array([np.diag(c1), np.diag(c2)]))
    chk = _compare(0.99, "halves", ["a", "b"], ["p", "q", "r"], [e1, e2], [c1, c2], se)
    d = e1 - e2
    assert chk.statistic == pytest.approx(d @ np.linalg.solve(c1 + c2, d), rel=1e-10)
    assert chk.dof == 3
    s = np.array([1.0, 1e-6, 1.0])  # q in other units
    scaled = _compare(0.99, "halves", ["a", "b"], ["p", "q", "r"], [e1 * s, e2 * s],
                      [c1 * np.outer(s, s), c2 * np.outer(s, s)], se * s)  # fmt: skip
    assert scaled.statistic == pytest.approx(chk.statistic, rel=1e-8)
    # a parameter one part cannot determine is left out, and named
    se_inf = se.copy()
    se_inf[1, 2] = np.inf
    part = _compare(0.99, "halves", ["a", "b"], ["p", "q", "r"], [e1, e2], [c1, c2], se_inf)
    assert part.left_out == ["r"] and part.names == ["p", "q"] and part.dof == 2
    assert "not compared (a part cannot determine them): r" in part.line()
    same = _compare(0.99, "halves", ["a", "b"], ["p", "q", "r"], [e1, e1], [c1, c2], se_inf)
    assert same.passed is True and same.statistic == pytest.approx(0.0, abs=1e-20)
    advice = trust_advice(same)
    assert "passes for p, q: trust their robust ones" in advice
    assert "r could not be checked" in advice


def test_given_records_are_the_parts_and_a_short_record_says_not_made():
    data = [record(2).window(0, 500, "a"), record(3).window(0, 500, "b")]
    res = ti.fit(ti.Problem(DUFFING, data, p0={"k": 3.0, "c": 0.5, "g": 1.2, "a": 0.5}))
    check = res.model_check()
    assert check.how == "records" and check.parts == ["record 'a'", "record 'b'"]
    assert check.passed is True
    short = ti.fit(ti.Problem(LINEAR, record(4).window(0, 30), p0={"k": 3.0, "c": 0.5, "g": 1}))
    none = short.model_check()
    assert none.passed is None and "halves (15 samples) are shorter than 20" in none.line()
    assert "could not be made" in trust_advice(none)


def test_a_filter_fit_at_its_sigma_e_floor_is_not_checked():
    """The two-tank filter whose σ_e went to its floor (3.5e-10): its halves' σ_e would be compared
    at their floors (±1e14 in one half); the check says why it is not made instead."""
    from tensorid import benchmarks

    pr = benchmarks.two_tank_problem(
        predictor="ekf", process_noise={"x2": 0.01}, free_x0=["x1", "x2"]
    )
    res = ti.fit(pr)
    check = res.model_check()
    # σ_e's value at its floor is rounding's (3.5e-10, or 3.3e-26 under other XLA flags)
    assert check.passed is None and re.search(r"σ_e\(y\) = \S+ sits at its floor", check.line())
    assert "could not be made (the measurement noise" in trust_advice(check)


def _runs(problem) -> set:
    """(program, argument shapes) of every compiled program the problem's sweeps have
    run in this process (the sweeps are shared by problems of one model)."""
    from tensorid.engine.compiling.programs import Program

    return {
        (id(prog), shapes)
        for prog in vars(problem._sweeps).values() if isinstance(prog, Program)
        for shapes in prog._runs
    }  # fmt: skip


def _new_lengths(check, res) -> set[int]:
    """The lengths of the 1-D arguments (t, θ, x0) of the programs ``check(res)`` ran
    that had not run before."""
    before = _runs(res.problem)
    check(res)
    new = {key for _, key in _runs(res.problem) - before}  # key: (tree, (shape, dtype)...)
    return {sh[0] for _, leaves in new for sh, _ in leaves if len(sh) == 1}


def _same_check(a, b) -> None:
    assert a.parts == b.parts and a.names == b.names and a.passed == b.passed
    np.testing.assert_allclose(a.estimates, b.estimates, rtol=1e-9, atol=0)
    np.testing.assert_allclose(a.stderr, b.stderr, rtol=1e-9, atol=0)
    assert a.statistic == pytest.approx(b.statistic, rel=1e-8)


def test_the_halves_run_the_fits_own_programs():
    """issue 50 item 2: each half is the record with the other samples masked, so the
    check's fits run the programs the fit compiled (61 samples), and give what fits
    of the halves' own length give. Unmasked, the halves of an odd record (0-29 and
    31-60, the middle one in neither) have one length, 30, not two."""
    from tensorid.analysis.model_check import model_check

    res = ti.fit(ti.Problem(LINEAR, record(5).window(0, 61), p0={"k": 3.0, "c": 0.5, "g": 1}))
    assert res.problem.masked
    checks = []
    assert not _new_lengths(lambda r: checks.append(model_check(r)), res) & {30, 31}
    assert checks[0].parts == ["samples 0-29", "samples 31-60"] and checks[0].passed is not None
    res.problem.masked = False  # the parts as records of their own length
    assert {30, 31} & _new_lengths(lambda r: checks.append(model_check(r)), res) == {30}
    _same_check(*checks)


def test_a_model_not_finite_on_the_masked_samples_is_fitted_as_on_the_half_alone(monkeypatch):
    """An unobserved sample adds nothing to J, ∇J, ∇²J or the scores, even where the
    model is not finite there (a zero weight times NaN would be NaN, and a fit would
    reject the step): a half's fit is the fit of the half alone. The padding's inputs
    are made so large here that RK4's stage sums overflow on it."""
    from tensorid.analysis import model_check as mc
    from tensorid.analysis.sandwich import scores

    res = ti.fit(ti.Problem(LINEAR, record(6).window(0, 80), p0={"k": 3.0, "c": 0.5, "g": 1}))
    padded = mc._padded

    def huge(rec, start, stop):
        e = padded(rec, start, stop)
        u = np.where(np.arange(rec.P)[:, None] < stop - start, e.u, 1.7e308)
        return ti.Experiment(e.t, u, e.y, observed=e.observed)

    monkeypatch.setattr(mc, "_padded", huge)
    [(_, part, theta, _), _] = list(mc._parts(res))
    assert not np.isfinite(part.simulate(theta)[0].y[40:]).all()
    J, g, H = part.cost_grad_hess(theta)
    assert np.isfinite(J) and np.isfinite(g).all() and np.isfinite(H).all()
    assert np.isfinite(part.residuals(theta)).all()
    [shares] = scores(part, theta)  # the error bars' per-sample scores: 0 where masked
    assert np.isfinite(shares).all() and not shares[40:].any()
    checks = []
    assert not _new_lengths(lambda r: checks.append(mc.model_check(r)), res) & {40}
    monkeypatch.undo()
    res.problem.masked = False
    _same_check(checks[0], mc.model_check(res))


def test_a_record_s_predictions_at_its_unobserved_samples_are_the_simulation():
    """The masked march keeps the accumulators at a row where nothing was observed,
    not the row's own outputs: a record with gaps predicts (one step, and k steps
    ahead, which start from those states) the simulation there, not 0."""
    e = record(7).window(0, 60)
    seen = np.ones((60, 1), dtype=bool)
    seen[10:15] = False
    data = ti.Experiment(e.t, e.u, e.y, observed=seen)
    pb = ti.Problem(LINEAR, data, p0={"k": 3.0, "c": 0.5, "g": 1.0})
    sim = pb.simulate(pb.theta0)[0].y[:, 0]
    for horizon in (1, 2):
        [pred] = pb.predict(pb.theta0, horizon=horizon)
        np.testing.assert_allclose(pred.predicted[:, 0], sim, rtol=1e-12, atol=1e-15)


def test_which_problems_pass_their_record_with_a_mask():
    """Problem.masked: one record, output error, single shooting, no events, inputs
    linear or held between samples (a smooth interpolation is fitted to the whole
    record, so a masked half would see other inputs than the half alone), and a
    Hessian path that opts in (a new path's sweep keeps y as it was)."""
    from tensorid.engine.sweeping.hessians import HessianPath, TransitionTensors

    class Opted(HessianPath):
        name = "opted-out"

        def sweep(self, sweeps, batched, threads_cap):
            return TransitionTensors().sweep(sweeps, batched, threads_cap)

    e = record(8).window(0, 80)
    p0 = {"k": 3.0, "c": 0.5, "g": 1.0}

    def masked(data=e, **kw) -> bool:
        return ti.Problem(LINEAR, data, p0=p0, **kw).masked

    assert masked() and masked(interpolation="zoh")
    assert not masked([e.window(0, 40), e.window(40, 80)])
    assert not masked(interpolation="cubic") and not masked(interpolation="bandlimited")
    assert not masked(hessian="adjoint") and not masked(segments=2)
    assert not masked(hessian=Opted())
    assert not masked(predictor="ekf", process_noise={"v": 0.1})
    pb = ti.Problem(LINEAR, e, p0=p0, hessian=Opted())
    assert not isinstance(pb.arrays[0][2], dict)


def test_halves_of_one_repeated_excitation_cannot_pass_a_wrong_model():
    """issue 51 item 6: two periods of one multisine carry the same model error, so the
    halves agree (Q = 0) although the model is wrong; the console said "passes: trust
    the robust ones" while the input correlation failed. Now it names the limitation,
    and the failing input test as the model error it is."""
    from test_constraints import MODEL

    truth = ti.Model(lambda x, p, u: jnp.stack([-p[0] * x[0] - 3.0 * x[0] ** 3 + p[1] * u[0]]),
                     output=lambda x, p: x[:1], states=["x"], params=["a", "b"],
                     inputs=["u"], outputs=["y"])  # fmt: skip
    P, rng = 200, np.random.default_rng(0)
    t = np.arange(2 * P) * 0.05
    phases = rng.uniform(0, 2 * np.pi, 8)
    period = sum(np.cos(2 * np.pi * k * np.arange(P) / P + phases[k - 1]) for k in range(1, 9))
    u = np.tile(period, 2) / 3
    y = ti.simulate(truth, {"a": 1.0, "b": 2.0}, [0.0], ti.Experiment(t, u)).y
    y = y + 0.01 * rng.standard_normal(y.shape)
    res = ti.fit(ti.Problem(MODEL, ti.Experiment(t, u, y), p0={"a": 0.5, "b": 0.5}, x0=[0.0]))
    check, tests = res.model_check(), res.residual_tests()
    assert check.passed and check.repeated and "its parts repeat one excitation" in check.line()
    assert tests.independence[0].passed is False
    advice = trust_advice(check, tests)
    assert advice.startswith("The model-error check cannot see model error here")
    assert "y against input u FAILS" in advice and "Trust neither" in advice
    assert "trust the robust ones" not in advice


def _two_outputs(log):
    """LINEAR with a second output, log x (NaN where x < 0), or a log that is finite
    everywhere and the same where x > 0 (|x| + 1e-300 is x there, bit for bit)."""
    return ti.Model(
        rhs=LINEAR.f, states=["x", "v"], params=["k", "c", "g"], inputs=["u"],
        output=lambda x, p: jnp.stack([x[0], log(x[0])]), outputs=["y", "log y"],
        name="linear-log",
    )  # fmt: skip


def test_an_output_not_observed_in_a_row_adds_nothing_where_another_is_observed():
    """Skipping is per output, not per row: in a row where y is measured and log y is
    not (the oscillator is below 0 there), log y's NaN prediction adds nothing to J,
    ∇J, ∇²J, the Gauss-Newton part, the residuals or the scores (a zero weight times
    NaN was NaN, and the fit rejected every step)."""
    from tensorid.analysis.sandwich import scores

    e = record(9).window(0, 200)
    x = ti.simulate(LINEAR, {"k": 4.0, "c": 0.8, "g": 1.0}, [0.3, 0.0], e).y[:, 0]
    seen = np.stack([np.ones(e.P, bool), x > 0.05], axis=1)
    assert 20 < (~seen[:, 1]).sum() < e.P - 20
    noise = 0.01 * np.random.default_rng(3).standard_normal((e.P, 2))
    y = np.stack([x, np.log(np.abs(x))], axis=1) + noise
    data = ti.Experiment(e.t, e.u, y, observed=seen)
    p0 = {"k": 3.8, "c": 0.7, "g": 1.1}
    nan, safe = (ti.Problem(_two_outputs(f), data, p0=p0, x0=[0.3, 0.0])
                 for f in (jnp.log, lambda v: jnp.log(jnp.abs(v) + 1e-300)))  # fmt: skip
    theta = nan.theta0
    log_y = nan.simulate(theta)[0].y[:, 1]  # the model's own: NaN where x < 0
    assert np.isnan(log_y[~seen[:, 1]]).sum() > 20 and np.isfinite(log_y[seen[:, 1]]).all()
    for a, b in zip(nan.cost_grad_hess_gn(theta), safe.cost_grad_hess_gn(theta), strict=True):
        np.testing.assert_allclose(a, b, rtol=1e-12)
    for a, b in zip(nan.cost_grad_gn(theta), safe.cost_grad_gn(theta), strict=True):
        np.testing.assert_allclose(a, b, rtol=1e-12)
    np.testing.assert_allclose(nan.cost(theta), safe.cost(theta), rtol=1e-12)
    np.testing.assert_allclose(nan.residuals(theta), safe.residuals(theta), rtol=1e-12)
    np.testing.assert_allclose(scores(nan, theta)[0], scores(safe, theta)[0], rtol=1e-12)
    fits = [ti.fit(pb) for pb in (nan, safe)]
    assert fits[0].success and np.isfinite(fits[0].cost)
    np.testing.assert_allclose(fits[0].theta, fits[1].theta, rtol=1e-8)
