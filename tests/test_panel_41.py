"""Issue 41's panel: the newest surface's corner cases, each a test that gives one
clear line or a correct result (the filter, robust losses, compare, the CLI's flags,
fit.json's counts, the docs' numbers)."""

from __future__ import annotations

import re
import warnings

import jax.numpy as jnp
import numpy as np
import pytest

import tensorid as ti


def _decay():
    def rhs(x, p, u):
        return jnp.stack([-p[0] * x[0] + u[0]])

    model = ti.Model(
        rhs=rhs, output=lambda x, p: x[:1], states=["x"], params=["k"], inputs=["u"],
        outputs=["y"],
    )  # fmt: skip
    t = np.arange(400) * 0.01
    u = np.sin(3 * t) + 0.5 * np.sin(11 * t)
    y = ti.simulate(model, {"k": 2.0}, [0.0], ti.Experiment(t, u)).y
    y = y + 1e-3 * np.random.default_rng(1).standard_normal(y.shape)
    return model, ti.Experiment(t, u, y)


def _robust(scale, loss="huber"):
    model, data = _decay()
    return ti.Problem(model, data, p0={"k": 1.5}, x0=[0.0], loss=loss, loss_scale=scale)


# -- silently wrong: a robust loss's scale below what the data resolve -------------------


def test_huber_error_bars_keep_their_size_down_to_least_absolute_deviations():
    """The sandwich's scale cancels in the LAD limit: at c = 1e-6 σ the error bar is
    about LAD's (1.25× least squares'), not ∝ c (it was ~1e-4 of it)."""
    model, data = _decay()
    ls = ti.fit(ti.Problem(model, data, p0={"k": 1.5}, x0=[0.0]))
    se_ls = float(ls.uncertainty().stderr[0])
    tiny = ti.fit(_robust(1e-9))
    u = tiny.uncertainty()
    assert 0.8 < float(u.stderr[0]) / se_ls < 2.0
    assert any("below what these residuals resolve" in w for w in u.warnings)
    # a resolved scale keeps the exact Hessian's sandwich and says nothing
    mid = ti.fit(_robust(1.345e-3)).uncertainty()
    assert not any("resolve" in w for w in mid.warnings)
    assert 0.8 < float(mid.stderr[0]) / se_ls < 1.5


def test_cauchy_scale_below_resolution_has_no_error_bars_and_says_why():
    u = ti.fit(_robust(1e-9, "cauchy")).uncertainty()
    assert np.isnan(u.stderr).all()
    assert u.not_available.startswith("not available: the cauchy scale is below what")


@pytest.mark.parametrize(
    "scale, words",
    [(1e-300, "below what the data resolve"), (1e300, "too large to compute with")],
)
def test_a_scale_out_of_range_is_refused_before_any_work(scale, words):
    with pytest.raises(ValueError, match=words):
        _robust(scale)


def test_robust_fit_on_three_samples_names_the_sample_count():
    model, data = _decay()
    short = ti.Experiment(data.t[:3], data.u[:3], data.y[:3])
    with pytest.raises(ValueError, match="3 samples are too few to set the loss scale"):
        ti.Problem(model, short, p0={"k": 1.5}, x0=[0.0], loss="huber")


# -- compare: a filter's noise terms ---------------------------------------------------
FIRST = """rhs = {"x": "-a*x + b*u"}
output = {"y": "x"}
inputs = ["u"]
params = ["a", "b"]
p0 = {"a": 1.0, "b": 1.0}
x0 = {"x": 0.0}
"""
FILTER_FIT = {
    "params": {"a": 2.0, "b": 3.0, "log_sigma_w_x": -6.0, "log_sigma_e_y": -4.6},
    "x0": [0.0],
    "predictor": "ekf",
}


