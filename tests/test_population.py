"""Population fits of a fleet: exact derivatives against plain JAX, the bundled
theophylline study against nlmixr2's published fit, and the checks of the input."""

from __future__ import annotations

import csv
import functools
import re
import warnings
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from conftest import autodiff

import tensorid as ti
from tensorid.population.objective import Objective
from tensorid.population.validation import empirical_bayes

THEOPH = Path(ti.__file__).parent / "datasets" / "theophylline.csv"  # bundled copy


@functools.cache  # one model object: the tests share its compiled programs
def one_compartment() -> ti.Model:
    def rhs(x, p, u):
        ka, cl, v = p
        return jnp.stack([-ka * x[0], ka * x[0] - cl / v * x[1]])

    return ti.Model(
        rhs=rhs,
        output=lambda x, p: x[1:] / p[2],
        states=["depot", "center"],
        params=["ka", "cl", "v"],
        inputs=["Dose"],
        outputs=["cp"],
    )


def simulated_fleet(n_units=4, seed=0, times=(0.5, 1, 2, 4, 8, 12, 24)):
    """Units of the one-compartment model with log-normal ka and cl, shared v."""
    rng = np.random.default_rng(seed)
    m, units = one_compartment(), []
    for i in range(n_units):
        t = np.array([0.0, *times]) + np.r_[0, rng.uniform(-0.1, 0.1, len(times))]
        p = {"ka": 1.5 * np.exp(0.5 * rng.standard_normal()), "v": 30.0}
        p["cl"] = 2.5 * np.exp(0.3 * rng.standard_normal())
        u = np.full((t.size, 1), 300.0 + 20 * i)
        sim = ti.simulate(m, p, [u[0, 0], 0.0], ti.Experiment(t, u), substeps=20)
        y = sim.y + 0.3 * rng.standard_normal(sim.y.shape)
        units.append(ti.Experiment(t, u, y, name=f"u{i}"))
    return m, units


def fleet_problem(n_units=4, **kw):
    m, units = simulated_fleet(n_units)
    kw.setdefault("population", {"ka": 0.4, "cl": 0.4})
    return ti.Problem(
        m, units, p0={"ka": 1.2, "cl": 2.0, "v": 25.0}, x0={"depot": "Dose", "center": 0.0},
        substeps=20, **kw,
    )  # fmt: skip


def _over_units(unit_O, obj: Objective, etas):
    """ψ -> Σ_i unit_O(ψ, unit i, η̂_i): the units vmapped (traced and compiled once,
    not once per unit: a third of the reference's compile time at three units), the
    sum jitted with its gradient where the tests take one (``value_and_grad``)."""

    def total(psi):
        return jnp.sum(
            jax.vmap(unit_O, in_axes=(None, 0, 0))(psi, tuple(obj.data), jnp.asarray(etas))
        )

    return total


def _plain_objective(obj: Objective, etas, newton_steps: int = 2, laplace: bool = False):
    """O(ψ) written plainly: ŷ by the engine's simulation differentiated by JAX itself
    (no sensitivity sweeps), each η̂ by Newton steps inside the function from the
    converged η̂ held constant (two steps reproduce η̂(ψ) to fourth order in the change
    of ψ, so the first and second derivatives are those of the exact inner optimum),
    and the FOCEI determinant from jax.jacfwd; jax.grad / jax.hessian of it are the
    reference."""
    sw = obj.sweeps

    def yhat(psi, eta, unit):
        t, u, _, _, x0, p = unit
        x0_, p_ = sw.expand(obj.theta(psi, eta), x0, p)
        return sw._simulate(x0_, p_, t, u)[1]

    def ell(eta, psi, unit):
        _, logw, _, logsig = obj.split(psi)
        r = (unit[2] - yhat(psi, eta, unit)) * unit[3]
        return 0.5 * (jnp.sum(r**2 * jnp.exp(-2 * logsig)) + jnp.sum((eta * jnp.exp(-logw)) ** 2))

    def unit_O(psi, unit, eta):
        for _ in range(newton_steps):
            eta = eta - jnp.linalg.solve(
                jax.hessian(ell)(eta, psi, unit), jax.grad(ell)(eta, psi, unit)
            )
        _, logw, _, logsig = obj.split(psi)
        A = jax.jacfwd(lambda e: yhat(psi, e, unit))(eta)
        Aw = A * (jnp.sqrt(unit[3]) * jnp.exp(-logsig))[..., None]
        M = jnp.einsum("psj,psk->jk", Aw, Aw) + jnp.diag(jnp.exp(-2 * logw))
        M = jax.hessian(ell)(eta, psi, unit) if laplace else M
        n = jnp.sum(unit[3], axis=0)
        return (
            2 * ell(eta, psi, unit) + jnp.sum(n * (jnp.log(2 * jnp.pi) + 2 * logsig))
            + 2 * jnp.sum(logw) + jnp.linalg.slogdet(M)[1]
        )  # fmt: skip

    return _over_units(unit_O, obj, etas)


def central_differences(obj: Objective, psi, etas, h: float = 1e-5) -> np.ndarray:
    """dO/dψ by central differences of the objective, each unit's η̂ solved again at
    every ψ ± h: the fit's own compiled programs, nothing new to compile (a plainly
    written reference through jax.grad compiles for 25-30 s; the slow tests hold it)."""
    g = np.zeros(psi.size)
    for k in range(psi.size):
        step = h * max(1.0, abs(psi[k]))
        sides = []
        for sign in (1.0, -1.0):
            moved = np.array(psi, dtype=float)
            moved[k] += sign * step
            # (a unit's Newton steps may stall at rounding's level, short of the
            # solver's 1e-11: its η̂ is then as good as the converged ones)
            eta = obj.solve_inner(moved, etas)[0]
            sides.append(obj.value_grad(moved, eta)[0].sum())
        g[k] = (sides[0] - sides[1]) / (2 * step)
    return g


def assert_central_differences(obj: Objective, psi, etas) -> None:
    """The outer gradient against central differences of the objective."""
    g = obj.value_grad(psi, etas)[1].sum(0)
    np.testing.assert_allclose(g, central_differences(obj, psi, etas), rtol=1e-6, atol=1e-6)


def assert_plain(obj: Objective, psi, etas, plain) -> None:
    """The objective and its gradient against ``plain``'s (a plainly written one,
    differentiated by JAX)."""
    O, g = obj.value_grad(psi, etas)
    value, gp = autodiff(plain, hessian=False)(psi)
    assert O.sum() == pytest.approx(value, rel=1e-12)
    np.testing.assert_allclose(g.sum(0), gp, rtol=1e-8, atol=1e-8 * np.abs(gp).max())


def _fleet_point(n_units=4, method="focei"):  # (4: the programs of the 4-unit fits)
    obj = Objective(fleet_problem(n_units), method)
    psi = np.array([np.log(1.3), np.log(2.2), np.log(0.5), np.log(0.35), 26.0, np.log(0.4)])
    etas, ok = obj.solve_inner(psi, np.zeros((n_units, 2)))
    assert ok
    return obj, psi, etas


