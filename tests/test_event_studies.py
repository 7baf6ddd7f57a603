"""Event records fitted from NONMEM-style tables by the command line alone, beside R's
nlme on the same model and data (benchmarks/bench_events.py prints the tables of
docs/events.md; these tests hold the fit to nlme's numbers, as nlme printed them)."""

from __future__ import annotations

import json
import math
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

# Rscript benchmarks/peers/phenobarbital_nlme.R (nlme 3.1, method = "ML"): the log
# typical values with their standard errors, ω, σ and −2 log L
NLME = {"log_cl": (-5.093242, 0.080075), "log_v": (0.342534, 0.061600),
        "omega": (0.44021, 0.45044), "sigma": 2.79274, "m2ll": 1010.8315}  # fmt: skip


@pytest.mark.slow
def test_phenobarbital_from_its_nonmem_table_agrees_with_nlme(tmp_path):
    out = tmp_path / "fit"
    r = subprocess.run(
        [sys.executable, "-m", "tensorid", "fit", str(ROOT / "examples/phenobarbital/model.py"),
         str(ROOT / "src/tensorid/datasets/phenobarbital.csv"), "--records", "ID",
         "--columns", "t=TIME,conc=DV", "--no-progress", "--out", str(out)],
        capture_output=True, text=True, timeout=600,
    )  # fmt: skip
    assert r.returncode == 0, r.stderr[-3000:]
    fit = json.loads((out / "fit.json").read_text())
    assert fit["success"] and fit["observations"] == 155 and len(fit["units"]) == 59
    assert fit["cost"] == fit["objective"]
    for name in ("cl", "v"):
        value, se = NLME[f"log_{name}"]
        ours = math.log(fit["population"][name]["typical"])
        assert abs(ours - value) < 0.6 * se, (name, ours, value)
    for name, w in zip(("cl", "v"), NLME["omega"], strict=True):
        assert fit["population"][name]["omega"] == pytest.approx(w, rel=0.03)
    assert fit["residual_sd"]["conc"] == pytest.approx(NLME["sigma"], rel=0.01)
    # FOCEI's optimum of its own objective lies at or below nlme's approximation's
    assert NLME["m2ll"] - 1.0 < fit["objective"] < NLME["m2ll"]
    # docs/events.md shows this fit's numbers
    page = (ROOT / "docs/events.md").read_text()
    row = re.search(r"\| log cl \| ([-\d.]+) \|", page)
    assert row and float(row[1]) == pytest.approx(
        math.log(fit["population"]["cl"]["typical"]), abs=1e-4
    )


def _censored_fleet(seed=0, units=16, limit=1.0):
    import numpy as np

    import tensorid as ti

    m = ti.Model(
        rhs=lambda x, p, u: -p[0] / p[1] * x, output=lambda x, p: x / p[1],
        states=["a"], params=["cl", "v"], outputs=["c"],
    )  # fmt: skip
    rng = np.random.default_rng(seed)
    t = np.array([0.5, 1, 2, 4, 6, 8, 12, 16, 24])
    exps = []
    for i in range(units):
        p = {"cl": 2.0 * np.exp(0.3 * rng.standard_normal()), "v": 10.0}
        ev = ti.Events.doses(0.0, "a", 100.0)
        e = ti.Experiment(t, None, np.zeros((t.size, 1)), events=ev)
        y = ti.simulate(m, p, [0.0], e, substeps=8).y + 0.3 * rng.standard_normal((e.P, 1))
        below = (y < limit) & e.mask.astype(bool) if e.mask is not None else y < limit
        y = np.where(below, limit, y)
        exps.append(ti.Experiment(e.t, None, y, name=str(i), events=ev,
                                  observed=e.observed, censored=below))  # fmt: skip
    return m, exps


