"""A benchmark record from file to published score with the command line alone:
`tensorid simulate` and `tensorid compare` call the library's scoring, inputs a
record lacks held constant, one column map per file, the file's own sampling time,
clock jitter, parameters fixed and freed from the command line, and where a fit
came from (provenance)."""

from __future__ import annotations

import hashlib
import json
import warnings
from pathlib import Path

import numpy as np
import pytest

import tensorid as ti
from tensorid import cli

REPO = Path(__file__).resolve().parents[1]
SILVERBOX = REPO / "examples" / "silverbox"

DISCRETE = """discrete = True
rhs = {"x1": "a1*x1 - a2*x2 + b*tanh(c*u)", "x2": "x1"}
output = {"y": "x1 + 0.2*x1**3"}
inputs = ["u"]
params = ["a1", "a2", "b", "c"]
p0 = {"a1": 1.2, "a2": 0.5, "b": 0.8, "c": 1.5}
x0 = {"x1": 0.1, "x2": -0.2}
free_x0 = ["x1", "x2"]
"""
TRUE = {"a1": 1.2, "a2": 0.5, "b": 0.8, "c": 1.5}


def _discrete_record(tmp_path, P=120, jitter=0.0, header="t,u,y", noise=0.0):
    (tmp_path / "ar.py").write_text(DISCRETE)
    model = ti.load_model(tmp_path / "ar.py").model
    rng = np.random.default_rng(0)
    t = np.arange(P) * 1e-3
    u = rng.uniform(-1, 1, P)
    y = ti.simulate(model, TRUE, [0.1, -0.2], ti.Experiment(t, u)).y[:, 0]
    y = y + noise * rng.standard_normal(P)
    t_file = t + jitter * rng.uniform(-1, 1, P)
    path = tmp_path / "rec.csv"
    np.savetxt(path, np.column_stack([t_file, u, y]), delimiter=",", header=header, comments="")
    return model, path, t, u, y


def test_simulate_a_discrete_model_equals_the_library(tmp_path, capsys):
    model, path, t, u, y = _discrete_record(tmp_path)
    params = [f"{k}={v * 1.01}" for k, v in TRUE.items()]
    x0 = ["x1=0.05", "x2=0.01"]
    rc = cli.main(["simulate", str(tmp_path / "ar.py"), str(path), "--out", str(tmp_path / "s")]
                  + ["--params", *params, "--x0", *x0])  # fmt: skip
    assert rc == 0
    table = np.loadtxt(tmp_path / "s" / "simulation.csv", delimiter=",", skiprows=1)
    p = {k: v * 1.01 for k, v in TRUE.items()}
    ref = ti.simulate(model, p, [0.05, 0.01], ti.Experiment(t, u))
    np.testing.assert_allclose(table[:, 3], ref.y[:, 0], rtol=1e-14, atol=1e-15)
    out = capsys.readouterr().out.splitlines()
    assert out[1] == "initial state x1=0.05, x2=0.01 (x1, x2 from --x0)"  # not the file's too
    gof = float(out[0].split()[-1])
    assert gof == pytest.approx(ti.gof(y, ref.y[:, 0]), abs=1e-4)  # printed to 4 digits
    assert gof > 0.5  # not the ODE's -1e8 of old


def test_simulate_with_an_init_window_estimates_x0_on_it_only(tmp_path, capsys):
    _, path, *_ = _discrete_record(tmp_path)
    rc = cli.main(["simulate", str(tmp_path / "ar.py"), str(path), "--init-window", "10",
                   "--out", str(tmp_path / "s.csv")])  # fmt: skip
    assert rc == 0
    out = capsys.readouterr().out
    assert "estimated on its first 10 samples" in out and "after the first 10" in out
    assert float(out.splitlines()[0].split()[2]) > 0.999999  # the true model: y fits


