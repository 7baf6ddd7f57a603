"""The automatic scale of θ (fitting/scaling.py): |θ0|, or a curvature step where
|θ0| says nothing (0) or, for a free initial state, is too small."""

from __future__ import annotations

import numpy as np
import pytest

import tensorid as ti
from tensorid.benchmarks import silverbox_problem
from tensorid.fitting.scaling import auto_scale


def test_initial_states_are_floored_at_the_curvature_step_rounded_down():
    theta0 = np.array([1e-4, 5.0, 2.5, 1e-4, 0.0, 0.5])  # three initial states
    H = np.diag([4.0, 4.0, 4.0, 4.0, 4.0, 0.0])  # J0 = 36: curvature steps 3 (no curvature: inf)
    scale = auto_scale(theta0, 36.0, H, n_init=3)
    # initial states: a tiny guess takes the step rounded down to a power of two (2),
    # a larger one keeps |θ0|, and so does one within a factor 2 of the step (2.5);
    # parameters keep |θ0| however small; a zero takes the step (3); no curvature: |θ0|
    np.testing.assert_array_equal(scale, [2.0, 5.0, 2.5, 1e-4, 3.0, 0.5])
    np.testing.assert_array_equal(auto_scale(theta0, 36.0, H), [1e-4, 5.0, 2.5, 1e-4, 3.0, 0.5])


@pytest.mark.parametrize("velocity", [1e-4, -1e-4, 1e-6])
def test_a_tiny_initial_velocity_guess_does_not_slow_gauss_newton(velocity):
    # Silverbox's initial velocity is -1.3 at the optimum: scaled by |θ0| alone, a
    # guess of 1e-4 put it 1e4 scaled units away, and Gauss-Newton took 21 iterations
    # (from 1e-6: 178) for the trust radius to double up to there; now 8
    prob = silverbox_problem()
    best = ti.fit(prob, "gauss-newton")
    start = prob.theta0 * np.array([1.0, 0.9, 1.1, 0.95, 1.05])
    start[0] = velocity
    res = ti.fit(prob, "gauss-newton", theta0=start)
    assert res.success and res.cost == pytest.approx(best.cost, rel=1e-9)
    assert res.nit < 14, res.nit
