"""The EMPS example (examples/emps): the bundled records, the controller read off them,
the closed-loop model's exact derivatives, and (slow) the whole study."""

from __future__ import annotations

import importlib.util
import json
import subprocess
import sys
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from conftest import autodiff

import tensorid as ti
from tensorid.datasets import EMPS_IDIM_LS, emps, emps_record

EXAMPLE = Path(__file__).resolve().parents[1] / "examples" / "emps"


def _module(name: str):
    spec = importlib.util.spec_from_file_location(f"emps_{name}", EXAMPLE / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_the_bundled_records_are_the_benchmarks():
    for record, vir_range in (("estimation", (-4.3257, 4.1385)), ("test", (-7.9378, 9.0343))):
        d = emps_record(record)
        assert d["qm"].size == 24841 and d["t"][-1] == pytest.approx(24.84)
        assert (d["vir"].min(), d["vir"].max()) == pytest.approx(vir_range, abs=1e-4)
        assert (d["kp"], d["kv"]) == (160.18, 243.45)
        assert d["gtau"] == pytest.approx(35.1507, abs=1e-4)
    assert emps_record("test")["pulses"].max() == 5 and emps_record()["pulses"].max() == 0
    assert emps("test", closed_loop=True).u.shape == (24841, 2)
    with pytest.raises(ValueError, match='"estimation" or "test"'):
        emps_record("validation")
    emps_record()["qm"][0] = 123.0  # a user's change stays in the user's copy
    assert emps_record()["qm"][0] != 123.0


def test_the_models_controller_reproduces_the_recorded_controller_output():
    closed = _module("closed_loop")
    for record in ("estimation", "test"):
        d = emps_record(record)
        q = d["qm"]
        vir = closed.controller(q[1:], q[:-1], d["qg"][1:], d["pulses"][1:])
        rms = np.sqrt(np.mean((d["vir"][1:] - vir) ** 2))
        assert rms < 0.08 * np.sqrt(np.mean(d["vir"] ** 2)), (record, rms)


def test_the_reference_model_in_the_loop_tracks_the_measured_position():
    closed = _module("closed_loop")
    data = emps("estimation", closed_loop=True)
    q0 = data.y[0, 0]
    sim = ti.simulate(closed.model, EMPS_IDIM_LS, [q0, 0.0, q0], data)
    assert np.sqrt(np.mean((sim.y[:, 0] - data.y[:, 0]) ** 2)) < 3e-6  # m; 2.2e-6 measured


def _closed_loop_problem(delay: int) -> ti.Problem:
    model = _module("closed_loop").make_model(delay)
    full = emps("estimation", closed_loop=True)
    short = ti.Experiment(full.t[:60], full.u[:60], full.y[:60])
    return ti.Problem(
        model, short, p0={"M": 90.0, "Fv": 190.0, "Fc": 21.0, "offset": -3.0},
        x0=np.r_[short.y[0, 0], 0.0, short.y[0, 0], np.zeros(delay)], free_x0=model.states,
    )  # fmt: skip


@pytest.mark.slow  # 6 s; jax.hessian of this model takes 10-15 s to compile (below)
def test_the_closed_loop_hessian_equals_differences_of_the_exact_gradient():
    prob = _closed_loop_problem(0)
    th = prob.theta0
    _, g, H = prob.cost_grad_hess(th)
    np.testing.assert_allclose(g, jax.jit(jax.grad(prob.jax_cost))(jnp.asarray(th)), rtol=1e-9)
    steps = 1e-5 * np.maximum(np.abs(th), 1e-3)
    fd = np.stack(
        [
            (prob.cost_grad_hess(th + h * e)[1] - prob.cost_grad_hess(th - h * e)[1]) / (2 * h)
            for h, e in zip(steps, np.eye(th.size), strict=True)
        ],
        axis=1,
    )
    np.testing.assert_allclose(H, fd, rtol=1e-5, atol=1e-6 * np.abs(H).max())


@pytest.mark.slow
@pytest.mark.parametrize("delay", [0, 1])
def test_the_closed_loop_derivatives_equal_autodiff(delay):
    prob = _closed_loop_problem(delay)
    th = jnp.asarray(prob.theta0)
    J, g, H = prob.cost_grad_hess(prob.theta0)
    J_ad, g_ad, H_ad = autodiff(prob.jax_cost)(th)
    np.testing.assert_allclose(J, J_ad, rtol=1e-12)
    np.testing.assert_allclose(g, g_ad, rtol=1e-9, atol=1e-14)
    np.testing.assert_allclose(H, H_ad, rtol=1e-9, atol=1e-12)


@pytest.mark.slow
def test_the_study_runs_and_the_closed_loop_lands_beside_the_reference(tmp_path):
    run = subprocess.run(
        [sys.executable, str(EXAMPLE / "run.py"), "--out", str(tmp_path)],
        capture_output=True, text=True, timeout=900,
    )  # fmt: skip
    assert run.returncode == 0, run.stderr[-3000:]
    out = json.loads((tmp_path / "results.json").read_text())
    closed = out["fits"]["closed"]
    assert closed["status"].startswith("converged")
    for name in ("Fv", "Fc", "offset"):  # 0.1 %, 0.5 %, 0.1 % from IDIM-LS measured
        assert closed["params"][name] == pytest.approx(EMPS_IDIM_LS[name], rel=0.03)
    assert closed["params"]["M"] == pytest.approx(EMPS_IDIM_LS["M"], rel=0.08)  # 4.5 %
    reference = out["table"][0]
    assert reference["label"] == "IDIM-LS reference"
    # fitted in the loop, it predicts the test record at least as well as the reference
    assert closed["test_rmse"] <= reference["closed"]["test_rmse"]
    shooting = out["fits"]["open-shooting"]
    assert shooting["shooting"]["segments"] == [100]
    assert shooting["test_rmse"] < 0.02  # m
    assert out["fits"]["closed-delayed"]["cost"] > closed["cost"]
    for loop in ("open", "closed"):
        assert (tmp_path / f"emps_test_{loop}_loop.png").stat().st_size > 10_000