def test_the_command_s_figures_are_the_same_drawn_by_its_renderer_or_here(tmp_path, capsys):
    """`tensorid simulate` as a user runs it starts its renderer before its imports
    and draws there; called in a process (the tests, the Python API) it draws here:
    the same files, window shading and all."""
    import subprocess
    import sys

    _, path, *_ = _discrete_record(tmp_path)
    argv = ["simulate", str(tmp_path / "ar.py"), str(path), "--init-window", "10"]
    assert cli.main([*argv, "--out", str(tmp_path / "here")]) == 0
    run = subprocess.run(
        [sys.executable, "-m", "tensorid", *argv, "--out", str(tmp_path / "there")],
        capture_output=True, text=True, cwd=tmp_path,
    )  # fmt: skip
    assert run.returncode == 0, run.stderr
    for name in ("simulation_y.png", "simulation.csv"):
        here, there = (tmp_path / d / name for d in ("here", "there"))
        assert here.read_bytes() == there.read_bytes(), name
    assert not list((tmp_path / "there").glob(".*part"))


def _fit_silverbox(tmp_path, *extra):
    out = tmp_path / "fit"
    argv = ["fit", str(SILVERBOX / "model.py"), str(SILVERBOX / "train.csv"),
            "--validate", str(SILVERBOX / "validate.csv"), "--init-window", "50",
            "--fix", "m=5.1693e-06", "--fix", "b=3.6544", "--bounds", "a=0.5:1.5",
            "--out", str(out), "--no-progress", *extra]  # fmt: skip
    assert cli.main(argv) == 0
    return out


def test_compare_equals_validate_on_a_discrete_model(tmp_path, capsys):
    _, path, *_ = _discrete_record(tmp_path, P=80, noise=0.01)
    val = tmp_path / "val.csv"
    path.rename(val)
    _discrete_record(tmp_path, P=60, noise=0.01)
    model = str(tmp_path / "ar.py")
    argv = ["fit", model, str(path), "--validate", str(val), "--init-window", "10"]
    assert cli.main([*argv, "--fix", "c=1.5", "--out", str(tmp_path / "f"), "--no-progress"]) == 0
    fit = json.loads((tmp_path / "f" / "fit.json").read_text())
    argv = ["compare", model, str(val), "--params", str(tmp_path / "f" / "fit.json")]
    assert cli.main([*argv, "--init-window", "10", "--out", str(tmp_path / "c")]) == 0
    c = json.loads((tmp_path / "c" / "compare.json").read_text())
    for metric in ("rmse", "nrmse", "gof"):
        assert c["outputs"]["y"][metric] == pytest.approx(
            fit[metric]["validation"]["val"]["y"], rel=1e-9, abs=1e-15
        )
    assert c["integration"]["scheme"] == "discrete" and c["scored_samples"] == 70
    assert fit["overrides"] == {"fix": {"c": 1.5}} and "c" not in fit["estimates"]
    for d, command in ((fit, "tensorid fit "), (c, "tensorid compare ")):
        prov = d["provenance"]
        assert prov["command"].startswith(command) and prov["model"]["path"] == model
        assert prov["model"]["sha256"] == hashlib.sha256(Path(model).read_bytes()).hexdigest()
        assert set(prov["versions"]) == {"tensorid", "jax", "numpy", "python"}
    assert [Path(d["path"]).name for d in fit["provenance"]["data"]] == ["rec.csv", "val.csv"]
    report = (tmp_path / "f" / "report.md").read_text()
    assert report.splitlines()[0] == f"# Fit of `{model}`" and "## Provenance" in report


