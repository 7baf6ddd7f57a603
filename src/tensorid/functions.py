"""Smooth replacements for functions whose derivatives break down at the edge of
their domain, for use inside models."""

from __future__ import annotations

import jax.numpy as jnp

from . import _config  # noqa: F401


def safe_sqrt(x, eps: float = 1e-6):
    """√x for x > eps; below eps the second-order Taylor polynomial of √ at eps.

    Equal to jnp.sqrt wherever x > eps, twice continuously differentiable
    everywhere, and finite (with finite first and second derivatives) for x <= 0,
    where jnp.sqrt gives NaN and its derivative is infinite at 0. A fit whose states
    cross zero therefore keeps exact, finite derivatives; check the simulated states
    afterwards to tell whether the model left its physical domain.
    """
    x = jnp.asarray(x)
    inside = x > eps
    root = jnp.sqrt(jnp.where(inside, x, eps))  # the where keeps NaN out of the gradient
    s = jnp.sqrt(eps)
    dx = x - eps
    taylor = s + dx / (2 * s) - dx**2 / (8 * eps * s)
    return jnp.where(inside, root, taylor)
