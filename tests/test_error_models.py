"""Residual-error models as plug-ins (tensorid/population/errors.py): the exponential
(log-additive) model's objective and exact gradient against a plainly written one, a
fit that recovers the truth it was simulated with, and its bad input in one line."""

from __future__ import annotations

import functools
import warnings

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from test_population import (
    _over_units,
    assert_central_differences,
    assert_plain,
    one_compartment,
)

import tensorid as ti
from tensorid.app.fleet_report import fleet_lines
from tensorid.population.diagnostics import COLUMNS
from tensorid.population.errors import ERROR_MODELS, ResidualErrors
from tensorid.population.objective import Objective

SIGMA = 0.15  # the log-scale SD the fleets are simulated with


@functools.cache
def lognormal_fleet(n_units: int, seed: int = 0):
    """Units of the one-compartment model, ka and cl log-normal, v shared, and
    y = ŷ·exp(σε); the dose row at t = 0 is not an observation (ŷ = 0 there)."""
    rng = np.random.default_rng(seed)
    m, units = one_compartment(), []
    for i in range(n_units):
        t = np.array([0.0, 0.5, 1, 2, 4, 8, 12, 24]) + np.r_[0, rng.uniform(-0.1, 0.1, 7)]
        p = {"ka": 1.5 * np.exp(0.5 * rng.standard_normal()), "v": 30.0}
        p["cl"] = 2.5 * np.exp(0.3 * rng.standard_normal())
        u = np.full((t.size, 1), 300.0 + 20 * i)
        sim = ti.simulate(m, p, [u[0, 0], 0.0], ti.Experiment(t, u), substeps=20)
        y = sim.y * np.exp(SIGMA * rng.standard_normal(sim.y.shape))
        seen = np.arange(t.size) > 0
        units.append(ti.Experiment(t, u, y, name=f"u{i}", observed=seen))
    return m, units


def lognormal_problem(n_units: int, seed: int = 0, **kw) -> ti.Problem:
    m, units = lognormal_fleet(n_units, seed)
    return ti.Problem(
        m, list(units), p0={"ka": 1.2, "cl": 2.0, "v": 25.0},
        x0={"depot": "Dose", "center": 0.0}, substeps=20,
        population={"ka": 0.4, "cl": 0.4}, residual_error="exponential", **kw,
    )  # fmt: skip


def _plain_exponential(obj: Objective, etas):
    """The FOCEI objective of y with log y = log ŷ + ε written plainly: ŷ by the
    engine's simulation differentiated by JAX, the inner optimum by one Newton step
    from the converged one, the curvature from ∂log ŷ/∂η, and the Jacobian of the log
    (2 Σ log y) so that it is the objective of y."""
    sw = obj.sweeps

    def logyhat(psi, z, unit):
        t, u, _, mask, x0, p = unit
        x0_, p_ = sw.expand(obj.theta(psi, z), x0, p)
        f = sw._simulate(x0_, p_, t, u)[1]
        return jnp.log(jnp.where(mask > 0, f, 1.0))

    def ell(z, psi, unit):
        logw, logsig = psi[2:4], psi[-1]
        y, mask = unit[2], unit[3]
        r = (jnp.log(jnp.where(mask > 0, y, 1.0)) - logyhat(psi, z, unit)) * mask
        return 0.5 * (jnp.sum(r**2) * jnp.exp(-2 * logsig) + jnp.sum((z * jnp.exp(-logw)) ** 2))

    def unit_O(psi, unit, z):
        z = z - jnp.linalg.solve(jax.hessian(ell)(z, psi, unit), jax.grad(ell)(z, psi, unit))
        logw, logsig, mask = psi[2:4], psi[-1], unit[3]
        A = jax.jacfwd(lambda e: logyhat(psi, e, unit))(z) * mask[..., None]
        M = jnp.einsum("psj,psk->jk", A, A) * jnp.exp(-2 * logsig) + jnp.diag(jnp.exp(-2 * logw))
        n = jnp.sum(mask)
        jac = 2 * jnp.sum(jnp.log(jnp.where(mask > 0, unit[2], 1.0)) * mask)
        return (
            2 * ell(z, psi, unit) + n * (jnp.log(2 * jnp.pi) + 2 * logsig) + 2 * jnp.sum(logw)
            + jnp.linalg.slogdet(M)[1] + jac
        )  # fmt: skip

    return _over_units(unit_O, obj, etas)