def test_the_outer_gradient_is_that_of_central_differences():
    """The implicit-function gradient through every unit's η̂, against central
    differences of the objective (the same programs as the fit below)."""
    obj, psi, etas = _fleet_point()
    assert_central_differences(obj, psi, etas)


@pytest.mark.slow  # its plainly written reference compiles for 20-25 s
def test_the_outer_gradient_is_that_of_the_plain_objective():
    obj, psi, etas = _fleet_point()
    assert_plain(obj, psi, etas, _plain_objective(obj, etas, newton_steps=1))


@pytest.mark.slow  # the Laplace determinant needs a third order: a minute of compiling
def test_the_laplace_gradient_is_that_of_the_plain_objective():
    obj, psi, etas = _fleet_point(2, "laplace")
    assert_plain(obj, psi, etas, _plain_objective(obj, etas, newton_steps=1, laplace=True))


@pytest.mark.slow  # jax.hessian through the plain objective compiles for minutes
def test_the_outer_hessian_is_that_of_the_plain_objective():
    obj, psi, etas = _fleet_point()
    H = obj.hessian(psi, etas)
    Hp = autodiff(_plain_objective(obj, etas))(psi)[2]
    np.testing.assert_allclose(H, Hp, rtol=1e-7, atol=1e-7 * np.abs(Hp).max())


def _plain_combined(obj: Objective, etas):
    """The FOCEI objective with a combined residual error (σ² = a² + b²ŷ², a and b the
    last two entries of ψ, one output) and individual values beside the random
    effects, written plainly: ŷ by the engine's simulation differentiated by JAX, the
    inner optimum by one Newton step from the converged one held constant, σ² at η̂
    in the determinant (FOCE with interaction)."""
    sw, qp = obj.sweeps, obj.qp

    def yhat(psi, z, unit):
        t, u, _, _, x0, p = unit
        x0_, p_ = sw.expand(obj.theta(psi, z), x0, p)
        return sw._simulate(x0_, p_, t, u)[1]

    def var(psi, f):
        return jnp.exp(2 * psi[-2]) + jnp.exp(2 * psi[-1]) * f**2

    def ell(z, psi, unit):
        logw = psi[qp : 2 * qp]
        f, mask = yhat(psi, z, unit), unit[3]
        V = jnp.where(mask > 0, var(psi, f), 1.0)
        data = jnp.sum(((unit[2] - f) * mask) ** 2 / V + mask * jnp.log(V))
        return 0.5 * (data + jnp.sum((z[:qp] * jnp.exp(-logw)) ** 2))

    def unit_O(psi, unit, z):
        z = z - jnp.linalg.solve(jax.hessian(ell)(z, psi, unit), jax.grad(ell)(z, psi, unit))
        logw = psi[qp : 2 * qp]
        f = yhat(psi, z, unit)
        A = jax.jacfwd(lambda e: yhat(psi, e, unit))(z)[..., :qp]
        V = jnp.where(unit[3] > 0, var(psi, f), 1.0)
        Aw = A * jnp.sqrt(unit[3] / V)[..., None]
        M = jnp.einsum("psj,psk->jk", Aw, Aw) + jnp.diag(jnp.exp(-2 * logw))
        n = jnp.sum(unit[3])
        return (
            2 * ell(z, psi, unit) + n * jnp.log(2 * jnp.pi) + 2 * jnp.sum(logw)
            + jnp.linalg.slogdet(M)[1]
        )  # fmt: skip

    return _over_units(unit_O, obj, etas)


def _combined_point():
    """ka log-normal over the units, cl each unit's own, v shared, σ² = a² + b²ŷ²."""
    m, units = simulated_fleet(3)
    pr = ti.Problem(
        m, units, p0={"ka": 1.2, "cl": 2.0, "v": 25.0}, x0={"depot": "Dose", "center": 0.0},
        substeps=20, population={"ka": 0.4}, individual=["cl"], residual_error="combined",
    )  # fmt: skip
    obj = Objective(pr, "focei")
    assert obj.names == ["log_ka", "log_omega_ka", "v", "log_sigma_cp", "log_prop_cp"]
    psi = np.array([np.log(1.3), np.log(0.5), 26.0, np.log(0.2), np.log(0.05)])
    etas, ok = obj.solve_inner(psi, obj.start_etas())
    assert ok and np.all(etas[:, 1] > 0.5)  # cl's own values, near the truth (2.5)
    return obj, psi, etas


def test_combined_error_and_individual_values_beside_random_effects_gradient():
    """The outer gradient (implicit-function theorem through (η̂, cl̂)) against
    central differences of the objective."""
    obj, psi, etas = _combined_point()
    assert_central_differences(obj, psi, etas)


@pytest.mark.slow  # its plainly written reference compiles for 25-30 s
def test_combined_error_and_individual_values_beside_random_effects_exact_gradient():
    """The outer objective and its gradient are those of the plainly written one."""
    obj, psi, etas = _combined_point()
    assert_plain(obj, psi, etas, _plain_combined(obj, etas))


@pytest.mark.slow  # its plain reference compiles for 20-30 s; the diagonal Ω's stays fast
def test_a_full_omega_has_the_plain_objectives_gradient_and_reports_the_correlation():
    """Ω = L Lᵀ estimated whole (ka and cl correlated): the outer objective and its
    exact gradient are those of the plainly written FOCEI objective with ηᵀΩ⁻¹η and
    log det Ω from L; a fit reports the correlation with its standard error."""
    obj = Objective(fleet_problem(3, omega="full"), "focei")
    assert obj.names == ["log_ka", "log_cl", "log_omega_ka", "log_omega_cl",
                         "omega_chol_cl_ka", "v", "log_sigma_cp"]  # fmt: skip
    psi = np.array([np.log(1.3), np.log(2.2), np.log(0.5), np.log(0.35), 0.1, 26.0, np.log(0.4)])
    etas, ok = obj.solve_inner(psi, np.zeros((3, 2)))
    assert ok
    O, g = obj.value_grad(psi, etas)
    sw = obj.sweeps

    def unit_O(psi_, unit, e):
        L = jnp.array([[jnp.exp(psi_[2]), 0.0], [psi_[4], jnp.exp(psi_[3])]])
        Oinv = jnp.linalg.inv(L @ L.T)

        def yhat(e):
            x0, p = sw.expand(obj.theta(psi_, e), unit[4], unit[5])
            return sw._simulate(x0, p, unit[0], unit[1])[1]

        def ell(e):
            r = (unit[2] - yhat(e)) * unit[3]
            return 0.5 * (jnp.sum(r**2) * jnp.exp(-2 * psi_[-1]) + e @ Oinv @ e)

        e = e - jnp.linalg.solve(jax.hessian(ell)(e), jax.grad(ell)(e))
        A = jax.jacfwd(yhat)(e)[:, 0, :] * jnp.exp(-psi_[-1])
        M = A.T @ A + Oinv
        n = jnp.sum(unit[3])
        total = 2 * ell(e) + n * (jnp.log(2 * jnp.pi) + 2 * psi_[-1])
        return total + jnp.linalg.slogdet(L @ L.T)[1] + jnp.linalg.slogdet(M)[1]

    plain = _over_units(unit_O, obj, etas)

    value, gp = autodiff(plain, hessian=False)(psi)
    assert O.sum() == pytest.approx(value, rel=1e-12)
    np.testing.assert_allclose(g.sum(0), gp, rtol=1e-8, atol=1e-8 * np.abs(gp).max())
    with pytest.raises(ValueError, match="two or more"):
        fleet_problem(2, omega="full", population={"ka": 0.3})


