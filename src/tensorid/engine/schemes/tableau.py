"""The arithmetic every Runge-Kutta scheme shares: a Butcher tableau checked at
construction, stage sums over the stepped state, and the explicit stages. The stepped
state is the state vector x (N,) or a tuple (x, S, T) whose entries have N leading
rows (see :mod:`tensorid.engine.integrators`)."""

from __future__ import annotations

from collections.abc import Callable

import jax

# f(y, s): the (augmented) vector field at fraction s of the sample interval;
# fs(x, s): the model's own F, which implicit schemes need for F_x
Field = Callable


def _x(y):
    return y[0] if isinstance(y, tuple) else y


def _n_levels(y) -> int:
    return len(y) if isinstance(y, tuple) else 1


def _axpy(y, step, terms):
    """y + step Σ coef·k over (coef, k) pairs, skipping zero coefficients at trace time."""
    terms = [(cf, k) for cf, k in terms if cf != 0.0]
    if not terms:
        return y

    def combine(y_leaf, *k_leaves):
        acc = terms[0][0] * k_leaves[0]
        for (cf, _), kl in zip(terms[1:], k_leaves[1:], strict=True):
            acc = acc + cf * kl
        return y_leaf + step * acc

    return jax.tree_util.tree_map(combine, y, *[k for _, k in terms])


def _explicit_stages(a, c, f: Field, y, step, s0, ds) -> list:
    """The stage derivatives k_i of one explicit step of size ``step`` from fraction s0."""
    ks: list = []
    for row, ci in zip(a, c, strict=True):
        ks.append(f(_axpy(y, step, zip(row, ks, strict=False)), s0 + ci * ds))
    return ks


def _check_tableau(name, a, b, c, order, implicit: bool) -> None:
    """Reject a tableau whose shapes or consistency conditions are wrong, at
    construction: a typo in a coefficient would otherwise give a quietly wrong order."""
    s = len(b)
    if not (len(a) == s == len(c)) or s == 0:
        raise ValueError(f"scheme {name!r}: a, b and c need one entry per stage ({s})")
    for i, row in enumerate(a):
        want = i + 1 if implicit else i
        if len(row) > want or (implicit and len(row) != want):
            raise ValueError(
                f"scheme {name!r}: row {i} of a has {len(row)} entries; an "
                f"{'implicit' if implicit else 'explicit'} row {i} has {want}"
            )
        if implicit and row[i] == 0.0:
            raise ValueError(f"scheme {name!r}: the diagonal a[{i}][{i}] of an implicit row is 0")
        if abs(sum(row) - c[i]) > 1e-12:
            raise ValueError(
                f"scheme {name!r}: c[{i}] = {c[i]} but row {i} of a sums to {sum(row)}"
            )
    if abs(sum(b) - 1.0) > 1e-12:
        raise ValueError(f"scheme {name!r}: the weights b sum to {sum(b)}, not 1")
    if not (isinstance(order, int) and order >= 1):
        raise ValueError(f"scheme {name!r}: order must be a positive integer, got {order!r}")