@pytest.fixture
def first(tmp_path):
    """(model file, data file) of the bad-input panel's first-order model."""
    t = np.arange(200) * 0.05
    u = np.sin(0.7 * t) + 0.5 * np.sign(np.sin(0.19 * t))
    model = ti.Model(
        rhs=lambda x, p, u: -p[0] * x + p[1] * u[0], states=["x"], params=["a", "b"],
        inputs=["u"], output=lambda x, p: x, outputs=["y"],
    )  # fmt: skip
    y = ti.simulate(model, {"a": 2.0, "b": 3.0}, [0.0], ti.Experiment(t, u)).y[:, 0]
    y = y + 0.01 * np.random.default_rng(0).standard_normal(y.shape)
    (tmp_path / "first.py").write_text(FIRST)
    rows = "".join(f"{a:.10g},{b:.10g},{c:.10g}\n" for a, b, c in zip(t, u, y, strict=True))
    (tmp_path / "first.csv").write_text("t,u,y\n" + rows)
    return tmp_path / "first.py", tmp_path / "first.csv"


def _cli(capsys, *args) -> tuple[int, str, str]:
    from tensorid import cli

    capsys.readouterr()
    code = cli.main([str(a) for a in args])
    out = capsys.readouterr()
    return code, out.out, out.err


def _filter_fit(folder, **params) -> str:
    import json

    fit = {**FILTER_FIT, "params": {**FILTER_FIT["params"], **params}}
    for k in [k for k, v in params.items() if v is None]:
        del fit["params"][k]
    path = folder / "fit.json"
    path.write_text(json.dumps(fit))
    return str(path)


def _compare(capsys, first, fit, *extra):
    model, data = first
    out = model.parent / "cmp"
    return (*_cli(capsys, "compare", model, data, "--params", fit, "--out", out, *extra), out)


def test_compare_refuses_a_noise_level_no_filter_can_compute_with(first, capsys):
    fit = _filter_fit(first[0].parent, log_sigma_e_y=800.0)
    code, out, err, folder = _compare(capsys, first, fit, "--horizon", "1")
    assert code == 2 and not (folder / "compare.json").exists()
    assert err.count("\n") == 1 and "fit.json: its log_sigma_e_y = 800" in err


def test_compare_s_status_is_not_ok_when_the_scores_are_not_finite(first, capsys, monkeypatch):
    import json

    from tensorid.app import filter_fits

    monkeypatch.setattr(filter_fits, "LOG_SIGMA_RANGE", 1e4)  # past the check: the net below
    fit = _filter_fit(first[0].parent, log_sigma_e_y=800.0)
    code, out, err, folder = _compare(capsys, first, fit, "--horizon", "1")
    saved = json.loads((folder / "compare.json").read_text())
    assert code == 1 and saved["status"] == "scores_not_finite"
    assert saved["outputs"]["y"]["rmse"] is None
    assert "the scores are not finite although the simulation is" in err


def test_a_filter_fit_json_without_noise_terms_is_refused_not_simulated(first, capsys):
    fit = _filter_fit(first[0].parent, log_sigma_w_x=None, log_sigma_e_y=None)
    code, out, err, _ = _compare(capsys, first, fit, "--horizon", "1")
    assert code == 2 and 'says "predictor": "ekf" but holds no noise terms' in err
    assert "not a --predictor ekf fit" not in err


def test_a_filter_fit_json_s_noise_in_its_params_alone_is_a_filter(first, capsys):
    code, out, err, _ = _compare(capsys, first, _filter_fit(first[0].parent), "--horizon", "1")
    assert code == 0 and "1-step prediction" in out and "not a --predictor ekf" not in err


def test_ctrl_c_while_the_exit_handlers_run_is_said_and_exits_130(tmp_path):
    """Ctrl-C right after a command printed (JAX's exit handler running): one line and
    exit status 130, as during the work, not 'Exception ignored in atexit callback'."""
    import subprocess
    import sys

    script = tmp_path / "late.py"
    script.write_text(
        "import atexit, os, signal, time\n"
        "from tensorid import cli\n"
        "def main():\n"
        "    print('scores')\n"
        "    atexit.register(lambda: (os.kill(os.getpid(), signal.SIGINT), time.sleep(0.5)))\n"
        "    return 0\n"
        "cli.main = main\n"
        "cli.console()\n"
    )
    run = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, timeout=120)
    assert run.returncode == 130, run
    assert run.stderr.strip() == "tensorid: interrupted", run.stderr


