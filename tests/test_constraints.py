"""Constraints between parameters (issue 40 item 7): kept by the exact-derivative
trust-region methods, checked against the KKT conditions from jax.grad; refusals of
bad expressions before any work; the model file, --constraint and fit.json."""

from __future__ import annotations

import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from conftest import autodiff

import tensorid as ti
from tensorid import cli


def _rhs(x, p, u):
    return jnp.stack([-p[0] * x[0] + p[1] * u[0]])


MODEL = ti.Model(_rhs, output=lambda x, p: x[:1], states=["x"], params=["a", "b"],
                 inputs=["u"], outputs=["y"], name="first-order")  # fmt: skip


def _data(seed=0):
    t = np.arange(200) * 0.05
    u = np.sin(t) + 0.5 * np.sin(3.1 * t)
    y = ti.simulate(MODEL, {"a": 1.0, "b": 2.0}, [0.0], ti.Experiment(t, u)).y
    return ti.Experiment(t, u, y + 0.01 * np.random.default_rng(seed).standard_normal(y.shape))


def _problem(constraints=None, **kw):
    return ti.Problem(MODEL, _data(), p0={"a": 0.5, "b": 0.5}, x0=[0.0],
                      constraints=constraints, **kw)  # fmt: skip


@pytest.mark.parametrize("method", ["auto", "newton", "gauss-newton", "newton-cg"])
def test_active_constraint_holds_and_its_multiplier_is_the_kkt_one(method):
    # the unconstrained optimum is a ≈ 1 < b ≈ 2: "a >= b" binds
    prob = _problem(["a >= b", "b <= 10*a"])
    res = ti.fit(prob, method)
    assert res.success
    a, b = res.theta
    assert a - b >= 0.0 and a - b < 1e-9  # holds, on the constraint
    active, inactive = res.constraints.items
    assert active["active"] and not inactive["active"]
    assert inactive["multiplier"] == 0.0 and inactive["value"] > 1.0
    # KKT, independently: ∇J = λ ∇c with ∇c = (1, -1), ∇J from jax.grad of J alone
    g = np.asarray(jax.grad(prob.jax_cost)(jnp.asarray(res.theta)))
    lam = active["multiplier"]
    assert lam > 0
    np.testing.assert_allclose(g, lam * np.array([1.0, -1.0]), rtol=1e-5)
    assert res.grad_norm < 1e-3 * lam  # the Lagrangian's gradient, not ∇J's
    assert res.constraints.second_order is True
    # the bars held on the constraint: a and b move together, so theirs are equal
    se = res.constraints.restricted_stderr
    assert se["a"] == pytest.approx(se["b"], rel=1e-6)
    assert "constraints (" in str(res) and "multiplier λ" in str(res)


def test_inactive_constraints_leave_the_fit_as_it_was():
    free = ti.fit(_problem())
    res = ti.fit(_problem(["b >= a", "a >= 0.1"]))
    np.testing.assert_array_equal(res.theta, free.theta)
    assert res.cost == free.cost and res.constraints.outer == 1
    assert [d["multiplier"] for d in res.constraints.items] == [0.0, 0.0]
    assert not any(d["active"] for d in res.constraints.items)
    assert res.constraints.restricted_stderr == {}


def test_an_infeasible_start_and_a_nonlinear_constraint():
    # start a = 0.5 > b²/8 = 0.03 is outside "a <= b**2/8"; the fit pulls it over
    prob = ti.Problem(MODEL, _data(), p0={"a": 0.5, "b": 0.5}, x0=[0.0],
                      constraints=["a <= b**2/8"])  # fmt: skip
    res = ti.fit(prob, "newton")
    a, b = res.theta
    assert res.success and 0.0 <= b**2 / 8 - a < 1e-9
    (item,) = res.constraints.items
    g = np.asarray(jax.grad(prob.jax_cost)(jnp.asarray(res.theta)))
    grad_c = np.array([-1.0, b / 4])  # c = b²/8 − a
    np.testing.assert_allclose(g, item["multiplier"] * grad_c, rtol=1e-5)


