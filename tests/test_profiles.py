"""Profile likelihood: exact where it can be checked (a linear model gives the Wald
interval), the same interval ends as optimisation-based profiling, one-sided at a
bound, unbounded and named where the data do not identify, and intervals that
cover the truth where Wald intervals do not."""

from __future__ import annotations

import json

import jax.numpy as jnp
import numpy as np
import pytest
from conftest import two_tank_model

import tensorid as ti
from tensorid import cli

DECAY = ti.Model(
    rhs=lambda x, p, u: -x / p[0], states=["x"], params=["tau"],
    output=lambda x, p: x, outputs=["y"],
)  # fmt: skip


def _decay_problem(seed: int, n: int = 10, T: float = 0.5, noise: float = 0.3, **kw):
    """y = x0·exp(−t/τ) on a short record: the classic case where τ's Wald interval is
    poor (τ = 1, x0 = 1 free). One model for all: its sweeps compile once."""
    model = DECAY
    t = np.linspace(0, T, n)
    y = np.exp(-t) + noise * np.random.default_rng(seed).standard_normal(n)
    return ti.Problem(model, ti.Experiment(t, None, y), p0={"tau": 1.0}, x0=[1.0],
                      free_x0=["x"], **kw)  # fmt: skip


def test_a_linear_model_gives_the_wald_interval_exactly():
    model = ti.Model(
        rhs=lambda x, p, u: p[0] * u[0] + p[1] * u[1] + 0 * x, states=["x"],
        params=["a", "b"], inputs=["u", "v"], output=lambda x, p: x, outputs=["y"],
    )  # fmt: skip
    t = np.linspace(0, 2, 60)
    u = np.stack([np.cos(3 * t), np.sin(5 * t)], 1)
    exp = ti.Experiment(t, u)
    y = ti.simulate(model, {"a": 2.0, "b": -1.0}, [0.5], exp).y[:, 0]
    y = y + 0.01 * np.random.default_rng(0).standard_normal(t.size)
    prob = ti.Problem(model, ti.Experiment(t, u, y), p0={"a": 1.0, "b": 0.0}, free_x0=["x"])
    res = ti.fit(prob)
    wald = res.uncertainty().ci95
    profiles = res.profile(["x(t0)", "a", "b"])
    for k, p in enumerate(profiles.values()):
        assert p.ends == {"lower": "crossed", "upper": "crossed"}
        np.testing.assert_allclose(p.interval, wald[k], rtol=1e-7)


@pytest.mark.parametrize("seed", [1, 4])
def test_integrated_profiles_end_where_optimisation_based_ones_do(seed):
    res = ti.fit(_decay_problem(seed))
    fast = res.profile(["x(t0)", "tau"])
    slow = res.profile(["x(t0)", "tau"], method="refit")
    for name in fast:
        assert fast[name].ends == slow[name].ends
        np.testing.assert_allclose(fast[name].interval, slow[name].interval, rtol=1e-6)


@pytest.mark.slow
def test_profiles_of_a_model_with_several_unknowns_agree_with_refits():
    model = two_tank_model()
    t = np.arange(300) * 2.0
    u = 0.5 + 0.3 * np.sign(np.sin(t / 80))
    truth = {"p1": 0.05, "p2": 0.08, "p3": 0.04, "p4": 0.05}
    exp = ti.Experiment(t, u)
    y = ti.simulate(model, truth, [1.0, 1.0], exp).y
    y = y + 0.01 * np.random.default_rng(2).standard_normal(y.shape)
    prob = ti.Problem(model, ti.Experiment(t, u, y), p0={k: 1.2 * v for k, v in truth.items()},
                      x0=[1.0, 1.0])  # fmt: skip
    res = ti.fit(prob)
    assert res.success
    fast, slow = res.profile(), res.profile(method="refit")
    for name in fast:
        # every re-optimisation ended through the one loop, converged, and is counted
        ended = {ti.Status[s.upper()] for s in fast[name].corrections}
        assert ended and all(s.success for s in ended) and not fast[name].notes
        np.testing.assert_allclose(fast[name].interval, slow[name].interval, rtol=1e-6)
        lo, hi = fast[name].interval
        assert lo < res.params[name] < hi


