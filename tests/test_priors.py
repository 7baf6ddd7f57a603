"""Priors (MAP estimation): exact derivatives with the prior's terms, the analytic
posterior mean of a linear model, the summary naming what the prior determines, and
the observed/expected information comparison."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import SILVERBOX_P, autodiff, silverbox_data, silverbox_model

import tensorid as ti

LINEAR = ti.Model(
    rhs=lambda x, p, u: p[0] * u[0] + p[1] * u[1] + 0 * x, states=["x"], params=["a", "b"],
    inputs=["u", "v"], output=lambda x, p: x, outputs=["y"], name="linear",
)  # fmt: skip


def _linear_record(noise=0.05, seed=0, n=40):
    t = np.linspace(0, 2, n)
    u = np.stack([np.cos(3 * t), np.sin(5 * t)], 1)
    y = ti.simulate(LINEAR, {"a": 2.0, "b": -1.0}, [0.0], ti.Experiment(t, u)).y[:, 0]
    return ti.Experiment(t, u, y + noise * np.random.default_rng(seed).standard_normal(t.size))


@pytest.mark.slow  # 7 s of jax.hessian compilation
def test_derivatives_with_priors_equal_autodiff():
    e = silverbox_data(P=48, noise=1e-4)
    priors = {"a": (1.0, 0.05), "d": (2e-4, 1e-5)}
    prob = ti.Problem(silverbox_model(), e, p0=SILVERBOX_P, free_x0=["y"], priors=priors)
    theta = prob.theta0 * 1.01
    J, g, H = prob.cost_grad_hess(theta)
    J_ad, g_ad, H_ad = autodiff(prob.jax_cost)(theta)
    assert J == pytest.approx(J_ad, rel=1e-12)
    np.testing.assert_allclose(g, g_ad, rtol=1e-9, atol=1e-12 * abs(g).max())
    np.testing.assert_allclose(H, H_ad, rtol=1e-9, atol=1e-9 * abs(H_ad).max())
    v = np.linspace(1, 2, prob.K)
    np.testing.assert_allclose(prob.cost_grad_hessp(theta, v)[2], H @ v, rtol=1e-9)
    _, g_gn, _ = prob.cost_grad_gn(theta)
    np.testing.assert_allclose(g_gn, g, rtol=1e-10)
    assert prob.cost(theta) == pytest.approx(J, rel=1e-12)


def test_map_of_a_linear_model_is_the_analytic_posterior_mean():
    e = _linear_record()
    prior = {"a": (1.5, 0.1)}
    prob = ti.Problem(LINEAR, e, p0={"a": 1.0, "b": 0.0}, priors=prior, noise=0.05)
    res = ti.fit(prob)
    # y = a·∫cos + b·∫sin, integrated as the problem integrates it: the regressors
    # are the simulated outputs for unit parameters
    phi = np.stack(
        [ti.simulate(LINEAR, p, [0.0], e).y[:, 0] for p in ({"a": 1, "b": 0}, {"a": 0, "b": 1})], 1
    )
    A = phi.T @ phi + np.diag([0.05**2 / 0.1**2, 0.0])
    rhs = phi.T @ e.y[:, 0] + np.array([0.05**2 * 1.5 / 0.1**2, 0.0])
    np.testing.assert_allclose(res.theta, np.linalg.solve(A, rhs), rtol=1e-8)


def test_the_summary_names_what_the_prior_not_the_data_determines():
    e = _linear_record()
    strong = ti.fit(ti.Problem(LINEAR, e, p0={"a": 1.0, "b": 0.0}, priors={"a": (1.5, 1e-4)}))
    assert strong.params["a"] == pytest.approx(1.5, abs=1e-3)
    assert any("a is determined more by its prior" in w for w in strong.warnings)
    assert "determined more by its prior" in strong.summary()
    plain = ti.fit(ti.Problem(LINEAR, e, p0={"a": 1.0, "b": 0.0}))
    weak = ti.fit(ti.Problem(LINEAR, e, p0={"a": 1.0, "b": 0.0}, priors={"a": (1.5, 100.0)}))
    assert weak.params["a"] == pytest.approx(plain.params["a"], rel=1e-5)
    assert not any("prior" in w for w in weak.warnings)


def test_the_noise_that_weighs_priors_is_estimated_from_the_data():
    e = _linear_record(noise=0.05, seed=3, n=400)  # sampled finely: the premise holds
    prob = ti.Problem(LINEAR, e, p0={"a": 1.0, "b": 0.0}, priors={"a": (1.5, 0.1)})
    assert prob.noise_variance == pytest.approx(0.05**2, rel=0.15)


@pytest.mark.parametrize(
    "priors, noise, match",
    [
        ({"c": (1, 1)}, None, "not a parameter"),
        ({"a": (1, 0)}, None, "sd > 0"),
        ({"a": 1.0}, None, r"\(mean, sd\)"),
        ({"a": (1, 1)}, -1.0, "noise"),
        (None, 0.1, "only used with priors"),
    ],
)
def test_bad_priors(priors, noise, match):
    with pytest.raises(ValueError, match=match):
        ti.Problem(LINEAR, _linear_record(), p0={"a": 1.0, "b": 0.0}, priors=priors, noise=noise)


def test_observed_and_expected_information_side_by_side():
    e = silverbox_data(P=128, noise=1e-3)
    res = ti.fit(ti.Problem(silverbox_model(), e, p0=SILVERBOX_P))
    info = res.information()
    np.testing.assert_allclose(info.stderr_observed, res.uncertainty().stderr)
    np.testing.assert_allclose(info.stderr_expected, res.uncertainty("gauss-newton").stderr)
    assert 1 <= info.condition_observed < np.inf and 1 <= info.condition_expected < np.inf
    assert max(abs(c) for c in info.weakest.values()) == pytest.approx(1.0)
    text = info.describe()
    assert "condition number" in text and "least determined direction" in text
    assert set(info.as_dict()) >= {"stderr_observed", "stderr_expected", "weakest_direction"}


# -- the noise level that weighs the priors, and what the priors moved ---------------------
# the README's oscillator is the Silverbox's structure (m ÿ + d ẏ + a y + b y³ = u)
OSCILLATOR = silverbox_model(name="oscillator")


def _readme_oscillator(priors=None, noise=None):
    """The README's own example (1,000 samples at 1 kHz, noise sd 1e-4): 40-80 samples
    per period of its inputs, too coarse for the second-difference noise estimate."""
    model = OSCILLATOR
    return ti.Problem(
        model, _oscillator_record(1e-3, 0), p0={"m": 1.2e-4, "d": 1.8e-3, "a": 0.9, "b": 3.0},
        x0=[0.0, 0.0], free_x0=["v"], bounds={"m": (1e-6, 1e-2)}, priors=priors, noise=noise,
    )  # fmt: skip


def _oscillator_record(dt: float, seed: int) -> ti.Experiment:
    """1,000 samples (one compilation for every record) every ``dt`` s, noise sd 1e-4."""
    t = np.arange(1000) * dt
    u = 0.5 * np.sin(2 * np.pi * 12 * t) + 0.3 * np.sin(2 * np.pi * 23 * t)
    truth = {"m": 1e-4, "d": 2e-3, "a": 1.0, "b": 4.0}
    y = ti.simulate(OSCILLATOR, truth, [0.0, 0.0], ti.Experiment(t, u)).y
    return ti.Experiment(t, u, y + 1e-4 * np.random.default_rng(seed).standard_normal(y.shape))


def test_the_readme_example_with_a_prior_gets_the_answer_of_the_true_noise():
    prior = {"b": (3.5, 0.01)}
    prob = _readme_oscillator(prior)
    assert prob.noise_variance == pytest.approx(1.77e-5, rel=0.01)  # 1,770x the truth
    res = ti.fit(prob)
    given = ti.fit(_readme_oscillator(prior, noise=1e-4))
    alone = ti.fit(_readme_oscillator())
    se_b = alone.uncertainty().stderr[-1]  # b's standard error from the data alone
    assert abs(res.params["b"] - given.params["b"]) < 2 * se_b  # was 0.11 = 880 se_b
    check = res.noise_check
    assert check.source == "second differences" and check.agree and 1 <= check.refits <= 6
    assert res.problem.noise_variance == pytest.approx(1e-8, rel=0.15)
    assert prob.noise_variance == pytest.approx(1.77e-5, rel=0.01)  # the caller's, untouched
    line = next(w for w in res.warnings if w.startswith("priors:"))
    assert "1.77e-05" in line and f"{check.residual:.3g}" in line and "noise=" in line
    assert "empirical Bayes" in line and "lag-1 correlation 0.98" in line
    # the data-only answer that the report compares with is the prior-free fit
    (move,) = res.prior_moves()
    assert move["data_only"] == pytest.approx(alone.params["b"], abs=0.01 * se_b)
    assert move["data_stderr"] == pytest.approx(se_b, rel=0.01) and not move["moved"]
    # a noise level given is the user's word: kept, and the check agrees with it
    assert given.noise_check.source == "given" and given.noise_check.refits == 0
    assert not any(w.startswith("priors:") for w in given.warnings)


@pytest.mark.parametrize("dt", [1e-3, 1e-4], ids=["coarse-1kHz", "fine-10kHz"])
def test_the_rule_keeps_map_estimates_within_their_intervals_of_the_true_noise(dt, monkeypatch):
    """Seeded records sampled coarsely (the noise estimate 1,770x too large) and finely
    (right to 10 %): with the rule, every MAP estimate lies well inside its stated
    95 % interval of the noise=-given answer; without it, the coarse ones do not."""
    from tensorid.fitting import priors

    kw = dict(p0={"m": 1.2e-4, "d": 1.8e-3, "a": 0.9, "b": 3.0}, x0=[0.0, 0.0],
              free_x0=["v"], bounds={"m": (1e-6, 1e-2)}, priors={"b": (3.5, 0.01)})  # fmt: skip
    for seed in (1, 2):
        e = _oscillator_record(dt, seed)
        given = ti.fit(ti.Problem(OSCILLATOR, e, noise=1e-4, **kw))
        res = ti.fit(ti.Problem(OSCILLATOR, e, **kw))
        ci = res.uncertainty().ci95
        off = np.abs(res.theta - given.theta) / (0.5 * (ci[:, 1] - ci[:, 0]))
        assert res.success and off.max() < 0.25, (seed, off)
        assert res.noise_check.refits == (4 if dt == 1e-3 else 0)
        if dt == 1e-3:  # the check fails without the rule: it can
            monkeypatch.setattr(priors, "MAX_REFITS", 0)
            old = ti.fit(ti.Problem(OSCILLATOR, e, **kw))
            monkeypatch.undo()
            ci = old.uncertainty().ci95
            assert (np.abs(old.theta - given.theta) > 0.5 * (ci[:, 1] - ci[:, 0])).any()
            assert any("1.77e-05" in w and "not re-estimated" in w for w in old.warnings)


def test_a_given_noise_that_the_residuals_contradict_is_a_warning():
    e = _linear_record()  # noise sd 0.05
    res = ti.fit(ti.Problem(LINEAR, e, p0={"a": 1.0, "b": 0.0}, priors={"a": (2, 1)}, noise=0.5))
    assert res.problem.noise_variance == 0.25 and res.noise_check.refits == 0
    line = next(w for w in res.warnings if w.startswith("priors:"))
    assert "given as noise=, 0.25," in line and f"{res.noise_check.residual:.3g}" in line
    assert "too much" in line and "check noise=" in line
    right = ti.fit(ti.Problem(LINEAR, e, p0={"a": 1.0, "b": 0.0}, priors={"a": (2, 1)}, noise=0.05))
    assert right.noise_check.agree and not any(w.startswith("priors:") for w in right.warnings)


def test_too_few_samples_to_check_a_given_noise_says_so_not_an_exact_fit():
    # two samples, two unknowns: no residual variance exists (it is not zero), and the
    # given noise= needs no fix: the warning says why the check could not be made
    t = np.linspace(0, 1, 2)
    e = ti.Experiment(t, np.stack([np.cos(3 * t), np.sin(5 * t)], 1), np.array([0.0, 0.5]))
    priors = {"a": (1.5, 0.1), "b": (0.0, 1.0)}
    res = ti.fit(ti.Problem(LINEAR, e, p0={"a": 1.0, "b": 0.0}, priors=priors, noise=0.05))
    line = next(w for w in res.warnings if w.startswith("priors:"))
    assert "cannot be checked against the residuals: 2 samples for 2 unknowns" in line
    assert "matches the data exactly" not in line and "give noise=" not in line
    assert res.noise_check.as_dict()["too_few"].startswith("not available: 2 samples")
    assert "residual variance at the fit none (2 samples" in str(res.noise_check)
    # a robust loss's residual spread is a number even then: it must not be used to
    # re-estimate the noise (no refits), and the check is not passed as agreement
    t3 = np.linspace(0, 1, 3)  # three samples for a, b and x(t0): the noise estimated
    e3 = ti.Experiment(t3, np.stack([np.cos(3 * t3), np.sin(5 * t3)], 1), [0.3, -1.2, 0.4])
    robust = ti.fit(
        ti.Problem(LINEAR, e3, p0={"a": 1.0, "b": 0.0}, x0=[0.0], free_x0=["x"],
                   priors=priors, loss="huber", loss_scale=1.0)
    )  # fmt: skip
    assert robust.noise_check.refits == 0 and not robust.noise_check.agree
    assert any("cannot be checked" in w and "give noise=" in w for w in robust.warnings)


def test_a_prior_that_moves_an_estimate_says_so_in_summary_fit_json_and_report(tmp_path):
    from tensorid.analysis.validation import training_scores
    from tensorid.app.reports import fit_json, fit_report

    e = _linear_record()
    alone = ti.fit(ti.Problem(LINEAR, e, p0={"a": 1.0, "b": 0.0}))
    prob = ti.Problem(LINEAR, e, p0={"a": 1.0, "b": 0.0}, priors={"a": (1.5, 0.01)}, noise=0.05)
    res = ti.fit(prob)
    moves = {m["unknown"]: m for m in res.prior_moves()}
    a = moves["a"]
    assert a["prior"] and a["moved"] and a["estimate"] == res.params["a"]
    assert a["data_only"] == pytest.approx(alone.params["a"], rel=1e-8)  # linear: exact
    assert a["data_stderr"] == pytest.approx(alone.uncertainty().stderr[0], rel=1e-6)
    n = abs(res.params["a"] - alone.params["a"]) / a["data_stderr"]
    assert a["standard_errors"] == pytest.approx(n, rel=1e-6) and n > 10
    assert moves["b"]["moved"] and not moves["b"]["prior"]  # correlated with a
    line = f"the prior on a moved it from {alone.params['a']:.6g} to {res.params['a']:.6g}"
    assert any(w.startswith(line) and f"{n:,.0f} standard errors" in w for w in res.warnings)
    assert line in res.summary().replace("\n", " ")
    data = fit_json(res, [])
    assert data["prior_moves"][0]["unknown"] == "a" and data["prior_moves"][0]["moved"]
    assert data["prior_noise_check"]["source"] == "given" and any(
        line in w for w in data["warnings"]
    )
    report = fit_report(res, data, training_scores(res), [])
    assert "## Priors" in report and line in report and "| a | 1.5 ± 0.01 |" in report