@pytest.mark.slow  # a whole fit with a full Ω: its own programs (half a minute cold)
def test_a_full_omega_fit_reports_the_correlation_with_its_error_bar():
    res = ti.fit(fleet_problem(8, omega="full"))
    assert res.success and set(res.omega_correlation) == {"cl,ka"}
    c = res.omega_correlation["cl,ka"]
    assert -1 < c["value"] < 1 and c["stderr"] > 0 and "correlation of η_cl and η_ka" in str(res)


def _moving_x0_problem(n_units: int) -> ti.Problem:
    """x0["center"] = "v * c0" (a concentration c0 before the dose, c0 shared, v
    log-normal over the units): each unit starts from its own v."""
    base = one_compartment()
    m = ti.Model(rhs=lambda x, p, u: base.rhs(x, p[:3], u), output=lambda x, p: x[1:] / p[2],
                 states=["depot", "center"], params=["ka", "cl", "v", "c0"], inputs=["Dose"],
                 outputs=["cp"])  # fmt: skip
    rng = np.random.default_rng(3)
    units = []
    for i in range(n_units):
        t = np.array([0.0, 0.5, 1, 2, 4, 8, 12, 24])
        v = 30.0 * np.exp(0.2 * rng.standard_normal())
        u = np.full((t.size, 1), 300.0)
        sim = ti.simulate(m, {"ka": 1.5, "cl": 2.5, "v": v, "c0": 2.0}, [300.0, 2.0 * v],
                          ti.Experiment(t, u), substeps=20)  # fmt: skip
        y = sim.y + 0.1 * rng.standard_normal(sim.y.shape)
        units.append(ti.Experiment(t, u, y, name=f"u{i}"))
    return ti.Problem(m, units, p0={"ka": 1.2, "cl": 2.0, "v": 25.0, "c0": 1.0},
                      x0={"depot": "Dose", "center": "v * c0"}, substeps=20,
                      population={"v": 0.3})  # fmt: skip


@pytest.mark.slow  # its plain reference compiles for 20-30 s
def test_an_initial_state_that_moves_with_estimated_parameters():
    """The gradient through an x0 expression of estimated parameters (every state's
    sensitivity seeded, chained by JAX) is that of the plainly written objective."""
    pr = _moving_x0_problem(3)
    obj = Objective(pr, "focei")
    psi = np.array([np.log(28.0), np.log(0.3), 1.4, 2.4, 1.5, np.log(0.2)])
    etas, ok = obj.solve_inner(psi, obj.start_etas())
    assert ok
    O, g = obj.value_grad(psi, etas)
    sw = obj.sweeps

    def unit_O(psi_, unit, e):
        def yhat(e):
            p = unit[5].at[jnp.arange(4)].set(obj.theta(psi_, e))
            x0 = unit[4].at[1].set(p[2] * p[3])
            return sw._simulate(x0, p, unit[0], unit[1])[1]

        def ell(e):
            r = (unit[2] - yhat(e)) * unit[3]
            return 0.5 * (jnp.sum(r**2) * jnp.exp(-2 * psi_[-1]) + (e[0] / jnp.exp(psi_[1])) ** 2)

        e = e - jnp.linalg.solve(jax.hessian(ell)(e), jax.grad(ell)(e))
        A = jax.jacfwd(yhat)(e) * jnp.exp(-psi_[-1])
        M = jnp.einsum("psj,psk->jk", A, A) + jnp.exp(-2 * psi_[1])
        n = jnp.sum(unit[3])
        total = 2 * ell(e) + n * (jnp.log(2 * jnp.pi) + 2 * psi_[-1])
        return total + 2 * psi_[1] + jnp.linalg.slogdet(M)[1]

    plain = _over_units(unit_O, obj, etas)

    value, gp = autodiff(plain, hessian=False)(psi)
    assert O.sum() == pytest.approx(value, rel=1e-12)
    np.testing.assert_allclose(g.sum(0), gp, rtol=1e-8, atol=1e-8 * np.abs(gp).max())


@pytest.mark.slow  # a whole fit of its own model: a minute cold
def test_a_fit_finds_the_c0_an_initial_state_expression_was_made_with():
    res = ti.fit(_moving_x0_problem(6))
    assert res.success
    c0 = res.shared["c0"]
    assert abs(c0["value"] - 2.0) < 3 * c0["stderr"] and c0["stderr"] < 0.2


def test_a_proportional_error_at_a_zero_prediction_is_one_line():
    """Every unit starts with nothing in the center (ŷ = 0 at t = 0): a proportional
    error alone has no variance there, and the fit says so before it iterates."""
    with pytest.raises(ValueError, match="prediction at t = 0 is 0.*use 'combined'"):
        ti.fit(fleet_problem(2, residual_error="proportional"))


def test_the_inner_hessian_is_the_exact_one():
    """The unit's ∇²ℓ from the tensors (the tower in units.py) equals jax.hessian of ℓ
    with ŷ differentiated by JAX through the simulation."""
    pr = fleet_problem(2)
    obj = Objective(pr, "laplace")
    psi = jnp.array([np.log(1.3), np.log(2.2), np.log(0.5), np.log(0.35), 26.0, np.log(0.4)])
    unit = tuple(a[1] for a in obj.data)
    eta = jnp.array([0.2, -0.1])
    sw = obj.sweeps

    def ell_plain(e):
        t, u, y, mask, x0, p = unit
        x0_, p_ = sw.expand(obj.theta(psi, e), x0, p)
        r = (y - sw._simulate(x0_, p_, t, u)[1]) * mask
        return 0.5 * (jnp.sum(r**2 / 0.4**2) + jnp.sum((e / jnp.exp(psi[2:4])) ** 2))

    H = jax.jit(jax.hessian(obj.ell))(eta, psi, unit)
    np.testing.assert_allclose(H, autodiff(ell_plain)(eta)[2], rtol=1e-10)


def test_a_simulated_fleet_is_fitted_and_reported():
    pr = fleet_problem(4)  # (4 units: the programs of the other 4-unit fits)
    res = ti.fit(pr)
    assert isinstance(res, ti.PopulationResult) and res.success
    assert np.isfinite(res.objective) and np.linalg.norm(res.jac) < 1e-5
    assert set(res.population) == {"ka", "cl"} and set(res.shared) == {"v"}
    for v in res.population.values():
        assert v["typical_stderr"] > 0 and v["omega"] > 0 and np.isfinite(v["cv_percent"])
    assert len(res.units) == 4 and res.units[0]["id"] == "u0"
    assert set(res.units[0]["params"]) == {"ka", "cl", "v"}
    text = str(res)
    assert "typical" in text and "residual SD of cp" in text
    # what a single fit's result offers (issue 49 item 4), without the units' arrays
    assert repr(res).startswith("PopulationResult(method='focei'") and len(repr(res)) < 300
    assert res._repr_html_().startswith("<pre>Population fit (FOCEI)")
    crit = res.criteria()
    assert crit["k"] == len(res.names) == 6 and crit["aic"] == res.objective + 12
    assert np.allclose(np.diag(res.correlation), 1.0) and res.correlation.shape == (6, 6)
    fits = res.gof()
    assert len(fits) == 4 and all(0.8 < f <= 1 for f in fits)