@pytest.mark.slow
def test_compare_equals_validate_on_a_bundled_record(tmp_path, capsys):
    out = _fit_silverbox(tmp_path)
    fit = json.loads((out / "fit.json").read_text())
    cmp_out = tmp_path / "cmp"
    rc = cli.main(["compare", str(SILVERBOX / "model.py"), str(SILVERBOX / "validate.csv"),
                   "--params", str(out / "fit.json"), "--init-window", "50",
                   "--out", str(cmp_out)])  # fmt: skip
    assert rc == 0
    c = json.loads((cmp_out / "compare.json").read_text())
    assert c["init_window"] == 50 and c["scored_samples"] == 2047 - 50
    y = c["outputs"]["y"]
    for metric in ("rmse", "nrmse", "gof"):
        assert y[metric] == pytest.approx(fit[metric]["validation"]["validate"]["y"], rel=1e-9)
    assert y["fit_percent"] == pytest.approx(100 * y["gof"], rel=1e-12)
    assert y["r2"] == pytest.approx(1 - y["nrmse"] ** 2, rel=1e-12)
    np.testing.assert_allclose(list(c["x0"].values()), fit["validation_x0"]["validate"], 1e-9)
    # the initial states' fit ended through the one loop, converged, and both files say so
    assert c["x0_fit_status"] == fit["validation_x0_status"]["validate"]
    assert ti.Status[c["x0_fit_status"].upper()].success
    assert c["params"] == fit["params"]
    assert (cmp_out / "compare_y.png").stat().st_size > 1000
    # the command line's overrides and the provenance are recorded
    assert fit["overrides"] == {"fix": {"m": 5.1693e-06, "b": 3.6544}, "bounds": {"a": [0.5, 1.5]}}
    assert fit["params"]["m"] == 5.1693e-06 and "m" not in fit["estimates"]
    prov = fit["provenance"]
    assert prov["model"]["path"].endswith("model.py") and len(prov["model"]["sha256"]) == 64
    assert [Path(d["path"]).name for d in prov["data"]] == ["train.csv", "validate.csv"]
    assert prov["command"].startswith("tensorid fit ") and "--fix m=5.1693e-06" in prov["command"]
    assert set(prov["versions"]) == {"tensorid", "jax", "numpy", "python"}
    assert c["provenance"]["command"].startswith("tensorid compare ")
    report = (out / "report.md").read_text()
    assert report.startswith("# Fit of `") and "model.py`" in report.splitlines()[0]
    assert "## Provenance" in report
    # simulate the saved fit with one parameter changed: the fit.json, then NAME=VALUE
    capsys.readouterr()
    argv = ["simulate", str(SILVERBOX / "model.py"), str(SILVERBOX / "validate.csv"),
            "--init-window", "50", "--out", str(tmp_path / "sim"), "--params"]  # fmt: skip
    assert cli.main([*argv, str(out / "fit.json")]) == 0
    same = float(capsys.readouterr().out.split()[2])
    assert same == pytest.approx(y["gof"], abs=1e-4)
    assert cli.main([*argv, str(out / "fit.json"), "a=0.9"]) == 0
    assert float(capsys.readouterr().out.split()[2]) < same - 0.01
    assert cli.main([*argv, "a=0.9", str(out / "fit.json")]) != 0
    assert "give one fit.json, first" in capsys.readouterr().err
    # a slice of the record, as fit's --validate-samples takes one
    sliced = ["compare", str(SILVERBOX / "model.py"), str(SILVERBOX / "validate.csv"),
              "--params", str(out / "fit.json"), "--out", str(tmp_path / "c2")]  # fmt: skip
    assert cli.main([*sliced, "--samples", "100:1100"]) == 0
    c2 = json.loads((tmp_path / "c2" / "compare.json").read_text())
    assert c2["scored_samples"] == 1000 and c2["samples"] == [100, 1100]


def test_compare_refuses_a_long_horizon_and_a_short_window_before_any_work(tmp_path, capsys):
    fit = tmp_path / "fit.json"
    fit.write_text(json.dumps({"params": TRUE}))
    _, path, *_ = _discrete_record(tmp_path)
    base = ["compare", str(tmp_path / "ar.py"), str(path), "--params", str(fit)]
    assert cli.main([*base, "--horizon", "500", "--out", str(tmp_path / "c")]) == 2
    assert "--horizon 500" in capsys.readouterr().err
    # an output-error fit's predictions at every horizon are its simulation
    assert cli.main([*base, "--horizon", "3", "--out", str(tmp_path / "h")]) == 0
    assert cli.main([*base, "--out", str(tmp_path / "s")]) == 0
    h, s = (json.loads((tmp_path / d / "compare.json").read_text()) for d in "hs")
    assert h["outputs"] == s["outputs"] and h["horizon"] == 3
    assert h["scored_as"] == s["scored_as"] == "simulation"  # horizon 3 alone misled
    capsys.readouterr()
    assert cli.main([*base, "--init-window", "119", "--out", str(tmp_path / "c")]) == 2
    assert "--init-window" in capsys.readouterr().err
    assert not (tmp_path / "c").exists()