def test_penalised_derivatives_are_exact():
    """The augmented-Lagrangian terms in J, ∇J, ∇²J and ∇²J v against jax."""
    prob = _problem(["a >= b", "a*b <= 3"])
    prob.penalty = (np.array([2.0, 0.5]), np.array([30.0, 7.0]))
    th = np.array([0.9, 1.2])
    J, g, H = prob.cost_grad_hess(th)
    J_ad, g_ad, H_ad = autodiff(prob.jax_cost)(th)
    assert J == pytest.approx(J_ad, rel=1e-12)
    np.testing.assert_allclose(g, g_ad, rtol=1e-9)
    np.testing.assert_allclose(H, H_ad, rtol=1e-8)
    v = np.array([0.3, -1.0])
    np.testing.assert_allclose(prob.cost_grad_hessp(th, v)[2], H @ v, rtol=1e-9)


@pytest.mark.parametrize(
    ("constraints", "says"),
    [
        (["a >= c"], "'c' is not a parameter of the model"),
        (["a == b"], "is an equality"),
        (["a + b"], "is not an inequality"),
        (["a >>= b"], "cannot parse"),
        (["a >= __import__('os')"], "is not a function constraints know"),
        (["a >= b.real"], "is not arithmetic"),
        (["x >= a"], "whose initial value is not estimated"),
        ([3], "is not a string"),
    ],
)
def test_bad_constraints_are_refused_in_one_line(constraints, says):
    with pytest.raises((ValueError, TypeError), match=None) as e:
        _problem(constraints)
    assert says in str(e.value) and "\n" not in str(e.value)


def test_fixed_only_constraints_and_other_methods_are_refused():
    with pytest.raises(ValueError, match="involves no estimated unknown"):
        _problem(["b >= 1"], fixed=["b"])
    with pytest.raises(ValueError, match="exact-derivative trust-region methods"):
        ti.fit(_problem(["a >= b"]), "fd-bfgs")
    # a fixed parameter is a constant, and a free initial state may be named
    prob = _problem(["a >= b", "x >= -1"], fixed=["b"], free_x0=["x"])
    assert prob.constraints.items[1].names == ("x",)
    # a chain is two constraints, each shown as its own inequality
    items = _problem(["0.5 <= a - b <= 3"]).constraints.items
    assert [k.text for k in items] == ["0.5 <= a - b", "a - b <= 3"]
    assert [k.expr for k in items] == ["a - b - 0.5", "3 - (a - b)"]


def test_model_file_and_command_line_constraints(tmp_path, capsys):
    data = _data()
    (tmp_path / "model.py").write_text(
        'rhs = {"x": "-a*x + b*u"}\noutput = {"y": "x"}\ninputs = ["u"]\n'
        'params = ["a", "b"]\np0 = {"a": 0.5, "b": 0.5}\nconstraints = ["b <= 10*a"]\n'
    )
    rows = np.column_stack([data.t, data.u[:, 0], data.y[:, 0]])
    np.savetxt(tmp_path / "d.csv", rows, delimiter=",", header="t,u,y", comments="")
    out = tmp_path / "out"
    argv = ["fit", str(tmp_path / "model.py"), str(tmp_path / "d.csv"), "--constraint",
            "a >= b", "--no-progress", "--out", str(out)]  # fmt: skip
    assert cli.main(argv) == 0
    d = json.loads((out / "fit.json").read_text())
    exprs = [c["expr"] for c in d["constraints"]]
    assert exprs == ["b <= 10*a", "a >= b"]  # the file's, then the flag's
    c = d["constraints"][1]
    assert c["active"] and c["multiplier"] > 0 and c["value"] >= 0
    assert d["params"]["a"] - d["params"]["b"] >= 0
    assert d["constraints_fit"]["converged"] is True
    assert "## Constraints" in (out / "report.md").read_text()
    assert "multiplier λ" in capsys.readouterr().out


