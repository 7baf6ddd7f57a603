import numpy as np
import pytest

import tensorid as ti


def test_gof_matches_its_definition_and_matlab_fit_percent():
    rng = np.random.default_rng(0)
    y = rng.standard_normal(200).cumsum()
    ys = y + 0.1 * rng.standard_normal(200)
    expected = 1 - np.linalg.norm(y - ys) / np.linalg.norm(y - y.mean())
    assert ti.gof(y, ys) == pytest.approx(expected, rel=1e-14)
    assert ti.gof(y, y) == 1.0
    assert ti.gof(y, np.full_like(y, y.mean())) == pytest.approx(0.0, abs=1e-14)
    assert ti.nrmse(y, ys) == pytest.approx(1 - expected, rel=1e-12)
    assert ti.rmse(y, ys) == pytest.approx(np.sqrt(np.mean((y - ys) ** 2)))


def test_metrics_per_output_column():
    y = np.stack([np.arange(10.0), np.arange(10.0) ** 2], axis=1)
    ys = y.copy()
    ys[:, 1] += 1.0
    g = ti.gof(y, ys)
    assert g.shape == (2,) and g[0] == 1.0 and g[1] < 1.0
    assert ti.rmse(y, ys)[1] == pytest.approx(1.0)


def test_non_finite_simulation_scores_minus_infinity_and_shapes_are_checked():
    y = np.arange(5.0)
    assert ti.gof(y, np.array([0, 1, np.nan, 3, 4.0])) == -np.inf
    with pytest.raises(ValueError, match="shape"):
        ti.gof(y, y[:4])


def test_a_constant_record_has_no_spread_even_where_its_mean_rounds():
    """The mean of 1,000 samples of 0.1 is not 0.1 to the last bit: that rounding
    (4e-16) was divided by, and a constant record scored GOF -1.4e15 and NRMSE
    1.4e15, printed as numbers. With no spread the scores are undefined (inf); an
    exact match still scores 1."""
    for c in (0.1, 0.3, 1.1):
        y = np.full(1000, c)
        assert ti.nrmse(y, y + 0.01) == np.inf and ti.gof(y, y + 0.01) == -np.inf
        assert ti.gof(y, y) == 1.0 and ti.nrmse(y, y) == 0.0