def test_an_input_the_record_lacks_is_held_constant(tmp_path):
    model = ti.Model(rhs=lambda x, p, u: -p[0] * x + u[0] + u[1], states=["x"], params=["k"],
                     inputs=["u", "pulses"], outputs=["x"])  # fmt: skip
    path = tmp_path / "r.csv"
    np.savetxt(path, np.column_stack([np.arange(5.0), np.ones(5), np.zeros(5)]),
               delimiter=",", header="t,u,x", comments="")  # fmt: skip
    with pytest.raises(ValueError, match="--columns pulses=0"):
        ti.load_data(path, model)
    for columns in ({"pulses": 0}, {"pulses": "2.5"}):
        e = ti.load_data(path, model, columns=columns)[0]
        np.testing.assert_array_equal(e.u[:, 1], float(columns["pulses"]))
        np.testing.assert_array_equal(e.u[:, 0], 1.0)


def test_one_column_map_per_file_names_each_record(tmp_path, capsys):
    import scipy.io

    model = ti.Model(rhs=lambda x, p, u: -p[0] * x + u[0], output=lambda x, p: x,
                     states=["x"], params=["k"], inputs=["u"], outputs=["y"])  # fmt: skip
    t = np.arange(40) * 0.1
    recs = {}
    for i in (1, 2, 3):
        u = np.sin(i * t)
        recs[f"u{i}"], recs[f"z{i}"] = u, ti.simulate(model, [1.0 + i], [0.0],
                                                        ti.Experiment(t, u)).y[:, 0]  # fmt: skip
    path = tmp_path / "three.mat"
    scipy.io.savemat(path, dict(recs, Ts=0.1))
    maps = [{"u": f"u{i}", "y": f"z{i}"} for i in (1, 2, 3)]
    exps = ti.load_data([path] * 3, model, columns=maps)
    assert [e.name for e in exps] == [f"three:u=u{i},y=z{i}" for i in (1, 2, 3)]
    for i, e in enumerate(exps, 1):
        np.testing.assert_array_equal(e.u[:, 0], recs[f"u{i}"])
        np.testing.assert_allclose(e.t, t, rtol=1e-15, atol=1e-15)  # from the file's Ts
    with pytest.raises(ValueError, match="2 column maps for 3 data files"):
        ti.load_data([path] * 3, model, columns=maps[:2])
    # on the command line: --columns once per file, named the same way, recorded
    (tmp_path / "m.py").write_text(
        'rhs = {"x": "-k*x + u"}\noutput = {"y": "x"}\ninputs = ["u"]\np0 = {"k": 1.5}\n'
    )
    base = ["fit", str(tmp_path / "m.py"), *[str(path)] * 3, "--out", str(tmp_path / "o")]
    columns = [a for m in maps for a in ("--columns", f"u={m['u']},y={m['y']}")]
    assert cli.main([*base, *columns[:4]]) == 2
    assert "given 2 times for 3 data files" in capsys.readouterr().err
    from tensorid.app.commands import _data_entries

    entries = _data_entries(model, [path] * 3, maps)
    assert [d["columns"] for d in entries] == [{"t": "t", **m} for m in maps]
    assert len({d["sha256"] for d in entries}) == 1 and len(entries[0]["sha256"]) == 64


