"""Outputs that read the inputs, y = C(x, p, u): a baseline, a covariate, a feed-through.
The output at sample h reads that sample's inputs, and the gradient and the Hessian go
through them exactly — through doses and moving events, by every path (the tensors,
the adjoint, the filter, the output sensitivities)."""

from __future__ import annotations

import subprocess
import sys

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from conftest import autodiff

import tensorid as ti
from tensorid.engine.modelling.events import Events

T = np.array([0.5, 1.0, 2.0, 4.0, 7.5, 12.0, 12.5, 14.0, 20.0])
DOSES = Events.doses(0.0, "depot", 100.0) + Events.doses(12.0, "depot", 80.0)


def _pk(lag: bool = False):
    """Depot and centre; the measured level is the concentration on top of a drifting
    baseline the record gives (input ``base``), scaled by a parameter."""
    return ti.model_from_equations(
        rhs={"depot": "-ka*depot", "center": "ka*depot - ke*center"},
        output={"cp": "center/v + s*base"},
        inputs=["base"],
        params=["ka", "ke", "v", "s"] + (["tlag"] if lag else []),
    )


def _base(t):
    return (2.0 + np.sin(0.4 * t))[:, None]


def _plain_cost(theta, t, u, y, seen, jumps, substeps):
    """RK4 written out: the doses after each grid time's observation; the output reads
    the sample's input."""
    ka, ke, v, s = theta

    def f(x):
        return jnp.stack([-ka * x[0], ka * x[0] - ke * x[1]])

    def rk4(x, dt):
        k1 = f(x)
        k2 = f(x + dt / 2 * k1)
        k3 = f(x + dt / 2 * k2)
        k4 = f(x + dt * k3)
        return x + dt / 6 * (k1 + 2 * k2 + 2 * k3 + k4)

    def sample(carry, data):
        x, J = carry
        y_h, u_h, seen_h, jump_h, dt = data
        J = J + seen_h * (y_h - x[1] / v - s * u_h) ** 2
        x = x.at[0].add(jump_h)
        x = jax.lax.fori_loop(0, substeps, lambda _, xx: rk4(xx, dt / substeps), x)
        return (x, J), None

    dts = jnp.append(jnp.diff(t), 0.0)
    (_, J), _ = jax.lax.scan(sample, (jnp.zeros(2), 0.0), (y, u, seen, jumps, dts))
    return J


def _record(model, p, **kw):
    grid = ti.Experiment(T, _base(T), np.zeros((T.size, 1)), events=DOSES)
    sim = ti.simulate(model, p, [0, 0], grid, **kw)
    rng = np.random.default_rng(3)
    y = sim.y[grid.observed[:, 0]] + 0.05 * rng.standard_normal((T.size, 1))
    return ti.Experiment(T, _base(T), y, events=DOSES)


def test_an_output_that_reads_an_input_has_the_exact_hessian_through_doses():
    m = _pk()
    truth = {"ka": 1.1, "ke": 0.15, "v": 9.0, "s": 0.7}
    e = _record(m, truth)
    assert m.reads_inputs and e.P == T.size + 1  # the dose at 0 is a node of its own
    pr = ti.Problem(m, e, p0=truth, x0=[0, 0], substeps=3)
    theta = np.array([1.2, 0.12, 10.0, 0.5])
    J, g, H = pr.cost_grad_hess(theta)
    jumps = pr.dosing.channels(e).reshape(e.P, 4, -1)[:, 0, 0]
    seen = e.observed[:, 0].astype(float)
    args = (e.t, e.u[:, 0], e.y[:, 0], seen, jumps, 3)
    Jref, gref, Href = autodiff(lambda th: _plain_cost(th, *args))(theta)
    th = jnp.asarray(theta)
    assert J == pytest.approx(Jref, rel=1e-12)
    np.testing.assert_allclose(g, gref, rtol=1e-9, atol=1e-12 * np.abs(g).max())
    np.testing.assert_allclose(H, Href, rtol=1e-8, atol=1e-10 * np.abs(Href).max())
    # the output sensitivities (error bars, design) read the input too
    D = pr.output_sensitivities(theta)[0]
    sims = jax.jacfwd(lambda th_: _simulated(pr, th_))(th)
    np.testing.assert_allclose(D[:, 0, :], sims, rtol=1e-9, atol=1e-12)
    res = ti.fit(pr)
    assert res.success
    np.testing.assert_allclose(res.params["s"], truth["s"], atol=0.1)


def _simulated(pr, theta):
    """ŷ at every grid node by the sweeps' own simulation (jax-traceable)."""
    (t, u, _), sw = pr.arrays_of(pr.experiments[0]), pr._sweeps
    x0, p = sw.expand(theta, jnp.asarray(pr.x0[0]), jnp.asarray(pr.p0))
    return sw._simulate(x0, p, t, u)[1][:, 0]


@pytest.mark.slow  # jax.hessian through the moving nodes: about 20 s from a cold cache
def test_with_a_lag_the_output_s_input_stays_with_its_sample():
    """A lag reorders the march's nodes at each evaluation; the output reads the input
    of its own sample whatever moved past it."""
    m = _pk(lag=True)
    truth = {"ka": 1.1, "ke": 0.15, "v": 9.0, "s": 0.7, "tlag": 0.3}
    e = _record(m, truth, lags={"depot": "tlag"})
    pr = ti.Problem(m, e, p0=truth, x0=[0, 0], substeps=3, lags={"depot": "tlag"})
    reference = autodiff(pr.jax_cost)
    for lag in (0.3, 0.8):  # before and after the sample at 0.5
        theta = np.array([1.2, 0.12, 10.0, 0.5, lag])
        _, g, H = pr.cost_grad_hess(theta)
        _, gref, Href = reference(theta)
        np.testing.assert_allclose(g, gref, rtol=1e-9)
        np.testing.assert_allclose(H, Href, rtol=1e-8, atol=1e-10)
    # the input term alone: s's gradient is Σ −2 r_h base_h over the observed samples
    sim = pr.simulate(theta)[0]
    r = (e.y - sim.y)[e.observed[:, 0], 0]
    assert g[3] == pytest.approx(-2 * np.sum(r * e.u[e.observed[:, 0], 0]), rel=1e-9)


