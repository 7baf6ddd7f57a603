"""Issue 49 (one pipeline) and 51 item 3: every flag of ``tensorid fit`` against a
fleet's problem is honoured (its effect reaches the fit) or refused in one line that
names it; none is dropped. The walk stops each command where the fit would start
(``tensorid.fit``) and compares what reached it with the plain command's; a slow
test then runs the flags that act after the fit (--profile, --validate,
--data-sensitivity) on a real fit."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np
import pytest

import tensorid as ti
from tensorid import cli
from tensorid.app import commands
from tensorid.app.fleet_flags import REFUSED

ROOT = Path(__file__).resolve().parents[1]
MODEL = ROOT / "examples" / "phenobarbital" / "model.py"
DATA = Path(ti.__file__).parent / "datasets" / "phenobarbital.csv"


class _Reached(Exception):
    """The command got as far as the fit."""


def _records(tmp_path: Path, first: int, last: int, name: str) -> Path:
    """Units first..last of phenobarbital, with DOSE2 = 2 AMT (for --events)."""
    rows = [r for r in csv.DictReader(DATA.open()) if first <= int(r["ID"]) <= last]
    path = tmp_path / name
    with path.open("w", newline="") as f:
        w = csv.DictWriter(f, [*rows[0], "DOSE2"])
        w.writeheader()
        for r in rows:
            dose = "." if r["AMT"] == "." else str(2 * float(r["AMT"]))
            w.writerow(r | {"DOSE2": dose})
    return path


def _problem_seen(problem) -> dict:
    """A Problem's data and settings, as text-comparable values."""
    e = problem.experiments
    return {
        "t": [x.t.tolist() for x in e], "y": [np.asarray(x.y).tolist() for x in e],
        "u": [np.asarray(problem.grid(x)[1]).tolist() for x in e],
        "p0": np.asarray(problem.p0).tolist(), "fixed": problem.fixed,
        "free_x0": problem.free_x0,
        "lower": problem.lower.tolist(), "upper": problem.upper.tolist(),
        "disc": repr(problem.discretisation), "population": problem.population,
        "individual": problem.individual, "error": problem.residual_error,
        "omega": problem.omega,
    }  # fmt: skip


def _options_seen(method, options) -> dict:
    """The fit's keywords as ``fit`` receives them (an executor or a callback: given
    or not)."""
    kept = {k: v for k, v in options.items() if k not in ("executor", "callback")}
    return {"method": method, **kept, "executor": options.get("executor") is not None,
            "callback": options.get("callback") is not None}  # fmt: skip


# flags that act after the fit (its analyses and files): what reaches the fit cannot
# show them; the slow test below runs --profile, --data-sensitivity and --out on a
# real fit (--validate reaches the walk as the held-out units' Problem)
AFTER_THE_FIT = {"--profile", "--profile-level", "--data-sensitivity", "--out"}


# a value for every flag (the fleet: units 1-4 of phenobarbital, cl and v log-normal)
VALUES = {
    "--columns": ["t=TIME,conc=DV"], "--ts": ["0.5"], "--samples": ["0:6"],
    "--records": ["ID"], "--events": ["AMT=DOSE2"], "--validate": ["HELD"],
    "--validate-columns": ["t=TIME,conc=DV"], "--validate-samples": ["0:9"],
    "--init-window": ["3"], "--horizon": ["2"], "--fix": ["v=1.2"], "--free": ["central"],
    "--bounds": ["cl=0.001:0.1"], "--start-from": ["START"], "--scheme": ["heun"],
    "--substeps": ["8"], "--rtol": ["1e-7"], "--atol": ["1e-9"],
    "--interpolation": ["zoh"], "--method": ["laplace"], "--hessian": ["adjoint"],
    "--starts": ["3"], "--spread": ["0.5"], "--seed": ["3"], "--maxiter": ["7"],
    "--gtol": ["1e-5"], "--ftol": ["1e-6"], "--xtol": ["1e-7"], "--no-polish": [],
    "--segments": ["2"], "--segment-length": ["5"], "--workers": ["2"], "--batch": ["2"],
    "--loss": ["huber"], "--loss-scale": ["2"], "--predictor": ["ekf"],
    "--process-noise": ["central=1"], "--measurement-noise": ["conc=1"],
    "--prior": ["cl=0.005,0.001"], "--noise": ["1"], "--weights": ["conc=2"],
    "--constraint": ["cl <= v"], "--profile": ["cl"], "--profile-level": ["0.9"],
    "--residual-lags": ["3"], "--data-sensitivity": [], "--no-model-check": [],
    "--individual": ["cl"], "--population": ["cl=0.3"], "--residual-error": ["proportional"],
    "--omega": ["full"], "--scheduler": ["SCHED"], "--worker-timeout": ["30"],
    "--out": ["OTHER"], "--no-progress": [],
}  # fmt: skip
# refused elsewhere than fleet_flags.REFUSED, each with a line that names the flag
# (--free central: a fleet's units start from x0, free_x0 is not taken; --free of a
# parameter the model file fixes is honoured, as for any fit)
# (--samples, --validate-samples, --ts: --records keeps each unit's own time stamps)
REFUSED_ELSEWHERE = {"--prior", "--noise", "--weights", "--constraint",
                     "--samples", "--validate-samples", "--ts", "--free"}  # fmt: skip