def test_a_fleets_profiles_held_out_units_and_unit_influence():
    """Issue 49 item 2 on the 4-unit fleet (its programs already compiled here): the
    profile of a typical value starts at the fit's −2 log L and its interval is near
    the Wald one; the fleet's own units as held-out units get the fit's η̂ and GOF
    back; every unit gets a finite Cook's distance and shift."""
    res = ti.fit(fleet_problem(4))
    prof = ti.profile(res, ["ka", "omega_cl", "v"])
    assert set(prof) == {"ka", "omega_cl", "v"}
    for name, log in (("ka", True), ("omega_cl", True), ("v", False)):
        p = prof[name]
        i = res.names.index(f"log_{name}" if log else name)
        se = np.sqrt(res.cov[i, i])
        wald = np.exp(res.x[i] + np.array([-1, 1]) * 1.96 * se) if log else (
            res.x[i] + np.array([-1, 1]) * 1.96 * se)  # fmt: skip
        assert p.ends == {"lower": "crossed", "upper": "crossed"}
        assert p.costs.min() == pytest.approx(res.objective, abs=1e-6)
        width = wald[1] - wald[0]
        assert abs(p.interval[0] - wald[0]) < 0.35 * width, (name, p.interval, wald)
        assert abs(p.interval[1] - wald[1]) < 0.35 * width, (name, p.interval, wald)
    again = res.validate(res.problem)
    assert [a["id"] for a in again] == [u["id"] for u in res.units]
    for a, u, g in zip(again, res.units, res.gof(), strict=True):
        assert a["gof"] == pytest.approx(g, abs=1e-6)
        assert a["eta"] == pytest.approx(u["eta"], abs=1e-5)
        assert a["gof_pred"] < a["gof"]  # the typical unit predicts worse than its own
    # one new unit alone (compare --ipred's Problem): a fit refuses it, η̂ does not
    m, units = simulated_fleet(4)
    one = ti.Problem(m, units[2:3], p0=res.params, x0={"depot": "Dose", "center": 0.0},
                     substeps=20, population={"ka": 0.4, "cl": 0.4})  # fmt: skip
    [alone] = empirical_bayes(one, dict(zip(res.names, res.x, strict=True)))
    assert alone["id"] == "u2" and alone["eta"] == pytest.approx(res.units[2]["eta"], abs=1e-6)
    assert res.validate(one)[0]["gof"] == pytest.approx(res.gof()[2], abs=1e-6)
    with pytest.raises(ValueError, match="unknowns .* are not those of this model"):
        empirical_bayes(one, {"log_ka": 0.0})
    moved = res.unit_influence(refits=0)
    assert sorted(d["id"] for d in moved) == ["u0", "u1", "u2", "u3"]
    assert all(np.isfinite(d["cook"]) and d["cook"] >= 0 for d in moved)
    assert [d["cook"] for d in moved] == sorted((d["cook"] for d in moved), reverse=True)


def test_a_fleet_fitted_from_several_starts_keeps_the_best():
    """Issue 49 item 2: starts of the typical values, shared parameters and ω (they
    were refused); each start's ending kept, best first, the best one's fit returned."""
    from tensorid.population.objective import Objective
    from tensorid.population.start import drawn_starts

    pr = fleet_problem(4)
    psis = drawn_starts(Objective(pr), 3, spread=0.5, seed=1)
    assert len(psis) == 3 and np.all(np.ptp(np.array(psis)[:, :5], axis=0) > 0)
    # a wide spread draws the typical values log-uniformly (linearly, some were < 0)
    assert np.isfinite(drawn_starts(Objective(pr), 8, spread=1.5, seed=0)).all()
    one = ti.fit(pr)
    res = ti.fit(pr, starts=3, spread=0.5, seed=1)
    assert [s["start"] for s in res.starts] != [] and len(res.starts) == 3
    J = [s["objective"] for s in res.starts]
    assert J == sorted(J) and res.objective == pytest.approx(J[0], abs=1e-9)
    assert res.objective <= one.objective + 1e-6
    assert "best of 3 starts" in res.summary()


def test_a_fleets_fit_json_survives_what_its_analyses_cannot_measure(tmp_path, capsys):
    """Review of issue 49's analyses: a held-out unit of one observation has no GOF
    (NaN), which made fit.json unwritable and lost every file; a fit that did not
    converge gets a note, not profiles from a point that is no optimum."""
    import json
    from types import SimpleNamespace

    from tensorid.app.population_run import report_population

    pr = fleet_problem(4)
    res = ti.fit(pr)
    m, units = simulated_fleet(6, seed=3)
    one = units[4]
    seen = np.zeros_like(one.y, dtype=bool)
    seen[3] = True  # one observation
    held_units = [units[5], ti.Experiment(one.t, one.u, one.y, name="one", observed=seen)]
    held = ti.Problem(m, held_units, p0={"ka": 1.2, "cl": 2.0, "v": 25.0},
                      x0={"depot": "Dose", "center": 0.0}, substeps=20,
                      population={"ka": 0.4, "cl": 0.4})  # fmt: skip
    args = SimpleNamespace(profile=None, profile_level=0.95, data_sensitivity=False)
    (tmp_path / "a").mkdir()
    (tmp_path / "b").mkdir()
    assert report_population(res, tmp_path / "a", set(), {}, args, held) == 0
    fit = json.loads((tmp_path / "a" / "fit.json").read_text())
    assert [h["id"] for h in fit["held_out"]] == ["u5", "one"]
    assert fit["held_out"][1]["gof"] is None and fit["held_out"][1]["observations"] == 1
    bad = ti.fit(pr, maxiter=1)
    args = SimpleNamespace(profile=[], profile_level=0.95, data_sensitivity=True)
    assert report_population(bad, tmp_path / "b", set(), {}, args, None) == 1
    fit = json.loads((tmp_path / "b" / "fit.json").read_text())
    assert "ci95_profile" not in fit and "unit_influence" not in fit
    assert any(n.startswith("no profiles, held-out units or unit influence") for n in fit["notes"])
    capsys.readouterr()


def theophylline_problem(**kw):
    rows = list(csv.DictReader(THEOPH.open()))
    ids = list(dict.fromkeys(r["ID"] for r in rows))
    exps = []
    for i in ids:
        rr = [r for r in rows if r["ID"] == i]
        t = np.array([float(r["Time"]) for r in rr])
        u = np.array([[float(r["Dose"]) * float(r["Wt"])] for r in rr])
        exps.append(ti.Experiment(t, u, [float(r["conc"]) for r in rr], name=i))
    return ti.Problem(
        one_compartment(), exps, p0={"ka": 1.57, "cl": 2.72, "v": 31.5},
        x0={"depot": "Dose", "center": 0.0}, substeps=40,
        population={"ka": 0.6**0.5, "cl": 0.3**0.5, "v": 0.1**0.5}, **kw,
    )  # fmt: skip