def test_clock_jitter_snaps_to_the_grid_with_a_note(tmp_path, capsys):
    model, path, t, u, y = _discrete_record(tmp_path, jitter=2.4e-8)
    with pytest.warns(UserWarning, match=r"within 2.\de-08 s .* snapped"):
        e = ti.load_data(path, model)[0]
    assert np.ptp(np.diff(e.t)) < 1e-15 and np.diff(e.t)[0] == pytest.approx(1e-3, rel=1e-6)
    # the plainest grid within the tolerance: the stamps as the clock meant them
    # (0.001, not the least-squares grid's 0.00099999998 + 3.1e-09), and as
    # simulation.csv writes them
    np.testing.assert_array_equal(e.t, np.round(t, 3))
    assert cli.main(["simulate", str(tmp_path / "ar.py"), str(path), "--out",
                     str(tmp_path / "sim")]) == 0  # fmt: skip
    rows = (tmp_path / "sim" / "simulation.csv").read_text().splitlines()
    assert [r.split(",")[0] for r in rows[:4]] == ["t", "0.0", "0.001", "0.002"]
    # the command line prints the note as one line (here before refusing the window)
    argv = ["simulate", str(tmp_path / "ar.py"), str(path), "--init-window", "500"]
    assert cli.main([*argv, "--out", str(tmp_path / "s")]) == 2
    err = capsys.readouterr().err.splitlines()
    assert err[0].startswith("tensorid: note: ") and "snapped" in err[0], err
    # uneven beyond the tolerance: kept as it is; a discrete model's error names --ts
    _discrete_record(tmp_path, jitter=1e-5)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        e = ti.load_data(path, model)[0]
    with pytest.raises(ValueError, match="--ts"):
        ti.Problem(model, e, p0=TRUE)


def test_time_stamps_uniform_to_their_own_rounding_are_kept_exactly(tmp_path):
    # found by the loaders' property test: near t = 2 a microsecond grid is uniform
    # only to a few 1e-16 s, which once counted as jitter and moved t[0] off 2.0
    (tmp_path / "ar.py").write_text(DISCRETE)
    model = ti.load_model(tmp_path / "ar.py").model
    t = 2.0 + np.concatenate([[0.0], np.cumsum(np.full(6, 1e-6))])
    path = tmp_path / "r.csv"
    path.write_text("t,u,y\n" + "".join(f"{float(x)!r},1,2\n" for x in t))
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no note either
        e = ti.load_data(path, model)[0]
    assert (e.t == t).all()


def test_a_csv_ts_column_gives_the_time(tmp_path):
    (tmp_path / "ar.py").write_text(DISCRETE)
    model = ti.load_model(tmp_path / "ar.py").model
    path = tmp_path / "r.csv"
    path.write_text("Ts,u,y\n0.01,1,2\n,2,3\n,3,4\n")
    e = ti.load_data(path, model)[0]
    np.testing.assert_allclose(e.t, [0.0, 0.01, 0.02])
    path.write_text("Ts,u,y\n0.01,1,2\n0.02,2,3\n,3,4\n")
    with pytest.raises(ValueError, match="'Ts' should hold the sampling time"):
        ti.load_data(path, model)


@pytest.mark.parametrize(
    "args, match",
    [
        (["--fix", "nope=1"], "--fix names \\['nope'\\]"),
        (["--fix", "m=1", "--free", "m"], "both --fix and --free"),
        (["--fix", "m=1e-6", "--bounds", "m=1e-7:1e-5"], "add --free m"),
        (["--bounds", "a=2:1"], "LO must be below HI"),
        (["--bounds", "y=0:1"], "not initial states"),
        (["--init-window", "1"], "--init-window"),
    ],
)
def test_bad_overrides_are_refused_before_the_fit(tmp_path, capsys, args, match):
    argv = [
        "fit",
        str(SILVERBOX / "model.py"),
        str(SILVERBOX / "train.csv"),
        "--validate",
        str(SILVERBOX / "validate.csv"),
        "--out",
        str(tmp_path / "o"),
        *args,
    ]
    assert cli.main(argv) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and __import__("re").search(match, err), err
    assert not (tmp_path / "o").exists()


