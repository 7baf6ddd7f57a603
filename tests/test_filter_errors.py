"""Error bars of filter fits (issue 40, item 3): the per-sample scores of −2 log L are
exact (each the difference of jax.grad of the likelihood of a record one sample
longer), robust (sandwich) error bars for a filter whose innovations are not white,
and a curvature with several flat directions named in one ranked line."""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np
import pytest
from conftest import autodiff
from test_ekf import CASES, ekf_problem

import tensorid as ti
from tensorid.analysis.sandwich import scores
from tensorid.analysis.uncertainty import flat_line


def test_a_filter_s_scores_are_exact_per_sample():
    m, pr = ekf_problem("two tanks")
    theta = pr.theta0
    (s,) = scores(pr, theta)
    assert s.shape == (29, pr.K)  # the first sample is out of the likelihood
    np.testing.assert_allclose(s.sum(0), pr.cost_grad(theta)[1], rtol=1e-12, atol=1e-12)
    _, params, x0, free, qn, interp = CASES["two tanks"]
    e = pr.experiments[0]

    def grad(n):  # ∇ of −2 log L over the first n samples (a filter is causal)
        short = ti.Problem(
            m, e.window(0, n), p0=params, x0=x0, free_x0=free, predictor="ekf",
            process_noise=qn, interpolation=interp, measurement_noise={"level": 0.05},
        )  # fmt: skip
        return autodiff(short.jax_cost, hessian=False)(theta)[1]

    np.testing.assert_allclose(grad(2), s[0], rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(grad(11) - grad(10), s[9], rtol=1e-9, atol=1e-12)


@pytest.mark.slow  # a whole filter fit (10-13 s cold); the scores' exactness stays fast
def test_a_filter_whose_innovations_are_not_white_gets_robust_error_bars():
    """The two-tank record by a filter with σ_e fixed at 3 mV: the innovations fail
    whiteness (Q = 637); stderr_robust was null for every filter fit."""
    from tensorid import benchmarks
    from tensorid.app.reports import fit_json

    pr = benchmarks.two_tank_problem(
        predictor="ekf", process_noise={"x2": 0.01}, measurement_noise={"y": 0.003},
        fixed=["log_sigma_e_y"], free_x0=["x1", "x2"],
    )  # fmt: skip
    res = ti.fit(pr)
    tests = res.residual_tests()
    assert tests.whiteness[0].passed is False
    robust, white = res.uncertainty("robust"), res.uncertainty()
    assert robust.kind == "robust" and robust.lags is not None
    # p1, p2, p4 move together along a nearly flat direction, whose relative curvature
    # sits at the "not identifiable" cut (1e-8) and falls either side of it with
    # rounding: the two kinds of bar must agree on which unknowns are unbounded, and
    # the determined ones get finite robust bars that are not the white ones
    determined = np.isfinite(white.stderr)
    assert (np.isfinite(robust.stderr) == determined).all()
    names = [n for n, d in zip(pr.theta_names, determined, strict=True) if d]
    assert {"p3", "log_sigma_w_x2"} <= set(names)
    assert (robust.stderr[determined] > 0).all()
    assert not np.allclose(robust.stderr[determined], white.stderr[determined], rtol=0.05)
    d = fit_json(res, [], residual=tests)
    assert d["stderr_robust"] == dict(zip(pr.theta_names, robust.stderr.tolist(), strict=True))
    text = res.summary()
    assert "robust std. error" in text and "the filter's innovations are not white" in text
    assert "Newey-West on the scores of −2 log L" in text


def test_a_filter_fit_with_white_innovations_has_robust_bars_like_the_white_ones():
    from test_ekf import duffing, sde_record

    pr = ti.Problem(
        duffing(), sde_record(0), p0={"k": 1.5, "c": 0.5, "a": 0.3}, x0=[0, 0],
        free_x0=["x", "v"], predictor="ekf", process_noise={"v": 0.1},
        measurement_noise={"y": 0.05}, interpolation="zoh",
    )  # fmt: skip
    res = ti.fit(pr)
    assert all(res.residual_tests().whiteness_passed)
    ratio = res.uncertainty("robust").stderr / res.uncertainty().stderr
    assert ((ratio > 0.6) & (ratio < 1.6)).all(), ratio
    assert "robust std. error" not in res.summary()  # white: the white bars stand


@pytest.mark.parametrize("predictor", ["simulation", "ekf"])
def test_flat_directions_are_one_ranked_line(predictor):
    """Two products a·b and c·d pinned, their factors not: two flat directions, one
    warning, the flattest first, each naming its unknowns (a filter fit of the tanks
    gave 11 warnings, one per direction)."""
    model = ti.Model(
        rhs=lambda x, p, u: jnp.stack([-p[0] * p[1] * x[0] + p[2] * p[3] * u[0]]),
        states=["x"], params=["a", "b", "c", "d"], inputs=["u"],
        output=lambda x, p: x, outputs=["y"],
    )  # fmt: skip
    t = np.linspace(0, 10, 200)
    u = np.sin(t) + np.sign(np.sin(0.3 * t))
    truth = {"a": 1.0, "b": 2.0, "c": 0.5, "d": 3.0}
    y = ti.simulate(model, truth, [0.0], ti.Experiment(t, u)).y
    y = y + 0.01 * np.random.default_rng(0).standard_normal(y.shape)
    noise = dict(process_noise={"x": 0.01}, measurement_noise={"y": 0.01})
    kw = noise if predictor == "ekf" else {}
    record = ti.Experiment(t, u, y)
    res = ti.fit(ti.Problem(model, record, p0=truth, x0=[0.0], predictor=predictor, **kw))
    flat = [w for w in res.warnings if "not identifiable" in w]
    assert len(flat) == 1
    assert "flat along 2 directions, the flattest first: (1) " in flat[0]
    assert "a, b (relative curvature" in flat[0] and "c, d (relative curvature" in flat[0]
    # the ranking and the cap on named directions
    many = [(-1e-12 * k, [f"p{k}", f"q{k}"]) for k in range(9)]
    line = flat_line(many)
    assert line.index("(1) p0, q0") < line.index("(2) p1, q1")
    assert "and 3 more moving p6, p7, p8, q6, q7, q8" in line
    assert line.count("relative curvature") == 6


@pytest.mark.parametrize("kind", ["hessian", "robust"])
def test_robust_kind_is_accepted_for_a_filter(kind):
    _, pr = ekf_problem("discrete time")
    res = ti.fit(pr)
    assert np.isfinite(res.uncertainty(kind).stderr).all()


def test_a_filter_failing_where_sigma_e_underflowed_says_so_not_the_states_region():
    """issue 51 item 7: the note blamed state estimates leaving their region when the
    measurement noise's variance had underflowed to 0."""
    from test_ekf import sde_record
    from test_start_from import _ekf

    from tensorid.engine.assembly.diagnostics import diagnose

    pr = _ekf(sde_record(0, P=60), {"k": 1.5, "c": 0.5, "a": 0.3}, x0=[0, 0])
    theta = pr.theta0.copy()
    theta[pr.theta_names.index("log_sigma_w_v")] = -400.0  # the states known exactly
    theta[pr.theta_names.index("log_sigma_e_y")] = -400.0
    why = diagnose(pr, theta)
    assert why is not None and "σ_e(y) = e^-400: its variance underflows to 0" in why, why
    assert "left the region" not in why
