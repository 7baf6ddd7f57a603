"""The automatic scale of θ (fitting/scaling.py): |θ0|, or a curvature step where
|θ0| says nothing (0) or, for a free initial state, is too small."""

from __future__ import annotations

import numpy as np
import pytest

import tensorid as ti
from tensorid.benchmarks import silverbox_problem
from tensorid.solve.scaling import auto_scale


def test_initial_states_are_floored_at_the_curvature_step_rounded_down():
    theta0 = np.array([1e-4, 5.0, 2.5, 1e-4, 0.0, 0.5])  # three initial states
    H = np.diag([4.0, 4.0, 4.0, 4.0, 4.0, 0.0])  # J0 = 36: curvature steps 3 (no curvature: inf)
    far = lambda: np.array([100.0, 100.0, 100.0])  # noqa: E731 - the states' reach
    scale = auto_scale(theta0, 36.0, H, n_init=3, reach=far)
    # initial states: a tiny guess takes the step rounded down to a power of two (2),
    # a larger one keeps |θ0|, and so does one above the rounded step (2.5);
    # parameters keep |θ0| however small; a zero takes the step (3); no curvature: |θ0|
    np.testing.assert_array_equal(scale, [2.0, 5.0, 2.5, 1e-4, 3.0, 0.5])
    np.testing.assert_array_equal(auto_scale(theta0, 36.0, H), [1e-4, 5.0, 2.5, 1e-4, 3.0, 0.5])


def test_the_floor_is_no_higher_than_the_state_reaches():
    theta0 = np.array([1e-4, 1e-4, 0.5])
    H = np.diag([1e-8, 1e-8, 1.0])  # almost no curvature: steps of 6e4
    # the simulation at θ0 takes the states to 0.3 and 1e-4: floors 0.25 and none
    scale = auto_scale(theta0, 36.0, H, n_init=2, reach=lambda: np.array([0.3, 1e-4]))
    np.testing.assert_array_equal(scale, [0.25, 1e-4, 0.5])
    # where the simulation failed, no floor
    np.testing.assert_array_equal(auto_scale(theta0, 36.0, H, 2, lambda: None), theta0)


def test_a_state_the_outputs_see_only_through_a_cubic_keeps_its_guess_as_scale():
    # x1 decays from its guess and reaches y only as c·x1³: at the start its
    # Gauss-Newton curvature is about 0 and the curvature step 2e6, which as its
    # scale left the fit stalled at the optimum ("NOT converged", radius collapsed)
    import jax.numpy as jnp

    def f(x, p, u):
        return jnp.array([-20.0 * x[0], -x[1] + p[1] * x[0] ** 3 + p[0] * u[0]])

    m = ti.Model(f, lambda x, p: x[1:], states=["x1", "x2"], params=["a", "c"], inputs=["u"],
                 outputs=["y"], name="weak")  # fmt: skip
    t = np.arange(200) * 0.05
    u = np.sin(t)[:, None]
    sim = ti.simulate(m, {"a": 1.0, "c": 1e-3}, [0.3, 0.2], ti.Experiment(t, u, np.zeros((200, 1))))
    noise = 0.01 * np.random.default_rng(0).standard_normal(sim.y.shape)
    data = ti.Experiment(t, u, sim.y + noise)
    pr = ti.Problem(m, data, p0={"a": 0.7, "c": 1e-3}, x0=[0.05, 0.1], free_x0=["x1", "x2"],
                    fixed=["c"])  # fmt: skip
    res = ti.fit(pr)
    assert res.success, res.message
    assert res.scale[0] == pytest.approx(0.05)


@pytest.fixture(scope="module")
def silverbox_best():
    """The Silverbox problem and its Gauss-Newton fit from the paper's guess."""
    prob = silverbox_problem()
    return prob, ti.fit(prob, "gauss-newton")


@pytest.mark.parametrize("velocity", [1e-4, -1e-4, 1e-6])
def test_a_tiny_initial_velocity_guess_does_not_slow_gauss_newton(velocity, silverbox_best):
    # Silverbox's initial velocity is -1.3 at the optimum: scaled by |θ0| alone, a
    # guess of 1e-4 put it 1e4 scaled units away, and Gauss-Newton took 21 iterations
    # (from 1e-6: 178) for the trust radius to double up to there; now 8
    prob, best = silverbox_best
    start = prob.theta0 * np.array([1.0, 0.9, 1.1, 0.95, 1.05])
    start[0] = velocity
    res = ti.fit(prob, "gauss-newton", theta0=start)
    assert res.success and res.cost == pytest.approx(best.cost, rel=1e-9)
    assert res.nit < 14, res.nit
