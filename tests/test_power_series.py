"""ŷ's Taylor polynomial (population/units.py): its custom derivative is the
polynomial's own, in every mode and nesting the outer evaluation uses, and its
derivatives at the expansion point are the tower's terms."""

from __future__ import annotations

import itertools
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from tensorid.population.units import power_series, taylor


def _terms(order: int, K: int = 3, lead=(2, 5), seed: int = 0) -> tuple:
    """Random terms T_k (lead, K, ..., K), each symmetric in its K axes (as derivatives
    are)."""
    rng = np.random.default_rng(seed)
    out = []
    for k in range(order + 1):
        T = rng.standard_normal((*lead, *(K,) * k))
        axes = list(range(len(lead), len(lead) + k))
        perms = list(itertools.permutations(axes))
        T = sum(np.transpose(T, (*range(len(lead)), *p)) for p in perms) / len(perms)
        out.append(jnp.asarray(T))
    return tuple(out)


def _plain(terms):
    """The same polynomial by einsum, differentiated by JAX's own rules."""
    letters = "abcdefgh"

    def f(d):
        out = terms[0]
        for k in range(1, len(terms)):
            sub = "xy" + letters[:k] + "," + ",".join(letters[:k]) + "->xy"
            out = out + jnp.einsum(sub, terms[k], *(d,) * k) / math.factorial(k)
        return out

    return f


@pytest.mark.parametrize("order", [1, 3, 4])
def test_its_derivatives_are_the_polynomials_own_in_every_mode(order):
    terms = _terms(order)
    mine, plain = power_series(terms), _plain(terms)
    d = jnp.array([0.3, -0.2, 0.5])
    scalar = lambda f: lambda d: jnp.sum(jnp.sin(f(d)))  # noqa: E731
    for transform in (
        lambda f: f,
        jax.jacfwd,
        jax.jacrev,
        lambda f: jax.jacfwd(jax.jacrev(f)),
        lambda f: jax.jacfwd(jax.jacfwd(jax.jacfwd(f))),
    ):
        # jitted: run eagerly, each of the nested transforms' operations compiled a program
        ours, theirs = jax.jit(transform(mine))(d), jax.jit(transform(plain))(d)
        np.testing.assert_allclose(ours, theirs, rtol=1e-12, atol=1e-12)
    # reverse over forward over reverse, of a scalar of it (as the outer gradient nests)
    nested = lambda f: jax.grad(lambda d: jnp.sum(jax.jacfwd(jax.grad(scalar(f)))(d)))  # noqa: E731
    np.testing.assert_allclose(
        jax.jit(nested(mine))(d), jax.jit(nested(plain))(d), rtol=1e-12, atol=1e-12
    )


def test_at_the_expansion_point_its_derivatives_are_the_towers_terms():
    """taylor of a function that is not a polynomial: value and derivatives up to the
    order at a0 are the function's own, the next one is not (zero)."""
    Y = lambda a, c: jnp.stack([jnp.exp(a[0] * a[1]) * c, jnp.sin(a[2] - a[0])])  # noqa: E731
    a0 = jnp.array([0.4, -0.7, 1.1])
    poly = taylor(Y, a0, (2.0,), 3)
    derivs = [lambda f: f, jax.jacfwd, lambda f: jax.jacfwd(jax.jacrev(f)),
              lambda f: jax.jacrev(jax.jacfwd(jax.jacfwd(f)))]  # fmt: skip
    for D in derivs:
        np.testing.assert_allclose(
            jax.jit(D(poly))(a0), jax.jit(D(lambda a: Y(a, 2.0)))(a0), rtol=1e-13
        )
    fourth = jax.jit(jax.jacfwd(jax.jacfwd(jax.jacfwd(jax.jacfwd(poly)))))(a0)
    assert np.all(np.asarray(fourth) == 0.0)
