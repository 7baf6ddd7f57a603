"""fit(): recovery of known systems, bounds, fixed parameters, blow-ups, baselines."""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np
import pytest
from conftest import SILVERBOX_P, silverbox_data, silverbox_model

import tensorid as ti


@pytest.fixture(scope="module")
def sb_problem_factory():
    data = silverbox_data(P=512, seed=0, x0=(0.0, 0.0))
    model = silverbox_model()

    def make(p0, **kw):
        return ti.Problem(model, data, p0=p0, x0=[0.0, 0.0], free_x0=["v"], **kw)

    return make


def _perturbed(seed, spread=0.2):
    rng = np.random.default_rng(seed)
    return {k: v * (1 + rng.uniform(-spread, spread)) for k, v in SILVERBOX_P.items()}


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_newton_recovers_noise_free_silverbox_from_20_percent(sb_problem_factory, seed):
    prob = sb_problem_factory(_perturbed(seed))
    res = ti.fit(prob, method="newton")
    assert res.success, res.message
    for k, v in SILVERBOX_P.items():
        assert res.params[k] == pytest.approx(v, rel=1e-6), k
    assert abs(res.x0[1]) < 1e-6  # true velocity at t0 is 0 (V/s)
    assert res.x0[0] == 0.0  # fixed initial state stays put
    assert res.cost < 1e-20
    assert res.nit < 40
    assert [h["iteration"] for h in res.history] == list(range(len(res.history)))
    costs = [h["cost"] for h in res.history if h["accepted"]]
    assert all(b <= a for a, b in zip(costs, costs[1:], strict=False))


def test_newton_cg_on_hessian_vector_products_reaches_the_same_optimum(sb_problem_factory):
    prob = sb_problem_factory(_perturbed(1))
    res = ti.fit(prob, method="newton-cg")
    assert res.success, res.message
    for k, v in SILVERBOX_P.items():
        assert res.params[k] == pytest.approx(v, rel=1e-6), k
    assert res.nhev >= res.nit > 0 and res.history[-1]["nhev"] == res.nhev
    assert res.hess.shape == (5, 5)  # computed once at the end, for the error bars
    # with bounds: stops on the active one, like newton
    prob = sb_problem_factory(dict(SILVERBOX_P, a=0.9), bounds={"a": (0.5, 0.95)})
    res = ti.fit(prob, method="newton-cg")
    assert res.success and res.params["a"] == 0.95


def test_starts_fitted_in_lock_step_match_separate_fits(sb_problem_factory):
    from tensorid.solve.multistart import draw_starts

    prob = sb_problem_factory(_perturbed(4))
    thetas = draw_starts(prob.theta0, prob.lower, prob.upper, 4, seed=3)
    thetas[2, 1] *= -1.0  # a negative mass: the simulation blows up at this start
    batch = ti.fit_batch(prob, "newton", thetas)
    assert [r.success for r in batch] == [True, True, False, True]
    assert "Choose another initial guess" in batch[2].message
    for th, rb in zip(thetas[[0, 1, 3]], [batch[0], batch[1], batch[3]], strict=True):
        rs = ti.fit(prob, theta0=th)
        assert rb.cost == pytest.approx(rs.cost, abs=1e-20)
        np.testing.assert_allclose(rb.theta, rs.theta, rtol=1e-6, atol=1e-10)
        assert rb.hess.shape == (5, 5) and len(rb.history) == rb.nit + 1
    # the same through fit(starts=..., batch=...), in this process
    res = ti.fit(prob, starts=4, batch=4, workers=1)
    assert res.success and len(res.starts) == 4
    for k, v in SILVERBOX_P.items():
        assert res.params[k] == pytest.approx(v, rel=1e-6), k
    with pytest.raises(ValueError, match="batch"):
        ti.fit(prob, method="fd-bfgs", starts=4, batch=2)
    with pytest.raises(ValueError, match="batch must be a positive integer"):
        ti.fit(prob, starts=4, batch=0)


