"""Starting from an earlier fit (issue 40, item 6): ``Problem(..., p0=res)`` and
``tensorid fit ... --start-from fit.json`` take its parameters, initial states and
noise intensities, so that the same problem starts at the earlier fit's cost; an
earlier fit of another model is refused in one line naming what differs."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest
from test_ekf import EKF_MODEL_FILE, duffing, sde_record

import tensorid as ti
from tensorid import cli


def _ekf(data, p0, x0=None, **kw):
    return ti.Problem(
        duffing(), data, p0=p0, x0=x0, free_x0=["x", "v"], predictor="ekf",
        process_noise={"v": 0.1}, interpolation="zoh", **kw,
    )  # fmt: skip


def test_a_problem_started_from_a_fit_starts_at_its_cost():
    data = sde_record(0, P=200)
    res = ti.fit(_ekf(data, {"k": 1.5, "c": 0.5, "a": 0.3}, x0=[0, 0]), maxiter=5)
    again = _ekf(data, res)  # the noise starts given (v: 0.1) give way to the fit's
    np.testing.assert_allclose(again.theta0, res.theta, rtol=1e-13, atol=1e-15)
    assert again.cost(again.theta0) == pytest.approx(res.cost, rel=1e-12)
    more = ti.fit(again)
    assert more.history[0]["cost"] == pytest.approx(res.cost, rel=1e-12)
    assert more.cost <= res.cost
    # from a fit.json's values: the same start
    start = ti.Start.of(res)
    assert start.process == {"v": pytest.approx(np.exp(res.params["log_sigma_w_v"]))}
    assert _ekf(data, start).cost(again.theta0) == pytest.approx(res.cost, rel=1e-12)
    # an explicit x0 wins over the fit's
    assert _ekf(data, res).x0[0].tolist() == pytest.approx(res.x0.tolist())
    assert _ekf(data, res, x0=[0.5, 0.0]).x0[0].tolist() == [0.5, 0.0]
    # output error from a filter fit: its parameters and initial states, no noise
    oe = ti.Problem(duffing(), data, p0=res, free_x0=["x", "v"], interpolation="zoh")
    assert oe.theta_names == ["x(t0)", "v(t0)", "k", "c", "a"]
    np.testing.assert_allclose(oe.theta0[2:], [res.params[n] for n in ("k", "c", "a")])


def test_a_fit_of_another_model_is_refused_in_one_line():
    data = sde_record(0, P=60)
    other = ti.Model(
        rhs=lambda x, p, u: -p[0] * x + u[0], states=["x"], params=["tau"], inputs=["u"],
        output=lambda x, p: x, outputs=["y"],
    )  # fmt: skip
    res = ti.fit(ti.Problem(other, data, p0={"tau": 1.0}), maxiter=2)
    with pytest.raises(ValueError) as e:
        _ekf(data, res)
    msg = str(e.value)
    assert "\n" not in msg and "has ['tau'], which the model lacks" in msg
    assert "lacks ['k', 'c', 'a']" in msg


@pytest.mark.slow  # two command-line fits (10 s cold); the library's start-from stays fast
def test_the_command_line_starts_from_a_fit_json(tmp_path, capsys):
    (tmp_path / "model.py").write_text(EKF_MODEL_FILE)
    d = sde_record(0, P=200)
    table = zip(d.t, d.u[:, 0], d.y[:, 0], strict=True)
    rows = ["t,u,y"] + [f"{a:.17g},{b:.17g},{c:.17g}" for a, b, c in table]
    (tmp_path / "train.csv").write_text("\n".join(rows) + "\n")
    base = ["fit", str(tmp_path / "model.py"), str(tmp_path / "train.csv"), "--interpolation",
            "zoh", "--no-progress", "--no-model-check"]  # fmt: skip
    assert cli.main([*base, "--out", str(tmp_path / "a")]) == 0
    first = json.loads((tmp_path / "a" / "fit.json").read_text())
    again = [*base, "--start-from", str(tmp_path / "a" / "fit.json")]
    assert cli.main([*again, "--out", str(tmp_path / "b")]) == 0
    second = json.loads((tmp_path / "b" / "fit.json").read_text())
    assert second["history"][0]["cost"] == pytest.approx(first["cost"], rel=1e-12)
    # which fit it started from, and its bytes (issue 51, item 7: fit.json did not say)
    started = second["provenance"]["start_from"]
    assert started["path"] == str(tmp_path / "a" / "fit.json") and len(started["sha256"]) == 64
    assert "start_from" not in first["provenance"]
    assert second["cost"] <= first["cost"]
    capsys.readouterr()
    # a fit.json of another model: one line, exit status 2, before any work
    other = dict(first, params={"tau": 1.0, "log_sigma_e_y": -3.0})
    (tmp_path / "other.json").write_text(json.dumps(other))
    bad = [*base, "--start-from", str(tmp_path / "other.json"), "--out", str(tmp_path / "c")]
    assert cli.main(bad) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "other.json" in err and "lacks ['k', 'c', 'a']" in err
    missing = [*base, "--start-from", str(tmp_path / "nope.json"), "--out", str(tmp_path / "d")]
    assert cli.main(missing) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "nope.json: cannot read it" in err
    # issue 51 item 7: a σ_e at its floor (e^-800 = 0) was refused, blamed on the model
    # file; now that output starts from its noise level in the data, saying so. And an
    # explicit --measurement-noise was overridden by the file's value without a word.
    floor = dict(first, params={**first["params"], "log_sigma_e_y": -800.0})
    (tmp_path / "floor.json").write_text(json.dumps(floor))
    short = [*base, "--maxiter", "1", "--out", str(tmp_path / "e")]
    assert cli.main([*short, "--start-from", str(tmp_path / "floor.json")]) in (0, 1)
    err = capsys.readouterr().err
    assert "its σ_e(y) = 0 sits at its floor; y's measurement noise starts from" in err
    began = json.loads((tmp_path / "e" / "fit.json").read_text())["history"][0]["cost"]
    file_start = ti.Start.read(tmp_path / "a" / "fit.json")
    lifted = _ekf(d, dataclasses.replace(file_start, measurement={}))  # the data's level
    assert began == pytest.approx(lifted.cost(lifted.theta0), rel=1e-10)
    given = [*short, "--start-from", str(tmp_path / "a" / "fit.json"), "--measurement-noise",
             "y=0.5"]  # fmt: skip
    assert cli.main(given) in (0, 1)
    began = json.loads((tmp_path / "e" / "fit.json").read_text())["history"][0]["cost"]
    given = _ekf(d, dataclasses.replace(file_start, measurement={"y": 0.5}))
    assert began == pytest.approx(given.cost(given.theta0), rel=1e-10)
