"""Initial states given as expressions of a record's inputs and the parameters,
``x0 = {"depot": "Dose * Wt", "center": 0.0}``: each experiment's x0 evaluated at its
first sample (a dose given at t0, a unit's covariates), the way fleet and clinical
records state where each unit starts.

An expression may name the model's inputs (their value at the record's first sample)
and parameters (their start value). In a fleet's fit (individual or population
parameters) it may name estimated parameters too: ``moving`` gives the initial states
as a JAX function of the parameters, which the fleet's sweeps differentiate through
(every state's sensitivity seeded, then chained). Elsewhere a parameter it names must
stay fixed (the Problem refuses that combination, naming the parameter)."""

from __future__ import annotations

from collections.abc import Mapping

import jax.numpy as jnp
import numpy as np

from .equations import direct_function


def has_expressions(x0) -> bool:
    """Whether ``x0`` is a dict with at least one text value."""
    return isinstance(x0, Mapping) and any(isinstance(v, str) for v in x0.values())


def evaluate(model, experiments, x0: Mapping, p0: np.ndarray) -> tuple[np.ndarray, set[str]]:
    """((E, N) initial states, the parameter names the expressions use)."""
    unknown = [k for k in x0 if k not in model.states]
    if unknown:
        raise ValueError(
            f"x0 names unknown states {unknown}; the model's states are {list(model.states)}"
        )
    out = np.zeros((len(experiments), model.N))
    used: set[str] = set()
    for state, spec in x0.items():
        i = model.states.index(state)
        if not isinstance(spec, str):
            out[:, i] = _number(state, spec)
            continue
        fn, names = _function(model, state, spec, "numpy")
        used |= names & set(model.params)
        for e, exp in enumerate(experiments):
            u0 = np.asarray(exp.u, dtype=float)[0] if np.size(exp.u) else np.zeros(0)
            value = float(fn(*u0, *p0[: model.M]))
            if not np.isfinite(value):
                raise ValueError(
                    f"x0[{state!r}] = {spec!r} is not finite on record "
                    f"{exp.name or e!r} (its first sample's inputs {u0.tolist()})"
                )
            out[e, i] = value
    return out, used


def _function(model, state: str, spec: str, modules: str):
    """(fn(*inputs, *params), the names it uses) of x0[state]'s expression: as written
    where it is plain arithmetic (no SymPy import), else by SymPy, whose parser says what
    is wrong; a name that is neither an input nor a parameter is refused."""
    names = list(model.inputs) + list(model.params)
    direct = direct_function(spec, names, np if modules == "numpy" else jnp)
    if direct is not None:
        return direct
    import sympy as sp  # here: sympy costs 0.2-0.5 s to import

    from .equations import _parse

    symbols = {n: sp.Symbol(n) for n in names}
    expr = _parse(f"x0[{state!r}]", spec, symbols)
    free = sorted(str(s) for s in expr.free_symbols)
    stray = [n for n in free if n not in names]
    if stray:
        raise ValueError(
            f"x0[{state!r}] = {spec!r} names {stray}, which are neither inputs "
            f"{list(model.inputs)} nor parameters {list(model.params)} of the model"
        )
    return sp.lambdify([symbols[n] for n in names], expr, modules), set(free)


def moving(model, x0: Mapping):
    """The states whose expressions name parameters, as ``f(x0 (N,), u0 (U,), p (M,))
    -> x0 (N,)`` in JAX (the others as given); None where no expression names one."""
    parts = []
    for state, spec in x0.items():
        if not isinstance(spec, str):
            continue
        fn, names = _function(model, state, spec, "jax")
        if names & set(model.params):
            parts.append((model.states.index(state), fn))
    if not parts:
        return None
    U = len(model.inputs)

    def initial(x0_row, u0, p):
        args = [u0[k] for k in range(U)] + [p[k] for k in range(model.M)]
        for i, fn in parts:
            x0_row = x0_row.at[i].set(fn(*args) * 1.0)
        return x0_row

    return initial


def _number(state: str, v) -> float:
    try:
        value = float(v)
    except (TypeError, ValueError):
        raise TypeError(
            f"x0[{state!r}] must be a number or an expression such as 'Dose * Wt', got {v!r}"
        ) from None
    if not np.isfinite(value) or isinstance(v, bool):
        raise ValueError(f"x0[{state!r}] must be a finite number, got {v!r}")
    return value
