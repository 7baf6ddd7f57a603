"""Experiment design: the Fisher information from exact sensitivities, a designed
input that beats the start, and predictions that simulated experiments confirm."""

from __future__ import annotations

import numpy as np
import pytest

import tensorid as ti
from tensorid.fitting.design import multisine, step_levels

FIRST = ti.Model(
    rhs=lambda x, p, u: -p[0] * x + p[1] * u[0], states=["x"], params=["a", "b"],
    inputs=["u"], output=lambda x, p: x, outputs=["y"], name="first-order",
)  # fmt: skip
T = np.arange(100) * 0.1
NOMINAL = {"a": 2.0, "b": 3.0}


@pytest.fixture(scope="module")
def design():
    return ti.design_input(FIRST, NOMINAL, T, step_levels(100, 5), np.full(5, 0.5),
                           bounds=[(0.0, 1.0)] * 5, noise=0.05)  # fmt: skip


def test_the_fisher_information_is_that_of_the_exact_output_sensitivities(design):
    u = design.u
    prob = ti.Problem(FIRST, ti.Experiment(T, u, np.zeros((100, 1))), p0=NOMINAL)
    S = prob.output_sensitivities(prob.theta0)[0][:, 0, :]  # (P, K)
    F = S.T @ S / 0.05**2
    se = np.sqrt(np.diag(np.linalg.inv(F)))
    np.testing.assert_allclose(list(design.stderr_after.values()), se, rtol=1e-10)
    np.testing.assert_allclose(list(design.predict(u).values()), se, rtol=1e-10)


def test_the_designed_input_beats_the_start_within_its_limits(design):
    assert design.value_after < design.value_before
    for n in design.names:
        assert design.stderr_after[n] < 0.5 * design.stderr_before[n]
    assert design.u.min() >= 0.0 and design.u.max() <= 1.0
    assert "before -> after" in design.describe()
    text = str(design)  # printed: the criterion and a row per unknown, no arrays
    assert text.startswith("input design (D, lower is better)") and "a " in text
    assert len(repr(design)) < 200 and "array" not in repr(design)


def test_predicted_standard_errors_are_what_simulated_experiments_give(design):
    realised = design.verify(draws=120, seed=1)
    for n in design.names:
        assert realised[n] == pytest.approx(design.stderr_after[n], rel=0.2)


def test_families_and_criteria():
    f = multisine(T, [0.1, 0.5, 1.5], offset=0.5, limits=(0.0, 1.0))
    u = f(np.array([0.4, 0.4, 0.4]))
    assert u.shape == (100,) and u.min() >= 0.0 and u.max() <= 1.0
    d = ti.design_input(FIRST, NOMINAL, T, f, np.array([0.1, 0.1, 0.1]),
                        bounds=[(0.0, 0.5)] * 3, noise=0.05, criterion="max-variance",
                        names=["a"], starts=2)  # fmt: skip
    assert d.stderr_after["a"] <= d.stderr_before["a"]
    with pytest.raises(ValueError, match="criterion"):
        ti.design_input(FIRST, NOMINAL, T, f, np.zeros(3), criterion="E")
    with pytest.raises(ValueError, match="noise"):
        ti.design_input(FIRST, NOMINAL, T, f, np.zeros(3), noise=0.0)
