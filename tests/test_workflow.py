"""From a model file and data files to a validated fit with error bars: the command
line end to end, uncertainty coverage, text equations, multi-start (local and Dask),
identifiability warnings, and the errors a user meets first."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap

import numpy as np
import pytest

import tensorid as ti
from tensorid import cli

TRUTH = {"k": 4.0, "c": 0.6, "g": 2.0, "k3": 1.5}

MODEL_FILE = """
import jax.numpy as jnp
import tensorid

def rhs(x, p, u):
    k, c, g, k3 = p
    return jnp.stack([x[1], g * u[0] - c * x[1] - k * x[0] - k3 * x[0] ** 3])

model = tensorid.Model(rhs=rhs, output=lambda x, p: x[:1], states=["pos", "vel"],
                       params=["k", "c", "g", "k3"], inputs=["force"], outputs=["pos"])
p0 = {"k": 3.0, "c": 0.8, "g": 1.5, "k3": 1.0}
x0 = {"pos": 0.0, "vel": 0.0}
free_x0 = ["vel"]
bounds = {"k": (0.1, 20.0), "c": (0.0, 5.0)}
"""

EQUATIONS_FILE = """
rhs = {"pos": "vel", "vel": "g*force - c*vel - k*pos - k3*pos**3"}
output = {"pos": "pos"}
inputs = ["force"]
params = ["k", "c", "g", "k3"]
p0 = {"k": 3.0, "c": 0.8, "g": 1.5, "k3": 1.0}
free_x0 = ["vel"]
"""


def _force(P, dt, seed):
    rng = np.random.default_rng(seed)
    t = np.arange(P) * dt
    u = sum(np.sin(2 * np.pi * f * t + rng.uniform(0, 6.3)) for f in (0.2, 0.45, 0.8, 1.3))
    return t, 0.5 * u


def _write_csv(path, P=250, dt=0.05, seed=0, noise=0.01, vel0=0.3, columns=("t", "force", "pos")):
    spec = ti.load_model(path.parent / "model.py")
    t, u = _force(P, dt, seed)
    y = ti.simulate(spec.model, TRUTH, [0.0, vel0], ti.Experiment(t, u)).y[:, 0]
    y = y + noise * np.random.default_rng(seed + 100).standard_normal(P)
    data = dict(zip(columns, (t, u, y), strict=True))
    with path.open("w") as f:
        f.write(",".join(data) + "\n")
        for row in zip(*data.values(), strict=True):
            f.write(",".join(f"{v:.10g}" for v in row) + "\n")
    return path


@pytest.fixture
def workdir(tmp_path):
    (tmp_path / "model.py").write_text(MODEL_FILE)
    return tmp_path


def test_a_robust_fit_from_the_command_line_says_what_it_did(workdir, capsys):
    train = _write_csv(workdir / "train.csv", seed=1)
    lines = train.read_text().splitlines()
    for k in range(20, len(lines), 25):  # a glitch every 25 samples: 4 % outliers
        t, f, y = lines[k].split(",")
        lines[k] = f"{t},{f},{float(y) + 2.0:.10g}"
    train.write_text("\n".join(lines) + "\n")
    out = workdir / "out"
    model = str(workdir / "model.py")
    options = ["--loss", "huber", "--starts", "2", "--workers", "1", "--no-progress"]
    rc = cli.main(["fit", model, str(train), *options, "--out", str(out)])
    assert rc == 0
    printed = capsys.readouterr().out
    assert "note: the huber fit started from the least-squares estimate" in printed
    assert "best of 2 starts" in printed
    d = json.loads((out / "fit.json").read_text())
    assert d["loss"] == "huber" and 0.005 < d["loss_scale"]["pos"] < 0.03  # 1.345 × 0.01
    assert d["aic"] is None and "squared loss" in d["criteria_not_available"]
    assert d["stderr_robust"] is not None and len(d["starts"]) == 2
    for name, true in TRUTH.items():  # the glitches do not pull the estimates off
        assert abs(d["params"][name] - true) < 4 * d["stderr"][name], name
    assert "## Notes" in (out / "report.md").read_text()


def test_fit_command_end_to_end(workdir, capsys):
    train = _write_csv(workdir / "train.csv", seed=1)
    val = _write_csv(workdir / "val.csv", seed=2, vel0=-0.2)
    out = workdir / "out"
    rc = cli.main(
        [
            "fit",
            str(workdir / "model.py"),
            str(train),
            "--validate",
            str(val),
            "--out",
            str(out),
            "--no-progress",
        ]
    )
    assert rc == 0
    d = json.loads((out / "fit.json").read_text())
    assert d["hessian_path"] == "tensors"  # N = 2, K = 5: the cost model keeps the tensors
    for key in (
        "params",
        "stderr",
        "ci95",
        "correlation",
        "x0",
        "cost",
        "gof",
        "success",
        "iterations",
        "method",
        "seconds",
        "warnings",
    ):
        assert key in d, key
    assert d["success"] and d["method"] == "auto" and d["warnings"] == []
    for name, value in TRUTH.items():
        lo, hi = d["ci95"][name]
        assert lo < value < hi, (name, lo, value, hi)
        assert d["stderr"][name] > 0
    assert d["gof"]["train"]["train"]["pos"] > 0.95
    assert d["gof"]["validation"]["val"]["pos"] > 0.95
    corr = np.array(d["correlation"])
    assert corr.shape == (5, 5) and np.allclose(np.diag(corr), 1)
    assert (out / "report.md").read_text().count("![") >= 3
    assert (out / "convergence.png").stat().st_size > 1000
    text = capsys.readouterr().out
    assert "std. error" in text and "GOF validation val" in text


def test_simulate_command(workdir, capsys):
    data = _write_csv(workdir / "d.csv", seed=3)
    rc = cli.main(
        [
            "simulate",
            str(workdir / "model.py"),
            str(data),
            "--out",
            str(workdir / "sim.csv"),
            "--x0",
            "vel=0.3",
            "--params",
        ]
        + [f"{k}={v}" for k, v in TRUTH.items()]
    )
    assert rc == 0
    sim = np.loadtxt(workdir / "sim.csv", delimiter=",", skiprows=1)
    assert sim.shape == (250, 4)
    gof_line = capsys.readouterr().out.splitlines()[0]
    assert float(gof_line.split()[-1]) > 0.95  # the data carry noise of std 0.01


def test_true_values_inside_95_percent_intervals_for_most_seeds(workdir):
    spec = ti.load_model(workdir / "model.py")
    inside = total = 0
    for seed in range(8):
        e = ti.load_data(_write_csv(workdir / f"s{seed}.csv", seed=seed, noise=0.02), spec.model)
        prob = ti.Problem(
            spec.model, e, p0=spec.p0, x0=spec.x0_array(), free_x0=spec.free_x0, bounds=spec.bounds
        )
        res = ti.fit(prob)
        u = res.uncertainty()
        truth = np.array([0.3] + list(TRUTH.values()))
        inside += int(((u.ci95[:, 0] < truth) & (truth < u.ci95[:, 1])).sum())
        total += truth.size
    assert inside / total >= 0.8, f"{inside}/{total} inside"


def test_text_equations_model_file_gives_the_same_fit(workdir):
    (workdir / "eq.py").write_text(EQUATIONS_FILE)
    data = _write_csv(workdir / "d.csv", seed=4)
    fits = []
    for f in ("model.py", "eq.py"):
        spec = ti.load_model(workdir / f)
        prob = ti.Problem(
            spec.model,
            ti.load_data(data, spec.model),
            p0=spec.p0,
            x0=spec.x0_array(),
            free_x0=spec.free_x0,
        )
        fits.append(ti.fit(prob))
    assert fits[1].params == pytest.approx(fits[0].params, rel=1e-9)
    assert fits[1].cost == pytest.approx(fits[0].cost, rel=1e-9)


def test_text_equations_errors():
    with pytest.raises(ValueError, match="cannot parse"):
        ti.model_from_equations(rhs={"x": "-k*x +"})
    # an output may read the inputs (a feed-through, a baseline): h(x, p, u)
    m = ti.model_from_equations(rhs={"x": "-k*x + u"}, output={"y": "x + d*u"}, inputs=["u"])
    assert m.reads_inputs and m.params == ("d", "k")
    m = ti.model_from_equations(rhs={"x": "-k*exp(x) + u"}, inputs=["u"])
    assert m.params == ("k",) and m.outputs == ("x",)


def test_model_file_that_fails_shows_the_users_line(tmp_path):
    bad = tmp_path / "bad.py"
    bad.write_text("import jax.numpy as jnp\n\nk = 1\nmodel = undefined_thing(k)\n")
    with pytest.raises(
        ValueError, match=r"bad.py failed, line 4 \(model = undefined_thing\(k\)\): NameError"
    ):
        ti.load_model(bad)
    (tmp_path / "empty.py").write_text("x = 1\n")
    with pytest.raises(ValueError, match="defines neither"):
        ti.load_model(tmp_path / "empty.py")


def test_wrong_csv_columns_list_the_expected_ones(workdir):
    data = _write_csv(workdir / "d.csv", columns=("time", "F", "pos"))
    spec = ti.load_model(workdir / "model.py")
    with pytest.raises(
        ValueError,
        match=r"lacks columns \['force'\]; expected \['t', 'force', "
        r"'pos'\].*found \['F', 'pos', 'time'\]",
    ):
        ti.load_data(data, spec.model)
    d2 = _write_csv(workdir / "d2.csv", columns=("u0", "force", "pos"))
    with pytest.raises(ValueError, match="no time column 't'"):
        ti.load_data(d2, spec.model)
    assert ti.load_data(d2, spec.model, ts=0.05)[0].t[1] == pytest.approx(0.05)


def test_mat_and_npz_data(workdir):
    import scipy.io

    spec = ti.load_model(workdir / "model.py")
    t, u = _force(50, 0.1, 0)
    y = np.cos(t)
    scipy.io.savemat(workdir / "d.mat", {"force": u[None, :], "pos": y[None, :]})
    np.savez(workdir / "d.npz", t=t, force=u, pos=y)
    a = ti.load_data(workdir / "d.mat", spec.model, ts=0.1)[0]
    b = ti.load_data(workdir / "d.npz", spec.model, samples=(10, 40))[0]
    np.testing.assert_allclose(a.y[:, 0], y)
    assert b.P == 30 and b.t[0] == pytest.approx(1.0)


def test_structurally_non_identifiable_model_is_named():
    """Only the product a·b enters the dynamics: the cost is flat along a·b = const."""
    m = ti.Model(
        rhs=lambda x, p, u: -p[0] * p[1] * x + u[0],
        output=lambda x, p: x,
        states=["x"],
        params=["a", "b", "c"],
        inputs=["u"],
        outputs=["y"],
    )
    t = np.linspace(0, 5, 80)
    u = np.sin(2 * t)
    y = ti.simulate(m, {"a": 2.0, "b": 0.5, "c": 1.0}, [1.0], ti.Experiment(t, u)).y
    y = y + 0.01 * np.random.default_rng(0).standard_normal(y.shape)
    prob = ti.Problem(
        m,
        ti.Experiment(t, u, y),
        p0={"a": 1.5, "b": 0.6, "c": 1.0},
        x0=[1.0],
        fixed=["c"],
        free_x0=["x"],
    )
    res = ti.fit(prob)
    assert np.isfinite(res.cost)
    assert res.params["a"] * res.params["b"] == pytest.approx(1.0, rel=0.02)
    warnings = " ".join(res.warnings)
    assert "not identifiable" in warnings and "a, b" in warnings and "x(t0)" not in warnings
    u_ = res.uncertainty()
    assert np.isinf(u_.stderr[1:]).all() and np.isfinite(u_.stderr[0])


@pytest.mark.slow
def test_multistart_local_and_dask_agree(workdir):
    distributed = pytest.importorskip("distributed")
    spec = ti.load_model(workdir / "model.py")
    e = ti.load_data(_write_csv(workdir / "d.csv", seed=5), spec.model)
    prob = ti.Problem(
        spec.model, e, p0=spec.p0, x0=spec.x0_array(), free_x0=spec.free_x0, bounds=spec.bounds
    )
    local = ti.fit(prob, starts=4, workers=2, batch=1)  # one start per task, as on Dask
    with (
        distributed.LocalCluster(
            n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None
        ) as cluster,
        distributed.Client(cluster) as client,
    ):
        remote = ti.fit(prob, starts=4, executor=client.get_executor())
        # and the command line's --scheduler, on the same cluster
        rc = cli.main(
            [
                "fit",
                str(workdir / "model.py"),
                str(workdir / "d.csv"),
                "--starts",
                "3",
                "--scheduler",
                cluster.scheduler_address,
                "--out",
                str(workdir / "dask-out"),
                "--no-progress",
            ]
        )
        assert rc == 0
        d = json.loads((workdir / "dask-out" / "fit.json").read_text())
        assert len(d["starts"]) == 3 and d["cost"] == pytest.approx(local.cost, rel=1e-9)
    assert len(local.starts) == len(remote.starts) == 4
    assert [s["cost"] for s in local.starts] == pytest.approx(
        [s["cost"] for s in remote.starts], rel=1e-9
    )
    assert remote.cost == pytest.approx(local.cost, rel=1e-12)
    np.testing.assert_allclose(remote.theta, local.theta, rtol=1e-9)
    costs = [s["cost"] for s in local.starts]
    # ranked by cost, starts tied to 1e-9 by fewest iterations (so tied costs may differ
    # in their last digits either way)
    assert all(b >= a * (1 - 1e-9) for a, b in zip(costs, costs[1:], strict=False))
    assert local.cost <= min(costs) * (1 + 1e-9)


def test_draw_starts_respect_bounds_and_are_seeded():
    from tensorid.solve.multistart import draw_starts

    theta0 = np.array([1.0, 5.0, 0.0])
    lo = np.array([0.5, -np.inf, -1.0])
    hi = np.array([2.0, np.inf, 1.0])
    a = draw_starts(theta0, lo, hi, 50, seed=1)
    np.testing.assert_array_equal(a, draw_starts(theta0, lo, hi, 50, seed=1))
    assert (a >= lo).all() and (a <= hi).all() and (a[0] == theta0).all()
    assert a[1:, 1].min() >= 4.0 and a[1:, 1].max() <= 6.0
    # Latin hypercube: one point in each of the 49 strata of each bounded entry
    strata = np.floor((a[1:, 0] - 0.5) / 1.5 * 49).astype(int)
    assert sorted(strata) == list(range(49))


def test_summary_and_plot_api(workdir):
    spec = ti.load_model(workdir / "model.py")
    e = ti.load_data(_write_csv(workdir / "d.csv", seed=6), spec.model)
    res = ti.fit(ti.Problem(spec.model, e, p0=spec.p0, x0=spec.x0_array(), free_x0=spec.free_x0))
    text = res.summary()
    assert "k3" in text and "95 % interval" in text
    files = res.plot(workdir / "figs")
    assert all(f.stat().st_size > 1000 for f in files) and len(files) == 2
    assert res.covariance.shape == (5, 5)
    assert textwrap.dedent(text)


@pytest.mark.slow  # 11 s: every scheme option compiles its own sweeps
def test_integration_options_on_the_command_line(workdir, capsys):
    train = _write_csv(workdir / "train.csv", seed=1)
    out = workdir / "out"
    args = ["fit", str(workdir / "model.py"), str(train), "--out", str(out), "--no-progress"]
    assert cli.main(args + ["--scheme", "sdirk3", "--substeps", "8"]) == 0
    d = json.loads((out / "fit.json").read_text())
    assert d["success"] and d["integration"]["scheme"] == "sdirk3"
    assert d["integration"]["substeps"] == 8
    assert cli.main(args + ["--scheme", "dopri5", "--rtol", "1e-9"]) == 0
    assert json.loads((out / "fit.json").read_text())["integration"]["rtol"] == 1e-9
    assert cli.main(args + ["--hessian", "adjoint"]) == 0
    assert json.loads((out / "fit.json").read_text())["hessian_path"] == "adjoint"
    capsys.readouterr()
    assert cli.main(args + ["--scheme", "dopri5", "--hessian", "adjoint"]) == 2
    assert "--hessian adjoint needs an explicit scheme" in capsys.readouterr().err
    # a bad combination is one clear line, not a traceback
    assert cli.main(args + ["--rtol", "1e-9"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("tensorid: error: --rtol/--atol apply to the adaptive schemes")


def test_compilation_cache_is_on_by_default_and_can_be_turned_off(tmp_path):
    # in a fresh process: the cache folder is process-wide JAX state. No call: the
    # import turns the cache on (in $TENSORID_CACHE_DIR); after the opt-out a new
    # model's sweeps compile without writing anything
    script = textwrap.dedent(
        """
        import os, numpy as np, tensorid as ti
        def fit(k):
            m = ti.Model(rhs=lambda x, p, u: -p[0] * x + u[0], output=lambda x, p: x,
                         states=["x"], params=["k"], inputs=["u"], outputs=["y"])
            t = np.linspace(0, 1, 17)
            e = ti.Experiment(t, np.zeros(17), np.exp(-k * t))
            return ti.fit(ti.Problem(m, e, p0={"k": 1.0}, x0=[1.0])).params["k"]
        print(fit(2.0), len(os.listdir(os.environ["TENSORID_CACHE_DIR"])))
        ti.disable_compilation_cache()
        print(fit(3.0), len(os.listdir(os.environ["TENSORID_CACHE_DIR"])))
        """
    )
    env = {**os.environ, "TENSORID_CACHE_DIR": str(tmp_path / "cache")}
    env.pop("TENSORID_CACHE", None)
    r = subprocess.run(
        [sys.executable, "-c", script], capture_output=True, text=True, check=True, env=env
    )
    (k2, n_on), (k3, n_off) = (line.split() for line in r.stdout.split("\n")[-3:-1])
    assert float(k2) == pytest.approx(2.0, rel=1e-3)  # RK4 x4 error
    assert float(k3) == pytest.approx(3.0, rel=1e-3)
    assert int(n_on) >= 2 and int(n_off) == int(n_on)  # cost and Hessian sweeps, at least


def test_tensorid_cache_0_turns_the_cache_off(monkeypatch):
    import jax

    from tensorid._config import default_compilation_cache

    folder = jax.config.values["jax_compilation_cache_dir"]
    monkeypatch.setenv("TENSORID_CACHE", "0")
    try:
        assert default_compilation_cache() is None
        assert not jax.config.values["jax_enable_compilation_cache"]
    finally:
        ti.enable_compilation_cache(folder)