# -- misleading: each names the real cause, before any work ------------------------------
@pytest.mark.parametrize(
    "flags, words",
    [
        (["--process-noise", "x=1e300"], "--process-noise x=1e+300 is out of the range"),
        (["--process-noise", "x=0.1", "x=0.2"], "--process-noise gives x twice; give it once"),
        (["--fix", "log_sigma_w_x=-3"], "--fix log_sigma_w_x: the state x has no process noise"),
    ],
)
def test_filter_flags_refused_with_their_cause(first, capsys, flags, words):
    model, data = first
    out = model.parent / "o"
    code, _, err = _cli(
        capsys, "fit", model, data, "--predictor", "ekf", *flags, "--out", out, "--no-progress"
    )
    assert code == 2 and err.count("\n") == 1 and words in err, err
    assert not out.exists()


def test_a_filter_fit_with_more_unknowns_than_residuals_is_refused_first(first, capsys):
    model, data = first
    short = model.parent / "three.csv"
    short.write_text("".join(data.read_text().splitlines(keepends=True)[:4]))
    code, _, err = _cli(
        capsys, "fit", model, short, "--predictor", "ekf", "--process-noise", "x=0.1",
        "--measurement-noise", "y=0.01", "--out", model.parent / "o", "--no-progress",
    )  # fmt: skip
    assert code == 2 and err.count("\n") == 1
    assert "3 residuals for 4 unknowns" in err and "fewer data than unknowns" in err


def test_a_non_finite_value_in_a_fit_json_names_the_file(first, capsys):
    fit = _filter_fit(first[0].parent, a=float("nan"))
    code, _, err, _ = _compare(capsys, first, fit)
    assert code == 2 and f"--params {fit}: params a=nan are not finite" in err


def test_a_boolean_noise_level_is_refused():
    model, data = _decay()
    with pytest.raises(ValueError, match=r"process_noise\['x'\] must be a number .*got True"):
        ti.Problem(model, data, p0={"k": 1.5}, x0=[0.0], predictor="ekf", process_noise={"x": True})


def test_a_stiff_model_on_rk4_names_the_flags_and_no_raw_numpy_warning(first, capsys):
    model, data = first
    stiff = model.with_name("stiff.py")
    stiff.write_text(FIRST.replace('{"a": 1.0, "b": 1.0}', '{"a": 1000.0, "b": 1000.0}'))
    code, out, err = _cli(capsys, "simulate", stiff, data, "--out", model.parent / "s")
    assert code == 1 and "overflow" not in err and "RuntimeWarning" not in err
    assert "--scheme sdirk3" in err and "--substeps" in err
    assert err.count("\n") == 1


def test_a_discrete_model_on_jittered_stamps_names_ts_not_another_rate(first, capsys):
    import json

    model, data = first
    disc = model.with_name("disc.py")
    disc.write_text(FIRST.replace('"-a*x + b*u"', '"0.5*x + b*u"') + "discrete = True\n")
    fit = model.with_name("disc.json")
    fit.write_text(json.dumps({"params": {"a": 1.0, "b": 1.0}, "x0": [0.0], "sample_time": 0.05}))
    rows = data.read_text().splitlines()
    rng = np.random.default_rng(0)
    jittered = [rows[0]] + [
        f"{0.05 * (k + 0.05 * rng.uniform(-1, 1)):.10g},{r.split(',', 1)[1]}"
        for k, r in enumerate(rows[1:])
    ]
    path = model.with_name("jitter.csv")
    path.write_text("\n".join(jittered) + "\n")
    code, _, err = _cli(capsys, "compare", disc, path, "--params", fit, "--out", model.parent / "c")
    assert code == 2 and err.count("\n") == 1
    assert "sample times are not uniform" in err and "--ts" in err and "another rate" not in err


