"""Steady-state doses (NONMEM's SS = 1): at such a dose every state is replaced by the
steady state of the dose repeated every II for ever, just before it is given,

    x_ss = Ψ(x_ss; p),   Ψ: one dosing cycle from the dose (a bolus: x + A(p) into its
                         state, then II of the model; an infusion: its rate for
                         amount/rate, then the rest of II),

which the dose's own event then follows. x_ss is found by Newton's method on
Ψ(x) − x from 0 with Ψ's exact Jacobian (jax.jacfwd); the sweeps push the
sensitivities through those iterations as through any jump, so at a converged x_ss
the derivatives are the implicit function's: exact. A linear model's cycle is affine
in x, and one iteration lands on x_ss; NEWTON iterations give a nonlinear one room.
Each part of the cycle is integrated by the record's scheme with CYCLE_STEPS times
its substeps (a cycle is longer than a sample interval).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

NEWTON = 6
CYCLE_STEPS = 8


def settle_map(sweeps):
    """``settle(x, p, uu)``: x where the sample's row ``uu`` holds no steady-state dose,
    else x_ss of the one it holds (its flag, target position, amount, rate and II
    follow the 4D channels: dosing.Dosing.channels); None where no record holds one."""
    from .dosing import maps

    dosing, model = sweeps.dosing, sweeps.model
    if dosing is None or not dosing.steady:
        return None
    U, D = dosing.inputs, len(dosing.targets)
    idx = np.array(dosing.targets, dtype=int)
    amount = maps(dosing)[3]
    scheme = sweeps.discretisation.scheme
    steps = CYCLE_STEPS * sweeps.discretisation.substeps

    def flow(x, p, uu, rate, span):
        def field(xx, _s):
            return model.f(xx, p, uu[:U]).at[idx].add(rate)

        return scheme.interval(field, field, x, span, span / steps, steps)[0]

    def cycle(x, p, uu):
        flag, d, a, r, ii = (uu[U + 4 * D + k] for k in range(5))
        ii = jnp.where(flag > 0, ii, 1.0)  # (no dose here: any cycle that contracts)
        which = (jnp.arange(D) == d).astype(x.dtype)
        infused = jnp.where(r > 0, a / jnp.where(r > 0, r, 1.0), 0.0)
        x = x.at[idx].add(amount(which * jnp.where(r > 0, 0.0, a), p, uu))
        x = flow(x, p, uu, amount(which * r, p, uu), infused)
        return flow(x, p, uu, jnp.zeros(D, x.dtype), ii - infused)

    def settle(x, p, uu):
        def gap(z):
            return cycle(z, p, uu) - z

        def solve():
            z = jnp.zeros_like(x)
            for _ in range(NEWTON):
                z = z - jnp.linalg.solve(jax.jacfwd(gap)(z), gap(z))
            return z

        return jax.lax.cond(uu[U + 4 * D] > 0, solve, lambda: x)

    return settle
