import jax
import jax.numpy as jnp
import numpy as np
import pytest

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


# -- the smooth replacements of hard nonlinearities: each within its stated bound ---------
from tensorid import functions as fn  # noqa: E402

X = np.linspace(-0.05, 0.05, 20001)
EPS = 2e-3


def _hard_and_bound():
    """(name, smooth values, hard values, bound per point) for every function."""
    a, Fc, Fs, vs, Fv = 0.3 * X[::-1], 20.0, 35.0, 0.01, 200.0
    sign = np.sign(X)
    out = [
        ("smooth_abs", fn.smooth_abs(X, EPS), np.abs(X), np.full(X.size, EPS)),
        ("smooth_sign", fn.smooth_sign(X, EPS), sign, 2 * np.exp(-2 * np.abs(X) / EPS)),
        ("smooth_max", fn.smooth_max(X, a, EPS), np.maximum(X, a), np.full(X.size, EPS / 2)),
        ("smooth_min", fn.smooth_min(X, a, EPS), np.minimum(X, a), np.full(X.size, EPS / 2)),
        ("saturation", fn.saturation(X, -0.02, 0.01, EPS), np.clip(X, -0.02, 0.01),
         np.full(X.size, EPS / 2)),
        ("dead_zone", fn.dead_zone(X, 0.015, EPS), X - np.clip(X, -0.015, 0.015),
         np.full(X.size, EPS / 2)),
        ("coulomb_friction", fn.coulomb_friction(X, Fc, EPS), Fc * sign,
         2 * Fc * np.exp(-2 * np.abs(X) / EPS)),
    ]  # fmt: skip
    for delta in (2.0, 1.0, 1.5):
        hard = (Fc + (Fs - Fc) * np.exp(-((np.abs(X) / vs) ** delta))) * sign + Fv * X
        bound = 2 * Fs * np.exp(-2 * np.abs(X) / EPS) + (
            0 if delta == 2 else (Fs - Fc) * delta * EPS / vs
        )
        smooth = fn.stribeck_friction(X, Fc, Fs, vs, Fv, EPS, delta)
        out.append((f"stribeck_friction delta={delta}", smooth, hard, bound))
    return out


CASES = _hard_and_bound()


@pytest.mark.parametrize("name, smooth, hard, bound", CASES, ids=[c[0] for c in CASES])
def test_smooth_functions_stay_within_their_stated_error(name, smooth, hard, bound):
    err = np.abs(np.asarray(smooth) - hard)
    assert (err <= bound * (1 + 1e-9) + 1e-14 * np.abs(hard).max()).all(), name
    # the bound is not vacuous: the error comes within a factor of 4 of it somewhere
    assert (err >= 0.25 * bound).any(), name


@pytest.mark.parametrize(
    "f",
    [
        lambda x: fn.smooth_abs(x, EPS),
        lambda x: fn.smooth_sign(x, EPS),
        lambda x: fn.smooth_max(x, 0.3 * x + 0.001, EPS),
        lambda x: fn.saturation(x, -0.02, 0.01, EPS),
        lambda x: fn.dead_zone(x, 0.015, EPS),
        lambda x: fn.stribeck_friction(x, 20.0, 35.0, 0.01, 200.0, EPS, 1.5),
    ],
)
def test_smooth_functions_have_finite_second_derivatives_at_their_corners(f):
    for x in (0.0, 0.01, -0.02, 0.015, -0.015, 1e-12):
        assert np.isfinite(float(jax.grad(jax.grad(f))(x)))
