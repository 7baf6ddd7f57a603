"""The rough edges a new user hit on the first release, one test each: intervals
printed too short, plots written unasked, multi-start counts, `simulate` output,
repeated labels, progress in logs, offline docs, ignored outputs."""

from __future__ import annotations

import io
import json
import re
import shutil
import subprocess
import warnings
from pathlib import Path

import numpy as np
import pytest
from conftest import SILVERBOX_P, silverbox_data, silverbox_model

import tensorid as ti
from tensorid import cli

ROOT = Path(__file__).resolve().parents[1]
EXAMPLE = ROOT / "examples" / "silverbox"


@pytest.fixture(scope="module")
def silverbox_fit(tmp_path_factory):
    """The README's fit command on the shipped example, as a user runs it."""
    out = tmp_path_factory.mktemp("fit") / "silverbox-fit"
    args = ["fit", str(EXAMPLE / "model.py"), str(EXAMPLE / "train.csv")]
    args += ["--validate", str(EXAMPLE / "validate.csv"), "--out", str(out), "--no-progress"]
    assert cli.main(args) == 0
    return out


def _interval_rows(report: str) -> list[tuple[str, str, str, str]]:
    rows = re.findall(r"^\| (\S+) \| (\S+) \| (\S+) \| \[(\S+), (\S+)\] \|.*$", report, flags=re.M)
    return [(n, se, lo, hi) for n, _, se, lo, hi in rows]


def test_every_interval_in_report_md_has_visible_width(silverbox_fit):
    rows = _interval_rows((silverbox_fit / "report.md").read_text())
    assert {r[0] for r in rows} >= {"m", "d", "a", "b", "u0"}
    for name, se, lo, hi in rows:
        assert lo != hi, (name, lo, hi)  # m = 5.17e-6 ± 4e-9 printed as [5e-06, 5e-06]
        assert float(lo) < float(hi)
        assert len(se.replace("0.", "").lstrip("0").split("e")[0].replace(".", "")) >= 2, se


def test_the_summary_prints_intervals_with_visible_width():
    prob = ti.load_model(EXAMPLE / "model.py")
    data = ti.load_data(EXAMPLE / "train.csv", prob.model)
    problem = ti.Problem(
        prob.model, data, p0=prob.p0, x0=prob.x0_array(), free_x0=prob.free_x0, bounds=prob.bounds
    )
    summary = ti.fit(problem).summary()
    rows = [line.split("│") for line in summary.splitlines() if "│" in line]
    row = "│".join(next(r for r in rows if r[1].strip() == "m"))
    lo, hi = row.split("[")[1].split("]")[0].split(", ")
    assert lo != hi and float(lo) < float(hi)