def test_fix_outside_the_model_file_s_bounds_is_said(tmp_path):
    from tensorid.app.files import load_model
    from tensorid.app.overrides import overridden

    (tmp_path / "m.py").write_text(FIRST + 'bounds = {"a": (0.1, 50)}\n')
    spec = load_model(tmp_path / "m.py")
    with pytest.warns(
        UserWarning, match=r"--fix a=100 is outside .*m.py's bounds for a \(0.1, 50\)"
    ):
        new, _ = overridden(spec, {"a": 100.0}, [], {})
    assert new.p0["a"] == 100.0 and "a" in new.fixed
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        overridden(spec, {"a": 20.0}, [], {})  # inside: no word


@pytest.mark.parametrize(
    "y, words",
    [
        (np.ones(10) + 1j, "benchmark record 'benchmark': y is complex (complex128)"),
        (np.array(["a"] * 10), "benchmark record 'benchmark': y holds values that are not numbers"),
    ],
)
def test_from_benchmark_names_a_complex_or_text_y(y, words):
    import types

    record = types.SimpleNamespace(u=np.ones(10), y=y, sampling_time=0.1)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no bare ComplexWarning on the way
        with pytest.raises(ValueError, match=re.escape(words)):
            ti.Experiment.from_benchmark(record)


def test_from_benchmark_refuses_a_column_twice():
    import types

    record = types.SimpleNamespace(u=np.ones(10), y=np.ones((10, 2)), sampling_time=0.1)
    with pytest.raises(ValueError, match=r"outputs=\[0, 0\] names a column twice"):
        ti.Experiment.from_benchmark(record, outputs=[0, 0])
    assert ti.Experiment.from_benchmark(record, outputs=[1, 0]).y.shape == (10, 2)


# -- the newcomer's list: what a user expects of the command line -------------------------
def test_version_and_the_out_defaults_are_said(capsys):
    from tensorid import _config, cli

    with pytest.raises(SystemExit) as end:
        cli.main(["--version"])
    assert end.value.code == 0
    assert capsys.readouterr().out.startswith(f"tensorid {_config.__version__} (JAX ")
    defaults = {"fit": "fit-results", "simulate": "simulation-results",
                "compare": "compare-results", "paper": "paper-results"}  # fmt: skip
    for command, default in defaults.items():
        with pytest.raises(SystemExit):
            cli.main([command, "--help"])
        text = " ".join(capsys.readouterr().out.split())
        assert f"(default: {default})" in text, command


def test_iteration_limits_priors_noise_and_weights_from_the_command_line(first, capsys):
    import json

    model, data = first
    out = model.parent / "o"
    code, _, err = _cli(
        capsys, "fit", model, data, "--maxiter", "1", "--gtol", "0", "--prior", "a=2,0.1",
        "--noise", "0.01", "--weights", "y=2", "--out", out, "--no-progress",
    )  # fmt: skip
    assert code == 1  # not converged, as documented: the iteration limit
    d = json.loads((out / "fit.json").read_text())
    assert d["iterations"] == 1 and d["status"] == "maxiter"
    assert d["priors"] == {"a": [2.0, 0.1]}
    assert d["prior_noise_variance"] == pytest.approx(1e-4)
    assert d["weights"] == {"y": 2.0}


@pytest.mark.parametrize(
    "flags, words",
    [
        (["--prior", "c=2,1"], "--prior names ['c'], not parameters"),
        (["--prior", "a=2,0"], "--prior: a prior's SD is a standard deviation"),
        (["--weights", "q=1"], "--weights names ['q'], not outputs"),
        (["--maxiter", "0"], "--maxiter: expected a whole number >= 1"),
        (["--gtol", "-1"], "--gtol"),
    ],
)
def test_the_new_flags_refuse_a_bad_value_in_one_line(first, capsys, flags, words):
    model, data = first
    try:
        code, _, err = _cli(capsys, "fit", model, data, *flags, "--out", model.parent / "o")
    except SystemExit as end:  # argparse
        code, err = end.code, capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1 and words in err, err


