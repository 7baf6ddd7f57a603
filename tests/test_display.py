"""Results read as tables, in a terminal (str) and in a notebook (_repr_html_), and
records of the nonlinear-benchmarks package become Experiments with their
initialisation window."""

from __future__ import annotations

import html
import re
from dataclasses import dataclass, replace

import numpy as np
import pytest
from test_priors import LINEAR, _linear_record

import tensorid as ti


@pytest.fixture(scope="module")
def fitted():
    # test_priors' model and record: their sweeps are compiled once for both files
    e = _linear_record()
    res = ti.fit(ti.Problem(LINEAR, e, p0={"a": 1.0, "b": 0.0}))
    prior = ti.fit(ti.Problem(LINEAR, e, p0={"a": 1.0, "b": 0.0}, priors={"a": (1.5, 0.1)}))
    return res, prior, e


def _shown(fitted):
    res, with_prior, e = fitted
    return {
        "FitResult": (res, ["a", "b"]),
        "Uncertainty": (res.uncertainty(), ["a", "b"]),
        "Information": (res.information(), ["a", "b"]),
        "Profile": (res.profile(["a"])["a"], ["a"]),
        "Score": (res.validate(e, 10)[0], ["y"]),
        "NoiseCheck": (with_prior.noise_check, ["y"]),
        "ResidualTests": (res.residual_tests(8), ["whiteness of y", "y against input v"]),
    }


def test_results_print_as_tables_naming_the_unknowns_and_outputs(fitted):
    for what, (obj, names) in _shown(fitted).items():
        text, page, short = str(obj), obj._repr_html_(), repr(obj)
        for shown in (text, page, short):
            assert "array(" not in shown and "np.float64" not in shown, (what, shown)
        assert "\n" not in short and len(short) < 300, (what, short)
        assert "┃" in text and "│" in text, (what, text)  # a table's rules, not a dump
        for name in names:
            assert re.search(rf"│ {re.escape(name)} +│", text), (what, name, text)
            assert f"<td>{html.escape(name)}</td>" in page, (what, name, page)
        assert page.startswith("<div>") and page.count("<table>") == page.count("</table>") >= 1
        assert "=[" not in text and f"{type(obj).__name__}(" not in text, (what, text)


def test_the_fit_prints_its_summary_and_keeps_its_one_line_repr(fitted):
    res = fitted[0]
    assert str(res) == res.summary().rstrip("\n")
    assert repr(res).startswith("FitResult(method='auto', status=")
    assert "params={a=" in repr(res)


def test_a_sandwich_says_so_and_notes_no_other_form(fitted):
    # a robust sandwich is built on the exact Hessian: its intervals are of that form
    u = replace(fitted[0].uncertainty(), kind="robust", lags=2)
    head = "sandwich, Newey-West after prewhitening, 2 lags"
    assert head in str(u) and "form" not in str(u).split("\n", 1)[1]


def test_html_escapes_what_it_shows(fitted):
    e = fitted[2]
    score = fitted[0].validate(ti.Experiment(e.t, e.u, e.y, name="<b>&"), 10)[0]
    page = score._repr_html_()
    assert "<b>&" not in page and "&lt;b&gt;&amp;" in page


def test_a_prior_that_the_data_contradict_shows_the_warning_in_the_noise_table(fitted):
    check = fitted[1].noise_check
    assert ("warning:" in str(check)) == (check.message() is not None)
    assert f"{check.used:.4g}" in str(check)


@dataclass
class Record:
    """What nonlinear_benchmarks' Input_output_data holds (the package downloads its
    data at run time, which a test must not do)."""

    u: np.ndarray
    y: np.ndarray
    sampling_time: float | None = None
    name: str = ""
    state_initialization_window_length: int | None = None


def test_a_benchmark_record_becomes_an_experiment_with_its_window(fitted):
    res, _, e = fitted
    ts = float(e.t[1] - e.t[0])
    test = Record(e.u, e.y[:, 0], ts, "test", state_initialization_window_length=10)
    exp = ti.Experiment.from_benchmark(test)
    assert exp.name == "test" and exp.init_window == 10 and exp.P == e.P
    np.testing.assert_allclose(exp.t, e.t - e.t[0], rtol=1e-12, atol=1e-12)
    np.testing.assert_array_equal(exp.y, e.y)
    assert "init_window=10" in repr(exp)
    # validate() scores it by the record's own protocol: as init_window=10 does
    [own], [given] = res.validate(exp), res.validate(exp.window(0, exp.P), 10)
    assert own.start == 10 and own.gof == pytest.approx(given.gof, rel=1e-12)
    [whole] = res.validate(exp, 20)  # an explicit window still wins
    assert whole.start == 20
    train = ti.Experiment.from_benchmark([Record(e.u, e.y, ts, "train")])[0]
    assert train.init_window is None and train.name == "train"


def test_benchmark_columns_and_a_missing_sampling_time():
    P = 20
    rec = Record(np.ones((P, 3)), np.zeros((P, 2)), None, "mimo")
    exp = ti.Experiment.from_benchmark(rec, inputs=[2, 0], outputs=1, Ts=0.5)
    assert exp.u.shape == (P, 2) and exp.y.shape == (P, 1) and exp.t[-1] == 0.5 * (P - 1)


@pytest.mark.parametrize(
    "record, match",
    [
        (Record(np.ones(20), np.ones(20), None, "r"), r"'r' has no sampling_time; give Ts="),
        (Record(np.ones(20), np.r_[np.ones(19), np.nan], 1.0, "r"), r"'r': y contains NaN"),
        (Record(np.ones(20), np.ones(19), 1.0, "r"), "u has 20 samples but y has 19"),
        (Record(np.ones((20, 2, 2)), np.ones(20), 1.0, "r"), r"input has shape \(20, 2, 2\)"),
        (Record(np.ones(20), np.ones(20), "Discrete time", "r"), "no sampling_time; give Ts="),
        (Record(np.ones(20), np.ones(20), -1.0, "r"), r"has sampling_time=-1.0; give Ts="),
        (Record(np.ones(20), np.ones(20), 1.0, "r", 19), "window_length must be a whole"),
        (Record(np.ones(20), None, 1.0, "r"), "this Record lacks y"),
    ],
)
def test_bad_benchmark_records_are_one_clear_line(record, match):
    with pytest.raises(ValueError, match=match) as err:
        ti.Experiment.from_benchmark(record)
    assert "\n" not in str(err.value)


def test_bad_benchmark_column_choices_are_one_clear_line():
    rec = Record(np.ones((20, 2)), np.ones(20), 1.0, "r")
    with pytest.raises(ValueError, match=r"inputs=5 must be column indices from 0 to 1"):
        ti.Experiment.from_benchmark(rec, inputs=5)
    with pytest.raises(ValueError, match="give Ts= the sampling period"):
        ti.Experiment.from_benchmark(rec, Ts=-1.0)