@pytest.mark.slow
def test_theophylline_matches_nlmixr2s_published_fit():
    """nlmixr2's FOCEi fit of the same model and data (its model-piping vignette):
    OBJF 116.804; tka 0.4663 (SE 0.1911), tcl 1.012 (0.08366), tv 3.460 (0.04654);
    BSV 70.00/26.80/13.88 %; shrinkage 1.421/3.968/10.28 %; add.sd 0.6947."""
    res = ti.fit(theophylline_problem())
    assert res.success
    assert res.objective_nlmixr == pytest.approx(116.804, abs=0.01)
    pop = res.population
    for n, (typ, se) in {
        "ka": (0.4663, 0.1911),
        "cl": (1.012, 0.08366),
        "v": (3.460, 0.04654),
    }.items():
        assert np.log(pop[n]["typical"]) == pytest.approx(typ, abs=0.01)
        assert pop[n]["typical_stderr"] / pop[n]["typical"] == pytest.approx(se, rel=0.03)
    for n, cv in {"ka": 70.00, "cl": 26.80, "v": 13.88}.items():
        assert pop[n]["cv_percent"] == pytest.approx(cv, abs=0.6)
    for n, sh in {"ka": 1.421, "cl": 3.968, "v": 10.28}.items():
        assert pop[n]["shrinkage_percent"] == pytest.approx(sh, abs=0.5)
    assert res.residual_sd["cp"] == pytest.approx(0.6947, abs=0.002)


@pytest.mark.parametrize(
    "population, words",
    [
        ({"kk": 0.3}, "not a parameter of the model"),
        ({"ka": 0.0}, "must be a finite number > 0"),
        ({"ka": float("nan")}, "must be a finite number > 0"),
        ({"ka": True}, "must be a finite number > 0"),
        ([("ka", 0.3)], "must be a dict"),
    ],
)
def test_bad_population_is_one_clear_line(population, words):
    m, units = simulated_fleet(2)
    with pytest.raises((ValueError, TypeError), match=words):
        ti.Problem(m, units, p0={"ka": 1, "cl": 2, "v": 30}, population=population)


def test_population_with_a_fixed_parameter_or_a_filter_is_refused():
    m, units = simulated_fleet(2)
    p0 = {"ka": 1, "cl": 2, "v": 30}
    with pytest.raises(ValueError, match="both fixed and in population"):
        ti.Problem(m, units, p0=p0, fixed=["ka"], population={"ka": 0.3})
    with pytest.raises(ValueError, match="leave predictor, segments and loss"):
        ti.Problem(m, units, p0=p0, loss="huber", population={"ka": 0.3})


def test_x0_expressions_are_evaluated_per_record():
    m, units = simulated_fleet(3)
    pr = ti.Problem(
        m, units, p0={"ka": 1, "cl": 2, "v": 30}, x0={"depot": "2 * Dose", "center": 1.5}
    )
    np.testing.assert_allclose(pr.x0[:, 0], [2 * e.u[0, 0] for e in units])
    np.testing.assert_allclose(pr.x0[:, 1], 1.5)
    with pytest.raises(ValueError, match="names \\['Wt'\\], which are neither inputs"):
        ti.Problem(m, units, p0={"ka": 1, "cl": 2, "v": 30}, x0={"depot": "Dose * Wt"})
    with pytest.raises(ValueError, match="an x0 expression names \\['v'\\], which are estimated"):
        ti.Problem(m, units, p0={"ka": 1, "cl": 2, "v": 30}, x0={"depot": "Dose / v"})
    # in a fleet's fit it may move with them (test_an_initial_state_that_moves...)
    ti.Problem(m, units, p0={"ka": 1, "cl": 2, "v": 30}, x0={"depot": "Dose / v"},
               population={"v": 0.2})  # fmt: skip
    fixed = ti.Problem(
        m, units, p0={"ka": 1, "cl": 2, "v": 30}, x0={"depot": "Dose / v"}, fixed=["v"]
    )
    np.testing.assert_allclose(fixed.x0[:, 0], [e.u[0, 0] / 30 for e in units])


@pytest.mark.slow  # its own programs (30 s cold); the gradient with individual values is fast
def test_individual_parameters_are_the_joint_least_squares_fit():
    """Each unit its own cl, ka and v shared: the reduced fit's estimates are the joint
    least-squares optimum, and its error bars those of the joint problem's dense
    Hessian (jax.hessian of the plainly written cost over every unknown)."""
    m, units = simulated_fleet(3)
    pr = ti.Problem(
        m, units, p0={"ka": 1.2, "cl": 2.0, "v": 25.0}, x0={"depot": "Dose", "center": 0.0},
        substeps=20, individual=["cl"],
    )  # fmt: skip
    res = ti.fit(pr)
    assert res.success and res.method == "joint" and res.population == {}
    obj = res.objective_function
    sw = obj.sweeps

    def joint_cost(z):  # z = (cl of each unit, ka, v)
        J = 0.0
        for i in range(3):
            t, u, y, mask, x0, p = (a[i] for a in obj.data)
            x0_, p_ = sw.expand(jnp.stack([z[3], z[i], z[4]]), x0, p)
            J = J + jnp.sum(((y - sw._simulate(x0_, p_, t, u)[1]) * mask) ** 2)
        return J

    z = jnp.asarray(
        [u["params"]["cl"] for u in res.units]
        + [res.shared["ka"]["value"], res.shared["v"]["value"]]
    )
    J, g, H = autodiff(joint_cost)(z)
    assert J == pytest.approx(res.objective, rel=1e-12)
    assert np.abs(g).max() < 1e-6 * np.abs(np.diag(H)).max() ** 0.5
    N = sum(e.P for e in units)
    cov = 2 * J / (N - 5) * np.linalg.inv(H)
    se = np.sqrt(np.diag(cov))
    np.testing.assert_allclose([u["stderr"]["cl"] for u in res.units], se[:3], rtol=1e-6)
    np.testing.assert_allclose([res.shared[n]["stderr"] for n in ("ka", "v")], se[3:], rtol=1e-6)


def test_bad_individual_is_one_clear_line():
    m, units = simulated_fleet(2)
    p0 = {"ka": 1, "cl": 2, "v": 30}
    with pytest.raises(ValueError, match="not a parameter of the model"):
        ti.Problem(m, units, p0=p0, individual=["kl"])
    with pytest.raises(ValueError, match="both individual .* and in population"):
        ti.Problem(m, units, p0=p0, individual=["ka"], population={"ka": 0.3})
    with pytest.raises(ValueError, match="must be one of"):
        ti.Problem(m, units, p0=p0, population={"ka": 0.3}, residual_error="relative")
    with pytest.raises(ValueError, match="not an output of the model"):
        ti.Problem(m, units, p0=p0, population={"ka": 0.3}, residual_error={"cq": "combined"})
    with pytest.raises(ValueError, match="estimated by a population fit"):
        ti.Problem(m, units, p0=p0, individual=["cl"], residual_error="proportional")
    with pytest.raises(TypeError, match="list of parameter names"):
        ti.Problem(m, units, p0=p0, individual="cl")
    with pytest.raises(ValueError, match="free_x0 is not supported"):
        ti.Problem(m, units, p0=p0, individual=["cl"], free_x0=["center"])


