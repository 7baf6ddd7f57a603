"""Smooth replacements for functions whose derivatives break down at the edge of
their domain, for use inside models."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from . import _config  # noqa: F401

# -- argument checks ---------------------------------------------------------------------------
# These functions run inside traced model code. A Python or NumPy number (the usual eps,
# a literal limit) is checked at trace time and a mistake raises one ValueError naming the
# function and argument. A traced value (eps given as a model parameter) cannot be checked;
# a sharpness or scale is then used by magnitude and floored (_floor) so that neither the
# value nor its first two derivatives become NaN; traced limits are used as given.


class ArgumentError(ValueError):
    """A wrong argument of one of these functions: the model's author must fix the call."""


def _concrete(value):
    """value as a float NumPy array, or None where it is traced (only known at run time)."""
    if isinstance(value, jax.core.Tracer):
        return None
    try:
        return np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        return None


def _fail(func: str, name: str, value, need: str, fix: str):
    shown = value.item() if value.size == 1 else f"an array containing {value.ravel()[0]!r}"
    raise ArgumentError(f"{func}: {name} = {shown!r} must be {need}; {fix}")


def _finite(func: str, name: str, value):
    v = _concrete(value)
    if v is not None and not np.isfinite(v).all():
        bad = v[~np.isfinite(v)] if v.ndim else v
        _fail(func, name, np.asarray(bad), "finite", f"give {name} a finite number")
    return v


def _positive(func: str, name: str, value, fix: str):
    """A strictly positive scale (eps, a velocity scale): checked if concrete, else floored."""
    v = _finite(func, name, value)
    if v is None:
        return _floor(value)
    if (v <= 0).any():
        _fail(func, name, np.asarray(v[v <= 0] if v.ndim else v), "> 0", fix)
    return value


def _non_negative(func: str, name: str, value, fix: str):
    v = _finite(func, name, value)
    if v is not None and (v < 0).any():
        _fail(func, name, np.asarray(v[v < 0] if v.ndim else v), ">= 0", fix)
    return value


def _floor(value):
    """|value|, at least tiny**0.25 (1e-77 in float64): a traced scale that reaches 0 or turns
    negative keeps its meaning (a sharpness has no sign) and its square and reciprocal stay
    finite, so the derivatives do not turn NaN."""
    value = jnp.asarray(value)
    dtype = value.dtype if jnp.issubdtype(value.dtype, jnp.floating) else jnp.float64
    return jnp.maximum(jnp.abs(value), jnp.finfo(dtype).tiny ** 0.25)


_EPS_FIX = "eps is the width of the smooth corner in the units of x: pass a small positive value"


def safe_sqrt(x, eps: float = 1e-6):
    """√x for x > eps; below eps a smooth, bounded continuation that decays to 0.

    Below eps, with z = (x - eps) / eps, the value is √eps · exp(z/2 - z²/4): it
    matches √ in value, slope and curvature at eps (so the function is twice
    continuously differentiable and the exact Hessian stays meaningful), increases
    with x, and tends to 0 for negative x, so the outflow of an "empty" tank fades
    out instead of growing. jnp.sqrt gives NaN below 0 and an infinite slope at 0.
    Values above eps are exactly jnp.sqrt's. Check the simulated states to tell
    whether the model left its physical domain.
    """
    eps = _positive("safe_sqrt", "eps", eps, _EPS_FIX)
    x = jnp.asarray(x)
    inside = x > eps
    root = jnp.sqrt(jnp.where(inside, x, eps))  # the where keeps NaN out of the gradient
    z = jnp.where(inside, 0.0, (x - eps) / eps)
    tail = jnp.sqrt(eps) * jnp.exp(z / 2 - z * z / 4)
    return jnp.where(inside, root, tail)


# -- hard nonlinearities, made smooth on purpose ---------------------------------------------
# The exact Hessian needs models that are twice differentiable: a kink (|x|, max) or a
# jump (sign, Coulomb friction) makes the second derivative a delta that no sweep sees,
# and Newton steps across it go wrong. Each function below replaces the hard one by a
# smooth one whose error is bounded by its sharpness ``eps`` (in the units of x); make
# eps small against the values x takes in the record (a velocity's noise level, say),
# but not so small that the smooth corner falls between samples: the integrator steps
# over a corner narrower than one step as if it were hard.


def smooth_abs(x, eps: float = 1e-3):
    """|x| as √(x² + eps²).

    Error: 0 < smooth_abs(x) − |x| <= eps, largest (eps) at x = 0 and below
    eps²/(2|x|) elsewhere. Convex, infinitely differentiable.
    """
    eps = _positive("smooth_abs", "eps", eps, _EPS_FIX)
    x = jnp.asarray(x)
    return jnp.sqrt(x * x + eps * eps)


def smooth_sign(x, eps: float = 1e-3):
    """sign(x) as tanh(x / eps).

    Error: |smooth_sign(x) − sign(x)| <= 2·exp(−2|x|/eps), below 1e-3 for |x| > 3.8·eps
    (0 at x = 0, where sign is 0). Odd, increasing, infinitely differentiable.
    """
    eps = _positive("smooth_sign", "eps", eps, _EPS_FIX)
    return jnp.tanh(jnp.asarray(x) / eps)


