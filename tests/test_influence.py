"""Data sensitivity dθ̂/dy: equal to refitting with one sample moved, and it points at
an outlier."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import SILVERBOX_P, silverbox_data, silverbox_model

import tensorid as ti

TIGHT = dict(gtol=1e-14, ftol=1e-16, xtol=1e-16)


@pytest.fixture(scope="module")
def record():
    e = silverbox_data(P=256, noise=1e-4)
    y = e.y.copy()
    y[100] += 5e-3  # an outlier, 50 noise levels off
    return ti.Experiment(e.t, e.u, y, name="rec")


@pytest.mark.slow  # compile-bound; keeps the default run under five minutes
def test_data_sensitivity_equals_a_refit_with_one_sample_moved(record):
    model = silverbox_model()
    res = ti.fit(ti.Problem(model, record, p0=SILVERBOX_P), **TIGHT)
    sens = res.data_sensitivity()
    assert sens.values[0].shape == (256, 1, 4)
    h = 1e-6
    for k in (50,):
        y = record.y.copy()
        y[k] += h
        moved = ti.fit(
            ti.Problem(model, ti.Experiment(record.t, record.u, y), p0=res.params), **TIGHT
        )
        fd = (moved.theta - res.theta) / h
        np.testing.assert_allclose(sens.values[0][k, 0], fd, rtol=1e-4, atol=1e-6 * abs(fd).max())


def test_the_sample_that_pulled_an_estimate_most_is_the_outlier(record):
    res = ti.fit(ti.Problem(silverbox_model(), record, p0=SILVERBOX_P))
    sens = res.data_sensitivity()
    for name in ("a", "b"):
        rec, k, output, _ = sens.most_influential(name, 1)[0]
        assert (rec, k, output) == ("rec", 100, "y")
    fig = sens.figure(["a", "b"])
    assert len(fig.axes) == 2
    # printed: one row per unknown naming that sample, not a dump of the arrays
    text = str(sens)
    assert "rec, y[100]" in text and text.count("\n") < 12
    assert repr(sens).startswith("DataSensitivity(") and len(repr(sens)) < 200