def test_starts_honour_spread_inside_bounds_and_go_log_uniform_over_decades():
    from tensorid.solve.multistart import draw_starts

    theta0 = np.array([1e-5, 1.0, 5.0])
    lo, hi = np.array([1e-7, 0.0, -np.inf]), np.array([1e-3, 10.0, np.inf])
    box = draw_starts(theta0, lo, hi, 400, seed=0)[1:]
    # across the box, by decades for the first entry: about a quarter in each decade
    decades = np.histogram(np.log10(box[:, 0]), bins=[-7, -6, -5, -4, -3])[0]
    assert decades.min() >= 90 and (box[:, 1] >= 0).all() and box[:, 1].max() > 9
    near = draw_starts(theta0, lo, hi, 400, spread=0.5, seed=0)[1:]
    assert near[:, 0].min() >= 1e-5 / 1.5 * (1 - 1e-12) and near[:, 0].max() <= 1.5e-5 * (1 + 1e-12)
    assert np.median(near[:, 0]) == pytest.approx(1e-5, rel=0.05)  # log-uniform: centred in log
    assert near[:, 1].min() >= 0.5 and near[:, 1].max() <= 1.5  # ±50 % inside [0, 10]
    assert near[:, 2].min() >= 2.5 and near[:, 2].max() <= 7.5


def test_starts_tied_at_the_best_cost_go_to_the_fewest_iterations_and_failures_are_told():
    from tensorid.analysis.summary import starts_outcome
    from tensorid.solve.multistart import ranked_starts

    def run(i, cost, nit, status="ftol", success=True):
        return {"start": i, "cost": cost, "nit": nit, "status": status, "success": success}

    runs = [
        run(0, 1.0 + 1e-12, 203),
        run(1, 1.0, 40),
        run(2, np.inf, 0, "nonfinite_start", False),
        run(3, 1.0 + 5e-13, 12),
        run(4, 2.0, 30, "maxiter", False),
        run(5, np.inf, 0, "nonfinite_start", False),
    ]
    ranked = ranked_starts(runs)
    assert [r["start"] for r in ranked] == [3, 1, 0, 4, 2, 5]
    assert starts_outcome(ranked) == (
        ", 3 at the best cost (to 1e-09 relative), 3 failed: 2 nonfinite start, 1 maxiter"
    )


def test_compare_and_simulate_replace_their_own_files_not_a_fits(tmp_path, capsys):
    """A compare (or simulate) into a folder an earlier one wrote leaves none of its
    figures behind (a model with another output left compare_w.png beside the new
    ones), and never removes a fit's files in the same folder."""
    _, path, *_ = _discrete_record(tmp_path, P=60, noise=0.01)
    model, f = str(tmp_path / "ar.py"), tmp_path / "f"
    assert cli.main(["fit", model, str(path), "--out", str(f), "--no-progress"]) == 0
    fits = {p.name for p in f.iterdir()}
    for command, manifest in (("compare", ".tensorid-compare-files"),
                              ("simulate", ".tensorid-simulate-files")):  # fmt: skip
        stale = f / f"{command}_w.png"  # as an earlier run of another model left it
        stale.write_bytes(b"an old figure")
        (f / manifest).write_text(f"{stale.name}\n")
        argv = [command, model, str(path), "--params", str(f / "fit.json"), "--out", str(f)]
        assert cli.main(argv) == 0
        assert not stale.exists()
        assert fits <= {p.name for p in f.iterdir()}  # the fit's files all kept
        assert json.loads((f / "fit.json").read_text())["params"]