def smooth_max(a, b, eps: float = 1e-3):
    """max(a, b) as (a + b + smooth_abs(a − b, eps)) / 2.

    Error: 0 < smooth_max − max <= eps/2, largest where a = b.
    """
    eps = _positive("smooth_max", "eps", eps, _EPS_FIX)
    return 0.5 * (a + b + smooth_abs(jnp.asarray(a) - b, eps))


def smooth_min(a, b, eps: float = 1e-3):
    """min(a, b) as (a + b − smooth_abs(a − b, eps)) / 2.

    Error: 0 < min − smooth_min <= eps/2, largest where a = b.
    """
    eps = _positive("smooth_min", "eps", eps, _EPS_FIX)
    return 0.5 * (a + b - smooth_abs(jnp.asarray(a) - b, eps))


def saturation(x, lo, hi, eps: float = 1e-3):
    """clip(x, lo, hi), smoothly: smooth_min(smooth_max(x, lo), hi).

    Error: |saturation − clip| <= eps/2 (the lower corner can only raise the value and
    the upper one only lower it, each by at most eps/2). Use for actuator limits and
    valve travel. lo <= hi, both finite (checked where they are numbers, not parameters).
    """
    _check_limits("saturation", "lo", lo, "hi", hi)
    eps = _positive("saturation", "eps", eps, _EPS_FIX)
    return _saturation(x, lo, hi, eps)


def _saturation(x, lo, hi, eps):
    return smooth_min(smooth_max(x, lo, eps), hi, eps)


def _check_limits(func: str, lo_name: str, lo, hi_name: str, hi):
    low, high = _finite(func, lo_name, lo), _finite(func, hi_name, hi)
    if low is not None and high is not None and (low > high).any():
        shown = f"{lo_name} = {float(low.max())!r} > {hi_name} = {float(high.min())!r}"
        raise ArgumentError(f"{func}: {shown}; give the lower limit first ({func}(x, lo, hi))")


def dead_zone(x, width, eps: float = 1e-3):
    """x − clip(x, −width, width), smoothly: 0 inside ±width, x ∓ width outside.

    Error: <= eps/2, as saturation's. Use for backlash-free play, valve overlap,
    a motor's threshold voltage. width >= 0 (checked where it is a number).
    """
    width = _non_negative("dead_zone", "width", width, "width is the half-width of the dead band")
    eps = _positive("dead_zone", "eps", eps, _EPS_FIX)
    return x - _saturation(x, -width, width, eps)


def coulomb_friction(v, Fc, eps: float = 1e-3):
    """Fc·sign(v) as Fc·smooth_sign(v, eps).

    Error: <= 2·|Fc|·exp(−2|v|/eps). eps is a velocity: below it the friction force is
    a steep viscous one (slope Fc/eps), so stiction (v = 0 held) is not modelled; pick
    eps well below the velocities the record moves at. Fc >= 0 (a negative one would push
    the motion instead of resisting it; checked where it is a number).
    """
    _non_negative("coulomb_friction", "Fc", Fc, "friction resists motion: give its magnitude")
    eps = _positive("coulomb_friction", "eps", eps, _EPS_FIX)
    return Fc * smooth_sign(v, eps)


def stribeck_friction(v, Fc, Fs, vs, Fv=0.0, eps: float = 1e-3, delta: float = 2.0):
    """(Fc + (Fs − Fc)·exp(−(|v|/vs)^delta))·sign(v) + Fv·v, smoothly.

    sign is smooth_sign; |v| is smooth_abs unless delta = 2 (the usual Gaussian
    Stribeck curve, where (v/vs)² needs no |v|).

    Error: <= 2·|Fs|·exp(−2|v|/eps) + (delta ≠ 2 only) |Fs − Fc|·delta·eps/vs, for
    delta >= 1, 0 < Fc <= Fs (the first term from sign, the second from |v|: the
    Stribeck term's slope in |v| is at most delta/vs). Fc, Fs, Fv >= 0, vs > 0, delta > 0
    (checked where they are numbers, not parameters).
    """
    f = "stribeck_friction"
    for name, value in (("Fc", Fc), ("Fs", Fs), ("Fv", Fv)):
        _non_negative(f, name, value, "friction resists motion: give its magnitude")
    vs = _positive(f, "vs", vs, "vs is the Stribeck velocity, where the break-away peak fades")
    delta_value = _finite(f, "delta", delta)
    if delta_value is not None and (delta_value <= 0).any():
        _fail(f, "delta", delta_value, "> 0", "delta is the Stribeck curve's exponent (often 2)")
    eps = _positive(f, "eps", eps, _EPS_FIX)
    v = jnp.asarray(v)
    gaussian = delta_value is not None and delta_value.size == 1 and delta_value.item() == 2.0
    s = (v / vs) ** 2 if gaussian else (smooth_abs(v, eps) / vs) ** delta
    return (Fc + (Fs - Fc) * jnp.exp(-s)) * smooth_sign(v, eps) + Fv * v