def test_the_docs_state_what_the_example_prints():
    """docs/your-own-model.md's constraint table is this file's example, as printed."""
    from pathlib import Path

    text = (Path(__file__).resolve().parents[1] / "docs/your-own-model.md").read_text()
    res = ti.fit(_problem(["a >= b", "b <= 10*a"]))
    rows = [ln.strip() for ln in str(res.constraints).splitlines() if "│" in ln]
    assert len(rows) == 2 and all(r in text for r in rows), "update the docs' table"
    assert f"constraints ({res.constraints.outer} augmented-Lagrangian iterations)" in text
    assert f"a = b = {res.theta[0]:.5g}" in text


def test_constraints_that_cannot_hold_together_are_said_to_fail():
    res = ti.fit(_problem(["a >= 20"], bounds={"a": (0.01, 10.0)}), "newton")
    assert res.status is ti.Status.CONSTRAINTS_VIOLATED and not res.success
    assert not res.constraints.converged and res.constraints.outer == 30
    assert any("'a >= 20' is not met to tolerance" in w for w in res.warnings)
    assert res.theta[0] == 10.0  # as close as the bounds allow


def test_an_active_constraint_without_a_multiplier_says_why():
    """issue 51 item 7: "active: yes" with multiplier 0 and no word that a bound had
    switched the term off."""
    t = np.arange(200) * 0.05
    u = np.sin(t) + 0.5 * np.sin(3.1 * t)
    e = ti.Experiment(t, u, ti.simulate(MODEL, {"a": 1.0, "b": 2.0}, [0.0], ti.Experiment(t, u)).y)
    cases = [
        (["b <= 2*a"], None, "the data's own optimum lies on it"),  # noise-free: b = 2a
        (["a >= 0.8"], {"a": (0.1, 0.8)}, "the bound on a holds the estimate there"),
    ]
    for constraints, bounds, why in cases:
        pr = ti.Problem(MODEL, e, p0={"a": 0.5, "b": 0.5}, x0=[0.0], constraints=constraints,
                        bounds=bounds)  # fmt: skip
        res = ti.fit(pr)
        (item,) = res.constraints.items
        assert item["active"] and item["multiplier"] == 0.0
        text = str(res)
        assert "yes, λ = 0" in text and why in text, text


def test_a_constraint_along_a_flat_direction_says_so_and_leaves_it_unbounded():
    """Issue 51 item 7: with a + b pinned by an active constraint and only a + b in the
    data, a - b is flat on the constraint's tangent space. The report said "curves
    downward ... try other starts" (rounding's sign) and printed the restricted
    standard errors of a and b as 0.0 (the covariance had dropped the flat direction),
    beside a warning that a and b are not identifiable."""
    m = ti.Model(
        rhs=lambda x, p, u: jnp.stack([-(p[0] + p[1]) * x[0] + u[0], -p[2] * x[1] + x[0]]),
        output=lambda x, p: x[1:], states=["x", "z"], params=["a", "b", "c"],
        inputs=["u"], outputs=["y"],
    )  # fmt: skip
    t = np.linspace(0, 10, 201)
    u = np.sin(t)[:, None] + 1
    sim = ti.simulate(m, {"a": 0.3, "b": 0.5, "c": 0.7}, [0.0, 0.0], ti.Experiment(t, u))
    y = sim.y + 0.001 * np.random.default_rng(0).standard_normal(sim.y.shape)
    pr = ti.Problem(m, [ti.Experiment(t, u, y)], p0={"a": 0.5, "b": 0.4, "c": 0.5},
                    x0=[0, 0], constraints=["a + b <= 0.5"])  # fmt: skip
    res = ti.fit(pr)
    text = res.summary()
    assert "curves downward" not in text
    assert "flat on their tangent space along a direction that moves a, b" in text
    assert "the standard errors are a inf, b inf, c 0.00" in text
