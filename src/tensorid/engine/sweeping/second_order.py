"""The second-order sweep of :class:`~tensorid.engine.sweeps.Sweeps`: the state, its
first-order sensitivities dx and its second-order sensitivities d2x (packed pairs,
or one direction's d2x_v) marched together, with J, ∇J and ∇²J (or ∇²J v) summed
sample by sample (the equations are in sweeps.py).

The carried state's layout (``Layout``): for the explicit and discrete schemes and a
small state (at most FLAT_MAX numbers), one flat vector [x; dxᵀ; d2xᵀ] (row k of dxᵀ
is column k of dx). A Runge-Kutta stage of one flat vector compiles to fewer fused
loops than the tuple (x, dx, d2x) does, and a small sweep is bound by the number of
operations per step, not by arithmetic. Larger states, and the implicit and adaptive
schemes (whose Newton solves and error control act on x alone), keep the tuple.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import jax
import jax.numpy as jnp

from ..schemes.integrators import DiscreteMap, ExplicitRungeKutta
from .packing import pair_indices, quadratic_packed


def _weighted(obs_h, w):
    """(y_h, w_h): a segment sweep passes per-sample loss weights with the data,
    obs = (y, W), which zero the sample a segment shares with the next; a record with
    gaps passes {"y": y, "mask": (P, S)}, which zeroes the weights of what was not
    measured; otherwise w (2, S) holds for every sample."""
    if isinstance(obs_h, dict):
        return obs_h["y"], w * jnp.stack([obs_h["mask"], jnp.ones_like(obs_h["mask"])])
    return obs_h if isinstance(obs_h, tuple) else (obs_h, w)


def _residuals(loss, y, pis, w, masked):
    """The loss's residuals (P, S) at the predictions π; a record with gaps ({"y",
    "mask"}): 0 where nothing was measured (not the NaN of a non-finite π there), the
    others from π as the loss sees it (``masked``: the predictor's)."""
    if not isinstance(y, dict):
        return loss.residual(y, pis, w)
    seen = y["mask"] > 0
    pis = jax.vmap(masked)(pis, seen, y["y"])
    r = loss.residual(y["y"], pis, (w[0] * y["mask"], w[1]))
    return jnp.where(seen, r, 0.0)


def _observed(obs_h, w, pi, masked, reverse: bool = False):
    """(y_h, w_h, π) of a sample (see _weighted); for a record with gaps, π is y_h
    wherever nothing was measured, output by output (``masked``: the predictor's
    :meth:`~tensorid.engine.predictors.Predictor.masked`): a prediction that is not finite
    there (the model blows up after a record's last observation, or an output such
    as log x is NaN where x < 0 and only the other output was measured) then adds
    nothing to J, ∇J, ∇²J or the scores, where a zero weight times NaN was NaN. A
    select's derivatives are selects, so the sweeps' derivatives, carried forward in
    time, stay finite too.

    ``reverse``: for J differentiated in reverse mode (``Problem.jax_cost`` under
    jax.grad), where the select's zero cotangent still meets the output's own
    derivative (0 · ∞ of log x at x = 0): at a sample where nothing was measured
    (a dose's own row), the outputs are computed from (x, p) cut from the derivatives
    (the "double where"; a no-op compiled without them). A sample where one output
    was measured and another is not finite still meets it there: jax.jacfwd does not.
    """
    y_h, w_h = _weighted(obs_h, w)
    if not isinstance(obs_h, dict):
        return y_h, w_h, pi
    seen = obs_h["mask"] > 0
    if reverse:
        pi = functools.partial(_cut, pi, seen.any())
    return y_h, w_h, lambda x, p: masked(pi(x, p), seen, y_h)


def _cut(pi, any_seen, x, p):
    """π(x, p), with x and p cut from the derivatives where ``any_seen`` is False."""
    x, p = jax.tree.map(lambda a: jnp.where(any_seen, a, jax.lax.stop_gradient(a)), (x, p))
    return pi(x, p)


@dataclass(frozen=True)
class Layout:
    """How (x (N,), dxᵀ (K, N)[, d2xᵀ (L, N)]) are carried: one flat vector, or the
    tuple (x, dx (N, K)[, d2x (N, L)]) that implicit and adaptive schemes need.
    ``second``: whether d2x is carried (False: the first-order sweep)."""

    N: int
    K: int
    flat: bool
    second: bool = True

    def pack(self, x, dxT, d2T=None):
        parts = (x, dxT) if d2T is None else (x, dxT, d2T)
        if self.flat:
            return jnp.concatenate([a.reshape(-1) for a in parts])
        return (x, *(a.T for a in parts[1:]))

    def split(self, state):
        """(x, dxᵀ, d2xᵀ or None) of a carried state."""
        if not self.flat:
            return state[0], state[1].T, (state[2].T if self.second else None)
        N, nK = self.N, self.N * self.K
        d2T = state[N + nK :].reshape(-1, N) if self.second else None
        return state[:N], state[N : N + nK].reshape(self.K, N), d2T

    def tuple(self, state):
        """(x, dx (N, K)[, d2x (N, L)]): the end state as the segment sweeps return it."""
        x, dxT, d2T = self.split(state)
        return (x, dxT.T) if d2T is None else (x, dxT.T, d2T.T)


# The flat vector wins while the carried state is small, where the sweep is bound by
# the operations per step; beyond, its reshapes and gathers cost more than they save.
# Measured (one core, ms, tuple -> flat): (J, g, H) Silverbox (42 numbers) 5.7 -> 4.2,
# Lotka-Volterra (56) 3.5 -> 2.8, chain of 2 masses (84) 32 -> 45, Chebyshev K = 10
# (132) 37 -> 38, chain of 5 masses (780) 252 -> 294. One Sweeps' sweeps share the
# layout, chosen by the full Hessian's state, so that their trajectories x agree
# bit for bit (multiple shooting compares the two sweeps' end states).
FLAT_MAX = 64


def layout(sweeps, second: bool = True) -> Layout:
    """The layout of ``sweeps``' carried state (``second``: with d2x): flat for explicit
    and discrete schemes whose full second-order state has at most FLAT_MAX numbers."""
    N, K = sweeps._size, sweeps.K
    explicit = isinstance(sweeps.discretisation.scheme, ExplicitRungeKutta | DiscreteMap)
    return Layout(N, K, explicit and N * (1 + K + K * (K + 1) // 2) <= FLAT_MAX, second)


def _machinery(sw, x0, p, v=None):
    """What every second-order sweep of ``sw`` shares: the layout of the carried state,
    ``directions`` (the (a, b, c) of each carried column), ``pairs(fn, x, A, B, C)``
    (fn_z a and fn_zz[a, b] + fn_z c for every column, by one nested jvp), ``push``
    (a map's value and the sensitivities carried through it), the packed pairs
    (jj, kk) or None for a direction v, and the number of carried columns."""
    M, K = sw.model.M, sw.K
    Psel = sw.seeds()[1]
    # the parameter parts of the directions are constants (or Psel v): keeping them
    # apart from the state parts, rather than in z = (x, p), spares the compiled
    # sweep the concatenations, which costs ~30 % of its time on Silverbox
    if v is None:
        jj, kk = pair_indices(K)
        Ap, Bp = jnp.asarray(Psel[:, jj].T), jnp.asarray(Psel[:, kk].T)
        ncols = jj.size
    else:
        Ap, Bp = jnp.asarray(Psel.T), jnp.broadcast_to(jnp.asarray(Psel) @ v, (K, M))
        ncols = K
    lay = layout(sw)

    def directions(dxT, d2T):
        """(a, b, c) per carried column, a and b split into state and parameter parts:
        its d2x (or d2x_v) column obeys F_zz[a, b] + F_z c (c has no parameter part)."""
        if v is None:
            return (dxT[jj], Ap), (dxT[kk], Bp), d2T
        return (dxT, Ap), (jnp.broadcast_to(v @ dxT, dxT.shape), Bp), d2T

    def pairs(fn, x, A, B, Cc):
        """(fn_z a, fn_zz[a, b] + fn_z c) for every column, by one nested jvp."""

        def one(ax, ap, bx, bp, cx):
            def first(x_, p_, ax_):  # ap is a constant of the outer derivative
                return jax.jvp(fn, (x_, p_), (ax_, ap))[1]

            return jax.jvp(first, (x, p, ax), (bx, bp, cx))

        return jax.vmap(one)(*A, *B, Cc)

    def push(fn, state):
        """(fn, fn_z Z, fn_zz[Z, Z] + fn_z d2x) of z ↦ fn(z, p): the field's
        right-hand side, or a filter's update map."""
        x, dxT, d2T = lay.split(state)
        Fa, d2 = pairs(fn, x, *directions(dxT, d2T))
        # the first K columns of A are Z itself (diagonal pairs come first)
        return lay.pack(fn(x, p), Fa[:K], d2)

    return lay, directions, pairs, push, ((jj, kk) if v is None else None), ncols


def second_order(sw, theta, x0, p, t, u, y, w, v=None, end=False, both=False):
    """See :meth:`Sweeps._second_order`."""
    x0, p = sw._start(theta, x0, p)
    K = sw.K
    dx0 = sw.seeds()[0]
    lay, directions, pairs, push, packed, ncols = _machinery(sw, x0, p, v)

    def field(state, uu):
        # ẋ, d(dx)/dt = F_z Z, d(d2x)/dt = F_zz[Z,Z] + F_x d2x
        return push(sw._f(p, uu), state)

    def observe(acc, state, obs_h, u_h):
        J, g, H = acc[:3]
        x, dxT, d2T = lay.split(state)
        y_h, w_h, pi = _observed(obs_h, w, functools.partial(sw._pi, u_h=u_h), sw.predictor.masked)
        Ca, e2 = pairs(pi, x, *directions(dxT, d2T))
        D = Ca[:K]  # (K, outputs) = (C_z Z)ᵀ
        ell, l1, l2, gamma = sw.loss.terms(y_h, pi(x, p), w_h)

        def quadratic(c):
            return quadratic_packed(D, c, packed, v)

        curv = quadratic(l2)
        out = (J + ell, g + D @ l1, H + curv + e2 @ l1)
        if both:  # the Gauss-Newton part: the same term with the loss's own weights
            out = out + (acc[3] + (curv if sw.loss.squared else quadratic(gamma)),)
        return out, None

    state0 = lay.pack(x0, jnp.asarray(dx0.T), jnp.zeros((ncols, lay.N)))
    acc0 = (jnp.zeros(()), jnp.zeros(K), jnp.zeros(ncols))
    acc0 = acc0 + (jnp.zeros(ncols),) if both else acc0
    update = sw._update(push)
    acc, _, _ = sw._march(field, observe, state0, acc0, t, u, y, p, end, update, push=push)
    return (*acc[0], lay.tuple(acc[1])) if end else acc


def output_tensors(sw, theta, x0, p, t, u):
    """The simulated outputs and their first and second derivatives at every sample,
    ``(ŷ (P, S), ∂ŷ/∂θ (P, S, K), ∂²ŷ/∂θ² (P, S, K, K))``: the model alone (output
    error), from the transition matrices and tensors as the Hessian sweep makes them
    (C_z Z and C_zz[Z, Z] + C_x d2x per sample). A fleet's population fit builds each
    unit's inner Hessian and the derivatives of its marginal likelihood from these."""
    x0, p = sw._start(theta, x0, p)
    K = sw.K
    dx0 = sw.seeds()[0]
    lay, directions, pairs, push, (jj, kk), ncols = _machinery(sw, x0, p)
    m = sw.model

    def field(state, uu):
        return push(sw._rhs(uu), state)

    def observe(acc, state, _, u_h):
        x, dxT, d2T = lay.split(state)
        h = functools.partial(m.h, u=u_h)
        Ca, e2 = pairs(h, x, *directions(dxT, d2T))
        d2 = jnp.zeros((K, K, e2.shape[-1])).at[jj, kk].set(e2).at[kk, jj].set(e2)
        return acc, (h(x, p), Ca[:K].T, jnp.moveaxis(d2, -1, 0))

    state0 = lay.pack(x0, jnp.asarray(dx0.T), jnp.zeros((ncols, lay.N)))
    _, outs, _ = sw._march(field, observe, state0, 0.0, t, u, jnp.zeros(t.shape), p, push=push)
    return outs
