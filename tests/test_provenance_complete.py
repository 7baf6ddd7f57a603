"""Provenance complete (issue 40, item 8): the slices of the records used, each data
file's role and time base, the working directory and absolute paths, no t=t in the
column map of a file without a t column, and the fit.json a compare scored."""

from __future__ import annotations

import hashlib
import json
import os
from pathlib import Path

import numpy as np
import scipy.io

import tensorid as ti
from tensorid import cli

MODEL = 'rhs = {"x": "-k*x + u"}\noutput = {"y": "x"}\ninputs = ["u"]\np0 = {"k": 1.5}\n'


def _files(tmp_path: Path) -> tuple[Path, Path, Path]:
    (tmp_path / "m.py").write_text(MODEL)
    model = ti.load_model(tmp_path / "m.py").model
    t = np.arange(300) * 0.1
    u = np.sign(np.sin(0.5 * t))
    y = ti.simulate(model, [2.0], [0.0], ti.Experiment(t, u)).y[:, 0]
    y = y + 0.01 * np.random.default_rng(0).standard_normal(y.size)
    scipy.io.savemat(tmp_path / "rec.mat", {"u": u, "y": y, "Ts": 0.1})  # no t column
    rows = ["t,u,y"] + [f"{a:.17g},{b:.17g},{c:.17g}" for a, b, c in zip(t, u, y, strict=True)]
    (tmp_path / "val.csv").write_text("\n".join(rows) + "\n")
    return tmp_path / "m.py", tmp_path / "rec.mat", tmp_path / "val.csv"


def test_fit_json_and_report_record_roles_slices_and_time_bases(tmp_path, monkeypatch):
    model, rec, val = _files(tmp_path)
    monkeypatch.chdir(tmp_path)
    out = tmp_path / "out"
    argv = ["fit", "m.py", "rec.mat", "--samples", "0:200", "--validate", "val.csv",
            "--validate-samples", "200:300", "--no-progress", "--out", str(out)]  # fmt: skip
    assert cli.main(argv) == 0
    d = json.loads((out / "fit.json").read_text())
    assert d["samples"] == [0, 200] and d["validate_samples"] == [200, 300]
    prov = d["provenance"]
    assert prov["working_directory"] == os.getcwd() == str(tmp_path)
    assert prov["model"]["absolute_path"] == str(model.resolve())
    train, test = prov["data"]
    assert train["role"] == "training" and test["role"] == "validation"
    assert train["samples"] == [0, 200] and test["samples"] == [200, 300]
    assert train["columns"] == {"u": "u", "y": "y"}  # it said t=t: the file has no t
    assert train["time"] == "the file's sampling time Ts"
    assert test["columns"] == {"t": "t", "u": "u", "y": "y"} and test["time"] == "column t"
    assert train["path"] == "rec.mat" and train["absolute_path"] == str(rec.resolve())
    report = (out / "report.md").read_text()
    assert "- training data file: `rec.mat`" in report and ", samples 0:200" in report
    assert "- validation data file: `val.csv`" in report and "time from column t" in report
    assert f"- working directory: `{tmp_path}`" in report
    # --ts: the time base said, and no t in the map even of a file with a t column
    assert cli.main([*argv[:3], "--ts", "0.1", "--no-progress", "--out", str(tmp_path / "o2")]) == 0
    (only,) = json.loads((tmp_path / "o2" / "fit.json").read_text())["provenance"]["data"]
    assert only["time"] == "--ts 0.1" and "t" not in only["columns"]
    # compare records the fit.json it scored
    fit_json = out / "fit.json"
    cmp = ["compare", "m.py", "val.csv", "--params", str(fit_json), "--out", str(tmp_path / "c")]
    assert cli.main(cmp) == 0
    c = json.loads((tmp_path / "c" / "compare.json").read_text())["provenance"]
    assert c["fit"]["path"] == str(fit_json)
    assert c["fit"]["sha256"] == hashlib.sha256(fit_json.read_bytes()).hexdigest()
    assert c["data"][0]["role"] == "scored" and c["working_directory"] == str(tmp_path)
