"""The transition-tensor gradient and Hessian are the exact derivatives of the
discretised cost: checked against JAX autodiff of the plain simulation, against
central differences, and against an independent simulator."""

from __future__ import annotations

import jax
import numpy as np
import pytest
from conftest import (
    SILVERBOX_P,
    autodiff,
    decay_model,
    derivative_problems,
    interpolation_problems,
    silverbox_model,
)
from scipy.integrate import solve_ivp

import tensorid as ti

# the smooth input interpolations (their first in the default run, the rest slow)
SMOOTH = interpolation_problems(hessian="tensors")
PROBLEMS = derivative_problems(hessian="tensors") + SMOOTH  # this module checks the tensors
IDS = [name for name, _, _ in PROBLEMS]
CASES = [
    pytest.param(*case, id=case[0], marks=[pytest.mark.slow] if case in SMOOTH[1:] else [])
    for case in PROBLEMS
]


@pytest.mark.parametrize("name,prob,theta", CASES)
def test_gradient_and_hessian_equal_autodiff(name, prob, theta):
    J, g, H = prob.cost_grad_hess(theta)
    J_ad, g_ad, H_ad = autodiff(prob.jax_cost)(theta)
    assert J > 0 and np.isfinite(J)
    np.testing.assert_allclose(J, J_ad, rtol=1e-12)
    np.testing.assert_allclose(g, g_ad, rtol=1e-9, atol=1e-9 * np.abs(g_ad).max())
    np.testing.assert_allclose(H, H_ad, rtol=1e-9, atol=1e-9 * np.abs(H_ad).max())
    # the residual-weighted second-order term is not negligible here
    _, _, H_gn = prob.cost_grad_gn(theta)
    assert np.abs(H - H_gn).max() > 1e-4 * np.abs(H).max()


@pytest.mark.parametrize("name,prob,theta", CASES)
def test_hessian_vector_products_equal_the_hessian(name, prob, theta):
    """The one-direction sweep gives ∇²J v for any v; together the products rebuild H."""
    J, g, H = prob.cost_grad_hess(theta)
    K = theta.size
    Jg, gg = prob.cost_grad(theta)
    np.testing.assert_allclose((Jg, *gg), (J, *g), rtol=1e-12, atol=1e-12 * np.abs(g).max())
    rng = np.random.default_rng(K)
    for v in (rng.standard_normal(K), np.eye(K)[-1]):
        Jv, gv, Hv = prob.cost_grad_hessp(theta, v)
        np.testing.assert_allclose(Jv, J, rtol=1e-12)
        np.testing.assert_allclose(gv, g, rtol=1e-10, atol=1e-10 * np.abs(g).max())
        tol = 1e-9 * np.abs(H).max() * np.abs(v).max()
        np.testing.assert_allclose(Hv, H @ v, rtol=1e-9, atol=tol)
    cols = np.stack([prob.cost_grad_hessp(theta, e)[2] for e in np.eye(K)], axis=1)
    np.testing.assert_allclose(cols, H, rtol=1e-9, atol=1e-9 * np.abs(H).max())


@pytest.mark.parametrize("name,prob,theta", CASES)
def test_gauss_newton_pieces_equal_autodiff_of_residuals(name, prob, theta):
    J, g, H_gn = prob.cost_grad_gn(theta)
    jac = jax.jacfwd(lambda th: _jax_residuals(prob, th))(theta)
    r = prob.residuals(theta)
    np.testing.assert_allclose(J, r @ r, rtol=1e-12)
    np.testing.assert_allclose(g, 2 * np.asarray(jac).T @ r, rtol=1e-9, atol=1e-9 * np.abs(g).max())
    np.testing.assert_allclose(
        H_gn, 2 * np.asarray(jac).T @ np.asarray(jac), rtol=1e-9, atol=1e-9 * np.abs(H_gn).max()
    )


def _jax_residuals(prob, theta):
    import jax.numpy as jnp

    parts = []
    w = jnp.asarray(prob.loss_weights)
    for e, (t, u, y) in enumerate(prob._arrays):
        parts.append(
            prob._sweeps._residuals(
                theta[prob._slices(e)], jnp.asarray(prob.x0[e]), jnp.asarray(prob.p0), t, u, y, w
            )
        )
    return jnp.concatenate(parts)