def test_corrections_that_stop_short_are_counted_and_said(monkeypatch):
    # issue 39: the profile's re-optimisations end through the one loop, and where
    # they stop before converging the profile says so (it lies above the true one)
    import tensorid.analysis.profiles as profiles

    real = profiles.minimize_trust_region
    monkeypatch.setattr(
        profiles, "minimize_trust_region", lambda *a, **kw: real(*a, **{**kw, "maxiter": 1})
    )
    res = ti.fit(_decay_problem(0))
    p = res.profile("tau")["tau"]
    assert p.corrections.get("maxiter", 0) > 0
    assert len(p.notes) == 1 and "stopped before converging (maxiter" in p.notes[0]
    assert "the interval may be too narrow" in str(p)


def test_ctrl_c_in_a_correction_stops_the_profiles(monkeypatch):
    # the loop ends the correction's run cleanly (INTERRUPTED at its best point); the
    # profiles then stop as the user asked, instead of tracing on

    res = ti.fit(_decay_problem(0))
    calls = []

    def interrupting(problem_cost_grad_hess):
        def f(theta):
            calls.append(theta)
            if len(calls) > 3:
                raise KeyboardInterrupt
            return problem_cost_grad_hess(theta)

        return f

    monkeypatch.setattr(res.problem, "cost_grad_hess", interrupting(res.problem.cost_grad_hess))
    with pytest.raises(KeyboardInterrupt):
        res.profile("tau")
    assert len(calls) == 4  # nothing evaluated after Ctrl-C


def test_an_initial_state_fit_that_stops_short_is_said(monkeypatch):
    # validation's initial-state fit, another inner solve, ends through the one loop
    # too and its status is kept: converged here; stopped by its iteration limit, a
    # note says so
    import tensorid.analysis.validation as validation

    res = ti.fit(_decay_problem(0))
    record = _decay_problem(1).experiments[0]
    [score] = res.validate(record)
    assert score.x0_status.success and score.x0_fit == score.x0_status.name.lower()
    assert "initial states stopped" not in str(score)
    real = validation.minimize_trust_region
    monkeypatch.setattr(
        validation, "minimize_trust_region", lambda *a, **kw: real(*a, **{**kw, "maxiter": 1})
    )
    [short] = res.validate(record)
    assert short.x0_fit == "maxiter"
    assert "the fit of its initial states stopped before converging" in str(short)


def test_a_bound_makes_the_interval_one_sided():
    free = ti.fit(_decay_problem(3, noise=0.05))
    tau = free.params["tau"]
    wald_lo = free.uncertainty().ci95[1, 0]
    bound = 0.5 * (tau + wald_lo)  # inside the interval the data would give
    res = ti.fit(_decay_problem(3, noise=0.05, bounds={"tau": (bound, None)}))
    p = res.profile(["tau"])["tau"]
    assert p.ends["lower"] == "bound" and p.interval[0] == bound
    assert p.ends["upper"] == "crossed" and p.interval[1] > tau
    assert "stops at the bound" in p.describe()


