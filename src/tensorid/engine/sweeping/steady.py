"""Steady-state doses (NONMEM's SS = 1): at such a dose every state is replaced by the
steady state of the dose repeated every II for ever, just before it is given,

    x_ss = Ψ(x_ss; p),   Ψ: one dosing cycle from the dose (a bolus: x + A(p) into its
                         state, then II of the model; an infusion: its rate for
                         amount/rate, then the rest of II),

which the dose's own event then follows. x_ss is found by Newton's method on
Ψ(x) − x from 0 with Ψ's exact Jacobian (forward mode) until a step is below TOL. A
linear model's cycle is affine in x, and one iteration lands on x_ss (a second
confirms it); NEWTON iterations give a nonlinear one room (Michaelis-Menten
elimination near saturation takes about 15 from 0), and a steady state not found in
them is NaN: the simulation fails and says where, never a wrong x_ss. Each part of the cycle is
integrated by the record's scheme with CYCLE_STEPS times its substeps (a cycle is
longer than a sample interval).

The derivatives are the implicit function's, by a custom JVP rule rather than
through the Newton steps:

    dx_ss = (I − Ψ_x)⁻¹ (Ψ_p dp + Ψ_u du),      Ψ_x, Ψ_p, Ψ_u at x_ss
                                               (du: the dose row's, where differentiated),

and the rule calls x_ss again, so that every order (the sweeps' second, a
population fit's third and fourth) is exact at a converged x_ss. Differentiated
through the steps instead, each order multiplied the program by the steps: a
24-subject study's FOCEI fit took 424 s from the command line, 43.8 s now
(benchmarks/bench_events.py, docs/events.md).

In a batch of units (vmap) lax.cond computes both branches, so Newton's iterations
and the cycle's loops take a number of steps read when they run: none at a row
without a steady-state dose, so that a batch spends nothing on them at the rows where
no unit holds one (a batched loop runs while one of its units needs it). Reverse mode
cannot differentiate a loop of a run-time length: jax.grad and jax.hessian (forward
over reverse) and any nesting of forward mode go through a steady state; reverse mode
over a first derivative (jax.jacrev of jax.jacfwd or of jax.grad) does not. With a
fixed number of steps in the rule's Jacobians it did, and the 24-subject study's
second process took 17 s rather than 6-8 (measured by hand): no fit differentiates in
that order.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np

from ..schemes.integrators import ExplicitRungeKutta

NEWTON = 50
TOL = 1e-13  # a Newton step this small relative to each state of x_ss: converged
# ... or below this one and no longer shrinking: converged to the cycle's rounding (a
# nonlinear cycle of thousands of steps, whose Ψ(z) − z is not known better); a last
# step above it: not converged
FLOOR = 1e-9
SMALL = 1e-8  # a state below this share of the largest is judged against that share
CYCLE_STEPS = 8


def settle_map(sweeps):
    """``settle(x, p, uu)``: x where the sample's row ``uu`` holds no steady-state dose,
    else x_ss of the one it holds (its flag, target position, amount, rate and II
    follow the 4D channels: dosing.Dosing.channels); None where no record holds one."""
    dosing = sweeps.dosing
    if dosing is None or not dosing.steady:
        return None
    scheme = sweeps.discretisation.scheme
    if not isinstance(getattr(scheme, "scheme", scheme), ExplicitRungeKutta):
        raise ValueError(
            f"steady-state doses take an explicit fixed-step scheme (rk4, rk38, heun, "
            f"euler), not {scheme.name!r}"
        )
    flag = dosing.inputs + 4 * len(dosing.targets)

    def dosed(uu):
        return uu[flag] > 0

    steady = _implicit(_cycle(sweeps, flag), dosed)

    def settle(x, p, uu):
        return jax.lax.cond(dosed(uu), lambda: steady(x, p, uu), lambda: x)

    return settle


def _cycle(sweeps, flag: int):
    """Ψ(x, p, uu): one dosing cycle of the steady-state dose at row uu (its channels
    from position ``flag`` on), each part integrated with CYCLE_STEPS times the
    substeps, both parts in one loop (one step in the program: each order of
    derivative a fit asks for carries the cycle again)."""
    from .dosing import add_at, maps

    dosing, model = sweeps.dosing, sweeps.model
    U, D = dosing.inputs, len(dosing.targets)
    idx = np.array(dosing.targets, dtype=int)
    amount = maps(dosing)[3]
    scheme = sweeps.discretisation.scheme
    # a population's substeps are read at run time (Discretisation.at_run_time)
    steps = CYCLE_STEPS * sweeps.discretisation.substeps * getattr(scheme, "substeps", 1)
    rk = getattr(scheme, "scheme", scheme)

    def cycle(x, p, uu):
        on, d, a, r, ii = (uu[flag + k] for k in range(5))
        # no dose at this row: no step (the row is the other branch's; a batch of units
        # runs its loops as long as one unit needs them: every row, were it not so)
        n = jnp.where(on > 0, steps, 0)
        which = (jnp.arange(D) == d).astype(x.dtype)
        infused = jnp.where(r > 0, a / jnp.where(r > 0, r, 1.0), 0.0)
        x = add_at(x, idx, amount(which * jnp.where(r > 0, 0.0, a), p, uu))
        rate = amount(which * r, p, uu)
        # traced once, not once per stage (as ExplicitRungeKutta.interval does)
        field = jax.jit(lambda xx, q: add_at(model.f(xx, p, uu[:U]), idx, q))

        def step(i, xx):  # n steps over the infusion at its rate, n over the rest of II
            first = i < n
            h = jnp.where(first, infused, ii - infused) / jnp.maximum(n, 1)
            q = jnp.where(first, rate, jnp.zeros_like(rate))
            return rk.step(lambda yy, _s: field(yy, q), xx, h, 0.0, 0.0)

        return jax.lax.fori_loop(0, 2 * n, step, x)

    return cycle


def _implicit(cycle, dosed):
    """``steady(x, p, uu)``: the fixed point of ``cycle`` by Newton's method, with the
    implicit function's derivatives (the module's docstring); ``dosed(uu)``: whether
    the row holds a steady-state dose (none: no step, and x_ss = 0)."""

    def jacobians(z, p, uu, params=True, inputs=False):
        """(Ψ(z), Ψ_z (N, N), Ψ_p (N, M), Ψ_u (N, row)), the last two with no column
        unless asked for: every column in one integration of the cycle (separate loops,
        differentiated again in every order a fit asks for, multiply the program)."""
        N, M, R = z.size, p.size if params else 0, uu.size if inputs else 0
        eye = jnp.eye(N + M + R, dtype=z.dtype)
        tp = eye[:, N : N + M] if params else jnp.zeros((N + M + R, p.size), z.dtype)

        def one(*tangents):  # (the inputs held fixed unless asked for)
            fn = cycle if inputs else lambda zz, pp: cycle(zz, pp, uu)
            return jax.jvp(fn, (z, p, uu)[: len(tangents)], tangents)

        tangents = (eye[:, :N], tp, eye[:, N + M :])[: 3 if inputs else 2]
        psi, rows = jax.vmap(one, out_axes=(None, 0))(*tangents)
        return psi, rows[:N].T, rows[N : N + M].T, rows[N + M :].T

    def gap_matrix(Jz, uu):
        """I − Ψ_z, or I at a row without a steady-state dose (whose cycle takes no step:
        I − Ψ_z = 0, and a solve's NaN in the branch a batch computes but does not take)."""
        eye = jnp.eye(Jz.shape[0], dtype=Jz.dtype)
        return jnp.where(dosed(uu), eye - Jz, eye)

    @jax.custom_jvp
    def steady(x, p, uu):
        """x_ss by Newton steps on Ψ(z) − z from 0 until a step moves it by less than
        TOL of its size, or less than FLOOR and no less than half the step before (at
        most NEWTON steps; none without a dose); NaN where it does not converge. x
        gives the shape only."""

        def step(state):
            z, i, size, _ = state
            psi, Jz, _, _ = jacobians(z, p, uu, params=False)
            dz = jnp.linalg.solve(gap_matrix(Jz, uu), psi - z)
            # each state's step against its own size (a drug's mg beside 5e9 cells/L
            # had "converged" at the cells' scale), above a floor of the largest's
            big = jnp.max(jnp.abs(z + dz))
            scale = jnp.maximum(jnp.abs(z + dz) + SMALL * big, jnp.finfo(z.dtype).tiny)
            return z + dz, i + 1, jnp.max(jnp.abs(dz) / scale), size

        def more(state):
            _, i, size, last = state
            floor = (size < FLOOR) & (size >= last / 2)  # steps no longer shrink: rounding's
            return (i < jnp.where(dosed(uu), NEWTON, 0)) & (size > TOL) & ~floor

        inf = jnp.asarray(jnp.inf, x.dtype)
        z, _, size, _ = jax.lax.while_loop(more, step, (jnp.zeros_like(x), 0, inf, inf))
        # not converged (no steady state: a dose rate above what the model can
        # eliminate; or none found in NEWTON steps): NaN, a failed simulation, never a
        # wrong steady state
        return jnp.where(dosed(uu) & (size > FLOOR), jnp.nan, z)

    @functools.partial(steady.defjvp, symbolic_zeros=True)
    def implicit(primals, tangents):
        # dx_ss = (I − Ψ_z)⁻¹ (Ψ_p dp + Ψ_u du) at x_ss (the module's docstring). Ψ_z
        # and Ψ_p do not depend on the tangents: one loop serves every direction a
        # sweep carries, and reverse mode can transpose the solve (its matrix known)
        x, p, uu = primals
        _, dp, du = (_dense(t) for t in tangents)
        z = steady(x, p, uu)
        if dp is None and du is None:  # x_ss does not depend on x
            return z, jnp.zeros_like(z)
        # the inputs' columns only where they are differentiated (no fit does)
        _, Jz, Jp, Ju = jacobians(z, p, uu, inputs=du is not None)
        b = jnp.zeros_like(z) if dp is None else Jp @ dp
        b = b if du is None else b + Ju @ du
        return z, jnp.linalg.solve(gap_matrix(Jz, uu), b)

    return steady


def _dense(t):
    """A tangent, or None for a symbolic zero (an argument nothing differentiates)."""
    return None if isinstance(t, jax.custom_derivatives.SymbolicZero) else t
