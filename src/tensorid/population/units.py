"""A fleet's units as arrays of one shape, and each unit's outputs as a function of its
parameters whose derivatives, of any order JAX asks, come from the engine's sweeps.

Units have their own time stamps and numbers of samples; they are padded to the
longest (the last sample repeated: a zero-length interval changes nothing; its mask
is 0) so that one compiled program, vmapped over units, serves them all.

``outputs(sweeps)`` is ŷ(θ) (P, S) with a custom derivative tower: its first
derivative is the first-order sensitivity sweep's ∂ŷ/∂θ (the transition matrices),
whose own derivative is the second-order sweep's ∂²ŷ/∂θ² (the transition tensors),
differentiated further by JAX's forward mode through that sweep where a third order is
asked for (the outer Hessian). No finite differences anywhere.
"""

from __future__ import annotations

import dataclasses
import weakref
from dataclasses import dataclass

import jax
import jax.numpy as jnp
import numpy as np

from ..engine.sweeping.second_order import output_tensors

# units per compiled call: a larger fleet runs in blocks of this size (the last padded
# with copies of its last unit), so one program serves every fleet size, and no call
# hands XLA's CPU runtime a batch of thousands (jaxlib 0.10.2 deadlocked there: the
# outer Hessian of 1,600 one-compartment units in one call never returned)
BLOCK = 256


@dataclass(frozen=True)
class Units:
    """The fleet's records padded to P samples: t (E, P), u (E, P, U), y (E, P, S),
    mask (E, P, S) 1 where a sample is observed, x0 (E, N); ``names`` the units' ids."""

    t: np.ndarray
    u: np.ndarray
    y: np.ndarray
    mask: np.ndarray
    x0: np.ndarray
    names: list[str]
    samples: np.ndarray  # (E,) each unit's own number of samples
    cens: np.ndarray | None = None  # (E, P, S) 1 below its limit (y holds it); None: none

    @classmethod
    def of(cls, problem, records=None) -> Units:
        """The Problem's records (or ``records`` in their place, one per unit)."""
        exps = problem.experiments if records is None else records
        grids = [problem.grid(e) for e in exps]  # a moving event's nodes: more than e.P
        P = max(te.size for te, _ in grids)
        S, U = problem.model.S, len(problem.model.inputs)
        t, u = np.zeros((len(exps), P)), np.zeros((len(exps), P, grids[0][1].shape[1]))
        y, mask = np.zeros((len(exps), P, S)), np.zeros((len(exps), P, S))
        dosing = problem.dosing
        for i, (e, (te, ue)) in enumerate(zip(exps, grids, strict=True)):
            n = te.size
            t[i, :n], t[i, n:] = te, e.t[-1]
            u[i, :n], u[i, n:, :U] = ue, ue[-1, :U]  # padding: the channels' no event
            if dosing is not None and dosing.moving:  # a fixed node at the record's end
                u[i, n:, -2:] = (-1.0, e.t[-1])
            y[i, : e.P], mask[i, : e.P] = e.y, 1.0 if e.mask is None else e.mask
        names = [e.name or str(i) for i, e in enumerate(exps)]
        samples = np.array([e.P for e in exps])
        cens = None
        if any(getattr(e, "censored", None) is not None for e in exps):
            cens = np.zeros_like(y)
            for i, e in enumerate(exps):
                if e.censored is not None:
                    cens[i, : e.P] = e.censored
        return cls(t, u, y, mask, np.asarray(problem.x0, float), names, samples, cens)

    def subset(self, index) -> Units:
        """These units at ``index`` alone (a worker's chunk)."""
        i = np.asarray(index)
        return dataclasses.replace(
            self, t=self.t[i], u=self.u[i], y=self.y[i], mask=self.mask[i], x0=self.x0[i],
            names=[self.names[k] for k in i], samples=self.samples[i],
            cens=None if self.cens is None else self.cens[i],
        )  # fmt: skip

    def arrays(self):
        return tuple(jnp.asarray(a) for a in (self.t, self.u, self.y, self.mask, self.x0))