class _LostWorkers:
    """An executor whose every worker is lost: each future fails."""

    def __init__(self):
        self.submitted = 0

    def submit(self, fn, *args):
        from concurrent.futures import Future

        self.submitted += 1
        f: Future = Future()
        f.set_exception(ConnectionError("worker lost"))
        return f


@pytest.mark.slow  # the chunks' own programs (20 s cold); the gradients and a fit stay fast
def test_lost_workers_cost_time_not_the_fit():
    pr = fleet_problem(4)  # (4 units: the programs of the other 4-unit fits)
    here = ti.fit(pr)
    lost = _LostWorkers()
    with warnings.catch_warnings(record=True) as said:
        warnings.simplefilter("always")
        there = ti.fit(pr, executor=lost)
    said = [str(w.message) for w in said]
    assert any(s.endswith("sent again") for s in said), said
    assert any(s.endswith("computed here, as every chunk is from now on") for s in said), said
    # the first evaluation's two chunks, the first lost one sent again once; then every
    # chunk here for good (issue 51 item 2: it had re-sent every chunk each evaluation)
    assert lost.submitted == 3
    assert there.success and there.objective == pytest.approx(here.objective, rel=1e-12)
    # the units in other chunks are other programs, whose rounding the optimum's flat
    # directions magnify (1.4e-9 on an AVX-512 machine, below 1e-9 on another)
    np.testing.assert_allclose(there.x, here.x, rtol=1e-8, atol=1e-12)


@pytest.mark.slow  # two spawned workers compile their own programs
def test_units_on_a_local_pool_give_the_fit_made_here():
    pr = fleet_problem(6)
    here = ti.fit(pr)
    pooled = ti.fit(pr, workers=2)
    assert pooled.success and pooled.objective == pytest.approx(here.objective, rel=1e-12)
    np.testing.assert_allclose(pooled.x, here.x, rtol=1e-9, atol=1e-12)


def test_batches_of_starts_with_a_fleet_fit_are_refused_before_any_work(tmp_path, capsys):
    """(--starts itself is a fleet's now: test_a_fleet_fitted_from_several_starts...)"""
    from tensorid import cli
    from tensorid.datasets import theophylline_csv

    example = Path(__file__).resolve().parents[1] / "examples" / "theophylline" / "model.py"
    argv = ["fit", str(example), str(theophylline_csv()), "--records", "ID", "--columns",
            "t=Time,cp=conc", "--starts", "3", "--batch", "2",
            "--out", str(tmp_path / "o")]  # fmt: skip
    assert cli.main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("tensorid: error: --batch: a fleet's starts run one after another")
    assert len(err.splitlines()) == 1 and not (tmp_path / "o").exists()


def test_a_fit_that_did_not_converge_gives_no_error_bars_and_a_whole_fit_json():
    import json

    from tensorid.app.population_run import population_json

    res = ti.fit(fleet_problem(4), maxiter=1)
    assert not res.success
    assert all(np.isnan(v["typical_stderr"]) for v in res.population.values())
    data = json.loads(json.dumps(population_json(res, {}), allow_nan=False))
    assert data["population"]["ka"]["typical_stderr"] is None
    assert data["population"]["ka"]["typical"] == pytest.approx(res.population["ka"]["typical"])


def test_ctrl_c_keeps_the_best_point_so_far(tmp_path):
    import json

    from tensorid.app.population_run import save_interrupted

    def stop(entry):
        if entry["iteration"] >= 2:
            raise KeyboardInterrupt

    with pytest.raises(ti.FitInterrupted) as stopped:
        ti.fit(fleet_problem(4), callback=stop)
    res = stopped.value.result
    assert isinstance(res, ti.PopulationResult) and res.status is ti.Status.INTERRUPTED
    assert np.isfinite(res.objective) and len(res.units) == 4
    assert all(np.isnan(v["typical_stderr"]) for v in res.population.values())
    assert save_interrupted(res, tmp_path, set(), {}) == 130
    data = json.loads((tmp_path / "fit.json").read_text())
    assert data["status"] == "interrupted" and data["population"]["ka"]["typical"] > 0


def test_a_fleets_files_go_through_the_one_writer(tmp_path, monkeypatch, capsys):
    """Issue 49 item 1, one writer (app/keeping.write_folder) for a single fit's folder
    and a fleet's: a Ctrl-C while a fleet's figures were drawn ended in a traceback
    (fit.json was kept, the command said nothing); a folder where nothing can be
    written raised, where a single fit's JSON goes to the console; a figure that
    cannot be drawn is one line, the other files written."""
    import json
    from types import SimpleNamespace

    from tensorid.app import keeping, population_run
    from tensorid.app.population_run import report_population, save_interrupted

    res = ti.fit(fleet_problem(4))
    args = SimpleNamespace(profile=None, profile_level=0.95, data_sensitivity=False)
    real = population_run._figures

    def one_fails(res, out, profiles, renderer, failures):
        makers = real(res, out, profiles, renderer, failures)
        return [(stem, (lambda: 1 / 0) if stem == "vpc" else make) for stem, make in makers]

    monkeypatch.setattr(population_run, "_figures", one_fails)
    out = tmp_path / "a"
    out.mkdir()
    assert report_population(res, out, set(), {}, args) == 1
    printed = capsys.readouterr().out
    assert "could not draw vpc.png: division by zero" in printed
    assert {p.name for p in out.iterdir()} >= {"fit.json", "report.md", "units.png",
                                               "observations.csv", "residuals.png"}  # fmt: skip

    def pressed(*a, **k):
        raise KeyboardInterrupt

    monkeypatch.setattr(population_run, "_figures", pressed)  # (after fit.json is written)
    kept: dict = {}
    (tmp_path / "b").mkdir()
    (tmp_path / "c").mkdir()
    with pytest.raises(KeyboardInterrupt):
        report_population(res, tmp_path / "b", set(), {}, args, kept=kept)
    assert kept["fit.json"] == tmp_path / "b" / "fit.json"  # the complete one, first
    assert save_interrupted(res, tmp_path / "b", set(), {}, kept, after=True) == 130
    data = json.loads((tmp_path / "b" / "fit.json").read_text())
    assert data["population"]["ka"]["typical"] == pytest.approx(res.population["ka"]["typical"])
    assert "fit.json was written" in capsys.readouterr().err
    assert save_interrupted(res, tmp_path / "b", set(), {}, {}, after=True) == 130  # none yet
    assert "the estimates are in" in capsys.readouterr().err

    def nowhere(path, text):
        raise OSError("no room anywhere")

    monkeypatch.setattr(keeping, "write_kept", nowhere)
    monkeypatch.setattr(population_run, "_figures", real)
    assert report_population(res, tmp_path / "c", set(), {}, args) == 1
    shown = capsys.readouterr().out
    start = shown.index("{")
    printed_json = json.loads(shown[start : shown.index("\n}\n", start) + 3])
    assert printed_json["objective"] == pytest.approx(res.objective)  # on the console
    assert "fit.json is printed above" in shown