def test_multi_start_counts_in_fit_json_have_one_meaning(first, capsys):
    import json

    model, data = first
    out = model.parent / "ms"
    code, _, err = _cli(
        capsys, "fit", model, data, "--starts", "3", "--workers", "1", "--out", out,
        "--no-progress",
    )  # fmt: skip
    assert code == 0, err
    d = json.loads((out / "fit.json").read_text())
    best, starts = d["starts"][0], d["starts"]
    # iterations and function_evaluations: both the best start's run and its refinement
    assert d["iterations"] == best["nit"] + d["iterations_after_starts"]
    assert d["history"][-1]["iteration"] == d["iterations"]
    assert d["function_evaluations"] == best["nfev"] + d["function_evaluations_after_starts"]
    assert d["function_evaluations_best_start"] == d["function_evaluations"]
    # the totals: every start's, the refinement included
    assert d["iterations_total"] == sum(s["nit"] for s in starts) + d["iterations_after_starts"]
    assert d["function_evaluations_total"] == (
        sum(s["nfev"] for s in starts) + d["function_evaluations_after_starts"]
    )
    # each start's own time (they shared one lock-step batch and ended one by one)
    assert len({s["seconds"] for s in starts}) == len(starts)


def test_the_paper_console_does_not_read_converged_and_failed_as_a_contradiction():
    from tensorid.analysis.summary import as_text
    from tensorid.paper.command import _robustness_table

    row = dict(dataset="silverbox", accuracy="rk4x4", method="fd-bfgs", converged=6, starts=6,
               failed=6, median_seconds=0.39)  # fmt: skip
    table = _robustness_table([row], 1e-6)
    assert table.header[4] == "reported failure" and "failed" not in table.header
    assert "BFGS often reaches the optimum and then fails its line search" in " ".join(
        as_text([table]).split()
    )


def test_figure_names_do_not_repeat_the_record_s_kind():
    from dataclasses import replace

    from tensorid.analysis.figures import figure_jobs

    model, data = _decay()
    train = replace(data, name="train")
    res = ti.fit(ti.Problem(model, train, p0={"k": 1.5}, x0=[0.0]))
    stems = [stem for stem, kind, _ in figure_jobs(res) if kind == "compare"]
    assert stems == ["train_y"]  # was train_train_y
    both = res.validate([replace(data, name="validate"), replace(data, name="test")])
    stems = [stem for stem, kind, _ in figure_jobs(res, both) if kind == "compare"]
    assert stems == ["train_y", "validation_validate_y", "validation_test_y"]  # two: named


def test_figures_say_what_their_bands_lines_and_axes_are():
    from tensorid.analysis.figures import compare_figure, prediction_figure, residual_figure

    lags = np.arange(6)
    panel = dict(what="y against input u", passed=False, lags=lags, values=0.5**lags,
                 feedback=0.1 * np.ones(5))  # fmt: skip
    ax = residual_figure(0.2, [panel]).axes[0]
    legend = [t.get_text() for t in ax.get_legend().get_texts()]
    assert legend == ["±0.2: where uncorrelated samples fall",
                      "negative lags: against later inputs (feedback; not tested)",
                      "tested lags (the test fails)"]  # fmt: skip
    t = np.linspace(0, 1, 20)
    assert compare_figure(t, t, t, title="", ylabel="q").axes[1].get_ylabel() == (
        "residual [units of q]"
    )
    fig = prediction_figure(t, t, t, t, None, t, title="", ylabel="q")
    assert "dotted: ±2" in fig.axes[1].get_ylabel()


def test_a_filter_s_residual_tests_name_its_innovations():
    model, data = _decay()
    problem = ti.Problem(
        model, data, p0={"k": 2.0}, x0=[0.0], predictor="ekf", process_noise={"x": 0.01}
    )
    res = ti.fit(problem)
    tests = res.residual_tests(5)
    assert tests.whiteness[0].what == "whiteness of y's innovations"
