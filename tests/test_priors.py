"""Priors (MAP estimation): exact derivatives with the prior's terms, the analytic
posterior mean of a linear model, the summary naming what the prior determines, and
the observed/expected information comparison."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from conftest import SILVERBOX_P, silverbox_data, silverbox_model

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
    f = jax.jit(prob.jax_cost)
    assert J == pytest.approx(float(f(jnp.asarray(theta))), rel=1e-12)
    np.testing.assert_allclose(
        g, jax.grad(f)(jnp.asarray(theta)), rtol=1e-9, atol=1e-12 * abs(g).max()
    )
    H_ad = np.asarray(jax.hessian(f)(jnp.asarray(theta)))
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
