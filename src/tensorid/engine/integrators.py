"""Runge-Kutta schemes as data, and one routine that marches any state (a pytree)
across the sample grid.

Three kinds of scheme:

* ``ExplicitRungeKutta`` (euler, heun, rk4, rk38): ``substeps`` equal steps per
  sample interval.
* ``DiagonallyImplicitRungeKutta`` (implicit-euler, sdirk2, sdirk3): L-stable, for
  stiff models; each stage equation is solved by Newton's method to round-off.
* ``AdaptiveRungeKutta`` (bosh3, dopri5): an embedded explicit pair whose step size
  is chosen from a local error estimate against ``rtol``/``atol``.

Between samples t_h and t_{h+1} the input u(t) is known only at the samples, so a
stage at fraction s of the interval sees u_h + s (u_{h+1} - u_h) ("linear") or u_h
("zoh").

A Runge-Kutta map commutes with differentiation: differentiating the stage
equations of the scheme applied to x' = F(x) gives the same scheme applied to the
augmented system (x, S, T). So marching (x, S, T) with the scheme gives the exact
first and second derivatives of the discretised trajectory, also for implicit
stages (whose augmented stage equations are linear in S and T with the same matrix
I - h γ F_x as the state's Newton iteration). For the adaptive schemes the step
sizes are chosen from the states alone and held fixed under differentiation, as in
CVODES and diffrax: the derivatives are those of the discretisation on the steps
taken.

The marched state is either the state vector x (N,) or a tuple whose first entry is
x and whose other entries have N leading rows (S (N, K), T (N, K(K+1)/2)).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, replace

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


@dataclass(frozen=True)
class DiagonallyImplicitRungeKutta:
    """Tableau of a diagonally implicit scheme: row i of ``a`` holds a_i1 ... a_ii, and
    stage i solves z_i = y + h Σ_{j<i} a_ij k_j + h a_ii f(z_i), k_i = f(z_i).

    ``newton_tol``: Newton stops after two updates of x below this, relative."""

    name: str
    a: tuple[tuple[float, ...], ...]
    b: tuple[float, ...]
    c: tuple[float, ...]
    order: int
    newton_tol: float = 1e-10
    max_newton: int = 30


@dataclass(frozen=True)
class AdaptiveRungeKutta:
    """An explicit pair: y_next = y + h Σ b_i k_i, error estimate h Σ (b_i - e_i) k_i
    with the embedded weights ``e`` (order ``order - 1``). A step is accepted when
    the RMS of err / (atol + rtol max(|x|, |x_next|)) over the states is at most 1;
    at most ``max_steps`` steps per sample interval."""

    name: str
    a: tuple[tuple[float, ...], ...]
    b: tuple[float, ...]
    c: tuple[float, ...]
    order: int
    e: tuple[float, ...]
    rtol: float = 1e-6
    atol: float = 1e-9
    max_steps: int = 10_000


Scheme = ExplicitRungeKutta | DiagonallyImplicitRungeKutta | AdaptiveRungeKutta

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

IMPLICIT_EULER = DiagonallyImplicitRungeKutta("implicit-euler", ((1.0,),), (1.0,), (1.0,), 1)
# Alexander (1977), SIAM J. Numer. Anal. 14(6): L-stable, stiffly accurate.
_G2 = 1.0 - 1.0 / math.sqrt(2.0)
SDIRK2 = DiagonallyImplicitRungeKutta(
    "sdirk2", ((_G2,), (1.0 - _G2, _G2)), (1.0 - _G2, _G2), (_G2, 1.0), 2
)
_G3 = 0.435866521508458999416019
_T3 = (1.0 + _G3) / 2.0
_B31 = -(6.0 * _G3**2 - 16.0 * _G3 + 1.0) / 4.0
_B32 = (6.0 * _G3**2 - 20.0 * _G3 + 5.0) / 4.0
SDIRK3 = DiagonallyImplicitRungeKutta(
    "sdirk3",
    ((_G3,), (_T3 - _G3, _G3), (_B31, _B32, _G3)),
    (_B31, _B32, _G3),
    (_G3, _T3, 1.0),
    3,
)

# Bogacki & Shampine (1989) 3(2); Dormand & Prince (1980) 5(4).
BOSH3 = AdaptiveRungeKutta(
    "bosh3",
    ((), (0.5,), (0.0, 0.75), (2 / 9, 1 / 3, 4 / 9)),
    (2 / 9, 1 / 3, 4 / 9, 0.0),
    (0.0, 0.5, 0.75, 1.0),
    3,
    e=(7 / 24, 1 / 4, 1 / 3, 1 / 8),
)
DOPRI5 = AdaptiveRungeKutta(
    "dopri5",
    (
        (),
        (1 / 5,),
        (3 / 40, 9 / 40),
        (44 / 45, -56 / 15, 32 / 9),
        (19372 / 6561, -25360 / 2187, 64448 / 6561, -212 / 729),
        (9017 / 3168, -355 / 33, 46732 / 5247, 49 / 176, -5103 / 18656),
        (35 / 384, 0.0, 500 / 1113, 125 / 192, -2187 / 6784, 11 / 84),
    ),
    (35 / 384, 0.0, 500 / 1113, 125 / 192, -2187 / 6784, 11 / 84, 0.0),
    (0.0, 1 / 5, 3 / 10, 4 / 5, 8 / 9, 1.0, 1.0),
    5,
    e=(5179 / 57600, 0.0, 7571 / 16695, 393 / 640, -92097 / 339200, 187 / 2100, 1 / 40),
)

SCHEMES: dict[str, Scheme] = {
    s.name: s for s in (EULER, HEUN, RK4, RK38, IMPLICIT_EULER, SDIRK2, SDIRK3, BOSH3, DOPRI5)
}
INTERPOLATIONS = ("linear", "zoh")


def get_scheme(
    scheme: str | Scheme, rtol: float | None = None, atol: float | None = None
) -> Scheme:
    """The scheme named ``scheme`` (or the one given), with error tolerances set for
    an adaptive one."""
    if isinstance(scheme, str):
        try:
            scheme = SCHEMES[scheme]
        except KeyError:
            raise ValueError(
                f"unknown integration scheme {scheme!r}; choose one of {sorted(SCHEMES)}"
            ) from None
    elif not isinstance(scheme, Scheme):
        raise TypeError(f"scheme must be a name or a tensorid scheme, got {type(scheme).__name__}")
    if rtol is None and atol is None:
        return scheme
    if not isinstance(scheme, AdaptiveRungeKutta):
        adaptive = sorted(n for n, s in SCHEMES.items() if isinstance(s, AdaptiveRungeKutta))
        raise ValueError(
            f"rtol/atol apply to the adaptive schemes {adaptive}; {scheme.name!r} takes a "
            "fixed number of substeps per sample (set substeps instead)"
        )
    rtol = scheme.rtol if rtol is None else float(rtol)
    atol = scheme.atol if atol is None else float(atol)
    if not (rtol > 0 and atol >= 0 and math.isfinite(rtol) and math.isfinite(atol)):
        raise ValueError(f"need rtol > 0 and atol >= 0, finite; got rtol={rtol}, atol={atol}")
    if rtol < 1e-13:
        raise ValueError(f"rtol={rtol:g} is below double-precision round-off; use rtol >= 1e-13")
    return replace(scheme, rtol=rtol, atol=atol)


# -- the state: x, or (x, S, T, ...) with N leading rows each --------------------------
def _x(y):
    return y[0] if isinstance(y, tuple) else y


def _n_levels(y) -> int:
    return len(y) if isinstance(y, tuple) else 1


def _axpy(y, h, terms):
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


def _stages(scheme, f: Callable, y, h, s0, ds, solve=None):
    """The stage derivatives k_i; ``solve(base, gamma_h, s)`` returns the stage value
    of an implicit stage."""
    ks: list = []
    for i, ci in enumerate(scheme.c):
        row = scheme.a[i]
        if isinstance(scheme, DiagonallyImplicitRungeKutta):
            base = _axpy(y, h, zip(row[:i], ks, strict=True))
            gh = row[i] * h
            z = solve(base, gh, s0 + ci * ds)
            # (z - base)/(γh) equals f(z) at the solution and does not amplify the
            # Newton residual by the stiffness, unlike a fresh f(z).
            ks.append(jax.tree_util.tree_map(lambda zl, bl, g=gh: (zl - bl) / g, z, base))
        else:
            ks.append(f(_axpy(y, h, zip(row, ks, strict=False)), s0 + ci * ds))
    return ks


def rk_step(scheme: Scheme, f: Callable, y, h, s0, ds, solve=None):
    """One step of size h from interval fraction s0; f(y, s) is the vector field at
    interval fraction s, ds the fraction this step covers, and ``solve`` the stage
    solver of an implicit scheme."""
    ks = _stages(scheme, f, y, h, s0, ds, solve)
    return _axpy(y, h, zip(scheme.b, ks, strict=True))


def _newton_solver(scheme: DiagonallyImplicitRungeKutta, f: Callable, fs: Callable):
    """Solve z = base + γh f(z, s) for the (augmented) stage value z.

    Newton on the states alone, with the matrix I - γh F_x, until two updates in a
    row are below ``newton_tol`` relative to max|x| (the second brings every
    component to round-off). Each further level (S, then T) is linear in its own
    unknowns with that same matrix, so one sweep per level solves it exactly. A
    stage whose iteration does not converge comes back as NaN, which the fit
    treats as a blow-up."""
    jac = jax.jacfwd(fs)

    def solve(base, gh, s):
        x_base = _x(base)
        N = x_base.shape[0]
        eye = jnp.eye(N, dtype=x_base.dtype)

        def body(carry):
            x, it, nconv = carry
            dx = jnp.linalg.solve(eye - gh * jac(x, s), x - x_base - gh * fs(x, s))
            x = x - dx
            small = jnp.max(jnp.abs(dx)) <= scheme.newton_tol * jnp.max(jnp.abs(x))
            return x, it + 1, jnp.where(small, nconv + 1, 0)

        def cond(carry):
            _, it, nconv = carry
            return (nconv < 2) & (it < scheme.max_newton)

        x, _, nconv = jax.lax.while_loop(cond, body, (x_base, 0, 0))
        x = jnp.where((nconv >= 2) & jnp.all(jnp.isfinite(x)), x, jnp.nan)
        if _n_levels(base) == 1:
            return x
        lu = jax.scipy.linalg.lu_factor(eye - gh * jac(x, s))
        z = (x, *base[1:])
        for _ in range(_n_levels(base) - 1):
            r = jax.tree_util.tree_map(lambda zl, bl, fl: zl - bl - gh * fl, z, base, f(z, s))
            z = (x,) + tuple(
                zl - jax.scipy.linalg.lu_solve(lu, rl.reshape(N, -1)).reshape(rl.shape)
                for zl, rl in zip(z[1:], r[1:], strict=True)
            )
        return z

    return solve


def _error_norm(scheme: AdaptiveRungeKutta, x0, x1, err):
    sc = scheme.atol + scheme.rtol * jnp.maximum(jnp.abs(x0), jnp.abs(x1))
    return jnp.sqrt(jnp.mean((err / sc) ** 2))


def _adaptive_interval(scheme: AdaptiveRungeKutta, f: Callable, y, dt, h0):
    """Cover one sample interval of length dt with error-controlled steps from a
    first trial step h0; returns (y, the next trial step). Step sizes come from the
    states only, through stop_gradient: they are the discretisation, not a function
    of θ to differentiate."""

    def cond(c):
        _, s, _, n = c
        return (s < 1.0) & (n < scheme.max_steps)

    def body(c):
        y, s, h, n = c
        h = jnp.minimum(h, (1.0 - s) * dt)
        ds = h / dt
        ks = _stages(scheme, f, y, h, s, ds)
        y1 = _axpy(y, h, zip(scheme.b, ks, strict=True))
        errs = [bi - ei for bi, ei in zip(scheme.b, scheme.e, strict=True)]
        err = _axpy(jnp.zeros_like(_x(y)), h, zip(errs, [_x(k) for k in ks], strict=True))
        en = jax.lax.stop_gradient(_error_norm(scheme, _x(y), _x(y1), err))
        ok = (en <= 1.0) & jnp.all(jnp.isfinite(_x(y1)))
        # the estimate is O(h^order): aim at 0.9 of the tolerance next time
        factor = jnp.clip(0.9 * jnp.where(en > 0, en, 1e-10) ** (-1.0 / scheme.order), 0.2, 5.0)
        factor = jnp.where(jnp.isfinite(en), factor, 0.2)
        h_next = jax.lax.stop_gradient(h * factor)
        y = jax.tree_util.tree_map(lambda a, b: jnp.where(ok, a, b), y1, y)
        # land exactly on the sample: the last accepted step ends at s = 1
        s = jnp.where(ok, jnp.where(h >= (1.0 - s) * dt, 1.0, s + ds), s)
        return y, jax.lax.stop_gradient(s), h_next, n + 1

    h0 = jax.lax.stop_gradient(h0)
    y, s, h, _ = jax.lax.while_loop(cond, body, (y, jnp.zeros_like(dt), h0, 0))
    failed = (s < 1.0) | (h <= 1e-14 * dt)
    y = jax.tree_util.tree_map(lambda a: jnp.where(failed, jnp.nan, a), y)
    return y, h


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
    scheme: Scheme,
    substeps: int,
    interpolation: str,
    state_field: Callable | None = None,
):
    """Integrate ``y' = field(y, u)`` over the sample grid ``t`` and fold every sample
    into an accumulator.

    ``observe(acc, y, obs_h) -> (acc, out_h)`` is called at t_0 and after each
    interval; ``obs`` is a pytree whose leaves have a leading sample axis.
    ``state_field(x, u)`` is the model's own F, needed by implicit schemes (for
    F_x) when ``y`` is augmented. For adaptive schemes ``substeps`` sets the first
    trial step, dt/substeps.
    Returns the final accumulator and the stacked ``out_h`` (P leading).
    """
    state_field = field if state_field is None else state_field
    first = jax.tree_util.tree_map(lambda a: a[0], obs)
    rest = jax.tree_util.tree_map(lambda a: a[1:], obs)
    acc, out0 = observe(acc0, y0, first)
    ds = 1.0 / substeps

    def interval(carry, data):
        y, h_trial, acc = carry
        dt, ua, ub, obs_h = data

        def vf(yy, s):
            return field(yy, input_at(ua, ub, s, interpolation))

        if isinstance(scheme, AdaptiveRungeKutta):
            y, h_trial = _adaptive_interval(scheme, vf, y, dt, h_trial)
        else:
            h = dt / substeps
            solve = None
            if isinstance(scheme, DiagonallyImplicitRungeKutta):

                def fs(x, s):
                    return state_field(x, input_at(ua, ub, s, interpolation))

                solve = _newton_solver(scheme, vf, fs)

            def sub(i, yy):
                return rk_step(scheme, vf, yy, h, i * ds, ds, solve)

            y = jax.lax.fori_loop(0, substeps, sub, y)
        acc, out = observe(acc, y, obs_h)
        return (y, h_trial, acc), out

    h_first = (t[1] - t[0]) / substeps if t.shape[0] > 1 else jnp.ones(())
    (_, _, acc), outs = jax.lax.scan(
        interval, (y0, h_first, acc), (jnp.diff(t), u[:-1], u[1:], rest)
    )
    outs = jax.tree_util.tree_map(lambda a, b: jnp.concatenate([a[None], b]), out0, outs)
    return acc, outs
