"""Uncertainty on a badly scaled problem (Silverbox: raw Hessian condition ~1e18)."""

import numpy as np
import pytest

import tensorid as ti
from tensorid import benchmarks
from tensorid.analysis.uncertainty import flat_directions


@pytest.fixture(scope="module")
def silverbox_fit():
    return ti.fit(benchmarks.silverbox_problem(offset=True))


def test_standard_errors_survive_bad_scaling(silverbox_fit):
    res = silverbox_fit
    u = res.uncertainty()
    # independent: invert in units relative to |θ| instead of Jacobi units
    s = np.abs(res.theta)
    Hs = res.hess * np.outer(s, s)
    cov = 2 * u.sigma2 * np.linalg.inv(Hs) * np.outer(s, s)
    np.testing.assert_allclose(u.stderr, np.sqrt(np.diag(cov)), rtol=1e-6)
    rel = u.stderr / np.abs(res.theta)
    assert (rel > 1e-5).all() and (rel < 1.0).all()
    # the Gauss-Newton form agrees to first order at a good fit
    np.testing.assert_allclose(res.uncertainty("gauss-newton").stderr, u.stderr, rtol=0.1)
    assert res.warnings == []
    assert np.allclose(u.correlation, u.correlation.T) and (np.abs(u.correlation) <= 1 + 1e-9).all()


def test_flat_direction_names_only_the_unknowns_involved():
    H = np.diag([1e6, 1.0, 1e-4])
    H[1, 2] = H[2, 1] = 1e-2  # columns 1 and 2 exactly dependent
    H[2, 2] = 1e-4
    flat = flat_directions(H, ["m", "k", "c"])
    assert len(flat) == 1 and flat[0][1] == ["k", "c"]


def _decay_problem(**kw):
    m = ti.Model(
        rhs=lambda x, p, u: -p[0] * x + p[1] * u[0] - p[2],
        output=lambda x, p: x,
        states=["x"],
        params=["k", "b", "d"],
        inputs=["u"],
        outputs=["y"],
    )
    t = np.linspace(0, 5, 60)
    u = np.sign(np.sin(2.0 * t))
    truth = {"k": 1.0, "b": 0.5, "d": kw.pop("d_true", 0.0)}
    y = ti.simulate(m, truth, [1.0], ti.Experiment(t, u)).y[:, 0]
    y = y + 0.01 * np.random.default_rng(0).standard_normal(y.size)
    return ti.Problem(m, ti.Experiment(t, u, y), p0=kw.pop("p0", truth), x0=[1.0], **kw)


def test_an_indefinite_hessian_never_gives_a_zero_standard_error_and_names_the_direction():
    prob = _decay_problem(free_x0=["x"], fixed=["b", "d"])
    theta = np.array([1.0, 2.0])  # (x(t0), k): a point where the Hessian is indefinite
    res = ti.FitResult.at(prob, "newton", theta, np.abs(theta), ti.Status.MAXITER)
    assert np.linalg.eigvalsh(res.hess)[0] < 0  # the case this test is about
    u = res.uncertainty()
    assert np.isfinite(u.stderr).all() and (u.stderr > 0).all()
    assert u.forms == ["gauss-newton", "gauss-newton"]
    text = " ".join(u.warnings)
    assert "indefinite" in text and "a direction that moves k" in text
    assert "Gauss-Newton" in text
    gn = res.uncertainty("gauss-newton")
    np.testing.assert_allclose(u.stderr, gn.stderr)


def test_a_parameter_on_its_bound_is_flagged_and_its_interval_respects_the_bound():
    prob = _decay_problem(
        d_true=-0.05, bounds={"d": (0.0, None)}, p0={"k": 1.0, "b": 0.5, "d": 0.02}
    )
    res = ti.fit(prob)
    assert res.params["d"] == 0.0
    u = res.uncertainty()
    assert u.at_bound == {"d": "lower"}
    k = u.names.index("d")
    assert u.ci95[k, 0] >= 0.0 and u.ci95[k, 1] > 0.0
    assert any("d on its lower bound 0 (the data pull it further)" in w for w in res.warnings)
    assert "on lower bound" in res.summary()
    d = u.as_dicts()
    assert d["at_bound"] == {"d": "lower"} and d["ci95"]["d"][0] >= 0.0


def test_a_minimum_on_a_bound_is_not_called_a_saddle():
    # y = x + d²; the data sit 1 above the model, so d wants to grow past its bound 0.1:
    # along d the full Hessian may curve down, but with d held this is a strict minimum
    m = ti.Model(
        rhs=lambda x, p, u: -p[0] * x + p[1] * u[0],
        output=lambda x, p: x + p[2] ** 2,
        states=["x"],
        params=["k", "b", "d"],
        inputs=["u"],
        outputs=["y"],
    )
    t = np.linspace(0, 5, 80)
    u = np.sign(np.sin(1.7 * t))
    y = ti.simulate(m, {"k": 1.0, "b": 0.5, "d": 0.0}, [0.0], ti.Experiment(t, u)).y[:, 0] + 1.0
    prob = ti.Problem(
        m,
        ti.Experiment(t, u, y),
        p0={"k": 1.0, "b": 0.5, "d": 0.05},
        x0=[0.0],
        bounds={"d": (0.0, 0.1)},
    )
    res = ti.fit(prob)
    assert res.params["d"] == 0.1
    assert np.linalg.eigvalsh(res.hess)[0] < 0  # the full Hessian is indefinite here
    u_ = res.uncertainty()
    assert u_.at_bound == {"d": "upper"}
    assert not any("indefinite" in w for w in u_.warnings), u_.warnings
    assert u_.forms[u_.names.index("k")] == "hessian"
    assert np.isfinite(u_.stderr).all() and (u_.stderr > 0).all()


@pytest.mark.filterwarnings("error::RuntimeWarning")
def test_a_flat_direction_gives_no_raw_runtime_warning():
    # an unknown on a flat direction has infinite standard errors on both sides: the
    # observed/expected ratio inf/inf is left out, not warned about by numpy
    from tensorid.analysis.uncertainty import Information

    inf = np.inf
    info = Information(["a", "b"], np.array([inf, 0.2]), np.array([inf, 0.1]), inf, 10.0, {})
    assert "observed/expected standard errors 2.00 to 2.00" in info.describe()


def test_an_interval_cut_at_both_bounds_is_not_printed_as_an_interval():
    """issue 51 item 7: a parameter the data do not bound within its box had the box
    printed as its 95 % interval."""
    from conftest import decay_model

    t = np.linspace(0, 1, 6)
    rng = np.random.default_rng(0)
    y = np.exp(-2 * t)[:, None] + 0.5 * rng.standard_normal((6, 1))
    pr = ti.Problem(decay_model(), ti.Experiment(t, np.zeros(6), y), p0={"k": 1.0}, x0=[1.0],
                    bounds={"k": (0.95, 1.05)})  # fmt: skip
    res = ti.fit(pr)
    u = res.uncertainty()
    assert u.cut == {"k": "both"} and list(u.ci95[0]) == [0.95, 1.05]  # (fit.json's, as was)
    text = str(res.summary())
    assert "wider than [0.95, 1.05]" in text and "the data do not bound it" in text
