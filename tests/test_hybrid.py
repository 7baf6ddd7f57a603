"""method="auto" (fitting/hybrid.py): Gauss-Newton where it converges fast, the exact
Hessian where its convergence turns linear, and on past a saddle that Gauss-Newton
cannot see."""

from __future__ import annotations

import json
from pathlib import Path

import jax.numpy as jnp
import numpy as np
import pytest

import tensorid as ti
from tensorid import cli
from tensorid.benchmarks import lotka_volterra_problem, silverbox_problem

# residuals r1 = 1 - a, r2 = 1 + a - 2a² (outputs a and 2a² - a, both measured as 1):
# at a = 0 the gradient r1 r1' + r2 r2' = -1 + 1 vanishes and Gauss-Newton's curvature
# r1'² + r2'² = 2 is positive, but the exact one adds r2 r2'' = -4: a maximum of J
# that Gauss-Newton takes for a minimum. A third output exp(b), measured as e, gives
# Gauss-Newton some iterations before it gets there (a stays 0: its gradient is 0).
SADDLE = ti.Model(
    rhs=lambda x, p, u: 0.0 * x,
    output=lambda x, p: jnp.stack([p[0], 2.0 * p[0] ** 2 - p[0], jnp.exp(p[1])]),
    states=["x"], params=["a", "b"], outputs=["y1", "y2", "y3"], name="hidden-maximum",
)  # fmt: skip
T = np.linspace(0.0, 1.0, 11)


def _saddle_problem() -> ti.Problem:
    y = np.tile([1.0, 1.0, np.e], (T.size, 1))
    return ti.Problem(SADDLE, ti.Experiment(T, None, y), p0=[0.0, -1.0], x0=[0.0])


def test_auto_is_gauss_newton_where_gauss_newton_converges_fast():
    prob = silverbox_problem()
    gn, auto = ti.fit(prob, "gauss-newton"), ti.fit(prob)
    assert auto.method == "auto" and auto.success
    assert auto.hybrid == {
        "gauss_newton_evaluations": gn.nfev, "exact_evaluations": 0, "switches": 0,
        "saddles_left": 0,
    }  # fmt: skip
    assert auto.nit == gn.nit and auto.cost == pytest.approx(gn.cost, rel=1e-12)


def test_auto_switches_to_the_exact_hessian_where_gauss_newton_turns_linear():
    # Lotka-Volterra from a start where Gauss-Newton crawls (large residual term)
    prob = lotka_volterra_problem()
    start = prob.theta0 * np.array([1.188, 0.889, 0.635, 1.221, 1.025, 0.81])
    gn = ti.fit(prob, "gauss-newton", theta0=start)
    newton = ti.fit(prob, "newton", theta0=start)
    auto = ti.fit(prob, theta0=start)
    assert auto.hybrid["switches"] >= 1 and auto.hybrid["exact_evaluations"] > 0
    assert auto.cost == pytest.approx(min(gn.cost, newton.cost), rel=1e-9)
    assert auto.nit < gn.nit / 2, (auto.nit, gn.nit)


def test_auto_goes_on_past_a_saddle_where_gauss_newton_stops():
    prob = _saddle_problem()
    gn = ti.fit(prob, "gauss-newton")
    assert gn.success and gn.params["a"] == 0.0  # stopped at the maximum, "converged"
    assert gn.params["b"] == pytest.approx(1.0) and gn.nit > 1
    assert np.linalg.eigvalsh(gn.hess)[0] < 0 and gn.cost == pytest.approx(2 * T.size)
    auto = ti.fit(prob)
    assert auto.success and auto.hybrid["saddles_left"] == 1
    assert auto.cost < gn.cost and np.linalg.eigvalsh(auto.hess)[0] > 0
    assert np.abs(auto.jac).max() < 1e-8 and auto.params["b"] == pytest.approx(1.0)
    # counts continue across the restart, which came after Gauss-Newton's iterations
    its = [h["iteration"] for h in auto.history]
    assert its == list(range(auto.nit + 1)) and auto.nit > gn.nit
    nfev = [h["nfev"] for h in auto.history]
    assert nfev == sorted(nfev) and len(set(nfev)) == len(nfev)


@pytest.mark.slow  # compile-bound; keeps the default run under five minutes
def test_auto_in_lockstep_equals_auto_one_start_at_a_time():
    prob = lotka_volterra_problem()
    slow = [1.188, 0.889, 0.635, 1.221, 1.025, 0.81]  # Gauss-Newton turns linear
    starts = prob.theta0 * np.array([slow, [0.9, 1.1, 1, 1, 1, 1]])
    together = ti.fit_batch(prob, "auto", starts)
    for res, start in zip(together, starts, strict=True):
        alone = ti.fit(prob, "auto", theta0=start)
        assert res.nit == alone.nit and res.hybrid == alone.hybrid
        assert res.cost == pytest.approx(alone.cost, rel=1e-9)
    saddle = ti.fit_batch(_saddle_problem(), "auto", [[0.0, -1.0], [0.0, -1.0]])
    alone = ti.fit(_saddle_problem())
    assert all(r.hybrid == alone.hybrid and r.cost == alone.cost for r in saddle)


def test_the_command_line_fits_with_auto_by_default(tmp_path):
    example = Path(__file__).resolve().parents[1] / "examples" / "silverbox"
    out = tmp_path / "fit"
    args = ["fit", str(example / "model.py"), str(example / "train.csv"), "--out", str(out)]
    assert cli.main(args + ["--no-progress"]) == 0
    data = json.loads((out / "fit.json").read_text())
    assert data["method"] == "auto"
    h = data["hybrid"]  # Silverbox: Gauss-Newton all the way
    assert h["gauss_newton_evaluations"] == data["function_evaluations"] > 1
    assert h["exact_evaluations"] == h["switches"] == h["saddles_left"] == 0
