"""Data in the layout it comes in, and the benchmarks' validation protocol: one file
holding training and validation records in four columns, inputs and outputs in
separate files, and validation scored after an initialisation window."""

from __future__ import annotations

import json

import numpy as np
import pytest
import scipy.io

import tensorid as ti
from tensorid import cli

MODEL = """rhs = {"x": "v", "v": "-k*x - c*v + g*u"}
output = {"y": "x"}
inputs = ["u"]
p0 = {"k": 3.0, "c": 0.5, "g": 1.2}
x0 = {"x": 0.0, "v": 0.0}
free_x0 = ["x", "v"]
"""
TRUE = {"c": 0.6, "g": 1.0, "k": 4.0}


def _records(tmp_path):
    model = ti.load_model(_model_file(tmp_path)).model
    t = np.arange(600) * 0.05
    rng = np.random.default_rng(0)
    u_est, u_val = np.sin(0.7 * t) + 0.3 * np.sin(2.3 * t), np.sign(np.sin(0.4 * t))
    y_est = ti.simulate(model, TRUE, [0.2, 0.0], ti.Experiment(t, u_est)).y[:, 0]
    y_val = ti.simulate(model, TRUE, [-0.5, 0.3], ti.Experiment(t, u_val)).y[:, 0]
    y_est = y_est + 0.01 * rng.standard_normal(t.size)
    y_val = y_val + 0.01 * rng.standard_normal(t.size)
    path = tmp_path / "both.csv"
    table = np.column_stack([t, u_est, y_est, u_val, y_val])
    np.savetxt(path, table, delimiter=",", header="t,uEst,yEst,uVal,yVal", comments="")
    return model, path, t, (u_est, y_est), (u_val, y_val)


def _model_file(tmp_path):
    path = tmp_path / "model.py"
    if not path.exists():
        path.write_text(MODEL)
    return path


@pytest.mark.slow  # compile-bound; keeps the default run under five minutes
def test_one_file_two_records_and_the_init_window_protocol(tmp_path):
    model, data, t, _, (u_val, y_val) = _records(tmp_path)
    out = tmp_path / "fit"
    args = ["fit", str(_model_file(tmp_path)), str(data), "--columns", "u=uEst,y=yEst"]
    args += ["--validate", str(data), "--validate-columns", "u=uVal,y=yVal"]
    args += ["--init-window", "50", "--out", str(out), "--no-progress"]
    assert cli.main(args) == 0
    fit = json.loads((out / "fit.json").read_text())
    assert fit["init_window"] == 50
    # the independent computation: x0 fitted on the first 50 samples with the
    # parameters held, the error scored after them
    window = ti.Experiment(t[:50], u_val[:50], y_val[:50])
    held = ti.Problem(model, window, p0=fit["params"], x0=[0.0, 0.0], free_x0=["x", "v"],
                      fixed=list(model.params))  # fmt: skip
    x0 = ti.fit(held, gtol=1e-14, ftol=1e-15, xtol=1e-15).x0
    sim = ti.simulate(model, fit["params"], x0, ti.Experiment(t, u_val))
    rmse = float(np.sqrt(np.mean((y_val[50:] - sim.y[50:, 0]) ** 2)))
    (record,) = fit["rmse"]["validation"].values()
    assert record["y"] == pytest.approx(rmse, rel=1e-6)
    assert fit["params"]["k"] == pytest.approx(TRUE["k"], rel=0.02)


def test_inputs_and_outputs_in_separate_files_are_joined(tmp_path):
    model, _, t, (u, y), _ = _records(tmp_path)
    scipy.io.savemat(tmp_path / "u.mat", {"uEst": u[:, None]})  # a column vector
    scipy.io.savemat(tmp_path / "y.mat", {"yEst": y[None, :], "t": t})  # a row vector
    columns = {"u": "uEst", "y": "yEst"}
    for paths in (str(tmp_path / "u.mat") + "+" + str(tmp_path / "y.mat"),
                  [tmp_path / "u.mat", tmp_path / "y.mat"]):  # fmt: skip
        (e,) = ti.load_data(paths, model, columns=columns)
        assert e.name == "u+y" and np.allclose(e.u[:, 0], u) and np.allclose(e.y[:, 0], y)
    out = tmp_path / "fit"
    data = f"{tmp_path / 'u.mat'}+{tmp_path / 'y.mat'}"
    args = ["fit", str(_model_file(tmp_path)), data, "--columns", "u=uEst,y=yEst"]
    assert cli.main(args + ["--out", str(out), "--no-progress"]) == 0
    # the same times in both: one record; other times: said so (not "keep it in one")
    scipy.io.savemat(tmp_path / "u.mat", {"uEst": u[:, None], "t": t})
    (e,) = ti.load_data(data, model, columns=columns)
    scipy.io.savemat(tmp_path / "u.mat", {"uEst": u[:, None], "t": t + 0.5})
    with pytest.raises(ValueError, match="time column 't' differs from .*u.mat"):
        ti.load_data(data, model, columns=columns)
    scipy.io.savemat(tmp_path / "u.mat", {"uEst": u[:, None], "yEst": y})
    with pytest.raises(ValueError, match="'yEst' is in more than one of the joined files"):
        ti.load_data(data, model, columns=columns)


@pytest.mark.parametrize(
    "columns, match",
    [
        ({"u": "uX", "y": "yEst"}, "does not have"),
        ({"q": "uEst"}, "not one of the model"),
        # fitted against zeros before: GOF -inf after 200 iterations
        ({"u": "uEst", "y": 0}, "'y' is an output, which is measured"),
    ],
)
def test_bad_column_mappings_name_the_column(tmp_path, columns, match):
    model, data, *_ = _records(tmp_path)
    with pytest.raises(ValueError, match=match):
        ti.load_data(data, model, columns=columns)


def test_bad_column_arguments_on_the_command_line(tmp_path, capsys):
    _, data, *_ = _records(tmp_path)
    base = ["fit", str(_model_file(tmp_path)), str(data), "--out", str(tmp_path / "o")]
    with pytest.raises(SystemExit):
        cli.main(base + ["--columns", "u:uEst"])
    assert "NAME=COLUMN" in capsys.readouterr().err
    assert cli.main(base + ["--columns", "u=uEst,y=yEst", "--init-window", "5"]) == 2
    assert "--validate" in capsys.readouterr().err
