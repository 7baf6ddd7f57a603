"""The per-sample loss as a plug-in: robust losses' exact derivatives on every path
(forward tensors, second-order adjoint, lock-step batches, multiple-shooting
segments) against jax.grad / jax.hessian of the plainly written loss; fits that
outliers do not pull; the sandwich error bars; and their bad input."""

from __future__ import annotations

import warnings

import jax.numpy as jnp
import numpy as np
import pytest
from conftest import SILVERBOX_P, autodiff, oscillator_model, silverbox_data, silverbox_model

import tensorid as ti
from tensorid.engine.sweeping.losses import robust_noise


def _plain(name, e, c):
    """ℓ of one output's weighted residuals e with scale c, written out plainly."""
    z = e / c
    if name == "huber":
        return jnp.sum(jnp.where(jnp.abs(e) <= c, e**2, 2 * c * jnp.abs(e) - c**2))
    if name == "cauchy":
        return jnp.sum(c**2 * jnp.log(1 + z**2))
    if name == "student-t":
        return jnp.sum(c**2 * 4.0 * jnp.log(1 + z**2 / 4.0))  # nu = 4
    raise ValueError(f"no plainly written {name!r} loss here: write it out")  # not another


def _reference(prob, name):
    """J(θ) by plain simulation and the plainly written loss, traceable."""
    sw, m = prob._sweeps, prob.model
    scale = np.array([prob.loss_scale[o] for o in m.outputs])

    def J(theta):
        total = 0.0
        for e, (t, u, _) in enumerate(prob._arrays):
            y = prob.experiments[e].y  # the measurements (the sweeps' y carries a mask)
            local = theta[prob._slices(e)]
            x0, p = sw.expand(local, jnp.asarray(prob.x0[e]), jnp.asarray(prob.p0))
            ys = sw._simulate(x0, p, t, u)[1]
            for o in range(m.S):
                sw_ = np.sqrt(prob.weights[o])
                total = total + _plain(name, sw_ * (y[:, o] - ys[:, o]), sw_ * scale[o])
        return total

    return J


def _oscillator(**kw):
    """Two outputs (one weighted), two experiments, gross outliers in both."""
    m = oscillator_model()
    ptrue = {"k": 2.0, "c": 0.3, "g": 1.0, "q": 0.7}
    exps = []
    for seed, P in ((4, 90), (5, 70)):
        t = np.arange(P) * 0.05
        u = np.stack([np.sin(1.3 * t + seed), 0.5 * np.cos(0.7 * t)], axis=1)
        y = ti.simulate(m, ptrue, [0.3, -0.2], ti.Experiment(t, u)).y
        rng = np.random.default_rng(seed)
        y = y + 0.02 * rng.standard_normal(y.shape)
        y[rng.random(P) < 0.1] += 1.0
        exps.append(ti.Experiment(t, u, y, name=f"e{seed}"))
    return ti.Problem(
        m, exps, p0=ptrue, x0=[0.3, -0.2], free_x0=["om"], fixed=["g"],
        weights={"y2": 2.5}, **kw,
    )  # fmt: skip


SLOW = pytest.mark.slow  # 10-30 s each of jax.hessian compilation


