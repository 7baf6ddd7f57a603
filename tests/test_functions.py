import jax
import jax.numpy as jnp
import numpy as np

from tensorid.functions import safe_sqrt


def test_equals_sqrt_above_eps_and_is_twice_differentiable_at_eps():
    x = np.array([2e-6, 1e-3, 0.5, 9.0])
    np.testing.assert_array_equal(np.asarray(safe_sqrt(x)), np.sqrt(x))
    eps = 1e-6
    d1, d2 = jax.grad(safe_sqrt), jax.grad(jax.grad(safe_sqrt))
    for f, exact in ((safe_sqrt, np.sqrt(eps)), (d1, 0.5 / np.sqrt(eps)), (d2, -0.25 * eps**-1.5)):
        below, above = float(f(eps * (1 - 1e-9))), float(f(eps * (1 + 1e-9)))
        assert abs(below - exact) < 1e-6 * abs(exact)
        assert abs(above - exact) < 1e-6 * abs(exact)


def test_bounded_increasing_and_finite_below_zero():
    x = jnp.linspace(-1.0, 1e-6, 2001)
    s = np.asarray(safe_sqrt(x))
    assert np.isfinite(s).all() and (s >= 0).all() and (np.diff(s) >= 0).all()
    assert float(safe_sqrt(-1.0)) == 0.0
    assert np.isfinite(float(jax.grad(jax.grad(safe_sqrt))(-0.5)))