def _exponential_point():
    obj = Objective(lognormal_problem(3), "focei")
    assert obj.names[-1] == "log_exp_cp" and obj.plain
    psi = np.array([np.log(1.3), np.log(2.2), np.log(0.5), np.log(0.35), 26.0, np.log(0.2)])
    etas, ok = obj.solve_inner(psi, np.zeros((3, 2)))
    assert ok
    return obj, psi, etas


def test_an_exponential_errors_gradient_is_that_of_central_differences():
    obj, psi, etas = _exponential_point()
    assert_central_differences(obj, psi, etas)


@pytest.mark.slow  # its plainly written reference compiles for 25-35 s
def test_an_exponential_error_has_the_plain_objective_and_gradient():
    obj, psi, etas = _exponential_point()
    assert_plain(obj, psi, etas, _plain_exponential(obj, etas))


def test_every_model_of_the_registry_has_its_terms_named_in_psi():
    """ψ's residual-error entries: all outputs' first term, then their second; each
    model's variance as its formula says; a sample drawn on its own scale."""
    errs = ResidualErrors(("combined", "exponential", "additive"), ["a", "b", "c"])
    assert errs.names == ["log_sigma_a", "log_sigma_c", "log_prop_a", "log_exp_b"]
    assert list(errs.first) == [0, 3, 1] and errs.logs == [1] and not errs.constant
    noise = np.log([0.5, 0.2, 0.1, 0.3])
    yhat = np.array([[2.0, 4.0, 6.0]])
    v = np.asarray(errs.variance(jnp.asarray(noise), jnp.asarray(yhat)))
    np.testing.assert_allclose(v, [[0.25 + 0.01 * 4, 0.09, 0.04]], rtol=1e-14)
    s = errs.sample(np.full(4000, 4.0), 0.3, np.random.default_rng(0).standard_normal(4000), 1)
    assert s.min() > 0 and np.log(s).std() == pytest.approx(0.3, rel=0.05)
    assert all(m.name == k and m.terms for k, m in ERROR_MODELS.items())


def test_observations_at_or_below_zero_are_one_line_for_a_log_scale_error():
    m, units = lognormal_fleet(2)
    y = units[1].y.copy()
    y[3] = 0.0
    bad = [units[0], ti.Experiment(units[1].t, units[1].u, y, name="u1", observed=np.arange(8) > 0)]
    with pytest.raises(ValueError, match=r"'exponential' for cp: unit u1's observation at t = "
                       r"\S+ is 0, which has no logarithm.*'combined'"):  # fmt: skip
        Objective(ti.Problem(m, bad, p0={"ka": 1.2, "cl": 2.0, "v": 25.0},
                             x0={"depot": "Dose", "center": 0.0}, population={"ka": 0.4},
                             residual_error={"cp": "exponential"}))  # fmt: skip


def test_a_dose_row_observed_at_zero_prediction_is_one_line():
    m, units = lognormal_fleet(2)
    seen = [ti.Experiment(e.t, e.u, np.r_[[[0.5]], e.y[1:]], name=e.name)
            for e in units]  # fmt: skip
    pr = ti.Problem(m, seen, p0={"ka": 1.2, "cl": 2.0, "v": 25.0},
                    x0={"depot": "Dose", "center": 0.0}, population={"ka": 0.4},
                    residual_error="exponential")  # fmt: skip
    with pytest.raises(ValueError, match="prediction at t = 0 is 0, where an exponential "
                       "error has no logarithm; use 'combined'"):  # fmt: skip
        ti.fit(pr)


def test_the_report_names_the_models_formula():
    data = {"residual_error": {"cp": {"model": "exponential", "exponential": 0.15,
                                      "exponential_stderr": 0.01}}}  # fmt: skip
    (line,) = [x for x in fleet_lines(data) if x.startswith("Residual error")]
    assert "log y = log prediction + ε" in line and "cp (exponential): exponential 0.15" in line