@pytest.mark.slow  # three more sweeps' programs and jax.hessian of the filter: about 18 s
def test_the_filter_and_the_adjoint_read_the_output_s_input():
    m = ti.model_from_equations(
        rhs={"x": "-k*x + b*u"}, output={"y": "x + c*u**2"}, inputs=["u"], params=["k", "b", "c"]
    )
    t = np.linspace(0, 5, 41)
    u = (np.sin(1.3 * t) + 0.5)[:, None]
    truth = {"k": 0.7, "b": 1.2, "c": 0.4}
    sim = ti.simulate(m, truth, [1.0], ti.Experiment(t, u, np.zeros((41, 1))))
    y = sim.y + 0.02 * np.random.default_rng(0).standard_normal(sim.y.shape)
    e = ti.Experiment(t, u, y)
    theta = np.array([0.8, 0.5, 1.0, 0.2])
    kw = dict(p0=truth, x0=[0.8], free_x0=["x"])
    tensors = ti.Problem(m, e, **kw).cost_grad_hess(theta)
    adjoint = ti.Problem(m, e, hessian="adjoint", **kw).cost_grad_hess(theta)
    for a, b in zip(tensors, adjoint, strict=True):
        np.testing.assert_allclose(a, b, rtol=1e-9, atol=1e-12)
    ekf = ti.Problem(m, e, predictor="ekf", process_noise={"x": 0.05}, **kw)
    th = np.concatenate([theta, ekf.theta0[len(theta) :]])
    _, g, H = ekf.cost_grad_hess(th)
    _, gref, Href = autodiff(ekf.jax_cost)(th)
    np.testing.assert_allclose(g, gref, rtol=1e-8, atol=1e-10)
    np.testing.assert_allclose(H, Href, rtol=1e-7, atol=1e-9)


def test_a_python_output_with_three_arguments_reads_the_inputs():
    m = ti.Model(
        rhs=lambda x, p, u: -p[0] * x,
        output=lambda x, p, u: x + p[1] * u[0],
        states=["x"], params=["k", "d"], inputs=["u"], outputs=["y"],
    )  # fmt: skip
    assert m.reads_inputs
    with pytest.raises(ValueError, match="its output reads the inputs; pass them"):
        m.h(jnp.ones(1), jnp.ones(2))
    two = ti.Model(rhs=lambda x, p, u: -p[0] * x, output=lambda x, p: x, states=["x"],
                   params=["k"], inputs=["u"], outputs=["y"])  # fmt: skip
    assert not two.reads_inputs


def test_an_event_table_s_covariate_read_by_the_output_from_the_command_line(tmp_path):
    """A NONMEM-style table with a baseline column BASE per subject; the model file's
    output reads it (cp = center/v + BASE): fitted from the command line alone."""
    model = tmp_path / "model.py"
    model.write_text(
        'rhs = {"depot": "-ka*depot", "center": "ka*depot - ke*center"}\n'
        'output = {"cp": "center/v + BASE"}\n'
        'inputs = ["BASE"]\n'
        'params = ["ka", "ke", "v"]\n'
        'x0 = {"depot": 0.0, "center": 0.0}\n'
        'p0 = {"ka": 0.8, "ke": 0.2, "v": 8.0}\n'
    )
    m = ti.model_from_equations(
        rhs={"depot": "-ka*depot", "center": "ka*depot - ke*center"},
        output={"cp": "center/v + BASE"}, inputs=["BASE"], params=["ka", "ke", "v"],
    )  # fmt: skip
    truth = {"ka": 1.1, "ke": 0.15, "v": 9.0}
    rows = ["ID,TIME,AMT,DV,EVID,MDV,BASE"]
    rng = np.random.default_rng(5)
    for i, base in enumerate([1.0, 3.0, 5.0]):
        rec = ti.Experiment(T, np.full((T.size, 1), base), np.zeros((T.size, 1)), events=DOSES)
        sim = ti.simulate(m, truth, [0, 0], rec)
        for h, ti_ in enumerate(rec.t):
            if ti_ in (0.0, 12.0):
                rows.append(f"{i + 1},{ti_},{100.0 if ti_ == 0 else 80.0},.,1,1,{base}")
            if rec.observed[h, 0]:
                dv = sim.y[h, 0] + 0.05 * rng.standard_normal()
                rows.append(f"{i + 1},{ti_},.,{dv:.6f},0,0,{base}")
    data = tmp_path / "pk.csv"
    data.write_text("\n".join(rows) + "\n")
    out = tmp_path / "fit"
    cmd = [sys.executable, "-m", "tensorid", "fit", str(model), str(data), "--records", "ID",
           "--columns", "t=TIME,cp=DV", "--out", str(out), "--no-progress"]  # fmt: skip
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr
    import json

    fit = json.loads((out / "fit.json").read_text())
    est = fit["params"]
    for name, value in truth.items():
        assert est[name] == pytest.approx(value, rel=0.1), (name, est)
