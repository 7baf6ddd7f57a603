"""Uncertainty on a badly scaled problem (Silverbox: raw Hessian condition ~1e18)."""

import numpy as np
import pytest

import tensorid as ti
from tensorid import benchmarks
from tensorid.fitting.uncertainty import flat_directions


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
