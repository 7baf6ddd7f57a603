"""Smooth replacements for functions whose derivatives break down at the edge of
their domain, for use inside models."""

from __future__ import annotations

import jax.numpy as jnp

from . import _config  # noqa: F401


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
    x = jnp.asarray(x)
    return jnp.sqrt(x * x + eps * eps)


def smooth_sign(x, eps: float = 1e-3):
    """sign(x) as tanh(x / eps).

    Error: |smooth_sign(x) − sign(x)| <= 2·exp(−2|x|/eps), below 1e-3 for |x| > 3.8·eps
    (0 at x = 0, where sign is 0). Odd, increasing, infinitely differentiable.
    """
    return jnp.tanh(jnp.asarray(x) / eps)


def smooth_max(a, b, eps: float = 1e-3):
    """max(a, b) as (a + b + smooth_abs(a − b, eps)) / 2.

    Error: 0 < smooth_max − max <= eps/2, largest where a = b.
    """
    return 0.5 * (a + b + smooth_abs(jnp.asarray(a) - b, eps))


def smooth_min(a, b, eps: float = 1e-3):
    """min(a, b) as (a + b − smooth_abs(a − b, eps)) / 2.

    Error: 0 < min − smooth_min <= eps/2, largest where a = b.
    """
    return 0.5 * (a + b - smooth_abs(jnp.asarray(a) - b, eps))


def saturation(x, lo, hi, eps: float = 1e-3):
    """clip(x, lo, hi), smoothly: smooth_min(smooth_max(x, lo), hi).

    Error: |saturation − clip| <= eps/2 (the lower corner can only raise the value and
    the upper one only lower it, each by at most eps/2). Use for actuator limits and
    valve travel.
    """
    return smooth_min(smooth_max(x, lo, eps), hi, eps)


def dead_zone(x, width, eps: float = 1e-3):
    """x − clip(x, −width, width), smoothly: 0 inside ±width, x ∓ width outside.

    Error: <= eps/2, as saturation's. Use for backlash-free play, valve overlap,
    a motor's threshold voltage.
    """
    return x - saturation(x, -width, width, eps)


def coulomb_friction(v, Fc, eps: float = 1e-3):
    """Fc·sign(v) as Fc·smooth_sign(v, eps).

    Error: <= 2·|Fc|·exp(−2|v|/eps). eps is a velocity: below it the friction force is
    a steep viscous one (slope Fc/eps), so stiction (v = 0 held) is not modelled; pick
    eps well below the velocities the record moves at.
    """
    return Fc * smooth_sign(v, eps)


def stribeck_friction(v, Fc, Fs, vs, Fv=0.0, eps: float = 1e-3, delta: float = 2.0):
    """(Fc + (Fs − Fc)·exp(−(|v|/vs)^delta))·sign(v) + Fv·v, smoothly.

    sign is smooth_sign; |v| is smooth_abs unless delta = 2 (the usual Gaussian
    Stribeck curve, where (v/vs)² needs no |v|).

    Error: <= 2·|Fs|·exp(−2|v|/eps) + (delta ≠ 2 only) |Fs − Fc|·delta·eps/vs, for
    delta >= 1, 0 < Fc <= Fs (the first term from sign, the second from |v|: the
    Stribeck term's slope in |v| is at most delta/vs).
    """
    v = jnp.asarray(v)
    s = (v / vs) ** 2 if delta == 2.0 else (smooth_abs(v, eps) / vs) ** delta
    return (Fc + (Fs - Fc) * jnp.exp(-s)) * smooth_sign(v, eps) + Fv * v