@pytest.mark.parametrize(
    "name,hessian",
    [
        ("huber", "tensors"),
        pytest.param("cauchy", "adjoint", marks=SLOW),
        pytest.param("student-t", "tensors", marks=SLOW),
        pytest.param("huber", "adjoint", marks=SLOW),
    ],
)
def test_robust_derivatives_equal_autodiff_of_the_plain_loss(name, hessian):
    prob = _oscillator(loss=name, loss_scale={"y1": 0.05, "y2": 0.08}, hessian=hessian)
    theta = prob.theta0 + np.array([0.05, -0.03, 0.2, -0.1, 0.05])
    sims = prob.simulate(theta)
    r = np.concatenate([e.y - s.y for e, s in zip(prob.experiments, sims, strict=True)])
    beyond = np.mean(np.abs(r) > np.array([0.05, 0.08]))
    assert 0.05 < beyond < 0.95  # both branches of the loss are exercised

    plain = _reference(prob, name)
    reference = autodiff(plain)
    J, g, H, G = prob.cost_grad_hess_gn(theta)
    J_ad, g_ad, H_ad = reference(theta)
    assert J == pytest.approx(J_ad, rel=1e-12)
    np.testing.assert_allclose(g, g_ad, rtol=1e-9, atol=1e-12 * abs(g).max())
    np.testing.assert_allclose(H, H_ad, rtol=1e-9, atol=1e-9 * abs(H_ad).max())
    assert prob.cost(theta) == pytest.approx(J, rel=1e-12)
    assert np.sum(prob.residuals(theta) ** 2) == pytest.approx(J, rel=1e-12)

    # Gauss-Newton: Σ Dᵀ γ D with the loss's IRLS weights γ = w ρ'(z)/z, positive
    # where Cauchy's and Student-t's curvature is not
    scale = np.array([0.05, 0.08])
    G_ref = np.zeros_like(G)
    sims = prob.simulate(theta)
    for D, e, s in zip(prob.output_sensitivities(theta), prob.experiments, sims, strict=True):
        w = prob.weights
        z = np.sqrt(w) * (e.y - s.y) / (np.sqrt(w) * scale)
        if name == "huber":
            gamma = np.where(np.abs(z) <= 1, 2.0, 2.0 / np.abs(z)) * w
        else:
            nu = 1.0 if name == "cauchy" else 4.0
            gamma = 2.0 / (1 + z**2 / nu) * w
        G_ref += np.einsum("hsk,hs,hsl->kl", D, gamma, D)
    np.testing.assert_allclose(G, G_ref, rtol=1e-9, atol=1e-12 * abs(G_ref).max())
    assert np.linalg.eigvalsh(G).min() > 0

    thetas = np.stack([theta, theta * 1.01])
    Jb, gb, Hb = prob.cost_grad_hess_batch(thetas)
    np.testing.assert_allclose(Hb[0], H, rtol=1e-10, atol=1e-12 * abs(H).max())
    np.testing.assert_allclose(Hb[1], reference(thetas[1])[2], rtol=1e-9,
                               atol=1e-9 * abs(H).max())  # fmt: skip
    v = np.linspace(-1, 1, prob.K)
    np.testing.assert_allclose(prob.cost_grad_hessp(theta, v)[2], H_ad @ v, rtol=1e-9,
                               atol=1e-9 * abs(H_ad @ v).max())  # fmt: skip


@SLOW
def test_robust_segments_equal_autodiff():
    prob = _oscillator(loss="cauchy", loss_scale=0.06, segments=[3, 2])
    sh = prob.shooting
    z = sh.start(prob.theta0) * 1.02 + 0.01
    lifted = sh.evaluate(z)

    def J(zz):
        return sh.jax_pieces(zz)[0]

    J_ad, g_ad, H_ad = autodiff(J)(z)
    assert lifted.J == pytest.approx(J_ad, rel=1e-12)
    np.testing.assert_allclose(lifted.g, g_ad, rtol=1e-9, atol=1e-12 * abs(lifted.g).max())
    np.testing.assert_allclose(lifted.H, H_ad, rtol=1e-9, atol=1e-9 * abs(H_ad).max())


def _outlier_record(fraction, seed=0, P=400):
    m = silverbox_model()
    e = silverbox_data(P=P, seed=seed, noise=1e-4)
    rng = np.random.default_rng(100 + seed)
    y = e.y.copy()
    hit = rng.random(P) < fraction
    y[hit, 0] += rng.choice([-1, 1], hit.sum()) * rng.uniform(0.02, 0.05, hit.sum())
    return m, ti.Experiment(e.t, e.u, y)


