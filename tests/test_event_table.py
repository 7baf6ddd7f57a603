"""Event tables in NONMEM's layout (app/event_table.py): doses, infusions and repeats
read from the rows, rows without an observation kept, each unit's clock from its first
row; every mistake one line naming the file, the unit and the line."""

from __future__ import annotations

import json
import subprocess
import sys
import warnings

import numpy as np
import pytest

import tensorid as ti
from tensorid.engine.modelling.events import EventNote

MODEL = """
rhs = {"depot": "-ka * depot", "central": "ka * depot - cl / v * central"}
output = {"cp": "central / v"}
params = ["ka", "cl", "v", "F"]
doses = {"depot": "F * amt"}
p0 = {"ka": 1.0, "cl": 3.0, "v": 30.0, "F": 0.7}
fixed = ["F"]
"""

HEADER = "ID,TIME,AMT,DV,EVID,MDV,CMT,II,ADDL,RATE,WT\n"


def _table(tmp_path, rows: str, name="pk.csv"):
    (tmp_path / "model.py").write_text(MODEL)
    p = tmp_path / name
    p.write_text(HEADER + rows)
    return p


ROWS = """1,0,100,.,1,1,1,12,2,0,70
1,1,.,2.1,0,0,2,0,0,0,70
1,4,.,2.4,0,0,2,0,0,0,70
1,12,.,1.0,0,0,2,0,0,0,70
1,13,.,2.9,0,0,2,0,0,0,70
1,30,.,1.5,0,0,2,0,0,0,70
2,0,50,.,1,1,2,0,0,25,60
2,6,.,1.2,0,0,2,0,0,0,60
"""


def test_doses_repeats_and_infusions_are_read_with_rows_that_observe_nothing(tmp_path):
    p = _table(tmp_path, ROWS)
    spec = ti.load_model(tmp_path / "model.py")
    one, two = ti.load_data(p, spec.model, records="ID", columns={"t": "TIME", "cp": "DV"})
    # unit 1: the dose at 0 with its repeats at 12 and 24 (a new grid time), its samples
    assert list(one.t) == [0, 1, 4, 12, 13, 24, 30]
    assert one.observations == 5 and not one.observed[0, 0] and not one.observed[5, 0]
    assert one.events.kind == ("bolus",) * 3
    np.testing.assert_array_equal(one.events.time, [0, 12, 24])
    assert one.events.state == (0, 0, 0)  # CMT 1: the first state, the depot
    # unit 2: one observation, kept; an infusion of 50 at 25 per hour into CMT 2 (0-2 h)
    assert two.observations == 1 and list(two.t) == [0, 2, 6]
    assert two.events.kind == ("infusion",) and two.events.state == (1,)
    # the sample at 12 is observed before the dose at 12 (a trough)
    pr = ti.Problem(spec.model, [one, two], p0=spec.p0, fixed=["F"], doses=spec.doses)
    sims = pr.simulate(pr.theta0)
    h = list(one.t).index(12)
    assert sims[0].x[h, 0] < 1e-3 * 70  # the depot nearly empty before the dose at 12


@pytest.mark.parametrize(
    "row, words",
    [
        ("1,2,.,1,7,0,2,0,0,0,70", "EVID 7 on line 3 is not understood"),
        ("1,2,10,.,1,1,5,0,0,0,70", "CMT 5 on line 3 names no state"),
        ("1,2,10,.,1,1,1,12,0,0,70", "has II = 12 but no ADDL"),
        ("1,2,10,.,1,1,1,0,3,0,70", "has ADDL = 3 but no II"),
        ("1,2,-10,.,1,1,1,0,0,0,70", "has AMT -10"),
        ("1,2,10,.,1,1,1,0,0,-1,70", "RATE -1 on line 3"),
        ("1,2,.,x,0,0,2,0,0,0,70", "holds 'x' on line 3"),
        ("1,0.5,.,1,0,0,2,0,0,0,70", "goes backwards on line 3"),
        # dropped without a word before: a dose on an observation row, an infinite
        # observation, an MDV that is neither 0 nor 1
        ("1,2,100,.,0,1,1,0,0,0,70", "has AMT 100 and EVID 0, which doses nothing"),
        ("1,2,.,inf,0,0,2,0,0,0,70", "observation on line 3 is infinite"),
        ("1,2,.,1,0,2,2,0,0,0,70", "MDV 2 on line 3 is not understood"),
    ],
)
def test_a_bad_event_row_is_one_line_naming_the_file_the_unit_and_the_line(tmp_path, row, words):
    p = _table(tmp_path, f"1,1,.,2,0,0,2,0,0,0,70\n{row}\n1,3,.,1,0,0,2,0,0,0,70\n")
    spec = ti.load_model(tmp_path / "model.py")
    with pytest.raises(ValueError, match=words) as e:
        ti.load_data(p, spec.model, records="ID", columns={"t": "TIME", "cp": "DV"})
    assert "unit '1'" in str(e.value) and "\n" not in str(e.value)