@pytest.mark.slow  # a 24-unit population fit of its own structure: about 40 s cold
def test_an_exponential_error_fit_recovers_the_truth_it_was_simulated_with(tmp_path):
    res = ti.fit(lognormal_problem(24, seed=1))
    assert res.success
    e = res.residual_error["cp"]
    assert (
        e["model"] == "exponential" and abs(e["exponential"] - SIGMA) < 3 * e["exponential_stderr"]
    )
    for name, truth in (("ka", 1.5), ("cl", 2.5)):
        pop = res.population[name]
        assert abs(pop["typical"] - truth) < 3 * pop["typical_stderr"], (name, pop)
    assert abs(res.shared["v"]["value"] - 30.0) < 3 * res.shared["v"]["stderr"]
    assert "residual error of cp (exponential): exponential" in str(res)
    # the per-observation table: CWRES of a unit as written out plainly (A = ∂log ŷ/∂η
    # by JAX through the engine's simulation), and CWRES, NPDE ~ N(0, 1) on this fleet
    tab, obj = res.table(), res.objective_function
    assert len(tab["DV"]) == 24 * 7 and list(tab) == list(COLUMNS)
    i, unit = 5, tuple(a[5] for a in obj.data)
    seen = unit[3][:, 0] > 0

    def log_yhat(eta):
        x0, p = obj.sweeps.expand(obj.theta(jnp.asarray(res.x), eta), unit[4], unit[5])
        return jnp.log(obj.sweeps._simulate(x0, p, unit[0], unit[1])[1][:, 0])

    eta = jnp.asarray(res.etas[i])
    A = np.asarray(jax.jacfwd(log_yhat)(eta))[seen]
    omega = np.diag([res.population[n]["omega"] ** 2 for n in ("ka", "cl")])
    C = A @ omega @ A.T + e["exponential"] ** 2 * np.eye(int(seen.sum()))
    mean = np.asarray(log_yhat(eta))[seen] - A @ res.etas[i]
    plain = np.linalg.solve(np.linalg.cholesky(C), np.log(np.asarray(unit[2])[seen, 0]) - mean)
    np.testing.assert_allclose(tab["CWRES"][tab["ID"] == "u5"], plain, rtol=1e-7, atol=1e-9)
    for what in ("CWRES", "NPDE", "IWRES"):
        v = tab[what].astype(float)
        assert abs(v.mean()) < 0.2 and 0.75 < v.std() < 1.25, (what, v.mean(), v.std())
    written = res.plot(tmp_path)
    assert [p.name for p in written] == ["units.png", "observed_predicted.png", "vpc.png",
                                         "residuals.png"]  # fmt: skip


def test_the_table_is_written_as_csv_and_drawn_without_a_fit(tmp_path):
    """observations.csv's cells (10 digits, empty where not finite) and the residual
    panels, from a table alone."""
    import csv
    from types import SimpleNamespace

    from tensorid.app.population_run import _table_csv
    from tensorid.population.figures import residuals_figure

    rng = np.random.default_rng(0)
    n = 40
    tab = {c: rng.standard_normal(n) for c in COLUMNS}
    tab["ID"] = np.array(["a"] * 20 + ["b"] * 20, dtype=object)
    tab["OUTPUT"] = np.array(["cp"] * n, dtype=object)
    tab["NPDE"][3] = np.nan
    res = SimpleNamespace(table=lambda: tab, problem=SimpleNamespace(model=one_compartment()))
    _table_csv(res, tmp_path / "t.csv")
    with (tmp_path / "t.csv").open() as f:
        rows = list(csv.DictReader(f))
    assert len(rows) == n and rows[3]["NPDE"] == "" and rows[25]["ID"] == "b"
    assert float(rows[0]["CWRES"]) == pytest.approx(tab["CWRES"][0], rel=1e-9)
    fig = residuals_figure(res)
    assert [a.get_ylabel() for a in fig.axes] == ["CWRES", "CWRES", "IWRES", "residual"]


def test_a_censored_sample_predicted_at_zero_has_probability_one_on_the_log_scale():
    """Beal's M3 with an exponential error: before the dose arrives (ŷ = 0) a sample
    below its limit has P(y < limit) = 1, so it adds nothing (it made ℓ = +∞)."""
    m = ti.Model(rhs=lambda x, p, u: jnp.stack([-p[0] * x[0], p[0] * x[0] - p[1] * x[1]]),
                 output=lambda x, p: x[1:] / 10.0, states=["depot", "center"],
                 params=["ka", "ke"], outputs=["cp"])  # fmt: skip
    t = np.array([0.0, 0.5, 1, 2, 4, 8])
    y = np.array([[0.1], [2.0], [3.0], [3.5], [2.5], [0.1]])
    cens = np.zeros((6, 1), bool)
    cens[[0, -1]] = True
    exps = [ti.Experiment(t, None, y * (1 + 0.1 * i), name=str(i), censored=cens)
            for i in range(3)]  # fmt: skip
    pr = ti.Problem(m, exps, p0={"ka": 1.0, "ke": 0.2}, x0=[100.0, 0.0], population={"ka": 0.3},
                    residual_error="exponential")  # fmt: skip
    obj = Objective(pr, "laplace")
    psi = jnp.asarray([0.0, np.log(0.3), 0.2, np.log(0.2)])
    unit = tuple(a[0] for a in obj.data)
    eta = jnp.zeros(1)
    value, grad = jax.value_and_grad(obj.ell, argnums=1)(eta, psi, unit)
    assert np.isfinite(float(value)) and np.isfinite(np.asarray(grad)).all()
    f = np.asarray(obj.predict(psi, eta, unit))[:6, 0]  # the censored t = 0 sample: ŷ = 0
    assert f[0] == 0.0


