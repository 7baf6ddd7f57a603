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