# the base command's own (without them the fleet is not read as one)
BASE = {"--columns", "--records"}
# flags that need another to act on (given with it)
WITH = {"--validate-columns": ["--validate", "HELD"], "--validate-samples": ["--validate", "HELD"],
        "--init-window": ["--validate", "HELD"], "--horizon": ["--validate", "HELD"],
        "--profile-level": ["--profile"], "--worker-timeout": ["--workers", "2"],
        "--individual": ["--population", "v=0.4"], "--fix": ["--population", "cl=0.4"],
        "--rtol": ["--scheme", "dopri5"], "--atol": ["--scheme", "dopri5"]}  # fmt: skip


def _flags() -> list[str]:
    import argparse

    parser = cli.build_parser()
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    options = {o for a in sub.choices["fit"]._actions for o in a.option_strings}
    return sorted(o for o in options if o.startswith("--") and o != "--help")


@pytest.fixture(scope="module")
def walk(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("flags")
    train = _records(tmp, 1, 4, "train.csv")
    held = _records(tmp, 5, 6, "held.csv")
    start = tmp / "start.json"  # a fleet's --start-from: its typical values
    start.write_text(json.dumps({"params": {"cl": 0.006, "v": 1.1}, "kind": "population"}))
    base = ["fit", str(MODEL), str(train), "--records", "ID", "--columns", "t=TIME,conc=DV",
            "--out", str(tmp / "out")]  # fmt: skip
    subs = {"HELD": str(held), "START": str(start), "OTHER": str(tmp / "other")}
    return base, subs


def _reach(monkeypatch, capsys, argv) -> tuple[int | None, str, str]:
    """(exit code or None where the fit was reached, what reached it: every Problem
    the command built (the training units', the held-out units') and the keywords
    ``fit`` was called with, stderr)."""
    got: dict = {"problems": []}
    build = commands._problem

    def built(*a, **k):
        problem = build(*a, **k)
        got["problems"].append(_problem_seen(problem))
        return problem

    def stop(problem, method, **options):
        got["fit"] = _options_seen(method, options)
        raise _Reached

    monkeypatch.setattr(commands, "_problem", built)
    monkeypatch.setattr(commands, "fit", stop)
    monkeypatch.setattr(commands, "_workers", _no_workers)
    try:
        code = cli.main(argv)
    except _Reached:
        code = None
    seen = repr(got) if "fit" in got else ""
    return code, seen, capsys.readouterr().err


class _no_workers:
    """--workers/--scheduler without a pool (the walk stops before any work)."""

    def __init__(self, args):
        self.args = args

    def __enter__(self):
        a = self.args
        return (object() if a.scheduler else None), a.worker_timeout

    def __exit__(self, *exc):
        return False


def test_every_fit_flag_is_honoured_or_refused_for_a_fleet(walk, monkeypatch, capsys):
    base, subs = walk
    code, plain, err = _reach(monkeypatch, capsys, base)
    assert code is None, err
    missing = [f for f in _flags() if f not in VALUES]
    assert not missing, f"flags the walk has no value for: {missing}"
    dropped, unnamed = [], []
    for flag in [f for f in _flags() if f not in BASE | AFTER_THE_FIT]:
        extra = [flag, *(subs.get(v, v) for v in VALUES[flag])]
        extra += [subs.get(v, v) for v in WITH.get(flag, [])]
        code, seen, err = _reach(monkeypatch, capsys, base + extra)
        if flag in REFUSED or flag in REFUSED_ELSEWHERE:
            if code != 2 or flag not in err:
                unnamed.append(f"{flag}: exit {code}, {err.strip()!r}")
        elif code is not None:
            dropped.append(f"{flag}: refused ({err.strip()}) but listed as honoured")
        elif seen == plain:
            dropped.append(f"{flag}: nothing it sets reached the fit")
    assert not dropped + unnamed, "\n".join(dropped + unnamed)


def test_each_refusal_is_one_line_naming_the_flag_not_the_model_file(walk, monkeypatch, capsys):
    base, subs = walk
    for flag in REFUSED:
        extra = [flag, *(subs.get(v, v) for v in VALUES[flag])]
        extra += [subs.get(v, v) for v in WITH.get(flag, [])]
        code, _, err = _reach(monkeypatch, capsys, base + extra)
        line = err.strip()
        assert code == 2 and "\n" not in line and line.startswith("tensorid: error: "), line
        assert flag in line and "np.float64" not in line, line


def test_every_fit_parameter_is_honoured_or_refused_for_a_fleet(tmp_path, monkeypatch):
    """ti.fit's keywords on a fleet: each reaches fit_population or is refused in one
    line naming it (gtol, ftol and xtol were refused; the fit takes them)."""
    import inspect
    from concurrent.futures import ThreadPoolExecutor

    from tensorid.fitting import methods

    spec = ti.load_model(MODEL)
    exps = ti.load_data(_records(tmp_path, 1, 4, "t.csv"), spec.model, records="ID",
                        columns={"t": "TIME", "conc": "DV"})  # fmt: skip
    problem = ti.Problem(spec.model, exps, p0=spec.p0, x0=spec.x0, population=spec.population)
    got: dict = {}

    def reached(problem, kind, **kw):
        got.update(kw, method=kind)
        raise _Reached

    monkeypatch.setattr(methods, "fit_population", reached)
    pool = ThreadPoolExecutor(1)
    values = {"method": "laplace", "theta0": [0.006, 1.1], "starts": 3, "spread": 0.5,
              "sampling": "uniform", "seed": 3, "executor": pool, "workers": 2, "batch": 2,
              "x_scale": [1.0, 1.0], "maxiter": 7, "gtol": 1e-5, "ftol": 1e-6, "xtol": 1e-7,
              "callback": print, "options": ti.FitOptions(), "timeout": 30.0,
              "polish": False}  # fmt: skip
    honoured = {"method", "executor", "workers", "maxiter", "gtol", "ftol", "xtol", "callback",
                "timeout", "starts", "spread", "sampling", "seed"}  # fmt: skip
    params = [n for n in inspect.signature(ti.fit).parameters if n != "problem"]
    assert set(params) == set(values), "a new keyword of ti.fit: add it to the walk"
    wrong = []
    for name in params:
        got.clear()
        try:
            ti.fit(problem, **{name: values[name]})
            wrong.append(f"{name}: returned")
        except _Reached:
            if name not in honoured or got.get(name) is not values[name]:
                wrong.append(f"{name}: reached the fit as {got.get(name)!r}")
        except (ValueError, TypeError) as e:
            if name in honoured or name not in str(e) or "\n" in str(e):
                wrong.append(f"{name}: {e}")
    pool.shutdown()
    assert not wrong, wrong
    with pytest.raises(ValueError, match="fleet|population"):
        ti.fit_batch(problem, "auto", np.array([[0.006, 1.1]]))


@pytest.mark.slow
def test_profile_validate_and_data_sensitivity_of_theophylline_from_the_command_line(
    tmp_path, capsys
):
    """Issue 49's done-means: --profile, --validate (new units) and --data-sensitivity
    of the theophylline population fit from the CLI; the profile intervals of the
    typical values beside the Wald ones; the most influential unit's refit equal to a
    fit of the fleet without it."""
    theoph = Path(ti.__file__).parent / "datasets" / "theophylline.csv"
    rows = list(csv.DictReader(theoph.open()))
    train, held = tmp_path / "train.csv", tmp_path / "held.csv"
    for path, keep in ((train, lambda i: i <= 9), (held, lambda i: i > 9)):
        with path.open("w", newline="") as f:
            w = csv.DictWriter(f, list(rows[0]))
            w.writeheader()
            w.writerows(r for r in rows if keep(int(r["ID"])))
    model = ROOT / "examples" / "theophylline" / "model.py"
    out = tmp_path / "out"
    argv = ["fit", str(model), str(train), "--records", "ID", "--columns", "t=Time,cp=conc",
            "--validate", str(held), "--profile", "ka", "cl", "v", "--data-sensitivity",
            "--out", str(out), "--no-progress"]  # fmt: skip
    assert cli.main(argv) == 0
    printed = capsys.readouterr().out
    docs = (ROOT / "docs" / "fleets.md").read_text()
    block = docs.split("tests/test_fleet_flags.py runs it")[1].split("```text\n")[1]
    for line in block.split("```")[0].splitlines():  # docs/fleets.md's block, as printed
        assert line in printed, line
    fit = json.loads((out / "fit.json").read_text())
    for name in ("ka", "cl", "v"):
        typ, se = fit["population"][name]["typical"], fit["population"][name]["typical_stderr"]
        lo, hi = fit["ci95_profile"][name]
        wald = np.exp(np.log(typ) + np.array([-1.96, 1.96]) * se / typ)
        assert lo < typ < hi
        assert fit["profile_ends"][name] == {"lower": "crossed", "upper": "crossed"}
        # a likelihood's profile is skewed where the Wald one is symmetric in log: near it
        assert abs(lo - wald[0]) < 0.15 * (wald[1] - wald[0]), (name, lo, hi, wald)
        assert abs(hi - wald[1]) < 0.25 * (wald[1] - wald[0]), (name, lo, hi, wald)
        assert (out / f"profile_{name}.png").is_file()
        if name == "ka":  # docs/fleets.md: "its standard error gives [1.10, 2.55]"
            assert f"[{wald[0]:.2f}, {wald[1]:.2f}]" == "[1.10, 2.55]"
    assert [h["id"] for h in fit["held_out"]] == ["10", "11", "12"]
    assert all(h["gof"] > h["gof_pred"] and h["gof"] > 0.7 for h in fit["held_out"])
    influence = fit["unit_influence"]
    assert len(influence) == 9 and influence[0]["refitted"]
    assert "## Held-out units" in (out / "report.md").read_text()
    # compare of a held-out unit: IPRED (--ipred, η̂ by empirical Bayes) and PRED, as
    # --validate scored it; at the substeps the fit raised to (fit.json integration)
    assert fit["integration"]["substeps"] == 16 and fit["individual"] == []
    held_11 = next(h for h in fit["held_out"] if h["id"] == "11")
    for flag, key in (["--ipred"], "gof"), ([], "gof_pred"):
        cmp = tmp_path / f"cmp{key}"
        argv = ["compare", str(model), str(held), "--records", "ID", "--unit", "11",
                "--columns", "t=Time,cp=conc", "--params", str(out / "fit.json"),
                "--out", str(cmp), *flag]  # fmt: skip
        assert cli.main(argv) == 0
        scored = json.loads((cmp / "compare.json").read_text())
        assert scored["outputs"]["cp"]["gof"] == pytest.approx(held_11[key], abs=1e-9)
        if flag:
            assert scored["eta"] == pytest.approx(held_11["eta"], abs=1e-9)
            assert scored["params"] == pytest.approx(held_11["params"], abs=1e-9)
    assert "this unit's own (ka=" in capsys.readouterr().out
    sim = ["simulate", str(model), str(held), "--records", "ID", "--unit", "11", "--columns",
           "t=Time,cp=conc", "--params", str(out / "fit.json"), "--ipred", "--out",
           str(tmp_path / "sim")]  # fmt: skip
    assert cli.main(sim) == 0
    assert f"GOF cp: {held_11['gof']:.4f}" in capsys.readouterr().out
    # the top unit's refit (its data masked) against a fit of the other eight
    spec = ti.load_model(model)
    exps = ti.load_data(train, spec.model, records="ID", columns={"t": "Time", "cp": "conc"},
                        covariates=spec.covariates)  # fmt: skip
    top = influence[0]["id"]
    kw = dict(p0=spec.p0, x0=spec.x0, population=spec.population, substeps=16)
    full = ti.fit(ti.Problem(spec.model, exps, **kw))
    rest = ti.fit(ti.Problem(spec.model, [e for e in exps if e.name != top], **kw))
    se = np.sqrt(np.diag(full.cov))
    shift = (rest.x - full.x) / se
    assert shift == pytest.approx([influence[0]["shift"][n] for n in full.names], abs=2e-3)
