"""Implicit and adaptive schemes: accuracy at their order, and the same exact
first and second derivatives as the explicit ones (checked against forward-over-
forward autodiff, since reverse mode does not pass through their while loops)."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from conftest import (
    ROBERTSON_K,
    SILVERBOX_P,
    decay_model,
    oscillator_model,
    robertson_data,
    robertson_model,
    silverbox_data,
    silverbox_model,
)

import tensorid as ti


@pytest.fixture(scope="module")
def robertson():
    return robertson_model(), robertson_data()


def _assert_exact(prob, theta, tol=1e-9):
    J, g, H = prob.cost_grad_hess(theta)
    th = jnp.asarray(theta)
    g_ad = np.asarray(jax.jacfwd(prob.jax_cost)(th))
    H_ad = np.asarray(jax.jacfwd(jax.jacfwd(prob.jax_cost))(th))
    assert np.isfinite(J) and J > 0
    np.testing.assert_allclose(J, float(prob.jax_cost(th)), rtol=1e-12)
    # compare in scaled units: Robertson's parameters span nine decades
    s = np.maximum(np.abs(theta), 1e-3)
    np.testing.assert_allclose(g * s, g_ad * s, rtol=tol, atol=tol * np.abs(g * s).max())
    Hs, Hs_ad = H * np.outer(s, s), H_ad * np.outer(s, s)
    np.testing.assert_allclose(Hs, Hs_ad, rtol=tol, atol=tol * np.abs(Hs).max())
    # the one-direction sweep (Newton-CG's Hessian-vector product), along a scaled v
    v = s * np.linspace(-1.0, 1.0, theta.size)
    _, _, Hv = prob.cost_grad_hessp(theta, v)
    np.testing.assert_allclose(Hv * s, H_ad @ v * s, rtol=tol, atol=tol * np.abs(Hs).max())
    return J, g, H


@pytest.mark.slow  # compile-bound; keeps the default run under five minutes
def test_implicit_schemes_converge_at_their_order():
    m = decay_model()
    t = np.linspace(0.0, 3.0, 31)
    data = ti.Experiment(t, np.sin(t))
    ref = ti.simulate(m, {"k": 1.3}, [1.0], data, substeps=512).x
    for scheme, order in (("implicit-euler", 1), ("sdirk2", 2), ("sdirk3", 3)):
        e1, e2 = (
            np.abs(ti.simulate(m, {"k": 1.3}, [1.0], data, substeps=n, scheme=scheme).x - ref).max()
            for n in (8, 16)
        )
        assert np.log2(e1 / e2) == pytest.approx(order, abs=0.2), scheme


def test_explicit_scheme_blows_up_on_robertson_where_implicit_ones_are_accurate(robertson):
    m, data = robertson
    x0 = [1.0, 0.0, 0.0]
    with pytest.warns(RuntimeWarning, match="stops being finite"):  # said, not silent
        assert not ti.simulate(m, ROBERTSON_K, x0, data, scheme="rk4").finite
    scale = np.abs(data.measured).max(axis=0)
    for scheme, substeps, tol in (("sdirk3", 4, 1e-4), ("sdirk3", 32, 1e-7), ("sdirk2", 16, 1e-4)):
        sim = ti.simulate(m, ROBERTSON_K, x0, data, scheme=scheme, substeps=substeps)
        assert (np.abs(sim.y - data.measured) / scale).max() < tol, (scheme, substeps)


@pytest.mark.parametrize(
    "scheme",
    # compile-bound: all in the slow run, to keep the default run under five minutes
    [pytest.param(s, marks=pytest.mark.slow) for s in ("sdirk3", "sdirk2", "implicit-euler")],
)
def test_implicit_derivatives_are_exact_on_robertson(robertson, scheme):
    m, data = robertson
    prob = ti.Problem(
        m, data, p0=ROBERTSON_K, x0=[1.0, 0.0, 0.0], free_x0=["A"], scheme=scheme, substeps=4
    )
    _assert_exact(prob, prob.theta0 * np.array([1.02, 1.1, 0.8, 1.3]))


def test_implicit_hessian_matches_central_differences_of_gradient(robertson):
    m, data = robertson
    prob = ti.Problem(m, data, p0=ROBERTSON_K, x0=[1.0, 0.0, 0.0], scheme="sdirk3")
    theta = prob.theta0 * np.array([1.1, 0.8, 1.3])
    _, _, H = prob.cost_grad_hess(theta)
    H_fd = np.zeros((3, 3))
    for k in range(3):
        h = 1e-5 * theta[k]
        e = np.zeros(3)
        e[k] = h
        gs = [prob.cost_grad_hess(theta + j * e)[1] for j in (-2, -1, 1, 2)]
        H_fd[:, k] = (gs[0] - 8 * gs[1] + 8 * gs[2] - gs[3]) / (12 * h)
    s = np.outer(theta, theta)
    np.testing.assert_allclose(H * s, H_fd * s, rtol=1e-6, atol=1e-6 * np.abs(H * s).max())


@pytest.mark.slow  # compile-bound; keeps the default run under five minutes
def test_newton_identifies_robertson_rate_constants(robertson):
    m, data = robertson
    start = {"k1": 0.05, "k2": 2e7, "k3": 1.3e4}
    prob = ti.Problem(
        m,
        data,
        p0=start,
        x0=[1.0, 0.0, 0.0],
        scheme="sdirk3",
        substeps=32,
        bounds=dict.fromkeys(start, (0, None)),
    )
    res = ti.fit(prob, "newton")
    assert res.success, res.message
    for k, v in ROBERTSON_K.items():
        assert res.params[k] == pytest.approx(v, rel=1e-4), k


@pytest.mark.parametrize("scheme", ["dopri5", "bosh3"])
def test_adaptive_error_follows_the_tolerance(scheme):
    data = silverbox_data(P=200, seed=4)
    ref = ti.simulate(silverbox_model(), SILVERBOX_P, [0.0, 0.0], data, substeps=256).y
    errs = []
    for rtol in (1e-5, 1e-8):
        sim = ti.simulate(
            silverbox_model(), SILVERBOX_P, [0.0, 0.0], data, scheme=scheme, rtol=rtol, atol=1e-14
        )
        errs.append(np.abs(sim.y - ref).max() / np.abs(ref).max())
    assert errs[1] < 1e-6 and errs[1] < errs[0] / 30, errs


@pytest.mark.parametrize(  # compile-bound: in the slow run
    "scheme, interpolation",
    [
        pytest.param(*c, marks=pytest.mark.slow)
        for c in (("dopri5", "linear"), ("bosh3", "linear"), ("dopri5", "bandlimited"))
    ],
)
def test_adaptive_derivatives_are_exact_for_the_steps_taken(scheme, interpolation):
    """(bandlimited: the input read at stage fractions not known in advance)"""
    m = oscillator_model()
    t = np.linspace(0, 6, 60)
    u = np.stack([np.sin(1.3 * t), np.cos(0.7 * t)], axis=1)
    truth = {"k": 2.0, "c": 0.3, "g": 1.0, "q": 0.7}
    sim = ti.simulate(m, truth, [0.3, 0.0], ti.Experiment(t, u))
    data = ti.Experiment(t, u, sim.y)
    prob = ti.Problem(m, data, p0=truth, x0=[0.3, 0.0], free_x0=["om"], scheme=scheme,
                      rtol=1e-7, atol=1e-10, interpolation=interpolation)  # fmt: skip
    _assert_exact(
        prob, prob.theta0 * np.array([1, 1.1, 0.9, 1.05, 0.8]) + np.array([0.2, 0, 0, 0, 0])
    )


def test_tolerances_are_checked():
    data = silverbox_data(P=50)
    m = silverbox_model()
    with pytest.raises(ValueError, match="adaptive schemes"):
        ti.Problem(m, data, p0=SILVERBOX_P, rtol=1e-6)
    with pytest.raises(ValueError, match="rtol > 0"):
        ti.Problem(m, data, p0=SILVERBOX_P, scheme="dopri5", rtol=0.0)
    with pytest.raises(ValueError, match="round-off"):
        ti.Problem(m, data, p0=SILVERBOX_P, scheme="dopri5", rtol=1e-14)
    with pytest.raises(ValueError, match="sdirk3"):
        ti.Problem(m, data, p0=SILVERBOX_P, scheme="radau")


@pytest.mark.parametrize(
    "kwargs, match",
    [
        (dict(a=((), (0.5,)), b=(0.5, 0.5), c=(0.0, 1.0)), "row 1 of a sums to 0.5"),
        (dict(a=((), (1.0,)), b=(0.6, 0.6), c=(0.0, 1.0)), "sum to 1.2"),
        (dict(a=((),), b=(1.0, 0.0), c=(0.0,)), "one entry per stage"),
        (dict(a=((), (0.5, 0.5)), b=(0.5, 0.5), c=(0.0, 1.0)), "explicit row 1 has 1"),
    ],
)
def test_a_wrong_tableau_is_refused_when_the_scheme_is_built(kwargs, match):
    with pytest.raises(ValueError, match=match):
        ti.ExplicitRungeKutta("bad", order=2, **kwargs)


def test_a_scheme_steps_any_callable_field_as_it_is():
    """RK4.interval called with a user's own field object: one that cannot be hashed,
    and two equal ones with other state (the stages' jitted call must not key on them)."""
    from dataclasses import dataclass

    from tensorid.engine.schemes.integrators import RK4

    @dataclass
    class Decay:  # (a dataclass: equal by value, unhashable)
        rate: float

        def __call__(self, y, s):
            return -self.rate * y

    y0 = jnp.ones(2)
    for rate in (1.0, 3.0):
        y = RK4.interval(Decay(rate), Decay(rate), y0, 1.0, None, 8)[0]
        z = -rate / 8  # RK4's amplification per step of y' = -rate y
        np.testing.assert_allclose(np.asarray(y), (1 + z + z**2 / 2 + z**3 / 6 + z**4 / 24) ** 8,
                                   rtol=1e-13)  # fmt: skip


def test_a_users_own_scheme_that_follows_the_protocol_runs():
    from tensorid.engine.schemes.integrators import RK4, RungeKuttaScheme

    class Halved:  # RK4 with twice the substeps: a scheme the package does not know
        name, order = "rk4-halved", 4

        def interval(self, f, fs, y, dt, carry, substeps):
            return RK4.interval(f, fs, y, dt, carry, 2 * substeps)

    assert isinstance(Halved(), RungeKuttaScheme) and not isinstance(object(), RungeKuttaScheme)
    m, data = silverbox_model(), silverbox_data(P=64)
    own = ti.simulate(m, SILVERBOX_P, [0.01, 0.0], data, scheme=Halved(), substeps=2)
    ref = ti.simulate(m, SILVERBOX_P, [0.01, 0.0], data, scheme="rk4", substeps=4)
    np.testing.assert_allclose(own.x, ref.x, rtol=1e-14)
    with pytest.raises(TypeError, match="scheme object"):
        ti.Discretisation("rk4")


def test_settings_given_twice_are_refused():
    d = ti.Discretisation.of("heun", 2)
    m, data = silverbox_model(), silverbox_data(P=32)
    with pytest.raises(ValueError, match="not both"):
        ti.simulate(m, SILVERBOX_P, [0.0, 0.0], data, discretisation=d, substeps=8)
    with pytest.raises(ValueError, match="not both"):
        ti.Problem(m, data, p0=SILVERBOX_P, discretisation=d, scheme="dopri5")
    with pytest.raises(ValueError, match="not both"):
        ti.fit(ti.Problem(m, data, p0=SILVERBOX_P), options=ti.FitOptions(), maxiter=3)
    assert ti.simulate(m, SILVERBOX_P, [0.0, 0.0], data, discretisation=d).finite