def test_a_constant_output_s_undefined_scores_are_said_why(tmp_path, capsys):
    """A validation record whose output is constant (a sensor stuck, a record at rest)
    has no spread for GOF, NRMSE, R² and fit percent to divide by: the table said GOF
    "not finite" as for a simulation that blew up, compare printed GOF -inf, and none
    said why. They read "undefined", with a note naming the record and its RMSE."""
    model, path, t, u, y = _discrete_record(tmp_path)
    flat = tmp_path / "flat.csv"
    rows = np.column_stack([t, u, np.full_like(y, 0.1)])  # 0.1: its mean rounds
    np.savetxt(flat, rows, delimiter=",", header="t,u,y", comments="")
    model_file, fit = str(tmp_path / "ar.py"), tmp_path / "f"
    argv = ["fit", model_file, str(path), "--validate", str(flat), "--no-progress"]
    assert cli.main([*argv, "--out", str(fit)]) == 0
    out = capsys.readouterr().out
    assert "│ undefined │" in out and "GOF validation flat: y undefined" in out
    note = "validation 'flat', y: GOF (fit percent), NRMSE and R² are undefined: y is constant"
    assert f"note: {note}" in out and "(0.1 at every scored sample)" in out
    data = json.loads((fit / "fit.json").read_text())
    assert data["gof"]["validation"]["flat"]["y"] is None
    assert len(data["gof_notes"]) == 1 and data["gof_notes"][0].startswith(note)
    assert note in (fit / "report.md").read_text()
    rc = cli.main(["compare", model_file, str(flat), "--params", str(fit / "fit.json"),
                   "--out", str(tmp_path / "c")])  # fmt: skip
    assert rc == 0
    out = capsys.readouterr().out
    assert "GOF undefined" in out and "fit undefined" in out and f"note: {note}" in out
    assert "-inf" not in out
    scored = json.loads((tmp_path / "c" / "compare.json").read_text())
    assert scored["gof_notes"] == data["gof_notes"]


def test_a_fit_of_another_or_edited_model_file_is_noted(tmp_path, capsys):
    """compare with a fit.json made from another model file, or from this one before
    an edit, scored the parameters with these equations without a word."""
    model, path, *_ = _discrete_record(tmp_path)
    fit = tmp_path / "f"
    argv = ["fit", str(tmp_path / "ar.py"), str(path), "--no-progress", "--out", str(fit)]
    assert cli.main(argv) == 0
    compare = ["compare", str(tmp_path / "ar.py"), str(path), "--params", str(fit / "fit.json"),
               "--out", str(tmp_path / "c")]  # fmt: skip
    capsys.readouterr()
    assert cli.main(compare) == 0
    assert "note" not in capsys.readouterr().err  # the same file: nothing to say
    (tmp_path / "other.py").write_text(DISCRETE.replace("0.2*x1**3", "0.3*x1**3"))
    assert cli.main([compare[0], str(tmp_path / "other.py"), *compare[2:]]) == 0
    err = capsys.readouterr().err
    assert f"note: the fit was made with {tmp_path / 'ar.py'} (SHA-256" in err
    (tmp_path / "ar.py").write_text(DISCRETE + "# edited\n")
    assert cli.main(compare) == 0
    assert "the fit was made with this model file before it was edited" in capsys.readouterr().err


def test_compare_scores_a_record_joined_from_an_input_and_an_output_file(tmp_path, capsys):
    """issue 51, item 5: `u.csv+y.csv` gave one role for two file entries (IndexError)."""
    _, path, t, u, y = _discrete_record(tmp_path, P=60, noise=0.01)
    model = str(tmp_path / "ar.py")
    argv = ["fit", model, str(path), "--fix", "c=1.5", "--out", str(tmp_path / "f")]
    assert cli.main([*argv, "--no-progress"]) == 0
    np.savetxt(tmp_path / "u.csv", np.column_stack([t, u]), delimiter=",", header="t,u",
               comments="")  # fmt: skip
    np.savetxt(tmp_path / "y.csv", np.column_stack([t, y]), delimiter=",", header="t,y",
               comments="")  # fmt: skip
    joined = f"{tmp_path / 'u.csv'}+{tmp_path / 'y.csv'}"
    argv = ["compare", model, joined, "--params", str(tmp_path / "f" / "fit.json")]
    assert cli.main([*argv, "--out", str(tmp_path / "c")]) == 0
    c = json.loads((tmp_path / "c" / "compare.json").read_text())
    assert [(Path(d["path"]).name, d["role"]) for d in c["provenance"]["data"]] == [
        ("u.csv", "scored"), ("y.csv", "scored"),
    ]  # fmt: skip
    assert np.isfinite(c["outputs"]["y"]["rmse"])


