"""Events whose times depend on the parameters (an absorption lag, ``Problem(lags=
{"depot": "tlag"})``): *moving nodes* of a record's grid, so that the integration
grid is placed at the event and the derivatives are those of the problem posed.

A record's arrays hold its own P nodes (fixed: its samples and the events without a
lag) followed by one node per lagged bolus and two per lagged infusion (its start and
its end), each with its nominal time and its target (``node_arrays``). At every
evaluation the march (``march_moving``) places each node at its time for the
parameters at hand, T_n(p) = t_n + lag_d(p), orders the nodes by it (the order is
piecewise constant in p: its derivative is zero wherever it is defined), and
integrates on a unit grid σ ∈ [0, 1] per interval with

    dx/dσ = L_h(p) · F(x, p, u),    L_h(p) = T_{h+1}(p) − T_h(p)

which is the same Runge-Kutta map as on the interval of length L_h, written so that
the sweeps differentiate L_h with F: the transition matrices and tensors then carry
∂/∂(lag) exactly. The infusions' rates are summed in that order (+rate at a start,
−rate at an end). The outputs come back in the arrays' order (the record's own P
first). Inputs at a moving node are interpolated at its nominal time, so a lag is
exact for records whose inputs are constant (covariates), as clinical records' are.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from ..modelling.events import state_index, stopped


def node_arrays(dosing, e, u) -> tuple[np.ndarray, np.ndarray]:
    """(t, u with the channels): the record's P nodes, then the moving events' nodes;
    channels per node: bolus, rate increment, reset flag, reset value, modelled
    infusion's amount increment (D each), the node's kind (−1: a fixed node; d: the
    lag of target d; D + d: its lag and its duration) and its nominal time."""
    D, t = len(dosing.targets), e.t
    lagged = {d for d, _ in dosing.lags}
    pos = {s: i for i, s in enumerate(dosing.targets)}
    fixed = np.zeros((t.size, 5, D))
    rows: list[tuple] = []  # (time, kind, bolus, rate, modelled amount)
    ev = e.events
    for k in range(0 if ev is None else len(ev)):
        kind, h = ev.kind[k], int(np.searchsorted(t, ev.time[k]))
        if kind == "reset-all":
            fixed[h, 2, :], fixed[h, 3, :] = 1.0, 0.0
            continue
        s = state_index(ev.state[k], dosing.states)
        d = pos[s]
        if kind == "reset":
            fixed[h, 2, d], fixed[h, 3, d] = 1.0, ev.amount[k]
        elif kind in ("bolus", "impulse"):
            if s in lagged:
                rows.append((ev.time[k], d, ev.amount[k], 0.0, 0.0))
            else:
                if fixed[h, 0, d]:
                    dosing._summed(e, d, f"two doses into it at t = {t[h]:g}")
                fixed[h, 0, d] += ev.amount[k]
        elif "reset-all" in ev.kind and (kind == "modelled-infusion" or s in lagged):
            raise ValueError(
                f"record {e.name!r}: a reset of every state (EVID 3, 4) with an infusion "
                "whose times move with the parameters (a lag, a modelled duration) is not "
                "supported yet: it would not stop it"
            )
        elif kind == "modelled-infusion":  # its end at its (lagged) start + D(p)
            a = ev.amount[k]
            rows += [(ev.time[k], d, 0.0, 0.0, a), (ev.time[k], D + d, 0.0, 0.0, -a)]
        else:  # an infusion: +rate at its start, −rate at its end (on the grid: merge)
            end = ev.time[k] + ev.amount[k] / ev.rate[k]
            if s in lagged:
                rows += [(ev.time[k], d, 0.0, ev.rate[k], 0.0), (end, d, 0.0, -ev.rate[k], 0.0)]
                continue
            fixed[h, 1, d] += ev.rate[k]
            end = stopped(ev, k, end)  # a reset of every state stops it (EVID 3, 4)
            if end <= t[-1]:
                fixed[int(np.searchsorted(t, end)), 1, d] -= ev.rate[k]
    nodes = np.array(rows, dtype=float).reshape(-1, 5)
    moving = np.zeros((nodes.shape[0], 5, D))
    index, n = nodes[:, 1].astype(int) % max(D, 1), np.arange(nodes.shape[0])
    moving[n, 0, index], moving[n, 1, index] = nodes[:, 2], nodes[:, 3]
    moving[n, 4, index] = nodes[:, 4]
    times = np.concatenate([t, nodes[:, 0]])
    kind = np.concatenate([np.full(t.size, -1.0), nodes[:, 1]])
    ch = np.concatenate([fixed, moving]).reshape(times.size, 5 * D)
    ch = np.concatenate([ch, kind[:, None], times[:, None]], axis=1)
    U = u.shape[1]
    u_m = np.stack([np.interp(nodes[:, 0], t, u[:, k]) for k in range(U)], axis=1) if U else None
    uu = u if u_m is None else np.concatenate([u, u_m])
    if uu.shape[0] != times.size:  # no inputs
        uu = np.zeros((times.size, 0))
    return times, np.concatenate([uu, ch], axis=1)


def _shift(dosing, shifts, kind):
    """How far a node of ``kind`` moves: 0 (−1, a fixed node), its target's lag (d),
    or its lag and its infusion's duration (D + d); ``shifts`` = (lags, durations)."""
    D = len(dosing.targets)
    lag, duration = shifts
    d = jnp.clip(kind.astype(int) % D, 0, D - 1)
    return jnp.where(kind >= 0, lag[d] + jnp.where(kind >= D, duration[d], 0.0), 0.0)


def length(dosing, lags, p, uu):
    """L_h(p): the length of the interval whose row of the march's inputs is ``uu``
    (its ends' kinds and nominal times follow the 4D channels); ``lags(p, uu)`` the
    targets' lags (dosing.Dosing.functions)."""
    U, D = dosing.inputs, len(dosing.targets)
    ks, ns, ke, ne = (uu[U + 5 * D + i] for i in range(4))
    shifts = lags(p, uu)
    return (ne + _shift(dosing, shifts, ke)) - (ns + _shift(dosing, shifts, ks))


def march_moving(march, dosing, lags, p, t, u, obs, **kw):
    """``march`` over the nodes ordered by their times at ``p`` (see the module
    docstring; ``lags`` as for ``length``); the outputs in the arrays' order."""
    U, D = dosing.inputs, len(dosing.targets)
    kind, nominal = u[:, U + 5 * D], u[:, U + 5 * D + 1]
    order = jnp.argsort(nominal + _shift(dosing, lags(p, u[0]), kind), stable=True)
    us = u[order]
    for block in (1, 4):  # the rates and the modelled amounts running on each interval
        cols = slice(U + block * D, U + (block + 1) * D)
        us = us.at[:, cols].set(jnp.cumsum(us[:, cols], axis=0))
    ends = jnp.concatenate([us[1:, U + 5 * D :], us[-1:, U + 5 * D :]])
    u2 = jnp.concatenate([us, ends], axis=1)  # [.., kind, nominal, next kind, next nominal]
    obs2 = jax.tree_util.tree_map(lambda a: a[order], obs)
    grid = jnp.arange(u.shape[0], dtype=jnp.result_type(float))
    acc, outs, fail = march(t=grid, u=u2, obs=obs2, held=dosing.width, **kw)
    back = jnp.argsort(order)
    return acc, jax.tree_util.tree_map(lambda a: a[back], outs), fail
