"""method="auto" (fitting/hybrid.py): Gauss-Newton where it converges fast, the exact
Hessian where its convergence turns linear, and on past a saddle that Gauss-Newton
cannot see."""

from __future__ import annotations

import json
from pathlib import Path
from types import SimpleNamespace

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


def test_auto_buys_no_hessian_while_gauss_newton_only_waits_for_its_radius():
    # a start whose initial velocity is 1e-4 where the optimum's is -1.3: in scaled
    # units (|θ0|) it is 1e4 away, and Gauss-Newton's steps, each as predicted, only
    # wait for the trust radius to double up to there. Their small relative decreases
    # are no stall that an exact Hessian would end (it took 7-10 of them for nothing).
    # The automatic scale now takes an initial state's curvature step where |θ0| is
    # smaller (tests/test_scaling.py): x_scale = |θ0| keeps this slow path to test.
    prob = silverbox_problem()
    start = prob.theta0 * np.array([1.0, 0.9, 1.1, 0.95, 1.05])
    start[0] = 1e-4
    kw = dict(theta0=start, x_scale=np.abs(start))
    gn, auto = ti.fit(prob, "gauss-newton", **kw), ti.fit(prob, **kw)
    assert gn.success and auto.success
    assert gn.nit >= 15, gn.nit  # the slow path is still taken (21 iterations)
    assert auto.hybrid["exact_evaluations"] == 0, auto.hybrid
    assert auto.nit <= gn.nit and auto.cost == pytest.approx(gn.cost, rel=1e-9)


def test_newton_stays_exact_and_steps_by_the_model_that_predicted_better():
    from tensorid.solve.registry import resolve

    state = SimpleNamespace(tr=SimpleNamespace(problem=SimpleNamespace(K=1)))
    resolve("newton").prepare(state)  # what method "newton" steps with
    hybrid = state.hybrid
    assert hybrid.exact and hybrid.locked
    H_gn, H_exact = np.eye(1), -np.eye(1)  # J = φ²/2 + 1 is H_GN's model exactly
    for k in range(6):
        phi = np.array([2.0**-k])
        J, g = 0.5 * phi @ phi + 1.0, phi
        use = hybrid.take(phi, J, g, H_gn, H_exact, exact=True)[2]
        assert use is H_gn  # first as in NL2SOL, then as it predicted the last step
        hybrid.observe({"iteration": k, "accepted": True, "rho": 1.0})
        assert hybrid.exact  # never back to Gauss-Newton sweeps
    assert hybrid.report() is None  # res.hybrid stays method "auto"'s


@pytest.mark.slow
def test_newton_does_not_wander_on_a_chain_with_cubic_springs():
    # benchmarks/bench_chain_cubic.py, start 1: the exact model alone sent every step
    # along the residual term's negative curvature to the boundary, where the cost
    # did not follow: 150 iterations at radii 0.003-0.8, ending at cost 559.6
    from scipy.signal import lfilter

    from tensorid.benchmarks import mass_chain_model, mass_chain_truth
    from tensorid.solve.multistart import draw_starts

    model, truth, rng = mass_chain_model(5), mass_chain_truth(5), np.random.default_rng(0)
    t = np.arange(2000) * 0.05
    u = (6.0 * lfilter([0.1], [1.0, -0.9], rng.standard_normal(2000)))[:, None]
    y = ti.simulate(model, truth, np.zeros(10), ti.Experiment(t, u)).y
    y = y + 0.01 * np.sqrt(np.mean(y**2, axis=0)) * rng.standard_normal(y.shape)
    bounds = {n: (1e-3, None) for n in model.params}
    prob = ti.Problem(model, ti.Experiment(t, u, y), p0=truth, bounds=bounds)
    start = draw_starts(truth, prob.lower, prob.upper, 11, spread=0.2, sampling="uniform",
                        seed=0)[2]  # fmt: skip
    newton = ti.fit(prob, "newton", theta0=start)
    assert newton.cost == pytest.approx(1.8951815, rel=1e-6) and newton.nit < 60


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
