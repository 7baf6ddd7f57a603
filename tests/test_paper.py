"""The paper study on the bundled data: results.json's schema and the headline numbers.
Runs the command line once (quick, 2 starts, 2 worker processes)."""

from __future__ import annotations

import contextlib
import io
import json

import numpy as np
import pytest

from tensorid import benchmarks, cli, datasets, paper
from tensorid.paper import COMPARED

# the study runs the command line end to end: about 40 s
pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def study(tmp_path_factory):
    out = tmp_path_factory.mktemp("paper")
    console = io.StringIO()
    with contextlib.redirect_stdout(console):
        code = cli.main(
            [
                "paper",
                "--quick",
                "--starts",
                "2",
                "--workers",
                "2",
                "--out",
                str(out),
                "--no-progress",
            ]
        )
    assert code == 0
    (out / "console.txt").write_text(console.getvalue())
    return out, json.loads((out / "results.json").read_text())


def test_outputs_written(study):
    out, _ = study
    for name in (
        "results.json",
        "report.md",
        "silverbox_train.png",
        "silverbox_validation.png",
        "silverbox_offset_validation.png",
        "two_tank.png",
        "robustness.png",
    ):
        assert (out / name).stat().st_size > 1000, name
    report = (out / "report.md").read_text()
    assert "Why the validation GOF differs" in report and "| newton |" in report


def test_the_console_summary_names_its_columns(study):
    out, r = study
    text = (out / "console.txt").read_text()
    for column in ("dataset", "accuracy", "method", "converged", "reported failure", "median ms"):
        assert column in text
    # one row per data set, accuracy level and method, as results.json has them
    for row in r["robustness"]:
        assert f"{row['converged']}/{row['starts']}" in text and row["method"] in text


def test_schema(study):
    _, r = study
    sb, tt = r["silverbox"], r["two_tank"]
    assert set(sb["paper_model"]) >= {
        "params",
        "x0",
        "train_cost",
        "train_gof",
        "val_gof",
        "iterations",
    }
    assert set(sb["paper_model"]["params"]) == {"m", "d", "a", "b"}
    assert len(sb["paper_model"]["x0"]) == 2
    assert set(sb["paper_estimates"]) >= {"train_cost", "train_gof", "val_gof"}
    assert set(sb["offset_model"]) >= {"params", "train_cost", "train_gof", "val_gof"}
    assert set(tt["paper_model"]) >= {"params", "cost", "gof", "iterations"}
    assert set(tt["paper_estimates"]) >= {"cost", "gof"}
    keys = {
        "dataset",
        "method",
        "accuracy",
        "starts",
        "converged",
        "failed",
        "best_val_gof",
        "median_val_gof",
        "median_iterations",
        "median_seconds",
    }
    rows = r["robustness"]
    assert len(rows) == 2 * len(COMPARED)
    for row in rows:
        assert keys <= set(row)
        assert row["starts"] == 2 and 0 <= row["converged"] <= 2 and 0 <= row["failed"] <= 2


def test_headline_numbers(study):
    _, r = study
    sb, tt = r["silverbox"], r["two_tank"]
    assert sb["paper_model"]["val_gof"] >= 0.90
    assert sb["paper_model"]["train_cost"] <= sb["paper_estimates"]["train_cost"]
    assert sb["offset_model"]["val_gof"] >= 0.97
    assert tt["paper_model"]["gof"] >= 0.788
    # the paper's own estimates, evaluated on the same data, are reproduced too
    assert sb["paper_estimates"]["val_gof"] == pytest.approx(0.897, abs=0.005)
    assert sb["mean_removed"]["paper_estimates_val_gof"] == pytest.approx(0.9626, abs=0.01)
    for row in r["robustness"]:
        if row["method"] == "newton":
            assert row["converged"] == row["starts"] and row["failed"] == 0


def test_starts_are_seeded_and_within_20_percent():
    guess = np.array([0.0, 5.1025e-6, 2.15e-4, 0.968, 3.976])
    a, b = paper.draw_starts(guess, 100, 0), paper.draw_starts(guess, 100, 0)
    np.testing.assert_array_equal(a, b)
    assert (a[:, 0] == 0).all()
    ratio = a[:, 1:] / guess[1:]
    assert (ratio >= 0.8).all() and (ratio <= 1.2).all() and ratio.std() > 0.05


def test_bundled_windows_are_the_papers():
    tr, va = datasets.silverbox_train(), datasets.silverbox_validation()
    assert tr.P == 1024 and va.P == 2047
    assert tr.t[0] == pytest.approx(10584 * datasets.SILVERBOX_TS)
    assert tr.u[0, 0] == pytest.approx(0.00655235, rel=1e-5)  # V1[10584] in the .mat file
    assert datasets.two_tank().P == 501
    np.testing.assert_allclose(datasets.two_tank_levels()[0], [0.20507812, 0.38085938])
    with pytest.raises(ValueError, match="holds samples"):
        datasets.silverbox(0, 100)
    assert benchmarks.silverbox_problem().theta_names == ["ydot(t0)", "m", "d", "a", "b"]


def test_accuracy_levels_are_substeps_or_the_papers_tolerances():
    from tensorid.paper.study import all_levels, level_options

    assert all_levels() == (
        "rk4x4", "rk4x16", "rk4x64", "dopri5-1e-10", "dopri5-1e-12", "dopri5-1e-14",
    )  # fmt: skip
    assert level_options(16) == {"substeps": 16}
    assert level_options("dopri5-1e-12") == {"scheme": "dopri5", "rtol": 1e-12, "atol": 1e-12}
    # rtol 1e-14 is below 100 eps: raised to it, as MATLAB's ode45 does
    assert level_options("dopri5-1e-14")["rtol"] == pytest.approx(2.22e-14, rel=1e-3)
    with pytest.raises(ValueError, match="rk4xN"):
        level_options("rk45-1e-6")
    assert cli.main(["paper", "--levels", "euler", "--out", "never-written"]) == 2


def test_the_adaptive_rows_stand_beside_the_papers_table_1(tmp_path):
    # one start per method at the paper's loosest tolerance, both data sets
    runs = paper.robustness_study(1, ["dopri5-1e-10"], workers=1)
    rows = paper.summarise(runs, ["dopri5-1e-10"])
    assert {r["accuracy"] for r in rows} == {"dopri5-1e-10"} and len(rows) == 2 * len(COMPARED)
    assert all(r["tolerance"] == 1e-10 and r["substeps"] is None for r in rows)
    from tensorid.paper.report import _robustness

    meta = {"starts": 1, "seed": 0, "workers": 1, "converged_rtol": 1e-6, "segments": 5,
            "integration_error": paper.integration_errors(["dopri5-1e-10"])}  # fmt: skip
    text = "\n".join(_robustness({"meta": meta, "robustness": rows}))
    assert "Beside the paper's Table 1" in text
    assert "| 1e-10 | 96.251 % | 76.782 % (100/100 started) |" in text
    assert meta["integration_error"]["silverbox"]["dopri5-1e-10"] < 1e-6
