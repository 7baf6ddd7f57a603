"""Issue 41's panel: the newest surface's corner cases, each a test that gives one
clear line or a correct result (the filter, robust losses, compare, the CLI's flags,
fit.json's counts, the docs' numbers)."""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np
import pytest

import tensorid as ti


def _decay():
    def rhs(x, p, u):
        return jnp.stack([-p[0] * x[0] + u[0]])

    model = ti.Model(
        rhs=rhs, output=lambda x, p: x[:1], states=["x"], params=["k"], inputs=["u"],
        outputs=["y"],
    )  # fmt: skip
    t = np.arange(400) * 0.01
    u = np.sin(3 * t) + 0.5 * np.sin(11 * t)
    y = ti.simulate(model, {"k": 2.0}, [0.0], ti.Experiment(t, u)).y
    y = y + 1e-3 * np.random.default_rng(1).standard_normal(y.shape)
    return model, ti.Experiment(t, u, y)


def _robust(scale, loss="huber"):
    model, data = _decay()
    return ti.Problem(model, data, p0={"k": 1.5}, x0=[0.0], loss=loss, loss_scale=scale)


# -- silently wrong: a robust loss's scale below what the data resolve -------------------


def test_huber_error_bars_keep_their_size_down_to_least_absolute_deviations():
    """The sandwich's scale cancels in the LAD limit: at c = 1e-6 σ the error bar is
    about LAD's (1.25× least squares'), not ∝ c (it was ~1e-4 of it)."""
    model, data = _decay()
    ls = ti.fit(ti.Problem(model, data, p0={"k": 1.5}, x0=[0.0]))
    se_ls = float(ls.uncertainty().stderr[0])
    tiny = ti.fit(_robust(1e-9))
    u = tiny.uncertainty()
    assert 0.8 < float(u.stderr[0]) / se_ls < 2.0
    assert any("below what these residuals resolve" in w for w in u.warnings)
    # a resolved scale keeps the exact Hessian's sandwich and says nothing
    mid = ti.fit(_robust(1.345e-3)).uncertainty()
    assert not any("resolve" in w for w in mid.warnings)
    assert 0.8 < float(mid.stderr[0]) / se_ls < 1.5


def test_cauchy_scale_below_resolution_has_no_error_bars_and_says_why():
    u = ti.fit(_robust(1e-9, "cauchy")).uncertainty()
    assert np.isnan(u.stderr).all()
    assert u.not_available.startswith("not available: the cauchy scale is below what")


@pytest.mark.parametrize(
    "scale, words",
    [(1e-300, "below what the data resolve"), (1e300, "too large to compute with")],
)
def test_a_scale_out_of_range_is_refused_before_any_work(scale, words):
    with pytest.raises(ValueError, match=words):
        _robust(scale)


def test_robust_fit_on_three_samples_names_the_sample_count():
    model, data = _decay()
    short = ti.Experiment(data.t[:3], data.u[:3], data.y[:3])
    with pytest.raises(ValueError, match="3 samples are too few to set the loss scale"):
        ti.Problem(model, short, p0={"k": 1.5}, x0=[0.0], loss="huber")
