"""Runge-Kutta schemes: small classes that carry their Butcher tableau as data and
cover one sample interval with ``interval``.

Three kinds:

* ``ExplicitRungeKutta`` (euler, heun, rk4, rk38): ``substeps`` equal steps per
  sample interval.
* ``DiagonallyImplicitRungeKutta`` (implicit-euler, sdirk2, sdirk3): L-stable, for
  stiff models; each stage equation is solved by Newton's method to round-off
  (``NewtonStageSolver``).
* ``AdaptiveRungeKutta`` (bosh3, dopri5): an embedded explicit pair whose step size
  is chosen from a local error estimate against ``rtol``/``atol``
  (``StepSizeController``).

A Runge-Kutta map commutes with differentiation: differentiating the stage
equations of the scheme applied to x' = F(x) gives the same scheme applied to the
augmented system (x, S, T). So stepping (x, S, T) with the scheme gives the exact
first and second derivatives of the discretised trajectory, also for implicit
stages (whose augmented stage equations are linear in S and T with the same matrix
I - Δ γ F_x as the state's Newton iteration (Δ the step size)). For the adaptive schemes the step
sizes are chosen from the states alone and held fixed under differentiation, as in
CVODES and diffrax: the derivatives are those of the discretisation on the steps
taken.

The stepped state is either the state vector x (N,) or a tuple whose first entry is
x and whose other entries have N leading rows (S (N, K), T (N, K(K+1)/2)).
Each ``interval`` returns an integer failure code (``Status.code``) beside the
state, so that a failure is reported by the integrator itself.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import Protocol, runtime_checkable

import jax
import jax.numpy as jnp

from .. import _config  # noqa: F401
from .status import Status

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


@dataclass(frozen=True)
class ExplicitRungeKutta:
    """Butcher tableau of an explicit scheme: k_i = f(y + Δ Σ_{j<i} a_ij k_j, t + c_i Δ),
    y_next = y + Δ Σ b_i k_i, Δ the step size."""

    name: str
    a: tuple[tuple[float, ...], ...]
    b: tuple[float, ...]
    c: tuple[float, ...]
    order: int

    def __post_init__(self) -> None:
        _check_tableau(self.name, self.a, self.b, self.c, self.order, implicit=False)

    def step(self, f: Field, y, step, s0, ds):
        """One step of size ``step`` covering the fraction ds of the interval from s0."""
        ks = _explicit_stages(self.a, self.c, f, y, step, s0, ds)
        return _axpy(y, step, zip(self.b, ks, strict=True))

    def interval(self, f: Field, fs: Field, y, dt, carry, substeps: int):
        """Cover one sample interval of length dt with ``substeps`` equal steps;
        returns (y, carry, failure code)."""
        step, ds = dt / substeps, 1.0 / substeps
        y = jax.lax.fori_loop(0, substeps, lambda i, yy: self.step(f, yy, step, i * ds, ds), y)
        return y, carry, jnp.int32(0)


@dataclass(frozen=True)
class NewtonStageSolver:
    """Solve an implicit stage z = base + γΔ f(z, s) for the (augmented) value z.

    Newton on the states alone, with the matrix I - γΔ F_x, until two updates in a
    row are below ``tol`` relative to max|x| (the second brings every component to
    round-off). Each further level (S, then T) is linear in its own unknowns with
    that same matrix, so one sweep per level solves it exactly. Returns (z, ok); a
    stage that does not converge comes back as NaN, which a fit treats as a blow-up."""

    f: Field
    fs: Field
    tol: float
    max_iter: int

    def __call__(self, base, gamma_step, s):
        jac = jax.jacfwd(self.fs)
        x_base = _x(base)
        N = x_base.shape[0]
        eye = jnp.eye(N, dtype=x_base.dtype)

        def body(carry):
            x, it, nconv = carry
            dx = jnp.linalg.solve(
                eye - gamma_step * jac(x, s), x - x_base - gamma_step * self.fs(x, s)
            )
            x = x - dx
            small = jnp.max(jnp.abs(dx)) <= self.tol * jnp.max(jnp.abs(x))
            return x, it + 1, jnp.where(small, nconv + 1, 0)

        def cond(carry):
            _, it, nconv = carry
            return (nconv < 2) & (it < self.max_iter)

        x, _, nconv = jax.lax.while_loop(cond, body, (x_base, 0, 0))
        ok = (nconv >= 2) & jnp.all(jnp.isfinite(x))
        x = jnp.where(ok, x, jnp.nan)
        if _n_levels(base) == 1:
            return x, ok
        lu = jax.scipy.linalg.lu_factor(eye - gamma_step * jac(x, s))
        z = (x, *base[1:])
        for _ in range(_n_levels(base) - 1):
            r = jax.tree_util.tree_map(
                lambda zl, bl, fl: zl - bl - gamma_step * fl, z, base, self.f(z, s)
            )
            z = (x,) + tuple(
                zl - jax.scipy.linalg.lu_solve(lu, rl.reshape(N, -1)).reshape(rl.shape)
                for zl, rl in zip(z[1:], r[1:], strict=True)
            )
        return z, ok


@dataclass(frozen=True)
class DiagonallyImplicitRungeKutta:
    """Tableau of a diagonally implicit scheme: row i of ``a`` holds a_i1 ... a_ii, and
    stage i solves z_i = y + Δ Σ_{j<i} a_ij k_j + Δ a_ii f(z_i), k_i = f(z_i).

    ``newton_tol``: Newton stops after two updates of x below this, relative."""

    name: str
    a: tuple[tuple[float, ...], ...]
    b: tuple[float, ...]
    c: tuple[float, ...]
    order: int
    newton_tol: float = 1e-10
    max_newton: int = 30

    def __post_init__(self) -> None:
        _check_tableau(self.name, self.a, self.b, self.c, self.order, implicit=True)

    def step(self, f: Field, y, step, s0, ds, solve: NewtonStageSolver):
        """One step; returns (y_next, every stage converged)."""
        ks: list = []
        ok = jnp.bool_(True)
        for i, (row, ci) in enumerate(zip(self.a, self.c, strict=True)):
            base = _axpy(y, step, zip(row[:i], ks, strict=True))
            gamma_step = row[i] * step
            z, ok_i = solve(base, gamma_step, s0 + ci * ds)
            ok = ok & ok_i
            # (z - base)/(γΔ) equals f(z) at the solution and does not amplify the
            # Newton residual by the stiffness, unlike a fresh f(z).
            ks.append(jax.tree_util.tree_map(lambda zl, bl, g=gamma_step: (zl - bl) / g, z, base))
        return _axpy(y, step, zip(self.b, ks, strict=True)), ok

    def interval(self, f: Field, fs: Field, y, dt, carry, substeps: int):
        """Cover one sample interval with ``substeps`` equal implicit steps."""
        step, ds = dt / substeps, 1.0 / substeps
        solve = NewtonStageSolver(f, fs, self.newton_tol, self.max_newton)

        def sub(i, state):
            yy, ok = state
            y_next, ok_i = self.step(f, yy, step, i * ds, ds, solve)
            return y_next, ok & ok_i

        y, ok = jax.lax.fori_loop(0, substeps, sub, (y, jnp.bool_(True)))
        return y, carry, jnp.where(ok, 0, Status.NEWTON_FAILED.code).astype(jnp.int32)


@dataclass(frozen=True)
class StepSizeController:
    """Accept a step when the RMS of err / (atol + rtol max(|x|, |x_next|)) is at most
    1; the next step aims at 0.9 of the tolerance (the estimate is O(Δ^order)),
    changing by a factor between 0.2 and 5."""

    rtol: float
    atol: float
    order: int

    def error_norm(self, x0, x1, err):
        sc = self.atol + self.rtol * jnp.maximum(jnp.abs(x0), jnp.abs(x1))
        return jnp.sqrt(jnp.mean((err / sc) ** 2))

    def factor(self, en):
        f = jnp.clip(0.9 * jnp.where(en > 0, en, 1e-10) ** (-1.0 / self.order), 0.2, 5.0)
        return jnp.where(jnp.isfinite(en), f, 0.2)


@dataclass(frozen=True)
class AdaptiveRungeKutta:
    """An explicit pair: y_next = y + Δ Σ b_i k_i, error estimate Δ Σ (b_i - e_i) k_i
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

    def __post_init__(self) -> None:
        _check_tableau(self.name, self.a, self.b, self.c, self.order, implicit=False)
        if len(self.e) != len(self.b) or abs(sum(self.e) - 1.0) > 1e-12:
            raise ValueError(f"scheme {self.name!r}: e needs one weight per stage, summing to 1")

    @property
    def controller(self) -> StepSizeController:
        return StepSizeController(self.rtol, self.atol, self.order)

    def step(self, f: Field, y, step, s0, ds):
        """One trial step: (y_next, local error estimate of the states)."""
        ks = _explicit_stages(self.a, self.c, f, y, step, s0, ds)
        y1 = _axpy(y, step, zip(self.b, ks, strict=True))
        errs = [bi - ei for bi, ei in zip(self.b, self.e, strict=True)]
        err = _axpy(jnp.zeros_like(_x(y)), step, zip(errs, [_x(k) for k in ks], strict=True))
        return y1, err

    def interval(self, f: Field, fs: Field, y, dt, step0, substeps: int):
        """Cover one sample interval of length dt with error-controlled steps from the
        trial step ``step0`` (the carry); returns (y, next trial step, failure code). Step
        sizes come from the states only, through stop_gradient: they are the
        discretisation, not a function of θ to differentiate."""
        ctl = self.controller
        tiny = 1e-14 * dt

        def cond(c):
            _, s, step, n = c
            return (s < 1.0) & (n < self.max_steps) & (step > tiny)

        def body(c):
            y, s, step, n = c
            step = jnp.minimum(step, (1.0 - s) * dt)
            ds = step / dt
            y1, err = self.step(f, y, step, s, ds)
            en = jax.lax.stop_gradient(ctl.error_norm(_x(y), _x(y1), err))
            ok = (en <= 1.0) & jnp.all(jnp.isfinite(_x(y1)))
            step_next = jax.lax.stop_gradient(step * ctl.factor(en))
            y = jax.tree_util.tree_map(lambda a, b: jnp.where(ok, a, b), y1, y)
            # land exactly on the sample: the last accepted step ends at s = 1
            s = jnp.where(ok, jnp.where(step >= (1.0 - s) * dt, 1.0, s + ds), s)
            return y, jax.lax.stop_gradient(s), step_next, n + 1

        step0 = jax.lax.stop_gradient(step0)
        y, s, step, _ = jax.lax.while_loop(cond, body, (y, jnp.zeros_like(dt), step0, 0))
        code = jnp.where(
            step <= tiny,
            Status.STEP_UNDERFLOW.code,
            jnp.where(s < 1.0, Status.STEP_LIMIT.code, 0),
        ).astype(jnp.int32)
        y = jax.tree_util.tree_map(lambda a: jnp.where(code != 0, jnp.nan, a), y)
        return y, step, code


