"""Known input delays: u(t − τ) seen by the model, exact derivatives, recovery."""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np
import pytest
from conftest import autodiff

import tensorid as ti

TS = 0.01


def first_order(delay=None, interpolation_free=True):
    return ti.Model(
        rhs=lambda x, p, u: jnp.stack([-p[0] * x[0] + p[1] * u[0] + 0.3 * jnp.tanh(x[0]) * u[1]]),
        output=lambda x, p: jnp.stack([x[0] + 0.1 * x[0] ** 2]),
        states=["x"],
        params=["k", "g"],
        inputs=["u", "w"],
        outputs=["y"],
        input_delays=delay,
    )


def record(P=300, seed=0):
    rng = np.random.default_rng(seed)
    t = np.arange(P) * TS
    u = np.column_stack([np.repeat(rng.uniform(-1, 1, P // 20), 20), np.sin(7 * t)])
    return t, u


@pytest.mark.parametrize("interpolation", ["linear", "zoh"])
def test_a_whole_sample_delay_is_the_record_shifted(interpolation):
    t, u = record()
    shifted = u.copy()
    shifted[3:, 0], shifted[:3, 0] = u[:-3, 0], u[0, 0]
    kw = dict(interpolation=interpolation, substeps=2)
    delayed = ti.simulate(first_order({"u": 3 * TS}), {"k": 2.0, "g": 1.5}, [0.2],
                          ti.Experiment(t, u), **kw)  # fmt: skip
    plain = ti.simulate(first_order(), {"k": 2.0, "g": 1.5}, [0.2], ti.Experiment(t, shifted), **kw)
    np.testing.assert_allclose(delayed.y, plain.y, rtol=0, atol=1e-13)


def test_a_fractional_delay_interpolates_the_record():
    t, u = record()
    m = first_order({"u": 2.5 * TS})
    seen = m.delayed(t, u)
    np.testing.assert_allclose(seen[10:, 0], 0.5 * (u[7:-3, 0] + u[8:-2, 0]))
    np.testing.assert_array_equal(seen[:, 1], u[:, 1])  # the other input is not delayed


@pytest.mark.slow  # 9 s of jax.hessian compilation; the shooting test below keeps one check
def test_derivatives_with_a_delay_equal_autodiff():
    t, u = record(P=120)
    m = first_order({"u": 2.5 * TS, "w": 4 * TS})
    sim = ti.simulate(m, {"k": 2.0, "g": 1.5}, [0.2], ti.Experiment(t, u))
    y = sim.y + 0.01 * np.random.default_rng(1).standard_normal(sim.y.shape)
    prob = ti.Problem(m, ti.Experiment(t, u, y), p0={"k": 2.3, "g": 1.2}, x0=[0.1], free_x0=["x"])
    theta = prob.theta0
    J, g, H = prob.cost_grad_hess(theta)
    J_ad, g_ad, H_ad = autodiff(prob.jax_cost)(theta)
    np.testing.assert_allclose(J, J_ad, rtol=1e-12)
    np.testing.assert_allclose(g, g_ad, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(H, H_ad, rtol=1e-9, atol=1e-12)


def test_a_delayed_model_is_recovered_from_noise_free_data_and_the_delay_matters():
    t, u = record(P=400)
    m = first_order({"u": 5 * TS})
    y = ti.simulate(m, {"k": 2.0, "g": 1.5}, [0.2], ti.Experiment(t, u)).y
    data = ti.Experiment(t, u, y)
    res = ti.fit(ti.Problem(m, data, p0={"k": 3.0, "g": 1.0}, x0=[0.0], free_x0=["x"]))
    assert res.params["k"] == pytest.approx(2.0, rel=1e-8)
    assert res.params["g"] == pytest.approx(1.5, rel=1e-8)
    without = ti.fit(ti.Problem(first_order(), data, p0={"k": 3.0, "g": 1.0}, x0=[0.0],
                                free_x0=["x"]))  # fmt: skip
    assert without.cost > 1e6 * max(res.cost, 1e-30)


@pytest.mark.slow  # compile-bound; keeps the default run under five minutes
def test_multiple_shooting_sees_the_delay_across_segment_starts():
    t, u = record(P=300)
    m = first_order({"u": 7 * TS})
    y = ti.simulate(m, {"k": 2.0, "g": 1.5}, [0.2], ti.Experiment(t, u)).y
    prob = ti.Problem(m, ti.Experiment(t, u, y), p0={"k": 2.0, "g": 1.5}, x0=[0.2], segments=6)
    sh = prob.shooting
    L = sh.evaluate(sh.start(prob.theta0))
    assert np.abs(L.c).max() < 1e-12 and L.J < 1e-20  # the truth is continuous and exact


@pytest.mark.parametrize(
    "delays, message",
    [
        ({"v": 0.1}, "not an input"),
        ({"u": -0.1}, ">= 0"),
        ({"u": "soon"}, "number of seconds"),
        ([0.1], "dict"),
    ],
)
def test_bad_delays_are_one_line(delays, message):
    with pytest.raises((ValueError, TypeError), match=message):
        first_order(delays)


def test_a_model_file_with_text_equations_takes_input_delays(tmp_path):
    f = tmp_path / "m.py"
    f.write_text(
        'rhs = {"x": "-k*x + g*u"}\ninputs = ["u"]\nparams = ["k", "g"]\n'
        'input_delays = {"u": 0.03}\np0 = {"k": 1.0, "g": 1.0}\n'
    )
    spec = ti.load_model(f)
    assert spec.model.input_delays == {"u": 0.03}