def test_huber_and_cauchy_are_not_pulled_by_outliers_where_least_squares_is():
    m, e = _outlier_record(0.05)
    start = {k: v * 1.05 for k, v in SILVERBOX_P.items()}
    est, err, se = {}, {}, {}
    for loss in ("squared", "huber", "cauchy"):
        problem = ti.Problem(m, e, p0=start, loss=loss)
        before = {k: id(v) for k, v in vars(problem).items()}
        res = ti.fit(problem)
        assert res.success, (loss, res.message)
        # a fit leaves its Problem as it was: the robust stages fit copies (issue 39)
        assert {k: id(v) for k, v in vars(problem).items()} == before
        se[loss] = res.uncertainty().stderr
        err[loss] = np.abs(res.theta - np.array(list(SILVERBOX_P.values())))
        est[loss] = err[loss] / se[loss]
        if loss != "squared":
            assert res.problem is not problem and res.problem.loss_scale_estimated
            assert "least-squares estimate" in " ".join(res.notes)
            # the scale came from the residuals of the least-squares fit, near 1e-4 noise
            tuning = {"huber": 1.345, "cauchy": 2.385}[loss]
            assert 0.5e-4 < res.problem.loss_scale["y"] / tuning < 2e-4
    assert est["huber"].max() < 2.5 and est["cauchy"].max() < 2.5
    # with a prior too: the noise level that weighs it is read robustly from the
    # residuals (not from the robust cost, nor inflated by the outliers)
    res = ti.fit(ti.Problem(m, e, p0=start, loss="huber", priors={"a": (0.9675, 0.05)}))
    assert res.success and 0.3e-8 < res.noise_check.residual < 3e-8  # σ² = 1e-8
    # least squares: the outliers inflate its own error bars, but against what the data
    # can resolve (the robust fit's standard errors) it is pulled far off
    assert (err["squared"] / se["huber"]).max() > 10


STATIC = ti.Model(
    rhs=lambda x, p, u: (p[0] * u[0] + p[1] - x) / 0.01, states=["x"], params=["a", "b"],
    inputs=["u"], output=lambda x, p: x, outputs=["y"], name="static gain and offset",
)  # fmt: skip


def test_hac_error_bars_widen_for_coloured_residuals_and_not_for_white():
    t = np.arange(400) * 0.1
    u = np.sin(0.2 * t)[:, None]
    y = ti.simulate(STATIC, {"a": 2.0, "b": 0.5}, [0.5], ti.Experiment(t, u)).y
    white = 0.01 * np.random.default_rng(7).standard_normal(t.size)
    coloured = np.zeros_like(white)
    for k in range(1, white.size):  # AR(1) with lag-one correlation 0.95: a slow drift
        coloured[k] = 0.95 * coloured[k - 1] + np.sqrt(1 - 0.95**2) * white[k]
    for noise, wider in ((white, False), (coloured, True)):
        e = ti.Experiment(t, u, y + noise[:, None])
        res = ti.fit(ti.Problem(STATIC, e, p0={"a": 1.0, "b": 0.0}, x0=[0.5]))
        plain, robust = res.uncertainty(), res.uncertainty("robust")
        ratio = robust.stderr / plain.stderr
        assert robust.kind == "robust" and plain.lags is None
        if wider:  # the textbook inflation for AR(1) noise is √((1+ρ)/(1−ρ)) ≈ 6
            assert ratio.min() > 2.5
        else:
            assert 0.7 < ratio.min() and ratio.max() < 1.4


def test_bad_loss_arguments_are_one_line_before_any_work():
    m, e = _outlier_record(0.0, P=60)
    with pytest.raises(ValueError, match="loss must be one of"):
        ti.Problem(m, e, p0=SILVERBOX_P, loss="l1")
    with pytest.raises(ValueError, match="squared loss has none"):
        ti.Problem(m, e, p0=SILVERBOX_P, loss_scale=0.1)
    with pytest.raises(ValueError, match="finite and > 0"):
        ti.Problem(m, e, p0=SILVERBOX_P, loss="huber", loss_scale=-1.0)
    with pytest.raises(ValueError, match="unknown outputs"):
        ti.Problem(m, e, p0=SILVERBOX_P, loss="huber", loss_scale={"z": 1.0})
    flat = ti.Experiment(e.t, e.u, np.zeros_like(e.y))
    with pytest.raises(ValueError, match="give loss_scale="):
        ti.Problem(m, flat, p0=SILVERBOX_P, loss="cauchy")


def test_robust_noise_ignores_outliers():
    rng = np.random.default_rng(0)
    y = 1e-3 * rng.standard_normal((2000, 1))
    y[::50] += 1.0
    assert robust_noise(y)[0] == pytest.approx(1e-3, rel=0.1)