def test_plot_without_a_path_writes_nothing_and_returns_figures(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    prob = ti.Problem(silverbox_model(), silverbox_data(P=200), p0=SILVERBOX_P, x0=[0.0, 0.0])
    res = ti.fit(prob, maxiter=3)
    figs = res.plot()
    assert figs and all(hasattr(f, "savefig") for f in figs)
    assert list(tmp_path.iterdir()) == []
    written = res.plot(tmp_path / "figs")
    assert all(Path(p).is_file() for p in written)


@pytest.mark.parametrize("method", ["newton", "fd-lsq"])
def test_multistart_reports_the_best_starts_own_run_and_the_totals(method):
    prob = ti.Problem(
        silverbox_model(),
        silverbox_data(P=200),
        p0={k: v * 1.1 for k, v in SILVERBOX_P.items()},
        x0=[0.0, 0.0],
    )
    res = ti.fit(prob, method, starts=4, workers=1, spread=0.1)
    best = res.starts[0]
    assert res.nit >= best["nit"] > 1  # not just the refinement's single iteration
    its = [h["iteration"] for h in res.history]
    assert len(its) > 2 and its == sorted(set(its))  # the whole run, each iteration once
    if method == "newton":
        assert len(res.history) == res.nit + 1
    assert res.nit_total >= sum(s["nit"] for s in res.starts)
    assert res.nfev > res.nfev_best >= best["nfev"]
    assert "best of 4 starts" in res.summary() and "all starts" in res.summary()


def test_simulate_writes_a_folder_like_fit_and_says_which_x0(tmp_path, capsys, silverbox_fit):
    out = tmp_path / "sim"
    args = ["simulate", str(EXAMPLE / "model.py"), str(EXAMPLE / "validate.csv")]
    rc = cli.main(args + ["--params", str(silverbox_fit / "fit.json"), "--out", str(out)])
    assert rc == 0
    header = (out / "simulation.csv").read_text().splitlines()[0].split(",")
    assert header == ["t", "u", "y", "y_sim", "state_y", "state_ydot"]
    text = capsys.readouterr().out
    assert "initial state" in text and "estimated on this record" in text
    table = np.loadtxt(out / "simulation.csv", delimiter=",", skiprows=1)
    # estimated, not the training record's x0 silently reused
    train_x0 = json.loads((silverbox_fit / "fit.json").read_text())["x0"]
    assert not np.allclose(table[0, 4:], train_x0)
    assert np.allclose(
        table[0, 4:], [float(v) for v in re.findall(r"y=(\S+), ydot=(\S+) ", text)[0]], rtol=1e-5
    )


def test_simulate_says_which_parameters_came_from_the_model_file(tmp_path, capsys):
    # a partial NAME=VALUE list took the rest from p0 without a word (a new user's GOF
    # dropped to 0.84 and nothing said why)
    args = ["simulate", str(EXAMPLE / "model.py"), str(EXAMPLE / "validate.csv")]
    assert cli.main(args + ["--params", "m=5.17e-6", "d=2.18e-4", "--out", str(tmp_path)]) == 0
    text = capsys.readouterr().out
    line = next(t for t in text.splitlines() if t.startswith("parameters "))
    assert "a=" in line and "b=" in line and "u0=" in line and "m=" not in line
    assert line.endswith("(the model file's p0, not in --params)")
    assert cli.main(args + ["--out", str(tmp_path / "all")]) == 0
    assert "(the model file's p0)" in capsys.readouterr().out
    # a fit.json that lacks some (another model file's): the same line
    fitted = {"params": {"m": 5.17e-6, "d": 2.18e-4}, "x0": [0.0, 0.0]}
    (tmp_path / "fit.json").write_text(json.dumps(fitted))
    assert (
        cli.main(args + ["--params", str(tmp_path / "fit.json"), "--out", str(tmp_path / "f")]) == 0
    )
    assert "u0=0 (the model file's p0, not in --params)" in capsys.readouterr().out
    # compare said nothing of it: scored with u0 from p0 without a word
    args[0] = "compare"
    assert (
        cli.main(args + ["--params", str(tmp_path / "fit.json"), "--out", str(tmp_path / "c")]) == 0
    )
    assert "u0=0 (the model file's p0, not in --params)" in capsys.readouterr().out


def test_no_label_is_repeated(silverbox_fit, capsys):
    report = (silverbox_fit / "report.md").read_text()
    for bad in ("train train", "converged (converged", " 1 iterations", "validate validate"):
        assert bad not in report
    args = ["fit", str(EXAMPLE / "model.py"), str(EXAMPLE / "train.csv"), "--no-progress"]
    cli.main(args + ["--validate", str(EXAMPLE / "validate.csv"), "--out", str(silverbox_fit)])
    text = capsys.readouterr().out
    assert "GOF train train" not in text and "GOF validation validate" not in text
    assert "GOF train:" in text and "GOF validation:" in text
    p0 = {k: 1.05 * v for k, v in SILVERBOX_P.items()}
    prob = ti.Problem(silverbox_model(), silverbox_data(P=200), p0=p0, x0=[0.0, 0.0])
    res = ti.fit(prob, maxiter=1)
    titles = [ax.get_title() for f in res.plot() for ax in f.axes]
    assert not any("training: training" in t or "train: train" in t for t in titles)
    assert "1 iteration," in res.summary() or "1 iteration;" in res.summary()


def test_several_records_of_a_kind_keep_their_names():
    from tensorid.analysis.validation import record_label

    assert record_label("training", "train") == "training"
    assert record_label("training", "train", alone=False) == "training 'train'"
    assert record_label("training", "train2") == "training 'train2'"
    assert record_label("validation", "val") == "validation 'val'"
    exps = [silverbox_data(P=100, seed=s) for s in (1, 2)]
    res = ti.fit(ti.Problem(silverbox_model(), exps, p0=SILVERBOX_P, x0=[0.0, 0.0]), maxiter=1)
    titles = {ax.get_title() for f in res.plot() for ax in f.axes}
    assert any("'sb1'" in t for t in titles) and any("'sb2'" in t for t in titles)


def test_paper_progress_in_a_log_is_whole_lines():
    from tensorid.app.progress import study_progress

    log = io.StringIO()
    with study_progress(True, stream=log) as prog:
        prog.step("Silverbox")
        prog.start_robustness(20, 2)
        for i in range(20):
            prog.advance(
                {"dataset": "silverbox", "method": "newton", "substeps": 4, "success": i % 3 > 0}
            )
    text = log.getvalue()
    assert "\r" not in text and "━" not in text and "\x1b" not in text
    lines = text.splitlines()
    assert lines[0].endswith("Silverbox") and "20/20 fits done" in lines[-1]
    assert len(lines) <= 2 + 10  # a line per tenth, not per fit


def test_docs_need_no_network():
    config = (ROOT / "mkdocs.yml").read_text()
    assert "use_directory_urls: false" in config
    assets = re.findall(r"^\s+- (\S+\.js)\s*$", config, flags=re.M)
    assert assets and all(not a.startswith("http") for a in assets)
    assert all((ROOT / "docs" / a).is_file() for a in assets)
    assert "font: false" in config


@pytest.mark.skipif(shutil.which("git") is None, reason="needs git")
def test_readme_outputs_are_git_ignored():
    if not (ROOT / ".git").exists():
        pytest.skip("not a git checkout")
    for path in (
        "paper-results/report.md",
        "silverbox-fit/fit.json",
        "simulation.csv",
        "simulation-results/simulation.csv",
        "fit-results/fit.json",
    ):
        r = subprocess.run(["git", "check-ignore", "-q", path], cwd=ROOT)
        assert r.returncode == 0, f"{path} is not ignored"


def test_slow_studies_are_marked_out_of_the_default_run_but_not_out_of_ci():
    config = (ROOT / "pyproject.toml").read_text()
    assert "-m 'not slow'" in config and "slow:" in config
    ci = (ROOT / ".ci" / "run").read_text().splitlines()
    assert "python -m pytest" in ci
    # the slow studies on two processes, the timed fault studies alone: every slow file
    assert "python -m pytest -m slow -n 2 --dist loadfile --ignore tests/test_faults.py" in ci
    assert "python -m pytest -m slow -n 0 tests/test_faults.py" in ci


def test_a_bad_destination_is_refused_before_any_work(tmp_path, capsys):
    blocker = tmp_path / "taken"
    blocker.write_text("not a folder")
    args = ["fit", str(EXAMPLE / "model.py"), str(EXAMPLE / "train.csv"), "--no-progress"]
    for out in (blocker, blocker / "sub"):
        assert cli.main(args + ["--out", str(out)]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and str(blocker) in err[0] and "file" in err[0]


def test_a_failing_figure_write_keeps_fit_json_and_leaves_no_partial_file(
    tmp_path, capsys, monkeypatch
):
    import errno

    from matplotlib.figure import Figure

    def full_disk(self, *a, **k):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(Figure, "savefig", full_disk)
    # no renderer process (it would draw with its own savefig): every figure is drawn
    # here, as when the renderer cannot start
    monkeypatch.setattr("tensorid._early._SERVE", "raise SystemExit(1)")
    out = tmp_path / "fit"
    args = ["fit", str(EXAMPLE / "model.py"), str(EXAMPLE / "train.csv"), "--no-progress"]
    assert cli.main(args + ["--out", str(out)]) == 1
    assert json.loads((out / "fit.json").read_text())["success"]
    assert (out / "report.md").is_file()
    assert not list(out.glob("*.part")) and not list(out.glob("*.png"))
    captured = capsys.readouterr()
    assert "No space left on device" in captured.err and "fit.json was written" in captured.err
    assert "std. error" in captured.out  # the estimates reached the terminal anyway


def test_simulate_says_where_a_simulation_blows_up_and_exits_non_zero(tmp_path, capsys):
    args = ["simulate", str(EXAMPLE / "model.py"), str(EXAMPLE / "validate.csv")]
    args += ["--params", "m=1e-12", "--x0", "y=1", "ydot=0", "--out", str(tmp_path / "s")]
    assert cli.main(args) == 1
    err = capsys.readouterr().err
    assert "not finite" in err and "sample" in err and "Likely causes" in err
    with pytest.warns(RuntimeWarning, match="stops being finite"):
        m = silverbox_model()
        ti.simulate(m, dict(SILVERBOX_P, m=1e-12), [1.0, 0.0], silverbox_data(P=64))


def test_ctrl_c_ends_the_command_with_one_line(monkeypatch, capsys, tmp_path):
    import tensorid.app.commands as commands

    def interrupted(*a, **k):
        raise KeyboardInterrupt

    monkeypatch.setattr(commands, "fit", interrupted)
    args = ["fit", str(EXAMPLE / "model.py"), str(EXAMPLE / "train.csv"), "--no-progress"]
    assert cli.main(args + ["--out", str(tmp_path / "x")]) == 130
    assert capsys.readouterr().err.strip() == "tensorid: interrupted"


def test_ctrl_c_while_the_command_still_imports_is_one_line(tmp_path):
    """issue 51, item 2: Ctrl-C while NumPy and JAX were being imported printed a
    KeyboardInterrupt traceback of the imports."""
    import signal
    import sys
    import time

    args = ["fit", str(EXAMPLE / "model.py"), str(EXAMPLE / "train.csv"), "--out",
            str(tmp_path / "x")]  # fmt: skip
    proc = subprocess.Popen([sys.executable, "-m", "tensorid", *args], stderr=subprocess.PIPE,
                            stdout=subprocess.PIPE, text=True)  # fmt: skip
    time.sleep(0.4)  # JAX's import alone takes longer
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 130 and err.strip() == "tensorid: interrupted", err


def test_files_are_written_with_the_usual_permissions(tmp_path):
    import os
    import stat

    from tensorid.app.output import write_text

    umask = os.umask(0o022)
    try:
        path = write_text(tmp_path / "a.txt", "x")
    finally:
        os.umask(umask)
    assert stat.S_IMODE(path.stat().st_mode) == 0o644
    assert path.read_text() == "x" and not list(tmp_path.glob("*.part"))


def test_a_warning_during_a_command_is_one_line_of_the_tool(monkeypatch, capsys, tmp_path):
    import warnings

    import tensorid.app.commands as commands

    def corner(*a, **k):
        warnings.warn("overflow encountered in matmul", RuntimeWarning, stacklevel=1)
        raise ValueError("stop here")

    monkeypatch.setattr(commands, "_problem", corner)
    args = ["fit", str(EXAMPLE / "model.py"), str(EXAMPLE / "train.csv"), "--no-progress"]
    with warnings.catch_warnings():
        warnings.simplefilter("always")
        assert cli.main(args + ["--out", str(tmp_path / "x")]) == 2
    err = capsys.readouterr().err.splitlines()
    assert err[0] == "tensorid: warning: overflow encountered in matmul", err
    assert not any(".py:" in line or "warnings.warn" in line for line in err)


def test_a_filter_fit_json_of_another_model_names_the_fit_json(tmp_path, capsys):
    """A filter fit's noise naming an output the model lacks was refused without naming
    the fit.json it came from ("measurement_noise names ['w'], which the model lacks")."""
    sigma = {"sigma": 0.01}
    fitted = {
        "params": {"m": 5.17e-6, "d": 2.18e-4, "a": 0.96, "b": 3.65, "u0": 0.005,
                   "log_sigma_w_ydot": -2.0, "log_sigma_e_y": -7.0, "log_sigma_e_w": -7.0},
        "x0": [0.0, 0.0], "predictor": "ekf",
        "noise_intensities": {"process": {"ydot": sigma},
                              "measurement": {"y": sigma, "w": sigma}},
    }  # fmt: skip
    (tmp_path / "fit.json").write_text(json.dumps(fitted))
    args = ["compare", str(EXAMPLE / "model.py"), str(EXAMPLE / "validate.csv")]
    assert (
        cli.main(args + ["--params", str(tmp_path / "fit.json"), "--out", str(tmp_path / "c")]) == 2
    )
    err = capsys.readouterr().err.strip()
    assert err.startswith(f"tensorid: error: --params {tmp_path / 'fit.json'}") and "'w'" in err
    assert len(err.splitlines()) == 1 and not (tmp_path / "c").exists()


def test_a_validation_record_that_blows_up_is_said_not_finite(tmp_path, capsys):
    """A validation simulation that blew up showed GOF -inf, RMSE nan and NRMSE nan
    without a word why; it is "not finite" with a warning saying where and why."""
    (tmp_path / "m.py").write_text(
        'rhs = {"x": "-k*x + a*x**3 + u"}\noutput = {"y": "x"}\ninputs = ["u"]\n'
        'params = ["k", "a"]\np0 = {"k": 1.2, "a": 1.0}\nfixed = ["a"]\n'
    )
    t = np.arange(60) * 0.1
    for name, u in (("train", 0.1 * np.sin(t)), ("validate", 5.0 + 0 * t)):
        y = 0.1 * np.sin(t - 0.5) if name == "train" else np.cos(t)
        rows = "".join(f"{a:.6g},{b:.6g},{c:.6g}\n" for a, b, c in zip(t, u, y, strict=True))
        (tmp_path / f"{name}.csv").write_text("t,u,y\n" + rows)
    args = ["fit", str(tmp_path / "m.py"), str(tmp_path / "train.csv"), "--validate",
            str(tmp_path / "validate.csv"), "--no-progress",
            "--out", str(tmp_path / "f")]  # fmt: skip
    cli.main(args)
    out, err = capsys.readouterr()
    assert "GOF validation: y not finite" in out and "-inf" not in out and " nan" not in out
    assert "tensorid: warning: validation: not scored, the simulation is not finite" in err
    assert (
        "| validation | y | not finite | not finite | not finite |"
        in (tmp_path / "f" / "report.md").read_text()
    )


def test_a_model_file_s_own_variables_are_not_taken_for_misspelt_settings(tmp_path):
    """The misspelt-setting warning fired on ordinary model files: ``outputs = [...]``
    passed to a tensorid.Model ("did you mean output?") and constants in capitals
    (``PARAMS``, ``X0``: "did you mean params / x0?"); a misspelling still warns, naming
    the file."""
    from tensorid.app.files import load_model

    (tmp_path / "own.py").write_text(
        "import tensorid as ti\nPARAMS = ['k']\nX0 = [1.0]\noutputs = ['y']\n"
        "model = ti.Model(rhs=lambda x, p, u: -p[0] * x + u[0], output=lambda x, p: x,\n"
        "    states=['x'], params=PARAMS, inputs=['u'], outputs=outputs)\n"
        "p0 = {'k': 1.0}\nx0 = {'x': X0[0]}\n"
    )
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        load_model(tmp_path / "own.py")
    text = 'rhs = {"x": "-k*x + u"}\noutput = {"y": "x"}\ninputs = ["u"]\nparams = ["k"]\n'
    (tmp_path / "typo.py").write_text(text + 'outputs = ["y"]\n')
    with pytest.warns(UserWarning, match=r"typo\.py: outputs .* did you mean output\?"):
        load_model(tmp_path / "typo.py")


def test_fit_help_is_in_sections_and_every_option_has_one():
    """issue 51, item 9: `tensorid fit --help` was 54 options in one list."""
    from tensorid.app.options import FIT_SECTIONS

    sub = next(
        a for a in cli.build_parser()._actions if a.__class__.__name__ == "_SubParsersAction"
    )
    fit = sub.choices["fit"]
    options = next(g for g in fit._action_groups if g.title == "options")
    assert [a.dest for a in options._group_actions] == ["help"]  # the rest in sections
    text = fit.format_help()
    at = [text.index(f"\n{title}:\n") for title in FIT_SECTIONS]
    assert at == sorted(at)
    assert fit.parse_args(["m.py", "d.csv", "--substeps", "8"]).substeps == 8  # parsing as before