def test_censored_samples_enter_the_likelihood_as_beals_m3_and_focei_refuses_them():
    import jax.numpy as jnp
    import numpy as np
    from scipy.stats import norm

    import tensorid as ti
    from tensorid.population.objective import Objective

    m, exps = _censored_fleet(units=3)
    assert sum(int(e.censored.sum()) for e in exps) > 0
    pr = ti.Problem(m, exps, p0={"cl": 2.0, "v": 10.0}, x0=[0.0], population={"cl": 0.3},
                    fixed=["v"], substeps=8)  # fmt: skip
    with pytest.raises(ValueError, match="method='laplace'"):
        Objective(pr, "focei")
    obj = Objective(pr, "laplace")
    psi = jnp.array([np.log(2.1), np.log(0.25), np.log(0.35)])
    eta = jnp.array([0.1])
    unit = tuple(a[1] for a in obj.data)
    f = np.asarray(obj.predict(psi, eta, unit))[:, 0]
    e, sd = exps[1], 0.35
    seen, cens = e.mask[:, 0] > 0, e.censored[:, 0]
    plain = (
        -norm.logpdf(e.y[seen, 0], f[seen], sd).sum()
        - norm.logcdf((e.y[cens, 0] - f[cens]) / sd).sum()
        - seen.sum() * 0.5 * np.log(2 * np.pi)  # ℓ leaves out the 2π constants
        + 0.5 * (0.1 / 0.25) ** 2
    )
    assert float(obj.ell(eta, psi, unit)) == pytest.approx(plain, rel=1e-12)
    assert e.observations == int(seen.sum() + cens.sum())
    with pytest.raises(ValueError, match="population's likelihood"):
        ti.Problem(m, exps, p0={"cl": 2.0, "v": 10.0}, x0=[0.0], fixed=["v"])


@pytest.mark.slow
def test_a_censored_fleet_fitted_by_laplace_recovers_the_truth():
    import numpy as np

    import tensorid as ti

    m, exps = _censored_fleet(seed=3, units=24)
    share = sum(int(e.censored.sum()) for e in exps) / sum(e.observations for e in exps)
    assert share > 0.2  # a fifth of the samples or more below the limit
    pr = ti.Problem(m, exps, p0={"cl": 1.5, "v": 10.0}, x0=[0.0], population={"cl": 0.5},
                    fixed=["v"], substeps=8)  # fmt: skip
    res = ti.fit(pr, method="laplace")
    assert res.success
    pop = res.population["cl"]
    assert abs(pop["typical"] - 2.0) < 3 * pop["typical_stderr"]
    assert abs(res.residual_sd["c"] - 0.3) < 0.1
    del np


def test_a_population_with_lags_has_its_units_and_m3_keeps_finite_gradients():
    """A population over records with a lag (moving nodes: their channels' width) and
    Beal's M3 with a proportional error where ŷ = 0 (the gradient was NaN there)."""
    import jax
    import jax.numpy as jnp
    import numpy as np

    import tensorid as ti
    from tensorid.population.objective import Objective

    m = ti.Model(
        rhs=lambda x, p, u: jnp.stack([-p[0] * x[0], p[0] * x[0] - p[1] * x[1]]),
        output=lambda x, p: x[1:] / 10.0,
        states=["depot", "center"], params=["ka", "ke", "tlag"], outputs=["cp"],
    )  # fmt: skip
    t = np.array([0.0, 0.5, 1.0, 2.0, 4.0, 8.0])
    ev = ti.Events.doses(0.0, "depot", 100.0)
    exps = [ti.Experiment(t, None, np.full((6, 1), 2.0), name=str(i), events=ev)
            for i in range(3)]  # fmt: skip
    p0 = {"ka": 1.0, "ke": 0.2, "tlag": 0.3}
    pr = ti.Problem(m, exps, p0=p0, x0=[0, 0], population={"ka": 0.3}, lags={"depot": "tlag"})
    obj = Objective(pr)
    psi = jnp.asarray(obj.x0 if hasattr(obj, "x0") else np.zeros(obj.size))
    yhat = np.asarray(obj.predict_all(np.array([0.0, np.log(0.3), 0.2, 0.3, np.log(0.5)]),
                                      np.zeros((3, 1))))  # fmt: skip
    sim = pr.simulate(pr.theta0)[0]
    np.testing.assert_allclose(yhat[0, :6, 0], sim.y[:, 0], rtol=1e-12)
    # M3: a dose row at t = 0 (not observed, ŷ = 0 there: σ = 0 for a proportional
    # error), the last sample below its limit
    t2 = t[1:]
    below = np.zeros((5, 1), dtype=bool)
    below[-1, 0] = True
    cens = [ti.Experiment(t2, None, np.full((5, 1), 0.5), name=str(i), events=ev,
                          censored=below) for i in range(3)]  # fmt: skip
    pr = ti.Problem(m, cens, p0=p0, x0=[0, 0], population={"ka": 0.3}, fixed=["tlag"],
                    residual_error="proportional")  # fmt: skip
    obj = Objective(pr, "laplace")
    unit = tuple(a[0] for a in obj.data)
    psi = jnp.array([0.0, np.log(0.3), 0.2, np.log(0.2)])
    g = jax.grad(obj.ell, argnums=1)(jnp.array([0.1]), psi, unit)
    assert np.isfinite(np.asarray(g)).all()