def test_result_fields_and_fixed_parameters(sb_problem_factory):
    p0 = dict(_perturbed(5), d=SILVERBOX_P["d"])
    prob = sb_problem_factory(p0, fixed=["d"])
    assert prob.theta_names == ["v(t0)", "m", "a", "b"]
    res = ti.fit(prob, method="gauss-newton")
    assert res.success, res.message
    assert res.params["d"] == SILVERBOX_P["d"]
    assert res.theta.shape == (4,) and res.jac.shape == (4,) and res.hess.shape == (4, 4)
    assert res.x is res.theta and res.fun == res.cost
    assert res.params["m"] == pytest.approx(SILVERBOX_P["m"], rel=1e-6)
    assert res.nfev >= res.nit > 0 and res.seconds > 0
    assert res.gof()[0] > 0.999999


def test_bounds_are_respected_and_active_bound_reported(sb_problem_factory):
    # the true a = 0.9675 lies above the upper bound: the fit must stop on it
    p0 = dict(SILVERBOX_P, a=0.9)
    prob = sb_problem_factory(p0, bounds={"a": (0.5, 0.95), "m": (1e-6, 1e-5)})
    res = ti.fit(prob, method="newton")
    assert res.success, res.message
    assert res.params["a"] == 0.95
    assert 1e-6 <= res.params["m"] <= 1e-5
    assert res.jac[prob.theta_names.index("a")] < 0  # it pushes against the bound


def test_blow_up_during_fit_is_a_rejected_step():
    """x' = -p x^3 blows up for negative p with a large step; the fit must survive
    trial points where the simulation is not finite."""
    model = ti.Model(
        rhs=lambda x, p, u: -p[0] * x**3 + u[0],
        output=lambda x, p: x,
        states=["x"],
        params=["p"],
        inputs=["u"],
        outputs=["y"],
    )
    t = np.linspace(0, 4, 81)
    u = 0.5 * np.sin(2 * t)
    y = ti.simulate(model, {"p": 2.0}, [1.0], ti.Experiment(t, u)).y
    prob = ti.Problem(model, ti.Experiment(t, u, y), p0={"p": 0.02}, x0=[1.0])
    # the first Newton steps from a tiny p overshoot into negative p where x explodes
    assert not np.isfinite(prob.cost([-30.0]))
    res = ti.fit(prob, method="newton")
    assert res.success, res.message
    assert res.params["p"] == pytest.approx(2.0, rel=1e-8)
    assert np.isfinite(res.theta).all() and np.isfinite(res.cost)


def test_start_where_simulation_blows_up_fails_cleanly():
    model = ti.Model(
        rhs=lambda x, p, u: p[0] * x**2,
        output=lambda x, p: x,
        states=["x"],
        params=["p"],
        outputs=["y"],
    )
    t = np.linspace(0, 5, 50)
    prob = ti.Problem(model, ti.Experiment(t, y=np.ones(50)), p0={"p": 10.0}, x0=[1.0])
    for method in ti.METHODS:
        res = ti.fit(prob, method=method)
        assert not res.success
        assert "not finite" in res.message
        assert np.isfinite(res.theta).all()


@pytest.mark.parametrize("method", ["fd-lsq", "fd-bfgs"])
def test_finite_difference_baselines_run_on_the_same_simulator(sb_problem_factory, method):
    prob = sb_problem_factory(_perturbed(3, spread=0.02))
    res = ti.fit(prob, method=method)
    assert np.isfinite(res.cost) and res.cost < prob.cost(prob.theta0)
    assert res.nfev > res.nit  # finite differences cost evaluations of their own
    assert res.method == method


def test_several_experiments_share_parameters():
    model = silverbox_model()
    exps = [silverbox_data(P=300, seed=s, x0=(x, 0.0)) for s, x in ((10, 0.01), (11, -0.02))]
    prob = ti.Problem(
        model, exps, p0=_perturbed(7, 0.1), x0=[[0.0, 0.0], [0.0, 0.0]], free_x0=["y", "v"]
    )
    assert prob.K == 8
    res = ti.fit(prob, method="newton")
    assert res.success, res.message
    np.testing.assert_allclose(res.x0, [[0.01, 0.0], [-0.02, 0.0]], atol=1e-8)
    for k, v in SILVERBOX_P.items():
        assert res.params[k] == pytest.approx(v, rel=1e-6)