_TOWERS: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


def outputs(sw):
    """ŷ(θ, x0, p, t, u, y, seen) (P, S) for the Sweeps ``sw`` (θ its free
    parameters), with the derivative tower described in the module docstring. Where a
    sample was not measured (``seen`` 0: a dose's row, a padded sample) ŷ is y and
    every derivative 0, at every level of the tower: an output that is not finite
    there (log c before the first dose) then adds nothing, in forward and reverse mode
    alike (a zero cotangent times a NaN derivative would be NaN). One per Sweeps, each
    sweep behind its own ``jax.jit``: JAX then traces a sweep once per process and
    argument shape, and every program that differentiates ŷ (the inner steps, the
    outer evaluation, the diagnostics) transforms that trace instead of tracing the
    sweep's Python again (the theophylline fit's traces, 1.6 s shorter)."""
    if sw in _TOWERS:
        return _TOWERS[sw]
    ref = weakref.ref(sw)  # (the tower, kept by sw's entry, must not keep sw alive)

    def measured(a, seen, fill=0.0):
        """a (P, S, K…) at the measured samples, ``fill`` elsewhere (a select)."""
        return jnp.where((seen > 0).reshape(seen.shape + (1,) * (a.ndim - seen.ndim)), a, fill)

    @jax.jit  # ŷ, ∂ŷ, ∂²ŷ in one sweep
    def tensors(theta, x0, p, t, u, y, seen):
        v, d1, d2 = output_tensors(ref(), theta, x0, p, t, u)
        return measured(v, seen, y), measured(d1, seen), measured(d2, seen)

    second = jax.jit(lambda *a: tensors(*a)[2])  # (P, S, K, K); the sweep traced once

    @jax.jit
    def first_sweep(theta, x0, p, t, u, y, seen):  # (P, S, K)
        return measured(ref()._output_jacobian(theta, x0, p, t, u), seen)

    @jax.jit
    def simulated(theta, x0, p, t, u, y, seen):
        x0_, p_ = ref().expand(theta, x0, p)
        return measured(ref()._simulate(x0_, p_, t, u)[1], seen, y)

    @jax.custom_jvp
    def first(*a):
        return first_sweep(*a)

    @first.defjvp
    def _first_jvp(primals, tangents):
        return first(*primals), jnp.einsum("psjk,k->psj", second(*primals), tangents[0])

    @jax.custom_jvp
    def value(*a):
        return simulated(*a)

    @value.defjvp
    def _value_jvp(primals, tangents):
        return value(*primals), first(*primals) @ tangents[0]

    # taylor's first three terms, from one sweep
    value.tensors = tensors  # type: ignore[attr-defined]
    _TOWERS[sw] = value
    return value


def simulated_at(sweeps, theta, unit, steps):
    """ŷ (P, S) of ``unit`` (its arrays t, u, y, mask, x0, p) at its free parameters θ
    by ``sweeps``' scheme, a fixed-step one at ``steps`` substeps per interval, a
    number the program reads when it runs (Discretisation.at_run_time): one program,
    traced and compiled once, for every substeps (other schemes ignore ``steps``)."""
    d = sweeps.discretisation
    sw = (
        dataclasses.replace(sweeps, discretisation=d.at_run_time(steps))
        if d.fixed_steps
        else sweeps
    )
    x0, p = sw.expand(theta, unit[4], unit[5])
    return sw._simulate(x0, p, unit[0], unit[1])[1]


def blocked(program, args: tuple, units: tuple[int, ...]):
    """``program(*args)`` over the leading (unit) axis of the arguments at ``units``,
    in blocks of BLOCK (one call where the fleet is no larger); the outputs joined
    along that axis."""
    E = len(jax.tree_util.tree_leaves(args[units[0]])[0])
    if E <= BLOCK:
        return program(*args)
    parts = []
    for start in range(0, E, BLOCK):
        n = min(BLOCK, E - start)
        out = program(*block(args, units, start))
        parts.append(jax.tree_util.tree_map(lambda a, n=n: a[:n], out))
    return jax.tree_util.tree_map(lambda *a: jnp.concatenate(a), *parts)