def test_a_direction_the_data_cannot_see_is_named_not_identifiable():
    # only the product a·b reaches the output
    model = ti.Model(
        rhs=lambda x, p, u: -x + p[0] * p[1] * u[0], states=["x"], params=["a", "b"],
        inputs=["u"], output=lambda x, p: x, outputs=["y"],
    )  # fmt: skip
    t = np.linspace(0, 5, 80)
    exp = ti.Experiment(t, jnp.sin(2 * t))
    y = ti.simulate(model, {"a": 2.0, "b": 1.5}, [0.0], exp).y[:, 0]
    y = y + 0.01 * np.random.default_rng(0).standard_normal(t.size)
    prob = ti.Problem(model, ti.Experiment(t, np.sin(2 * t), y), p0={"a": 1.0, "b": 1.0})
    res = ti.fit(prob)
    p = res.profile(["a"])["a"]
    assert p.ends["upper"] == "flat" and p.interval[1] == np.inf
    assert not p.identifiable and "not identifiable" in p.describe()
    assert np.isfinite(p.costs).all()


@pytest.mark.slow
def test_profile_intervals_cover_the_truth_where_wald_intervals_do_not():
    """A small version of benchmarks/bench_profiles.py's coverage study (200 draws)."""
    wald = profile = 0
    draws = 40
    for seed in range(draws):
        res = ti.fit(_decay_problem(seed))
        lo, hi = res.uncertainty().ci95[1]
        wald += lo <= 1.0 <= hi
        plo, phi = res.profile(["tau"])["tau"].interval
        profile += plo <= 1.0 <= phi
    assert profile / draws >= 0.9
    assert profile > wald


def test_bad_profile_arguments():
    res = ti.fit(_decay_problem(0))
    with pytest.raises(ValueError, match="unknown names"):
        res.profile(["k"])
    with pytest.raises(ValueError, match="level"):
        res.profile(level=95)
    with pytest.raises(ValueError, match="method"):
        res.profile(method="grid")


@pytest.mark.slow  # compile-bound; keeps the default run under five minutes
def test_the_command_line_writes_profile_intervals(tmp_path, capsys):
    from pathlib import Path

    example = Path(__file__).resolve().parents[1] / "examples" / "silverbox"
    out = tmp_path / "fit"
    args = ["fit", str(example / "model.py"), str(example / "train.csv"), "--out", str(out)]
    assert cli.main(args + ["--no-progress", "--profile", "b", "u0"]) == 0
    data = json.loads((out / "fit.json").read_text())
    assert set(data["ci95_profile"]) == {"b", "u0"} and data["profile_level"] == 0.95
    assert set(data["profile_corrections"]) == {"b", "u0"}
    for ended in data["profile_corrections"].values():  # each traced, all converged
        assert ended and all(ti.Status[s.upper()].success for s in ended)
    for name, (lo, hi) in data["ci95_profile"].items():
        wald = data["ci95"][name]
        assert lo < data["estimates"][name] < hi
        assert abs(lo - wald[0]) < 0.1 * (wald[1] - wald[0])  # near-linear here
    assert (out / "profile_b.png").is_file() and "Profile likelihood" in (
        out / "report.md"
    ).read_text()
    assert "95% profile interval" in capsys.readouterr().out


def test_the_profile_figure_crosses_the_threshold_where_the_interval_ends():
    # three traced points; the ends found between them lie where straight lines
    # between the points would not cross the threshold
    from types import SimpleNamespace

    from tensorid.analysis.figures import profile_figure

    prof = SimpleNamespace(
        values=np.array([-1.0, 0.0, 1.0]), costs=np.array([8.0, 0.0, 8.0]), threshold=4.0,
        interval=(-0.8, 0.7), ends={"lower": "crossed", "upper": "crossed"},
        estimate=0.0, level=0.95, name="k", describe=lambda: "k",
    )  # fmt: skip
    fig = profile_figure(prof, sigma2=1.0, stderr=float("nan"))
    curve = fig.axes[0].lines[0].get_xydata()
    for end in prof.interval:
        assert [end, 4.0] in curve.tolist()
    prof.ends["upper"] = "bound"  # stopped at a bound below the threshold: not a crossing
    curve = profile_figure(prof, 1.0, float("nan")).axes[0].lines[0].get_xydata()
    assert [0.7, 4.0] not in curve.tolist() and [-0.8, 4.0] in curve.tolist()