def test_callback_sees_each_iteration(sb_problem_factory):
    seen = []
    res = ti.fit(sb_problem_factory(_perturbed(1)), method="newton", callback=seen.append)
    assert len(seen) == len(res.history)
    assert {"iteration", "cost", "grad_norm", "radius"} <= set(seen[0])


def test_unknown_method_is_rejected(sb_problem_factory):
    with pytest.raises(ValueError, match="unknown method"):
        ti.fit(sb_problem_factory(SILVERBOX_P), method="lbfgs")


def test_output_that_depends_on_parameters_is_identified():
    """y = c·x: c and x0 are not separately identifiable from y alone, but with two
    outputs (x and c·x) they are; the Newton fit must find both."""
    model = ti.Model(
        rhs=lambda x, p, u: -p[0] * x + u[0],
        output=lambda x, p: jnp.stack([x[0], p[1] * x[0] ** 2]),
        states=["x"],
        params=["k", "c"],
        inputs=["u"],
        outputs=["y1", "y2"],
    )
    t = np.linspace(0, 5, 60)
    u = np.cos(t)
    truth = {"k": 0.7, "c": 1.8}
    y = ti.simulate(model, truth, [0.5], ti.Experiment(t, u)).y
    prob = ti.Problem(
        model, ti.Experiment(t, u, y), p0={"k": 1.0, "c": 1.0}, x0=[0.0], free_x0=["x"]
    )
    res = ti.fit(prob)
    assert res.success
    assert res.params == pytest.approx(truth, rel=1e-8)
    assert res.x0[0] == pytest.approx(0.5, rel=1e-8)


def test_a_state_leaving_its_domain_is_named_with_time_and_remedies():
    model = ti.Model(
        rhs=lambda x, p, u: -p[0] * jnp.sqrt(x) + u[0],
        output=lambda x, p: x,
        states=["level"],
        params=["k"],
        inputs=["q"],
        outputs=["y"],
    )
    t = np.linspace(0, 5, 50)
    prob = ti.Problem(model, ti.Experiment(t, np.zeros(50), np.ones(50)), p0={"k": 3.0}, x0=[1.0])
    why = prob.diagnose(prob.theta0)
    assert "['level']" in why and "t = 0.714286 (sample 7 of 50)" in why
    assert "safe_sqrt" in why and "bounds" in why
    res = ti.fit(prob)
    assert not res.success and res.message.startswith("the simulation is not finite at k=3")
    assert np.isfinite(res.theta).all()
    assert prob.diagnose([0.1]) is None


def test_trial_points_that_blow_up_are_reported_when_the_fit_stalls():
    # the data are fit best by p = 2, but p > 1 is where x' = p x² explodes
    model = ti.Model(
        rhs=lambda x, p, u: p[0] * x**2 - x,
        output=lambda x, p: x,
        states=["x"],
        params=["p"],
        outputs=["y"],
    )
    t = np.linspace(0, 3, 31)
    y = 1.0 + 2.0 * t  # grows faster than any finite p < 1 allows
    prob = ti.Problem(model, ti.Experiment(t, y=y), p0={"p": 0.5}, x0=[1.0])
    res = ti.fit(prob, maxiter=60)
    assert np.isfinite(res.cost) and np.isfinite(res.theta).all()
    assert (
        res.notes and "trial point(s) were rejected because the simulation blew up" in res.notes[0]
    )
    assert "['x'] are not finite" in res.notes[0]
    if not res.success:
        assert "blew up" in res.message and res.notes[0] in res.warnings


def test_adaptive_scheme_on_a_stiff_model_fails_cleanly_and_points_to_sdirk():
    from conftest import ROBERTSON_K, robertson_data, robertson_model

    data = robertson_data()
    prob = ti.Problem(robertson_model(), data, p0=ROBERTSON_K, x0=[1.0, 0.0, 0.0], scheme="dopri5")
    res = ti.fit(prob)
    assert not res.success and "scheme='sdirk3'" in res.message and "stiff" in res.message