def test_compare_scores_a_population_fit_whose_x0_is_an_expression(tmp_path, capsys):
    """issue 51, item 4: compare of a population fit whose x0 is an expression of the
    unit's data (theophylline's "Dose * Wt") advised --x0, which compare lacks; now the
    expression is evaluated on the record with the fit's parameters, and the command
    says they are the population's typical values."""
    root = Path(__file__).resolve().parents[1]
    theo = root / "src/tensorid/datasets/theophylline.csv"
    fit = tmp_path / "fit.json"
    typical = {"ka": 1.5902, "cl": 2.7515, "v": 31.809}
    fit.write_text(json.dumps({"params": typical, "population": {"ka": {"omega": 0.63}}}))
    rc = cli.main(["compare", str(root / "examples/theophylline/model.py"), str(theo),
                   "--params", str(fit), "--records", "ID", "--unit", "3",
                   "--columns", "t=Time,cp=conc", "--out", str(tmp_path / "c")])  # fmt: skip
    out = capsys.readouterr().out
    assert rc == 0, out
    rows = [r.split(",") for r in theo.read_text().splitlines()]
    head, unit = rows[0], next(r for r in rows[1:] if r[rows[0].index("ID")] == "3")
    dose = float(unit[head.index("Dose")]) * float(unit[head.index("Wt")])
    assert f"initial state depot={dose:.6g}, center=0" in out
    assert "the population's typical values" in out
    scored = json.loads((tmp_path / "c" / "compare.json").read_text())
    assert scored["outputs"]["cp"]["gof"] > 0.5


def test_ipred_is_refused_in_one_line_where_it_cannot_estimate_a_units_own_values(tmp_path, capsys):
    """issue 49: --ipred (a unit's η̂ by empirical Bayes) needs a population fit's
    fit.json and the unit's own data, and estimates from the fit's values alone."""
    root = Path(__file__).resolve().parents[1]
    theo = root / "src/tensorid/datasets/theophylline.csv"
    model = root / "examples/theophylline/model.py"
    typical = {"ka": 1.5902, "cl": 2.7515, "v": 31.809}
    single, fleet = tmp_path / "single.json", tmp_path / "fleet.json"
    single.write_text(json.dumps({"params": typical}))
    fleet.write_text(json.dumps({"params": typical, "population": {"ka": {"omega": 0.63}}}))
    base = [str(model), str(theo), "--records", "ID", "--unit", "3", "--ipred",
            "--out", str(tmp_path / "c")]  # fmt: skip
    cases = [
        (["compare", *base, "--columns", "t=Time,cp=conc", "--params", str(single)],
         "is not a population fit's fit.json"),
        (["simulate", *base, "--columns", "t=Time,cp=conc", "--params", str(fleet), "ka=2"],
         "drop the NAME=VALUE pairs"),
        (["simulate", *base, "--columns", "t=Time", "--params", str(fleet)],
         "no measured outputs"),
        (["simulate", *base, "--columns", "t=Time,cp=conc"], "give its fit.json with --params"),
    ]  # fmt: skip
    for argv, expect in cases:
        assert cli.main(argv) == 2
        err = capsys.readouterr().err
        assert expect in err and "--ipred" in err and len(err.strip().splitlines()) == 1, err


def test_an_init_window_on_a_record_with_unmeasured_rows_counts_its_measurements():
    """12 rows, 2 measured (rows 1 and 11, as a unit of phenobarbital's doses and
    levels): a window of 3 rows left 1 measurement to score, and the score was NaN
    without a word. It is refused in one line; the whole record scores both."""
    m = ti.Model(rhs=lambda x, p, u: -p[0] * x, output=lambda x, p: x[:1],
                 states=["a"], params=["k"], outputs=["y"])  # fmt: skip
    t = np.arange(12.0)
    y = np.exp(-0.3 * t)[:, None]
    res = ti.fit(ti.Problem(m, ti.Experiment(t, None, y), p0={"k": 0.2}, x0=[1.0], free_x0=["a"]))
    seen = np.isin(np.arange(12), [1, 11])[:, None]
    e = ti.Experiment(t, None, y, observed=seen, name="u1")
    with pytest.raises(ValueError, match="init_window 3 leaves 1 measured sample.*and 1 to score"):
        res.validate(e, init_window=3)
    assert res.validate(e)[0].samples == 2