def test_steady_state_1_is_read_2_refused_and_a_dose_after_the_last_row_said_once(tmp_path):
    spec = ti.load_model(tmp_path / "model.py") if (tmp_path / "model.py").exists() else None
    p = _table(tmp_path, "1,0,10,.,1,1,1,0,0,0,70\n1,2,.,1,0,0,2,0,0,0,70\n")
    spec = ti.load_model(tmp_path / "model.py")
    text = p.read_text().replace("ID,TIME", "SS,ID,TIME").splitlines()
    p.write_text("\n".join([text[0]] + ["2," + r for r in text[1:]]) + "\n")
    with pytest.raises(ValueError, match="only SS 1"):
        ti.load_data(p, spec.model, records="ID", columns={"t": "TIME", "cp": "DV"})
    p.write_text(p.read_text().replace("2,1,0,10,.,1,1,1,0,0", "1,1,0,10,.,1,1,1,24,0"))
    (e,) = ti.load_data(p, spec.model, records="ID", columns={"t": "TIME", "cp": "DV"})
    assert e.events.kind == ("steady-state", "bolus") and e.events.interval[0] == 24
    late = "".join(
        f"{u},0,10,.,1,1,1,0,0,0,70\n{u},2,.,1,0,0,2,0,0,0,70\n{u},9,10,.,1,1,1,0,0,0,70\n"
        for u in (1, 2)
    )
    p = _table(tmp_path, late)
    with warnings.catch_warnings(record=True) as seen:
        warnings.simplefilter("always")
        exps = ti.load_data(p, spec.model, records="ID", columns={"t": "TIME", "cp": "DV"})
    notes = [w for w in seen if issubclass(w.category, EventNote)]
    assert len(notes) == 1 and "1 (1), 2 (1)" in str(notes[0].message)
    assert [len(e.events) for e in exps] == [1, 1]


