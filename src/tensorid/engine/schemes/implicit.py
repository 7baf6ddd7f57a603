"""Diagonally implicit Runge-Kutta schemes (implicit-euler, sdirk2, sdirk3): L-stable,
for stiff models. Each stage equation is solved by Newton's method to round-off
(``NewtonStageSolver``); the augmented stages (S, T) are linear with the same matrix
I - γΔ F_x, so one solve per level makes their derivatives exact."""

from __future__ import annotations

from dataclasses import dataclass

import jax
import jax.numpy as jnp

from .status import Status
from .tableau import Field, _axpy, _check_tableau, _n_levels, _x


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

    def interval(self, f: Field, fs: Field, y, dt, carry, substeps: int | jax.Array):
        """Cover one sample interval with ``substeps`` equal implicit steps."""
        step, ds = dt / substeps, 1.0 / substeps
        solve = NewtonStageSolver(f, fs, self.newton_tol, self.max_newton)

        def sub(i, state):
            yy, ok = state
            y_next, ok_i = self.step(f, yy, step, i * ds, ds, solve)
            return y_next, ok & ok_i

        y, ok = jax.lax.fori_loop(0, substeps, sub, (y, jnp.bool_(True)))
        return y, carry, jnp.where(ok, 0, Status.NEWTON_FAILED.code).astype(jnp.int32)