@dataclass(frozen=True)
class DiscreteMap:
    """A discrete-time model, x[k+1] = f(x[k], p, u[k]): one application of the map
    per sample interval, the input taken at the interval's start.

    The sweeps' augmented fields become maps too, and stay exact: for z = (x, p),
    ∂x[k+1]/∂θ = f_z Z and ∂²x[k+1]/∂θ² = f_zz[Z, Z] + f_x ∂²x[k]/∂θ², the same
    expressions that the continuous-time sweeps integrate (the chain rule of the map
    in place of the variational equations)."""

    name: str = "discrete"
    order: int = 1

    def interval(self, f: Field, fs: Field, y, dt, carry, substeps: int):
        return f(y, 0.0), carry, jnp.int32(0)


DISCRETE = DiscreteMap()


@runtime_checkable
class RungeKuttaScheme(Protocol):
    """What the march needs of a scheme: its name and order, and ``interval``, which
    covers one sample interval and returns (y, carry, failure code). The carry is
    the scheme's own state between intervals (the adaptive schemes' trial step)."""

    name: str
    order: int

    def interval(self, f: Field, fs: Field, y, dt, carry, substeps: int): ...


Scheme = ExplicitRungeKutta | DiagonallyImplicitRungeKutta | AdaptiveRungeKutta | DiscreteMap

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


RTOL_FLOOR = 100 * math.ulp(1.0)  # 2.2e-14: below it, steps chase round-off


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
    elif not isinstance(scheme, RungeKuttaScheme):
        raise TypeError(
            f"scheme must be a name or a scheme object (name, order, interval(...)), got "
            f"{type(scheme).__name__}"
        )
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
    if rtol < RTOL_FLOOR:
        raise ValueError(
            f"rtol={rtol:g} is below double-precision round-off; use rtol >= {RTOL_FLOOR:.3g} "
            "(100 machine epsilons, the floor MATLAB's solvers raise smaller values to)"
        )
    return replace(scheme, rtol=rtol, atol=atol)
