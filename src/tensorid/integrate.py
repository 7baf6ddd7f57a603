"""Fixed-step explicit Runge-Kutta schemes as data, and one routine that marches any
state (a pytree) across the sample grid.

Between samples t_h and t_{h+1} the interval is cut into ``substeps`` equal steps.
The input u(t) is known only at the samples, so a stage at fraction s of the
interval sees u_h + s (u_{h+1} - u_h) ("linear") or u_h ("zoh").

Because a Runge-Kutta map commutes with differentiation, marching the augmented
system (x, S, T) with the same scheme gives the exact first and second derivatives
of the discretised trajectory: the derivatives tensorid reports are those of the
cost it reports, not of an approximation to it.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import jax
import jax.numpy as jnp

from . import _config  # noqa: F401


@dataclass(frozen=True)
class ExplicitRungeKutta:
    """Butcher tableau of an explicit scheme: k_i = f(y + h Σ_{j<i} a_ij k_j, t + c_i h),
    y_next = y + h Σ b_i k_i."""

    name: str
    a: tuple[tuple[float, ...], ...]
    b: tuple[float, ...]
    c: tuple[float, ...]
    order: int


EULER = ExplicitRungeKutta("euler", ((),), (1.0,), (0.0,), 1)
HEUN = ExplicitRungeKutta("heun", ((), (1.0,)), (0.5, 0.5), (0.0, 1.0), 2)
RK4 = ExplicitRungeKutta(
    "rk4",
    ((), (0.5,), (0.0, 0.5), (0.0, 0.0, 1.0)),
    (1 / 6, 1 / 3, 1 / 3, 1 / 6),
    (0.0, 0.5, 0.5, 1.0),
    4,
)
RK38 = ExplicitRungeKutta(
    "rk38",
    ((), (1 / 3,), (-1 / 3, 1.0), (1.0, -1.0, 1.0)),
    (1 / 8, 3 / 8, 3 / 8, 1 / 8),
    (0.0, 1 / 3, 2 / 3, 1.0),
    4,
)
SCHEMES = {s.name: s for s in (EULER, HEUN, RK4, RK38)}
INTERPOLATIONS = ("linear", "zoh")


def get_scheme(scheme: str | ExplicitRungeKutta) -> ExplicitRungeKutta:
    if isinstance(scheme, ExplicitRungeKutta):
        return scheme
    try:
        return SCHEMES[scheme]
    except KeyError:
        raise ValueError(
            f"unknown integration scheme {scheme!r}; choose one of {sorted(SCHEMES)}"
        ) from None


def _axpy(y, h: float | jax.Array, terms):
    """y + h Σ coef·k over (coef, k) pairs, skipping zero coefficients at trace time."""
    terms = [(cf, k) for cf, k in terms if cf != 0.0]
    if not terms:
        return y

    def combine(y_leaf, *k_leaves):
        acc = terms[0][0] * k_leaves[0]
        for (cf, _), kl in zip(terms[1:], k_leaves[1:], strict=True):
            acc = acc + cf * kl
        return y_leaf + h * acc

    return jax.tree_util.tree_map(combine, y, *[k for _, k in terms])


def rk_step(scheme: ExplicitRungeKutta, f: Callable, y, h, s0, ds):
    """One step of size h from interval fraction s0; f(y, s) is the vector field at
    interval fraction s, and ds is the fraction covered by this step."""
    ks: list = []
    for i, ci in enumerate(scheme.c):
        yi = _axpy(y, h, zip(scheme.a[i], ks, strict=False))
        ks.append(f(yi, s0 + ci * ds))
    return _axpy(y, h, zip(scheme.b, ks, strict=True))


def input_at(u0: jax.Array, u1: jax.Array, s, interpolation: str) -> jax.Array:
    if interpolation == "zoh":
        return u0
    return u0 + s * (u1 - u0)


def march(
    field: Callable,
    observe: Callable,
    y0,
    acc0,
    t,
    u,
    obs,
    *,
    scheme: ExplicitRungeKutta,
    substeps: int,
    interpolation: str,
):
    """Integrate ``y' = field(y, u)`` over the sample grid ``t`` and fold every sample
    into an accumulator.

    ``observe(acc, y, obs_h) -> (acc, out_h)`` is called at t_0 and after each
    interval; ``obs`` is a pytree whose leaves have a leading sample axis.
    Returns the final accumulator and the stacked ``out_h`` (P leading).
    """
    first = jax.tree_util.tree_map(lambda a: a[0], obs)
    rest = jax.tree_util.tree_map(lambda a: a[1:], obs)
    acc, out0 = observe(acc0, y0, first)
    ds = 1.0 / substeps

    def interval(carry, data):
        y, acc = carry
        dt, ua, ub, obs_h = data
        h = dt / substeps

        def vf(yy, s):
            return field(yy, input_at(ua, ub, s, interpolation))

        def sub(i, yy):
            return rk_step(scheme, vf, yy, h, i * ds, ds)

        y = jax.lax.fori_loop(0, substeps, sub, y)
        acc, out = observe(acc, y, obs_h)
        return (y, acc), out

    (_, acc), outs = jax.lax.scan(interval, (y0, acc), (jnp.diff(t), u[:-1], u[1:], rest))
    outs = jax.tree_util.tree_map(lambda a, b: jnp.concatenate([a[None], b]), out0, outs)
    return acc, outs
