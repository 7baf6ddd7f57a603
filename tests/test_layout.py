"""The sweeps' two layouts of the carried state (engine/second_order.py): one flat
vector for small explicit problems, the tuple (x, dx, d2x) otherwise. Both must give
the same J, ∇J, ∇²J, ∇²J v and end states."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from tensorid import benchmarks
from tensorid.engine import second_order
from tensorid.engine.sweeping.sweeps import Sweeps


def _fresh(sw) -> Sweeps:
    """An uncompiled copy of ``sw``'s structure (the layout is chosen when it traces)."""
    return Sweeps(sw.model, sw.free_states, sw.free_params, sw.discretisation, sw.loss)


def _sweep_all(sw, args, theta, v):
    th = jnp.asarray(theta)
    x0, p, t, u, y, w = args
    so = sw.second_order_both(th, x0, p, t, u, y, w)
    fo = sw.first_order(th, x0, p, t, u, y, w)
    hv = sw.hessp(th, jnp.asarray(v), x0, p, t, u, y, w)
    W = jnp.broadcast_to(w, (t.size,) + w.shape)
    y = y["y"] if isinstance(y, dict) else y  # a segment takes its weights W instead
    seg = sw._segment(th, x0, p, t, u, y, W)
    gn = sw._segment_gn(th, x0, p, t, u, y, W)
    return [*so, *fo, *hv, *seg[:3], *seg[3], *gn[:3], *gn[3]]


def test_silverbox_is_flat_and_a_chain_of_two_masses_is_not():
    small = benchmarks.silverbox_problem()._sweeps
    large = benchmarks.mass_chain_problem(2, samples=20)._sweeps
    assert second_order.layout(small).flat
    assert not second_order.layout(large).flat
    implicit = benchmarks.silverbox_problem(scheme="sdirk2")._sweeps
    assert not second_order.layout(implicit).flat


@pytest.mark.parametrize(
    "make",
    [
        benchmarks.silverbox_problem,
        # the same layout again (N = 2): the slow run keeps it
        pytest.param(benchmarks.two_tank_problem, marks=pytest.mark.slow),
    ],
)
def test_flat_and_tuple_layouts_give_the_same_derivatives(make, monkeypatch):
    prob = make()
    (t, u, y), sw = prob._arrays[0], prob._sweeps
    t, u, y = t[:200], u[:200], jax.tree.map(lambda a: a[:200], y)  # y with its mask
    args = (jnp.asarray(prob.x0[0]), jnp.asarray(prob.p0), t, u, y)
    args = (*args, jnp.asarray(prob.loss_weights))
    theta = prob.theta0 * 1.01
    v = np.linspace(1.0, 2.0, theta.size)
    assert second_order.layout(sw).flat
    flat = _sweep_all(_fresh(sw), args, theta, v)
    monkeypatch.setattr(second_order, "FLAT_MAX", 0)
    assert not second_order.layout(sw).flat
    tup = _sweep_all(_fresh(sw), args, theta, v)
    assert len(flat) == len(tup)
    for a, b in zip(flat, tup, strict=True):
        a, b = np.asarray(a), np.asarray(b)
        assert a.shape == b.shape
        np.testing.assert_allclose(a, b, rtol=1e-12, atol=1e-13 * (np.abs(b).max() + 1e-300))
