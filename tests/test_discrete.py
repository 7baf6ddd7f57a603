"""Discrete-time models: x[k+1] = f(x[k], p, u[k]), exact derivatives by the same
recursion, recovery, and the checks around them."""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np
import pytest
from conftest import autodiff

import tensorid as ti


def hammerstein():
    """A second-order discrete system with a saturating input and a nonlinear output."""

    def f(x, p, u):
        a1, a2, b, c = p
        v = jnp.tanh(c * u[0])
        return jnp.stack([a1 * x[0] - a2 * x[1] + b * v, x[0]])

    return ti.Model(
        rhs=f,
        output=lambda x, p: jnp.stack([x[0] + 0.2 * x[0] ** 3]),
        states=["x1", "x2"],
        params=["a1", "a2", "b", "c"],
        inputs=["u"],
        outputs=["y"],
        discrete=True,
        name="hammerstein",
    )


TRUE = {"a1": 1.2, "a2": 0.5, "b": 0.8, "c": 1.5}


def record(P=200, seed=0, noise=0.0):
    rng = np.random.default_rng(seed)
    t = np.arange(P) * 0.1
    u = rng.uniform(-1, 1, (P, 1))
    sim = ti.simulate(hammerstein(), TRUE, [0.1, -0.2], ti.Experiment(t, u))
    return ti.Experiment(t, u, sim.y + noise * rng.standard_normal(sim.y.shape))


def test_the_map_is_applied_once_per_sample_with_the_input_at_its_start():
    data = record(P=30)
    x = np.array([0.1, -0.2])
    ys = []
    for k in range(30):
        ys.append(x[0] + 0.2 * x[0] ** 3)
        v = np.tanh(1.5 * data.u[k, 0])
        x = np.array([1.2 * x[0] - 0.5 * x[1] + 0.8 * v, x[0]])
    np.testing.assert_allclose(data.y[:, 0], ys, rtol=1e-14, atol=1e-15)


