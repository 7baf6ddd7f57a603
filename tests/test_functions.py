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


# -- arguments: a number that is wrong raises one line naming the function and argument ----
@pytest.mark.parametrize(
    "call, words",
    [
        (lambda: fn.smooth_sign(0.1, -1e-3), "smooth_sign: eps = -0.001 must be > 0"),
        (lambda: fn.smooth_abs(0.1, 0.0), "smooth_abs: eps = 0.0 must be > 0"),
        (lambda: fn.smooth_max(0.1, 0.2, np.nan), "smooth_max: eps = nan must be finite"),
        (lambda: fn.smooth_min(0.1, 0.2, np.inf), "smooth_min: eps = inf must be finite"),
        (lambda: fn.safe_sqrt(0.1, np.array([1e-6, -1.0])), "safe_sqrt: eps = -1.0"),
        (lambda: fn.saturation(0.0, 1.0, -1.0), "saturation: lo = 1.0 > hi = -1.0"),
        (lambda: fn.saturation(0.0, -np.inf, 1.0), "saturation: lo = -inf must be finite"),
        (lambda: fn.dead_zone(0.0, -0.5), "dead_zone: width = -0.5 must be >= 0"),
        (lambda: fn.coulomb_friction(0.1, -3.0), "coulomb_friction: Fc = -3.0 must be >= 0"),
        (lambda: fn.coulomb_friction(0.1, 3.0, -1e-3), "coulomb_friction: eps"),
        (lambda: fn.stribeck_friction(0.1, 1.0, 2.0, 0.0), "stribeck_friction: vs = 0.0"),
        (lambda: fn.stribeck_friction(0.1, 1.0, -2.0, 1.0), "stribeck_friction: Fs = -2.0"),
        (lambda: fn.stribeck_friction(0.1, 1.0, 2.0, 1.0, delta=0.0), "delta = 0.0"),
    ],
)
def test_a_wrong_number_raises_one_line_naming_function_and_argument(call, words):
    with pytest.raises(ValueError, match="^[^\n]*$") as err:
        call()
    assert words in str(err.value)


def test_a_wrong_number_is_caught_at_trace_time_inside_jit():
    with pytest.raises(ValueError, match="smooth_sign: eps"):
        jax.jit(lambda x: fn.smooth_sign(x, -1e-3))(0.2)


@pytest.mark.parametrize(
    "f",
    [
        lambda e: fn.smooth_sign(0.0, e),
        lambda e: fn.smooth_abs(0.0, e),
        lambda e: fn.saturation(0.5, -0.5, 0.5, e),
        lambda e: fn.safe_sqrt(0.0, e),
        lambda e: fn.stribeck_friction(0.3, 1.0, 2.0, e),  # a traced Stribeck velocity
        lambda e: fn.stribeck_friction(0.0, 1.0, 2.0, e, delta=1.5),
    ],
)
def test_a_traced_scale_at_zero_keeps_value_and_derivatives_finite(f):
    # eps (or vs) as a model parameter cannot be checked; at 0 nothing may turn NaN
    for g in (f, jax.grad(f), jax.grad(jax.grad(f))):
        assert np.isfinite(float(jax.jit(g)(0.0)))


def test_a_traced_negative_eps_acts_by_its_magnitude_and_does_not_flip_the_sign():
    push = jax.jit(lambda e: fn.coulomb_friction(0.3, 2.0, e))(-0.1)
    assert float(push) == pytest.approx(float(fn.coulomb_friction(0.3, 2.0, 0.1)))


def test_a_traced_delta_takes_the_general_path():
    args = (0.02, 1.0, 2.0, 0.01, 0.0, 1e-4)
    traced = jax.jit(lambda d: fn.stribeck_friction(*args, d))(2.0)
    assert float(traced) == pytest.approx(float(fn.stribeck_friction(*args)), rel=1e-3)
