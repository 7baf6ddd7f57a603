"""fit.json and report.md of a fleet fit (issue 42, item 6): a result with
``population``, ``residual_sd`` and ``units`` writes them under those keys and as
tables; an ordinary result writes neither."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

import tensorid as ti
from tensorid.analysis.validation import training_scores
from tensorid.app.reports import fit_json, fit_report, json_text


@pytest.fixture(scope="module")
def plain():
    """A small ordinary fit: x' = -a x + b u."""
    model = ti.model_from_equations({"x": "-a*x + b*u"}, {"y": "x"}, ["u"], ["a", "b"])
    t = np.linspace(0, 5, 60)
    u = np.sin(t)
    y = ti.simulate(model, {"a": 1.2, "b": 0.7}, [0.0], ti.Experiment(t, u)).y
    y = y + 0.01 * np.random.default_rng(1).standard_normal(y.shape)
    return ti.fit(ti.Problem(model, ti.Experiment(t, u, y, name="r"), p0={"a": 1.0, "b": 1.0}))


class Fleet:
    """A fleet result as the estimator will give it: the plain result, plus the three
    attributes the writers read."""

    def __init__(self, res, **extra):
        self._res = res
        self.__dict__.update(extra)

    def __getattr__(self, name):
        return getattr(self._res, name)


def _fleet(res, n_units: int):
    rng = np.random.default_rng(0)
    population = {
        "a": {"typical": 1.2, "typical_stderr": 0.05, "omega": 0.3, "omega_stderr": 0.04,
              "cv_percent": 30.7, "shrinkage_percent": 12.5},
        "b": {"typical": 0.7, "typical_stderr": np.float64(0.02), "omega": 0.1,
              "omega_stderr": math.nan, "cv_percent": 10.0, "shrinkage_percent": 41.0},
    }  # fmt: skip
    units = [
        {"id": f"u{i}", "params": {"a": 1.2 * math.exp(rng.normal(0, 0.3)), "b": 0.7},
         "stderr": {"a": 0.1, "b": 0.01}}
        for i in range(n_units)
    ]  # fmt: skip
    return Fleet(res, population=population, residual_sd={"y": 0.011}, units=units)


def test_an_ordinary_fit_writes_no_fleet_keys(plain):
    data = fit_json(plain, [])
    assert not {"population", "residual_sd", "units"} & set(data)
    report = fit_report(plain, data, training_scores(plain), [])
    assert "## Population" not in report and "## Units" not in report


def test_a_fleet_result_writes_population_residual_sd_and_units(plain):
    fleet = _fleet(plain, 3)
    data = json.loads(json_text(fit_json(fleet, [])))
    assert data["population"]["a"] == fleet.population["a"]
    assert set(data["population"]["b"]) == {
        "typical", "typical_stderr", "omega", "omega_stderr", "cv_percent", "shrinkage_percent"
    }  # fmt: skip
    assert data["population"]["b"]["omega_stderr"] is None  # NaN: not available
    assert data["residual_sd"] == {"y": 0.011}
    assert [u["id"] for u in data["units"]] == ["u0", "u1", "u2"]
    assert data["units"][1]["params"]["a"] == fleet.units[1]["params"]["a"]
    assert data["units"][1]["stderr"] == {"a": 0.1, "b": 0.01}
    assert data["params"] == plain.params  # the ordinary keys are still there


def test_report_has_the_population_table_and_the_first_20_units(plain):
    fleet = _fleet(plain, 25)
    data = fit_json(fleet, [])
    report = fit_report(fleet, data, training_scores(fleet), [])
    assert "## Population" in report
    assert "| a | 1.2 ± 0.05 | 0.3 ± 0.04 | 30.7 | 12.5 |" in report
    assert "| b | 0.7 ± 0.02 | 0.1 | 10 | 41 |" in report
    assert "Residual standard deviation (additive, per output): y 0.011." in report
    assert "## Units (25)" in report
    assert "| u19 |" in report and "| u20 |" not in report
    assert "and 5 more units in fit.json" in report