def _log_c(log):
    """A one-compartment model whose output is log c (log: jnp.log, or a log finite at 0)."""
    return ti.Model(rhs=lambda x, p, u: -p[0] / p[1] * x, output=lambda x, p: log(x / p[1]),
                    states=["a"], params=["cl", "v"], outputs=["log c"])  # fmt: skip


def _log_c_units(n: int, sd: float = 0.0):
    """n units dosed at t = 0 (the dose's row: no observation), log c measured after."""
    t, rng = np.array([0.5, 1, 2, 4, 8, 12]), np.random.default_rng(0)
    return [ti.Experiment(t, None, (np.log(10.0) - 0.2 * (1 + 0.1 * i) * t
                                    + sd * rng.standard_normal(6))[:, None],
                          name=str(i), events=ti.Events.doses(0.0, "a", 100.0))
            for i in range(n)]  # fmt: skip


def test_an_output_not_finite_at_a_dose_row_adds_nothing_to_a_unit_s_likelihood():
    """An output written as log c is −∞ at the dose's own row (c = 0 before the dose
    arrives), which is no observation: the likelihood's ŷ there is y, with every
    derivative 0 at every order of units.outputs' tower, so ℓ_i, its gradient (reverse
    mode) and its Hessian are those of a log that is finite there (a zero cotangent
    times an infinite derivative was NaN, and the population fit stopped at once)."""
    psi = jnp.asarray([np.log(2.0), np.log(0.3), np.log(10.0), np.log(0.1)])
    eta = jnp.asarray([0.1])
    out = []
    for log in (jnp.log, lambda c: jnp.log(jnp.abs(c) + 1e-300)):
        pr = ti.Problem(_log_c(log), _log_c_units(3), p0={"cl": 2.0, "v": 10.0}, x0=[0.0],
                        population={"cl": 0.3})  # fmt: skip
        obj = Objective(pr, "focei")
        unit = tuple(a[0] for a in obj.data)
        assert obj.units.mask[0, 0, 0] == 0 and unit[0][0] == 0.0  # the dose's row
        for o in (obj, obj.local(psi, eta, unit, 2)):  # the sweeps' tower, its polynomial
            value, grad = jax.value_and_grad(o.ell, argnums=(0, 1))(eta, psi, unit)
            out.append((value, *grad, jax.hessian(o.ell)(eta, psi, unit)))
    assert np.isneginf(float(jnp.log(0.0)))  # what the first model's output is there
    for a, b in zip(out[:2], out[2:], strict=True):
        for x, y in zip(a, b, strict=True):
            assert np.isfinite(np.asarray(x)).all()
            np.testing.assert_allclose(x, y, rtol=1e-12)


def test_a_fleet_of_individual_values_with_log_c_reports_a_finite_residual_sd():
    """Individual parameters alone (no random effects): the fit's residual SD and its
    check of the substeps read the model's own ŷ at the measured samples only (its −∞
    at the dose's row times a zero mask was NaN: σ NaN, and the check refitted at 16,
    64 and 128 substeps, each for a move of "inf residual SDs")."""
    pr = ti.Problem(_log_c(jnp.log), _log_c_units(4, sd=0.05), p0={"cl": 2.0, "v": 10.0},
                    x0=[0.0], individual=["cl"])  # fmt: skip
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)  # (−∞ − −∞ in the check: a warning)
        res = ti.fit(pr)
    assert res.success and np.isfinite(res.residual_sd["log c"]) and res.residual_sd["log c"] > 0
    assert pr.discretisation.substeps == res.problem.discretisation.substeps
    assert not [n for n in res.notes if "substeps" in n], res.notes
