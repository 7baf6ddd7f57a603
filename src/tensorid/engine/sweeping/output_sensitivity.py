"""The simulation's output sensitivities ∂ŷ_h/∂θ at every sample, for the error bars
that need each sample's share of the gradient (the sandwich covariance, data
sensitivity) and the experiment design's Fisher information. One first-order
sweep of the model alone (whatever the predictor), as the cost's gradient is made:
C_z Z with Z = ∂x/∂θ from the transition matrices, so the shares sum to that
gradient exactly. (Forward-mode differentiation of the simulation gives the same
numbers but traces several times slower, which a command-line fit waits for.)"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np


def output_jacobian(self, theta, x0, p, t, u):
    """∂ŷ/∂θ (P, S, K) of the simulation (the model alone, whatever the predictor):
    C_z Z at every sample, Z from the first-order sensitivity sweep (the same
    derivatives as the cost's gradient)."""
    x0, p = self.expand(theta, x0, p)
    m, nx = self.model, len(self.free_states)
    dx0 = np.zeros((m.N, self.K))
    dx0[list(self.free_states), list(range(nx))] = 1.0
    Pt = jnp.asarray(self.seeds()[1].T)

    def columns(fn, x, dx):  # (fn_z Z)ᵀ
        return jax.vmap(lambda sx, sp: jax.jvp(fn, (x, p), (sx, sp))[1])(dx.T, Pt)

    def own(x, uu):
        return self._rhs(uu)(x, p)

    def push(fn, state):  # (fn, fn_z Z) of z ↦ fn(z, p)
        return fn(state[0], p), columns(fn, *state).T

    def field(state, uu):
        return push(self._rhs(uu), state)

    def observe(acc, state, _, u_h):
        return acc, columns(functools.partial(m.h, u=u_h), *state).T

    state0 = (x0, jnp.asarray(dx0))
    zeros = jnp.zeros(t.shape)
    _, D, _ = self._march(field, observe, state0, 0.0, t, u, zeros, p, own=own, push=push)
    return D
