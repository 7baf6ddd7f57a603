"""How runs end: a ti.Status for every ending of a fit, and integrator failures
reported by the compiled march itself (experiment, sample, cause)."""

from __future__ import annotations

import re

import numpy as np
import pytest
from conftest import (
    ROBERTSON_K,
    SILVERBOX_P,
    robertson_data,
    robertson_model,
    silverbox_data,
    silverbox_model,
)

import tensorid as ti
from tensorid.solve.minimize import minimize_trust_region


def _blowup_model():
    # x' = p x²: from x(0) = 1 the solution 1 / (1 - p t) ends at t = 1 / p
    return ti.Model(
        rhs=lambda x, p, u: p[0] * x**2,
        output=lambda x, p: x,
        states=["x"],
        params=["p"],
        outputs=["y"],
    )


def test_every_status_has_its_own_message_and_integrator_codes_round_trip():
    messages = [s.message for s in ti.Status]
    assert len(set(messages)) == len(messages)
    for s in ti.Status:
        if s.code >= 0:
            assert ti.Status.from_code(s.code) is s
    with pytest.raises(ValueError):
        ti.Status.from_code(99)


@pytest.mark.parametrize(
    "scheme, substeps, status, sample",
    [
        ("rk4", 4, ti.Status.NONFINITE_STATE, 11),
        ("dopri5", 1, ti.Status.STEP_UNDERFLOW, 11),
        ("implicit-euler", 1, ti.Status.NEWTON_FAILED, 6),
    ],
)
def test_the_integrator_reports_how_and_where_it_failed(scheme, substeps, status, sample):
    t = np.linspace(0, 2, 21)
    # the user who does not read sim.status is told too: where, and why
    with pytest.warns(
        RuntimeWarning, match=f"finite at sample {sample} .*{re.escape(status.message)}"
    ):
        sim = ti.simulate(
            _blowup_model(), [1.0], [1.0], ti.Experiment(t), scheme=scheme, substeps=substeps
        )
    assert sim.status is status and sim.failed_at == sample
    assert np.isfinite(sim.x[:sample]).all() and not np.isfinite(sim.x[sample]).all()


def test_an_adaptive_scheme_on_a_stiff_model_reports_its_step_limit():
    data = robertson_data()
    with pytest.warns(RuntimeWarning, match=re.escape(ti.Status.STEP_LIMIT.message)):
        sim = ti.simulate(robertson_model(), ROBERTSON_K, [1.0, 0.0, 0.0], data, scheme="dopri5")
    assert sim.status is ti.Status.STEP_LIMIT and sim.failed_at >= 1


def test_a_finite_simulation_is_ok():
    sim = ti.simulate(silverbox_model(), SILVERBOX_P, [0.0, 0.0], silverbox_data(P=64))
    assert sim.status is ti.Status.OK and sim.failed_at is None


def test_diagnosis_names_the_experiment_the_time_and_the_integrators_cause():
    m = _blowup_model()
    t = np.linspace(0, 2, 21)
    ok = ti.Experiment(t[:5], y=1.0 / (1.0 - 0.5 * t[:5]), name="short")
    bad = ti.Experiment(t, y=np.ones(21), name="long")
    prob = ti.Problem(m, [ok, bad], p0={"p": 1.0}, x0=[1.0], scheme="implicit-euler", substeps=1)
    why = prob.diagnose(prob.theta0)
    assert "experiment 1 (long)" in why and "t = 0.6 (sample 6 of 21)" in why
    assert "Newton iteration did not converge" in why and "raise substeps" in why


def test_fit_endings_carry_a_status():
    prob = ti.Problem(
        silverbox_model(),
        silverbox_data(P=200),
        p0={k: 1.1 * v for k, v in SILVERBOX_P.items()},
        x0=[0.0, 0.0],
    )
    done = ti.fit(prob)
    assert done.status.success and done.success and done.message.startswith("converged")
    assert done.status in (
        ti.Status.GTOL,
        ti.Status.FTOL,
        ti.Status.XTOL,
        ti.Status.ROUNDING_FLOOR,
        ti.Status.NO_FURTHER_DECREASE,
        ti.Status.MACHINE_PRECISION,
    )
    short = ti.fit(prob, maxiter=2)
    assert short.status is ti.Status.MAXITER and not short.success
    assert "maxiter=2" in short.message
    for method in ti.METHODS:
        bad = ti.Problem(
            _blowup_model(),
            ti.Experiment(np.linspace(0, 5, 50), y=np.ones(50)),
            p0={"p": 10.0},
            x0=[1.0],
        )
        res = ti.fit(bad, method=method)
        assert res.status is ti.Status.NONFINITE_START and not res.success, method
    base = ti.fit(prob, method="fd-lsq")
    assert base.status is ti.Status.BASELINE_CONVERGED and base.success


def test_a_collapsed_trust_region_has_its_status():
    rng = np.random.default_rng(0)

    def noisy(x):  # a cost whose noise hides every decrease below 1e-3
        J = float(x @ x) + 1e-3 * rng.uniform()
        return J, 2 * x + 1.0, 2 * np.eye(2)

    r = minimize_trust_region(
        noisy, np.array([1.0, 1.0]), -np.inf * np.ones(2), np.inf * np.ones(2)
    )
    assert r.status is ti.Status.RADIUS_COLLAPSED and r.message == r.status.message


def test_fit_json_records_the_status(tmp_path):
    from tensorid.app.reports import fit_json

    p0 = {k: 1.1 * v for k, v in SILVERBOX_P.items()}
    prob = ti.Problem(silverbox_model(), silverbox_data(P=100), p0=p0, x0=[0.0, 0.0])
    d = fit_json(ti.fit(prob, maxiter=1), [])
    assert d["status"] == "maxiter" and not d["success"]


def test_every_ending_of_a_fit_is_in_the_when_things_go_wrong_page():
    from pathlib import Path

    page = (Path(__file__).resolve().parents[1] / "docs" / "troubleshooting.md").read_text()
    simulation = {"ok", "nonfinite_state", "step_limit", "step_underflow", "newton_failed"}
    missing = [str(s) for s in ti.Status if str(s) not in simulation | {"nonfinite_output"}]
    missing = [s for s in missing if f"`{s}`" not in page]
    assert not missing, f"docs/troubleshooting.md does not mention {missing}"