def test_methods_of_a_fleet_and_of_one_system_are_told_apart():
    m, units = simulated_fleet(2)
    p0 = {"ka": 1, "cl": 2, "v": 30}
    one = ti.Problem(m, units[:1], p0=p0, x0={"depot": "Dose", "center": 0.0})
    with pytest.raises(ValueError, match="method 'focei' is a population fit's"):
        ti.fit(one, "focei")
    fleet = ti.Problem(m, units, p0=p0, x0={"depot": "Dose", "center": 0.0},
                       population={"ka": 0.3})  # fmt: skip
    with pytest.raises(ValueError, match="'newton' is not one for a fit with population"):
        ti.fit(fleet, "newton")
    own = ti.Problem(m, units, p0=p0, x0={"depot": "Dose", "center": 0.0}, individual=["cl"])
    with pytest.raises(ValueError, match="'laplace' is not one for a fit with individual"):
        ti.fit(own, "laplace")


@pytest.mark.slow  # three population fits, two of them twice: about 45 s
def test_a_population_fit_raises_the_default_substeps_where_they_are_too_coarse():
    """Samples 11-12 h apart against an absorption half-life of half an hour: at the
    default 4 substeps the estimates are the scheme's. The fit raises them by itself,
    fits again from its estimates and ends where a fit with those substeps given ends;
    substeps the user gives are kept, with the warning."""
    m, units = simulated_fleet(6, times=(1, 12, 24, 36))
    kw = dict(p0={"ka": 1.2, "cl": 2.0, "v": 25.0}, x0={"depot": "Dose", "center": 0.0},
              population={"ka": 0.4, "cl": 0.4})  # fmt: skip
    with pytest.warns(UserWarning, match="substeps were raised from 4 to 16"):
        res = ti.fit(ti.Problem(m, units, **kw))
    assert res.problem.substeps in (16, 64) and res.success
    given = ti.fit(ti.Problem(m, units, substeps=res.problem.substeps, **kw))
    assert res.objective == pytest.approx(given.objective, rel=1e-7)
    np.testing.assert_allclose(res.x, given.x, rtol=1e-4, atol=1e-6)
    with pytest.warns(UserWarning, match="raise the substeps"):
        kept = ti.fit(ti.Problem(m, units, substeps=4, **kw))
    assert kept.problem.substeps == 4 and abs(kept.objective - res.objective) > 0.1


def test_a_refit_at_finer_substeps_that_cannot_start_keeps_the_fit_it_refines(monkeypatch):
    """A fit at the default substeps that the check refits at four times as many, where
    one unit's inner problem fails from its estimates there (theophylline with ka each
    subject's own: a plateau), returned the refit's start, −2 log L = inf and every SE
    NaN: the fit it refines is kept, with why, and the refit's drops are not said."""
    from dataclasses import replace

    from tensorid.population import estimate
    from tensorid.solve.solution import FitInterrupted

    pr = fleet_problem()
    done = ti.fit(pr)
    pr.discretisation = replace(pr.discretisation, chosen=False)  # the default, say
    dropping = estimate._dropping

    def failing(obj, fit, collapsed, start=None):
        if obj.problem.discretisation.substeps == 20:  # the fit itself
            return dropping(obj, fit, collapsed, start)
        obj.unconverged, obj.unfinite = ["3"], []
        collapsed.append((["ka"], 1.0))
        return obj, replace(done, objective=np.inf), start[1]

    monkeypatch.setattr(estimate, "_dropping", failing)
    monkeypatch.setattr(estimate, "coarse_steps", lambda obj, res, etas: 0.5)
    with warnings.catch_warnings(record=True) as seen:  # (and the coarse substeps')
        warnings.simplefilter("always")
        res = ti.fit(pr)
    said = " | ".join(str(w.message) for w in seen)
    assert re.search(r"repeated at 80 substeps .*unit\(s\) \['3'\]", said), said
    assert res.problem.substeps == 20 and res.objective == pytest.approx(done.objective)
    np.testing.assert_allclose(res.x, done.x, rtol=1e-9)
    assert not any("collapsed" in n or "dropped" in n for n in res.notes), res.notes
    assert any("raise the substeps" in n for n in res.notes)

    def interrupted(obj, fit, collapsed, start=None):  # Ctrl-C while the refit compiles
        if obj.problem.discretisation.substeps == 20:
            return dropping(obj, fit, collapsed, start)
        collapsed.append((["ka"], 1.0))
        raise KeyboardInterrupt

    monkeypatch.setattr(estimate, "_dropping", interrupted)
    with pytest.raises(FitInterrupted) as caught:
        ti.fit(pr)
    kept = caught.value.result
    np.testing.assert_allclose(kept.x, done.x, rtol=1e-9)
    assert np.isfinite(kept.population["ka"]["omega_stderr"])
    assert "refit at 80 substeps" in kept.notes[-1]
    assert not any("collapsed" in n for n in kept.notes)


@pytest.mark.parametrize("where", ["inner re-solve", "substeps check"])
def test_ctrl_c_after_the_outer_fit_converged_keeps_the_converged_point(monkeypatch, where):
    """issue 51, item 1: Ctrl-C after the outer optimiser converged (the inner re-solve,
    the error bars, the substeps check) lost the fit: now FitInterrupted holds it."""
    from tensorid.population import estimate
    from tensorid.solve.solution import FitInterrupted

    pr = fleet_problem()
    done = ti.fit(pr)

    def stop(*args, **kw):
        raise KeyboardInterrupt

    if where == "inner re-solve":  # once the outer loop has returned
        outer = estimate._outer

        def converged(*args, **kw):
            out = outer(*args, **kw)
            monkeypatch.setattr(Objective, "solve_inner", stop)
            return out

        monkeypatch.setattr(estimate, "_outer", converged)
    else:
        monkeypatch.setattr(estimate, "coarse_steps", stop)
    with pytest.raises(FitInterrupted) as caught:
        ti.fit(pr)
    kept = caught.value.result
    np.testing.assert_allclose(kept.x, done.x, rtol=1e-9)
    assert kept.objective == pytest.approx(done.objective, rel=1e-12)
    if where == "substeps check":  # the fit itself had finished: its error bars kept
        assert np.isfinite(kept.population["ka"]["omega_stderr"]) and "interrupted" in kept.notes[0]