def block(args: tuple, units: tuple[int, ...], start: int = 0) -> tuple:
    """The arguments of :func:`blocked`'s call for the block from unit ``start`` (the
    last block padded with copies of the last unit)."""
    E = len(jax.tree_util.tree_leaves(args[units[0]])[0])
    if E <= BLOCK:
        return args
    index = np.minimum(np.arange(start, start + BLOCK), E - 1)
    return tuple(
        jax.tree_util.tree_map(lambda a: a[index], a) if k in units else a
        for k, a in enumerate(args)
    )


def taylor(Y, a0, args: tuple, order: int):
    """ŷ as its Taylor polynomial of ``order`` about ``a0``: a ↦ Σ_k D^kŷ(a0)[a − a0]^k
    / k!, whose value and derivatives up to ``order`` at a0 are ŷ's own (exactly: the
    tower's terms), so that the outer gradient's and Hessian's nested derivatives,
    taken at a0, differentiate a polynomial instead of tracing the sweeps once per
    derivative and call site. Where ``order`` ≥ 2 the first three terms come from one
    second-order sweep (``Y.tensors``: the value and first-order sweeps are not run
    beside it); each higher order is a jacfwd over the one below with the lower terms
    as its auxiliary output (so no sweep is run twice): theophylline's outer Hessian
    compiled in 7 s, not 16, and with the one sweep traced in 1.3 s, not 1.45.

    Arguments:
        Y: ŷ(a, *args) (P, S), with the derivative tower of :func:`outputs`.
        a0: the expansion point (K,), constant (no derivative flows through it).
        args: Y's other arguments (x0, p, t, u, y, seen): data, not differentiated (the
            polynomial's coefficients are constants of its derivatives).
        order: the highest derivative the caller takes of ŷ.

    Returns:
        the polynomial, called as Y is (``args`` ignored: they are the ones given).
    """

    def deeper(fun):
        def with_next(a):
            def top(a):
                terms = fun(a)
                return terms[-1], terms

            D, terms = jax.jacfwd(top, has_aux=True)(a)
            return (*terms, D)

        return with_next

    tower = lambda a: (Y(a, *args),)  # noqa: E731
    have = 0
    if order >= 2 and hasattr(Y, "tensors"):  # the first three terms from one sweep
        tower, have = (lambda a: Y.tensors(a, *args)), 2  # noqa: E731
    for _ in range(order - have):
        tower = deeper(tower)
    polynomial = power_series(tower(a0))
    return lambda a, *_: polynomial(a - a0)


def power_series(terms: tuple):
    """d ↦ Σ_k terms[k][d]^k / k! (each term contracted with d over its last k axes),
    whose derivative is the same kind of sum one order lower: Σ_k terms[k+1][d]^k / k!
    contracted with the direction (a custom JVP). JAX's own rules would differentiate
    each product d·d·…·d term by term, k! ways at the k-th derivative; nested as the
    outer Hessian nests them, that made theophylline's evaluation 4.9 s of XLA
    compiling and 9 ms a call, against 2.7 s and 4 ms (values within 5e-14).

    Arguments:
        terms: (T_0, …, T_n), T_k of shape (…, K, …, K) with k trailing axes of K,
            symmetric in them (derivatives), the same leading shape.

    Returns:
        the series as a function of d (K,), differentiable in d to any order in any
        mode (not in the terms, which it closes over).
    """
    n = len(terms) - 1

    @jax.custom_jvp
    def series(d):
        out, factorial = terms[0], 1.0
        for k in range(1, n + 1):
            factorial *= k
            term = terms[k]
            for _ in range(k):
                term = term @ d
            out = out + term / factorial
        return out

    @series.defjvp
    def _series_jvp(primals, tangents):
        (d,), (v,) = primals, tangents
        if n == 0:  # a constant
            return series(d), jnp.zeros_like(terms[0])
        return series(d), power_series(terms[1:])(d) @ v

    return series