def test_other_names_are_mapped_with_events_and_the_cli_fits_a_table(tmp_path):
    rng = np.random.default_rng(0)
    spec_model = ti.load_model(
        (tmp_path / "model.py").write_text(MODEL) and tmp_path / "model.py"
    ).model
    times = np.array([0.5, 1, 2, 4, 8, 12, 13, 16, 24, 30])
    lines = []
    for unit in range(1, 4):
        ev = ti.Events.doses(0.0, 0, 100.0, ii=12.0, addl=1)
        e = ti.Experiment(times, None, np.ones((times.size, 1)), events=ev)
        truth = {"ka": 1.0 * (1 + 0.1 * unit), "cl": 3.0, "v": 30.0, "F": 0.7}
        sim = ti.simulate(spec_model, truth, [0, 0], e, doses={"depot": "F * amt"})
        lines.append(f"{unit},0,100,.,1,12,1")
        for t, c in zip(e.t[e.observed[:, 0]], sim.y[e.observed[:, 0], 0], strict=True):
            lines.append(f"{unit},{t:g},0,{c * (1 + 0.02 * rng.standard_normal()):.5f},0,0,0")
    (tmp_path / "pk.csv").write_text(
        "SUBJ,HOURS,DOSE,CONC,EVID,INTERVAL,MORE\n" + "\n".join(lines) + "\n"
    )
    out = tmp_path / "fit"
    r = subprocess.run(
        [sys.executable, "-m", "tensorid", "fit", str(tmp_path / "model.py"),
         str(tmp_path / "pk.csv"), "--records", "SUBJ", "--columns", "t=HOURS,cp=CONC",
         "--events", "AMT=DOSE,II=INTERVAL,ADDL=MORE", "--substeps", "8", "--out", str(out)],
        capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert r.returncode == 0, r.stderr[-2000:]
    fit = json.loads((out / "fit.json").read_text())
    assert fit["success"]
    assert fit["params"]["cl"] == pytest.approx(3.0, rel=0.05)
    assert fit["params"]["v"] == pytest.approx(30.0, rel=0.05)


def test_a_fleet_fit_refuses_what_it_would_drop_and_a_population_of_one_unit():
    """issue 51, item 3: ti.fit(population problem, starts=3) fitted once without a word;
    a population of one unit "converged" with ω = 4.8e-7 and NaN shrinkage."""
    m = ti.Model(rhs=lambda x, p, u: -p[0] * x, states=["x"], params=["k"])
    t = np.linspace(0, 4, 9)
    exps = [ti.Experiment(t, None, np.exp(-k * t)[:, None], name=str(i))
            for i, k in enumerate((0.9, 1.1, 1.0))]  # fmt: skip
    pr = ti.Problem(m, exps, p0={"k": 1.0}, x0=[1.0], population={"k": 0.2})
    # (gtol, ftol, xtol, starts, spread and seed are the fleet's own now:
    # tests/test_fleet_flags.py)
    for option in ({"batch": 2}, {"x_scale": [1.0]}, {"theta0": [1.0]}, {"polish": False}):
        with pytest.raises(ValueError, match=f"{next(iter(option))}=.* is not taken by a fit"):
            ti.fit(pr, **option)
    assert ti.fit(pr, starts=1, seed=0, polish=True, maxiter=2).nit <= 2  # the CLI's defaults
    # issue 49: fit_batch fitted a fleet as plain shared least squares
    with pytest.raises(ValueError, match="has population parameters .* with tensorid.fit"):
        ti.fit_batch(pr, "auto", np.array([[1.0], [0.9]]))
    one = ti.Problem(m, exps[:1], p0={"k": 1.0}, x0=[1.0], population={"k": 0.2})
    with pytest.raises(ValueError, match="need at least 2 units"):  # a new unit's, not a fit's
        ti.fit(one)


def test_a_repeated_residual_error_is_refused_before_any_work(capsys):
    """issue 51, item 3: `--residual-error cp=combined cp=additive` ran the last."""
    from pathlib import Path

    from tensorid import cli

    root = Path(__file__).resolve().parents[1]
    rc = cli.main([
        "fit", str(root / "examples/theophylline/model.py"),
        str(root / "src/tensorid/datasets/theophylline.csv"), "--records", "ID",
        "--columns", "t=Time,cp=conc", "--residual-error", "cp=combined", "cp=additive",
    ])  # fmt: skip
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and "'cp' is given 2 times" in err[0], err


@pytest.mark.parametrize(
    "flags, blamed",
    [
        (["--constraint", "ka>cl"], "constraints are not kept"),
        (["--noise", "0.5"], "noise is only used with priors"),
        (["--weights", "cp=2"], "a population fit estimates"),
        (["--prior", "ka=1,0.1"], "a fit with population parameters"),
        (["--fix", "ka=0.4"], "['ka'] is fixed (--fix) and also varies over the units "
                              "(population in "),
        (["--start-from", "{bad}"], "population['ka']: its start value p0 = -0.4 must"),
    ],
)  # fmt: skip
def test_a_fleet_s_refused_flag_is_named_not_the_model_file(tmp_path, capsys, flags, blamed):
    """issue 51, item 4: command-line settings refused for a fleet were blamed on the
    model file (and a start-from file's value shown as np.float64(-0.4))."""
    import json
    from pathlib import Path

    from tensorid import cli

    root = Path(__file__).resolve().parents[1]
    bad = tmp_path / "start.json"
    bad.write_text(json.dumps({"params": {"ka": -0.4, "cl": 2.7, "v": 31.8}}))
    flags = [f.replace("{bad}", str(bad)) for f in flags]
    rc = cli.main([
        "fit", str(root / "examples/theophylline/model.py"),
        str(root / "src/tensorid/datasets/theophylline.csv"), "--records", "ID",
        "--columns", "t=Time,cp=conc", "--out", str(tmp_path / "f"), *flags,
    ])  # fmt: skip
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1, err
    assert blamed.replace("{bad}", str(bad)) in err[0] and "np.float64" not in err[0], err
    if flags[0] != "--fix":  # the flag and its value lead; the model file only beside it
        assert err[0].startswith(f"tensorid: error: {' '.join(flags)} "), err


def test_a_text_value_is_said_as_its_own_unit_s(tmp_path, capsys):
    """issue 51, item 4: a text value on a line of unit 2 was reported as unit 1's."""
    from pathlib import Path

    from tensorid import cli

    root = Path(__file__).resolve().parents[1]
    lines = (root / "src/tensorid/datasets/theophylline.csv").read_text().splitlines()
    head = lines[0].split(",")
    at = next(i for i, ln in enumerate(lines) if ln.split(",")[head.index("ID")] == "2") + 3
    cells = lines[at].split(",")
    cells[head.index("conc")] = "abc"
    lines[at] = ",".join(cells)
    data = tmp_path / "theo.csv"
    data.write_text("\n".join(lines) + "\n")
    rc = cli.main(["fit", str(root / "examples/theophylline/model.py"), str(data), "--records",
                   "ID", "--columns", "t=Time,cp=conc", "--out", str(tmp_path / "f")])  # fmt: skip
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1, err
    assert (
        f"unit '2': column 'conc' holds a value that is not a number, 'abc' on line {at + 1}"
        in err[0]
    )


@pytest.mark.parametrize(
    "model, data, columns",
    [("theophylline", "theophylline.csv", "t=Time,cp=conc"),
     ("phenobarbital", "phenobarbital.csv", "t=TIME,conc=DV")],
)  # fmt: skip
def test_a_file_of_several_units_without_records_says_to_name_them(tmp_path, capsys, model,
                                                                     data, columns):  # fmt: skip
    """issue 51, item 4: a many-unit file without --records was explained as a varying
    covariate or as time that goes backwards."""
    from pathlib import Path

    from tensorid import cli

    root = Path(__file__).resolve().parents[1]
    rc = cli.main(["fit", str(root / "examples" / model / "model.py"),
                   str(root / "src/tensorid/datasets" / data), "--columns", columns,
                   "--out", str(tmp_path / "f")])  # fmt: skip
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1, err
    assert "the file holds several units; name its unit column with --records" in err[0]


def test_the_same_data_under_two_names_is_refused(tmp_path, capsys):
    """issue 51, item 3: a copy of the training file under another name halved every
    variance without a word (the same path twice was refused already)."""
    import shutil
    from pathlib import Path

    from tensorid import cli

    root = Path(__file__).resolve().parents[1] / "examples" / "silverbox"
    shutil.copy(root / "train.csv", tmp_path / "copy.csv")
    rc = cli.main(["fit", str(root / "model.py"), str(root / "train.csv"),
                   str(tmp_path / "copy.csv"), "--out", str(tmp_path / "f")])  # fmt: skip
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and "holds the same bytes as another file" in err[0], err


def test_the_python_api_s_raw_internal_errors_are_one_line_each():
    """issue 51, item 4: executor="nope", records=["ID"] and fit_population of a
    Problem without a fleet ended in AttributeError, TypeError: unhashable type and
    "zero-size array to reduction operation"."""
    from pathlib import Path

    from tensorid.population.estimate import fit_population

    m = ti.Model(rhs=lambda x, p, u: -p[0] * x, states=["x"], params=["k"])
    t = np.linspace(0, 4, 9)
    exps = [ti.Experiment(t, None, np.exp(-k * t)[:, None], name=str(i))
            for i, k in enumerate((0.9, 1.1, 1.0))]  # fmt: skip
    fleet = ti.Problem(m, exps, p0={"k": 1.0}, x0=[1.0], population={"k": 0.2})
    with pytest.raises(TypeError, match="executor must be a concurrent.futures executor"):
        ti.fit(fleet, executor="nope")
    with pytest.raises(TypeError, match="executor must be"):
        ti.fit(ti.Problem(m, exps, p0={"k": 1.0}, x0=[1.0]), executor="nope")
    with pytest.raises(ValueError, match="needs a Problem with population= or individual="):
        fit_population(ti.Problem(m, exps, p0={"k": 1.0}, x0=[1.0]))
    root = Path(__file__).resolve().parents[1]
    theo = ti.load_model(root / "examples/theophylline/model.py").model
    with pytest.raises(TypeError, match="records must be the name of the id column"):
        ti.load_data(root / "src/tensorid/datasets/theophylline.csv", theo, records=["ID"])


def test_what_the_reviewers_found_is_refused_in_one_line(tmp_path):
    """CENS other than 0 or 1 (Monolix's −1: above a limit) was fitted as a measurement;
    a reset of every state did not stop a lagged infusion; an x_scale array for a
    fleet ended in 'truth value of an array is ambiguous'."""
    (tmp_path / "model.py").write_text(MODEL)
    spec = ti.load_model(tmp_path / "model.py")
    p = tmp_path / "c.csv"
    p.write_text("ID,TIME,AMT,DV,EVID,CENS\n1,0,100,.,1,0\n1,1,.,2.0,0,0\n1,2,.,0.1,0,-1\n")
    with pytest.raises(ValueError, match="CENS -1 on line 4 is not supported"):
        ti.load_data(p, spec.model, records="ID", columns={"t": "TIME", "cp": "DV"})
    t = np.array([1.0, 2.0, 6.0])
    ev = ti.Events.doses(0.0, "depot", 100.0, rate=25.0) + ti.Events.resets(2.0, None)
    e = ti.Experiment(t, None, np.ones((3, 1)), events=ev)
    with pytest.raises(ValueError, match="would not stop it"):
        ti.Problem(spec.model, e, p0=spec.p0, lags={"depot": "0.5"}).cost_grad(np.ones(3))
    m = ti.Model(rhs=lambda x, p, u: -p[0] * x, states=["x"], params=["k"])
    exps = [ti.Experiment(t, None, np.exp(-k * t)[:, None], name=str(i))
            for i, k in enumerate((0.9, 1.1, 1.0))]  # fmt: skip
    fleet = ti.Problem(m, exps, p0={"k": 1.0}, x0=[1.0], population={"k": 0.2})
    with pytest.raises(ValueError, match="x_scale=.* is not taken by a fit"):
        ti.fit(fleet, x_scale=np.array([1.0]))


def test_repeats_past_a_unit_s_last_row_are_not_built(tmp_path):
    """ADDL 1e8 every 0.001 h: every repeat was built before those after the unit's last
    row were dropped (a MemoryError after 20 s); the ones that matter are built."""
    p = _table(tmp_path, "1,0,100,.,1,1,1,0.001,100000000,0,70\n1,1,.,2,0,0,2,0,0,0,70\n")
    spec = ti.load_model(tmp_path / "model.py")
    with pytest.warns(UserWarning, match="events after a record's last row"):
        (one,) = ti.load_data(p, spec.model, records="ID", columns={"t": "TIME", "cp": "DV"})
    assert len(one.events) == 1001 and one.t[-1] == 1.0


def test_a_unit_of_one_row_and_no_dose_is_left_out_with_a_note(tmp_path):
    """It stopped the whole fleet: "an experiment needs at least 2 samples, got 1"."""
    # unit 3: one row; unit 4: a baseline at its dose's time, then nothing observed
    extra = "3,0,.,0.5,0,0,2,0,0,0,70\n4,0,.,0.0,0,0,2,0,0,0,70\n4,0,100,.,1,1,1,0,0,0,70\n"
    p = _table(tmp_path, ROWS + extra)
    spec = ti.load_model(tmp_path / "model.py")
    with pytest.warns(UserWarning, match=r"unit\(s\) \['3', '4'\] hold one time"):
        units = ti.load_data(p, spec.model, records="ID", columns={"t": "TIME", "cp": "DV"})
    assert [u.name for u in units] == ["1", "2"]


def test_rows_of_an_output_no_column_is_mapped_to_are_said_once_for_the_file(tmp_path):
    """DVID 2 names cm, but only cp=DV is mapped: its rows were dropped without a word."""
    (tmp_path / "m.py").write_text(
        'rhs = {"c": "-k * c", "m": "k * c - km * m"}\noutput = {"cp": "c", "cm": "m"}\n'
        'params = ["k", "km"]\np0 = {"k": 0.2, "km": 0.1}\n'
    )
    rows = "".join(f"{i},0,100,.,1,1,.\n{i},1,.,80,0,.,1\n{i},1,.,15,0,.,2\n{i},2,.,60,0,.,1\n"
                   for i in (1, 2))  # fmt: skip
    (tmp_path / "t.csv").write_text("ID,TIME,AMT,DV,EVID,CMT,DVID\n" + rows)
    model = ti.load_model(tmp_path / "m.py").model
    with warnings.catch_warnings(record=True) as said:
        warnings.simplefilter("always")
        ti.load_data(tmp_path / "t.csv", model, records="ID", columns={"t": "TIME", "cp": "DV"})
    lines = [str(w.message) for w in said if "DVID names ['cm']" in str(w.message)]
    assert len(lines) == 1 and "--columns cm=DV" in lines[0]