def test_outputs_sampled_at_different_times_each_set_their_robust_scale():
    """y1 measured at the even samples, y2 at the odd ones: no row holds both, and the
    scale came from the rows that did ("0 samples are too few"; a given scale crashed
    in its check, "zero-size array"). Each output's scale (and weight) is now its own
    samples'."""
    from tensorid.engine.sweeping.losses import TUNING

    t = np.linspace(0, 10, 40)
    m = ti.Model(rhs=lambda x, p, u: -p[0] * x, output=lambda x, p: jnp.stack([x[0], 2 * x[0]]),
                 states=["a"], params=["k"], outputs=["y1", "y2"])  # fmt: skip
    noise = np.random.default_rng(0).standard_normal((40, 2)) * [0.01, 0.03]
    y = np.exp(-0.3 * t)[:, None] * [1.0, 2.0] + noise
    even = np.arange(40) % 2 == 0
    e = ti.Experiment(t, None, y, observed=np.stack([even, ~even], axis=1))
    est = ti.Problem(m, e, p0={"k": 0.2}, x0=[1.0], loss="huber")
    own = [robust_noise(y[rows, j : j + 1])[0] for j, rows in enumerate((even, ~even))]
    np.testing.assert_allclose(list(est.loss_scale.values()), TUNING["huber"] * np.array(own))
    given = ti.Problem(m, e, p0={"k": 0.2}, x0=[1.0], loss="huber", loss_scale=0.02)
    assert abs(ti.fit(given).params["k"] - 0.3) < 0.01
    # weights="auto" (1/variance of each output) from each output's own samples too: the
    # rows holding both were none, and the variances inf (weights 0)
    auto = ti.Problem(m, e, p0={"k": 0.2}, x0=[1.0], weights="auto").weights
    np.testing.assert_allclose(auto, [1 / np.var(y[even, 0]), 1 / np.var(y[~even, 1])])


def test_an_output_measured_nowhere_is_named_once_and_tested_nowhere():
    """y2 has no measurement in the record: its scale was taken as inf ("the outputs
    differ in scale by inf (... y2 ~ inf)"), and the residual tests counted 0 samples
    (not available). Now one warning names it, and y1 alone is weighed and tested."""
    t = np.linspace(0, 10, 40)
    m = ti.Model(rhs=lambda x, p, u: -p[0] * x, output=lambda x, p: jnp.stack([x[0], 2 * x[0]]),
                 states=["a"], params=["k"], outputs=["y1", "y2"])  # fmt: skip
    y = np.exp(-0.3 * t)[:, None] * [1.0, 2.0]
    y[:, 0] += np.random.default_rng(2).standard_normal(40) * 0.01
    e = ti.Experiment(t, None, y, observed=np.stack([np.ones(40, bool), np.zeros(40, bool)], 1))
    with warnings.catch_warnings(record=True) as said:
        warnings.simplefilter("always")
        est = ti.Problem(m, e, p0={"k": 0.2}, x0=[1.0])
        auto = ti.Problem(m, e, p0={"k": 0.2}, x0=[1.0], weights="auto").weights
    lines = [str(w.message) for w in said]
    assert len(lines) == 2 and all("['y2'] are measured at no sample" in s for s in lines)
    np.testing.assert_allclose(auto, [1 / np.var(y[:, 0]), 0.0])
    tests = ti.fit(est).residual_tests()
    assert tests.samples == 40 and [c.what for c in tests.whiteness] == ["whiteness of y1"]
    # a robust loss: its scale from y1 alone (it had refused: "0 samples are too few"),
    # error bars without numpy's warnings of empty means; and compare's scores count
    # y1 alone (it had exited 1: "the None-step predictions are not finite")
    from tensorid.app.filter_fits import scores_finite

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        warnings.simplefilter("error", RuntimeWarning)
        rob = ti.fit(ti.Problem(m, e, p0={"k": 0.2}, x0=[1.0], loss="huber"))
        assert np.isfinite(rob.uncertainty().stderr).all()
    assert abs(rob.params["k"] - 0.3) < 0.01
    assert scores_finite(rob.validate(e)[0])