@pytest.mark.slow  # a population fit of its own model: about 27 s
def test_a_parameter_with_no_effect_is_named_and_held_not_a_collapsed_fit():
    """issue 51, item 4: a parameter that cancels in the output (q/q) ended the fit as
    "the trust region collapsed ... the cost may be noisy", every SE NaN and q's
    shrinkage 100 %: now q is named, held where it started, and the rest converge with
    their error bars."""
    _, units = simulated_fleet(4)
    m = ti.model_from_equations(
        rhs={"depot": "-ka*depot", "center": "ka*depot - cl/v*center"},
        output={"cp": "center/v*q/q"}, inputs=["Dose"], params=["ka", "cl", "v", "q"],
    )  # fmt: skip
    pr = ti.Problem(m, units, p0={"ka": 1.2, "cl": 2.0, "v": 25.0, "q": 1.3},
                    x0={"depot": "Dose", "center": 0.0}, substeps=20,
                    population={"ka": 0.4, "cl": 0.4, "q": 0.3})  # fmt: skip
    with pytest.warns(UserWarning, match="q has no effect on the outputs"):
        res = ti.fit(pr)
    assert res.success, res.message
    assert res.population["q"]["typical"] == pytest.approx(1.3)
    assert np.isnan(res.population["q"]["typical_stderr"])
    assert all(np.isfinite(res.population[n]["typical_stderr"]) for n in ("ka", "cl"))
    assert np.isfinite(res.shared["v"]["stderr"])


@pytest.mark.slow  # two population fits of two structures: about 35 s
def test_a_random_effect_collapsing_to_0_is_dropped_and_the_fit_repeated():
    """issue 49, item 4: an ω collapsing to 0 crept along log ω → −∞ for tens of slow
    iterations and ended with an SE beside ω = 0.0000; now it is detected below 0.001
    with the objective still falling, the parameter made shared with a note that names
    it, and the fit ends where a fit without that random effect ends."""
    rng = np.random.default_rng(2)
    m, units = one_compartment(), []
    for i in range(8):  # ka the same in every unit: nothing for its ω to describe
        t = np.array([0.0, 0.5, 1, 2, 4, 8, 12, 24]) + np.r_[0, rng.uniform(-0.1, 0.1, 7)]
        p = {"ka": 1.5, "v": 30.0, "cl": 2.5 * np.exp(0.3 * rng.standard_normal())}
        u = np.full((t.size, 1), 300.0 + 20 * i)
        sim = ti.simulate(m, p, [u[0, 0], 0.0], ti.Experiment(t, u), substeps=20)
        y = sim.y + 0.3 * rng.standard_normal(sim.y.shape)
        units.append(ti.Experiment(t, u, y, name=f"u{i}"))
    kw = dict(p0={"ka": 1.2, "cl": 2.0, "v": 25.0}, x0={"depot": "Dose", "center": 0.0},
              substeps=20)  # fmt: skip
    with pytest.warns(UserWarning, match="the random effect of ka collapsed to 0"):
        res = ti.fit(ti.Problem(m, units, population={"ka": 0.4, "cl": 0.4}, **kw))
    assert res.success and "ka" in res.shared and list(res.population) == ["cl"]
    ref = ti.fit(ti.Problem(m, units, population={"cl": 0.4}, **kw))
    assert res.objective == pytest.approx(ref.objective, rel=1e-7)
    np.testing.assert_allclose(res.params["ka"], ref.params["ka"], rtol=1e-4)
    assert np.isfinite(res.shared["ka"]["stderr"])


# FitResult's names that are a single fit's machinery, not what a user reads
_MACHINERY = {"at", "of", "attached", "detached", "history_then", "followed_by", "blocks",
              "cached_model_check"}  # fmt: skip


def test_a_population_result_answers_every_name_a_fit_result_has():
    """Issue 49 item 1: a fleet's result is a FitResult with the population's part, and
    every public name of FitResult (fields, properties, methods) has its population
    meaning there, or says in one line what to use instead; error bars of ψ by the
    exact Hessian (2 H⁻¹, as ``cov``) and by the sandwich over the units (NONMEM's
    R⁻¹SR⁻¹), which equals H⁻¹ Σ g_i g_iᵀ H⁻¹ from the units' own gradients."""
    import dataclasses
    import inspect

    res = ti.fit(fleet_problem(4))
    names = {n for n in dir(ti.FitResult) if not n.startswith("_")}
    names |= {f.name for f in dataclasses.fields(ti.FitResult) if not f.name.startswith("_")}
    refused, values = {}, {}
    given = {"validate": (res.problem,), "profile": (["ka"],)}  # (what they need)
    for name in sorted(names - _MACHINERY):
        try:
            value = getattr(res, name)
            if callable(value) and not inspect.isclass(value):
                value = value(*given.get(name, ()))
        except (ValueError, AttributeError) as e:
            refused[name] = str(e)
            continue
        assert value is None or not isinstance(value, float) or np.isfinite(value), name
        values[name] = value
    assert isinstance(res, ti.FitResult)  # the one record, with the population's part
    assert set(refused) == {"residual_tests", "model_check", "information", "simulate"}, refused
    for name, why in refused.items():  # one line, naming itself and what to use
        assert name in why and "\n" not in why and "res." in why, (name, why)
    assert res.fun == res.objective and np.array_equal(res.theta, res.x)
    assert res.compile_seconds >= 0 and res.stats["nit"] == res.nit and res.warnings == []
    assert list(res.params) == ["ka", "cl", "v"] and res.blocks() == [res.summary()]
    h, r = res.uncertainty(), res.uncertainty("robust")
    assert np.allclose(h.stderr, np.sqrt(np.diag(res.cov))) and h.names == res.names
    _, g = res.objective_function.value_grad(res.x, res.etas)
    Hi = np.linalg.inv(res.hess)
    assert np.allclose(r.covariance, Hi @ (g.T @ g) @ Hi, rtol=1e-8)
    assert np.all(np.isfinite(r.stderr)) and np.all(r.stderr > 0)
    assert "sandwich H⁻¹ (Σ g_i g_iᵀ) H⁻¹ over the units" in str(r)
    with pytest.raises(ValueError, match="no Gauss-Newton form"):
        res.uncertainty("gauss-newton")
    assert sorted(d["id"] for d in values["data_sensitivity"]) == ["u0", "u1", "u2", "u3"]
    assert values["validate"][0]["id"] == "u0" and set(values["profile"]) == {"ka"}


def test_ctrl_c_while_a_fleets_files_are_made_keeps_them_from_the_command_line(
    tmp_path, monkeypatch, capsys
):
    """Issue 49, one writer: `tensorid fit` of a fleet pressed Ctrl-C while its figures
    were made ended in a traceback; now exit 130 with the complete fit.json kept (the
    fit itself is this file's 4-unit fleet, handed to the command in place of its own)."""
    import json

    from tensorid import cli
    from tensorid.app import commands, population_run

    res = ti.fit(fleet_problem(4))
    root = Path(__file__).resolve().parents[1]
    monkeypatch.setattr(commands, "fit", lambda problem, method, **options: res)

    def pressed(*a, **k):
        raise KeyboardInterrupt

    monkeypatch.setattr(population_run, "_figures", pressed)
    out = tmp_path / "out"
    rc = cli.main(["fit", str(root / "examples/phenobarbital/model.py"),
                   str(Path(ti.__file__).parent / "datasets/phenobarbital.csv"),
                   "--records", "ID", "--columns", "t=TIME,conc=DV", "--out", str(out),
                   "--no-progress"])  # fmt: skip
    err = capsys.readouterr().err
    assert rc == 130 and "Traceback" not in err and "fit.json was written" in err, err
    data = json.loads((out / "fit.json").read_text())
    assert data["objective"] == pytest.approx(res.objective) and "population" in data