@pytest.mark.parametrize("name,prob,theta", CASES)
def test_output_sensitivities_equal_autodiff_of_the_simulation(name, prob, theta):
    """Problem.output_sensitivities (one sensitivity sweep) against jax.jacfwd of the
    plain simulation, and its per-sample shares of the gradient sum to ∇J."""
    import jax.numpy as jnp

    sens = prob.output_sensitivities(theta)
    for e, (t, u, _) in enumerate(prob._arrays):
        idx = prob._slices(e)
        x0, p = jnp.asarray(prob.x0[e]), jnp.asarray(prob.p0)
        sw = prob._sweeps

        def outputs(th, x0=x0, p=p, t=t, u=u, sw=sw):
            x0_, p_ = sw.expand(th, x0, p)
            return sw._simulate(x0_, p_, t, u)[1]

        ref = np.asarray(jax.jacfwd(outputs)(jnp.asarray(theta[idx])))
        np.testing.assert_allclose(
            sens[e][..., idx], ref, rtol=1e-10, atol=1e-12 * np.abs(ref).max()
        )
    if not prob.priors:
        w = prob.loss_weights[0]
        g = sum(
            np.einsum("hsk,hs->k", D, -2 * w * (np.asarray(e.y) - s.y))
            for D, e, s in zip(sens, prob.experiments, prob.simulate(theta), strict=True)
        )
        np.testing.assert_allclose(
            g, prob.cost_grad(theta)[1], rtol=1e-9, atol=1e-9 * np.abs(g).max()
        )


FD_IDS = [*IDS[:3], SMOOTH[0][0]]


@pytest.mark.parametrize("name,prob,theta", [*PROBLEMS[:3], SMOOTH[0]], ids=FD_IDS)
def test_hessian_matches_central_differences_of_gradient(name, prob, theta):
    _, _, H = prob.cost_grad_hess(theta)
    K = theta.size
    H_fd = np.zeros((K, K))
    for k in range(K):
        # fourth-order stencil: the Silverbox cost is so curved in m that the
        # truncation error of a two-point difference alone is ~1e-4
        h = 1e-6 * max(abs(theta[k]), 1e-3)
        e = np.zeros(K)
        e[k] = h
        gs = [prob.cost_grad_hess(theta + j * e)[1] for j in (-2, -1, 1, 2)]
        H_fd[:, k] = (gs[0] - 8 * gs[1] + 8 * gs[2] - gs[3]) / (12 * h)
    # compare in scaled units so that entries of very different size weigh alike
    s = np.maximum(np.abs(theta), 1e-3)
    Hs, Hs_fd = H * np.outer(s, s), H_fd * np.outer(s, s)
    np.testing.assert_allclose(Hs, Hs_fd, rtol=1e-6, atol=1e-6 * np.abs(Hs).max())


def test_simulation_matches_an_accurate_ode_solver():
    """RK4 with linear input interpolation converges to the true solution when the
    input is exactly piecewise linear; compare with a tight solve_ivp."""
    m = silverbox_model()
    t = np.arange(200) * 2**14 / 1e7
    u = 0.1 * np.sin(2 * np.pi * 30 * t)
    sim = ti.simulate(m, SILVERBOX_P, [0.01, 0.0], ti.Experiment(t, u), substeps=32)
    p = SILVERBOX_P

    def rhs(tt, x):
        uu = np.interp(tt, t, u)
        return [x[1], (uu - p["d"] * x[1] - p["a"] * x[0] - p["b"] * x[0] ** 3) / p["m"]]

    ref = solve_ivp(
        rhs,
        (t[0], t[-1]),
        [0.01, 0.0],
        t_eval=t,
        rtol=1e-11,
        atol=1e-13,
        method="DOP853",
        max_step=(t[1] - t[0]) / 4,
    )
    assert np.abs(sim.y[:, 0] - ref.y[0]).max() < 1e-8 * np.abs(ref.y[0]).max()


def test_schemes_converge_at_their_order():
    m = decay_model()
    t = np.linspace(0.0, 3.0, 31)
    data = ti.Experiment(t, np.sin(t))
    ref = ti.simulate(m, {"k": 1.3}, [1.0], data, substeps=512).x
    for scheme, order in (("euler", 1), ("heun", 2), ("rk4", 4), ("rk38", 4)):
        e1, e2 = (
            np.abs(ti.simulate(m, {"k": 1.3}, [1.0], data, substeps=n, scheme=scheme).x - ref).max()
            for n in (4, 8)
        )
        assert np.log2(e1 / e2) == pytest.approx(order, abs=0.15), scheme


def test_zoh_holds_the_input_between_samples():
    m = decay_model()
    t = np.array([0.0, 1.0, 2.0])
    u = np.array([1.0, 0.0, 0.0])
    x_zoh = ti.simulate(m, {"k": 0.0}, [0.0], ti.Experiment(t, u), interpolation="zoh").x
    x_lin = ti.simulate(m, {"k": 0.0}, [0.0], ti.Experiment(t, u)).x
    np.testing.assert_allclose(x_zoh[:, 0], [0.0, 1.0, 1.0], atol=1e-14)
    np.testing.assert_allclose(x_lin[:, 0], [0.0, 0.5, 0.5], atol=1e-14)