@pytest.mark.parametrize("segments", [pytest.param(s, marks=pytest.mark.slow) for s in (None, 4)])
def test_derivatives_of_a_discrete_model_equal_autodiff(segments):
    data = record(P=80, noise=0.02)
    prob = ti.Problem(
        hammerstein(), data, p0={"a1": 1.1, "a2": 0.55, "b": 0.7, "c": 1.4},
        x0=[0.1, -0.2], free_x0=["x1"], fixed=["c"],
    )  # fmt: skip
    assert prob.discretisation.scheme.name == "discrete"
    th = jnp.asarray(prob.theta0)
    J, g, H = prob.cost_grad_hess(prob.theta0)
    J_ad, g_ad, H_ad = autodiff(prob.jax_cost)(th)
    np.testing.assert_allclose(J, J_ad, rtol=1e-12)
    np.testing.assert_allclose(g, g_ad, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(H, H_ad, rtol=1e-9, atol=1e-12)
    if segments:
        from test_shooting import _check_lagrangian, segmented

        sh = segmented(prob, segments).shooting
        _check_lagrangian(sh, sh.start(prob.theta0) * 1.01)


def test_a_discrete_model_is_recovered_from_noise_free_data():
    data = record(P=200)
    prob = ti.Problem(hammerstein(), data, p0={"a1": 1.0, "a2": 0.4, "b": 1.0, "c": 1.0},
                      x0=[0.0, 0.0], free_x0=["x1", "x2"])  # fmt: skip
    res = ti.fit(prob)
    assert res.success, res.message
    for k, v in TRUE.items():
        assert res.params[k] == pytest.approx(v, rel=1e-8)
    np.testing.assert_allclose(res.x0, [0.1, -0.2], atol=1e-8)


def test_a_discrete_model_refuses_an_integration_scheme_and_uneven_samples():
    data = record(P=40)
    with pytest.raises(ValueError, match="steps once per sample; drop scheme='dopri5'"):
        ti.Problem(hammerstein(), data, p0=TRUE, scheme="dopri5")
    t = data.t.copy()
    t[10:] += 0.05
    with pytest.raises(ValueError, match="not uniform"):
        ti.Problem(hammerstein(), ti.Experiment(t, data.u, data.y), p0=TRUE)
    continuous = ti.Model(rhs=lambda x, p, u: -p[0] * x, states=["x"], params=["k"])
    from tensorid.engine.schemes.discretisation import Discretisation
    from tensorid.engine.schemes.integrators import DISCRETE

    with pytest.raises(ValueError, match="discrete=True"):
        ti.Problem(continuous, ti.Experiment(data.t, None, data.y), p0=[1.0],
                   discretisation=Discretisation(DISCRETE, 1, "zoh"))  # fmt: skip


def test_a_model_file_with_discrete_text_equations(tmp_path):
    f = tmp_path / "ar.py"
    f.write_text(
        'discrete = True\nrhs = {"x": "a*x + b*u"}\ninputs = ["u"]\nparams = ["a", "b"]\n'
        'p0 = {"a": 0.5, "b": 0.5}\nx0 = {"x": 0.0}\n'
    )
    spec = ti.load_model(f)
    assert spec.model.discrete
    t = np.arange(50) * 1.0
    u = np.random.default_rng(0).standard_normal((50, 1))
    sim = ti.simulate(spec.model, {"a": 0.8, "b": 0.3}, [0.0], ti.Experiment(t, u))
    prob = ti.Problem(spec.model, ti.Experiment(t, u, sim.y), p0=spec.p0, x0=[0.0])
    res = ti.fit(prob)
    assert res.params["a"] == pytest.approx(0.8, rel=1e-10)
    assert res.params["b"] == pytest.approx(0.3, rel=1e-10)


def test_a_record_at_another_rate_is_refused_for_a_discrete_model(tmp_path, capsys):
    """A discrete-time model's step is one sample: a record sampled at another rate
    (here every other sample, 0.2 s against 0.1 s) is another model. Training with
    both, validating on it (res.validate, fit --validate before any work) and compare
    of a saved fit on it all ran without a word."""
    import json

    from tensorid import cli

    data = record(P=120)
    half = ti.Experiment(data.t[::2], data.u[::2], data.y[::2], name="half")
    with pytest.raises(ValueError, match=r"experiment 1 \(half\) is sampled every 0.2 s"):
        ti.Problem(hammerstein(), [data, half], p0=TRUE, x0=[0.1, -0.2])
    res = ti.fit(ti.Problem(hammerstein(), data, p0=TRUE, x0=[0.1, -0.2]))
    with pytest.raises(ValueError, match="validation record 'half' is sampled every 0.2 s"):
        res.validate(half)
    assert res.validate(record(P=60, seed=1))[0].gof["y"] > 0.99  # the same rate: scored
    f = tmp_path / "ar.py"
    f.write_text(
        'discrete = True\nrhs = {"x": "a*x + b*u"}\ninputs = ["u"]\nparams = ["a", "b"]\n'
        'p0 = {"a": 0.5, "b": 0.5}\nx0 = {"x": 0.0}\noutput = {"y": "x"}\n'
    )
    rows = "".join(f"{k * 0.1:.1f},{np.sin(k)},{np.cos(k)}\n" for k in range(60))
    (tmp_path / "a.csv").write_text("t,u,y\n" + rows)
    (tmp_path / "b.csv").write_text("t,u,y\n" + "".join(rows.splitlines(True)[::2]))
    fit = ["fit", str(f), str(tmp_path / "a.csv"), "--no-progress", "--out", str(tmp_path / "o")]
    assert cli.main([*fit, "--validate", str(tmp_path / "b.csv")]) == 2
    assert "'b' is sampled every 0.2 s" in capsys.readouterr().err
    assert not (tmp_path / "o").exists()  # refused before the fit
    assert cli.main(fit) == 0
    assert json.loads((tmp_path / "o" / "fit.json").read_text())["sample_time"] == 0.1
    compare = ["compare", str(f), str(tmp_path / "b.csv"), "--params",
               str(tmp_path / "o" / "fit.json"), "--out", str(tmp_path / "c")]  # fmt: skip
    capsys.readouterr()
    assert cli.main(compare) == 2
    assert "b.csv is sampled every 0.2 s" in capsys.readouterr().err
