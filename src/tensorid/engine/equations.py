"""Models written as text equations, parsed with SymPy into the same JAX functions a
hand-written model has:

    model_from_equations(rhs={"y": "v", "v": "(u - d*v - a*y - b*y**3)/m"},
                         output={"y": "y"}, inputs=["u"])

States are the keys of ``rhs`` (in order), outputs the keys of ``output``, inputs
must be named, and every other symbol is a parameter (in alphabetical order, unless
``params`` gives the order).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import jax.numpy as jnp
import sympy as sp

from .model import Model

# names SymPy would otherwise read as its own constants or functions
_LOCALS = {
    name: sp.Symbol(name)
    for name in ("beta", "gamma", "zeta", "lambda", "E", "I", "N", "O", "Q", "S")
}


def _parse(where: str, text: str, symbols: dict) -> sp.Expr:
    if not isinstance(text, str | int | float):
        raise TypeError(f"{where} must be a string like 'a*x - b', got {type(text).__name__}")
    try:
        expr = sp.sympify(str(text), locals={**_LOCALS, **symbols})
    except (sp.SympifyError, SyntaxError, TypeError) as e:
        raise ValueError(f"cannot parse {where} = {text!r}: {e}") from None
    if not isinstance(expr, sp.Expr):
        raise ValueError(f"{where} = {text!r} is not an expression")
    return expr


def model_from_equations(
    rhs: Mapping[str, str],
    output: Mapping[str, str] | None = None,
    inputs: Sequence[str] = (),
    params: Sequence[str] | None = None,
    name: str = "model",
) -> Model:
    """A Model from text equations: ``rhs`` {state: "dx/dt expression"}, ``output``
    {output: "expression"} (default: every state), ``inputs`` the input names."""
    if not isinstance(rhs, Mapping) or not rhs:
        raise TypeError("rhs must be a dict {state: 'expression for its derivative'}")
    states = list(rhs)
    output = dict(output) if output is not None else {s: s for s in states}
    inputs = list(inputs)
    known = {n: sp.Symbol(n) for n in states + inputs}
    rhs_e = [_parse(f"rhs[{s!r}]", rhs[s], known) for s in states]
    out_e = [_parse(f"output[{o!r}]", output[o], known) for o in output]
    for o, e in zip(output, out_e, strict=True):
        used_inputs = sorted(str(s) for s in e.free_symbols if str(s) in inputs)
        if used_inputs:
            raise ValueError(
                f"output[{o!r}] uses inputs {used_inputs}; outputs are C(x, p) "
                "and may not depend on inputs"
            )
    found: list[str] = []
    for e in rhs_e + out_e:
        for s in sorted(e.free_symbols, key=str):
            n = str(s)
            if n not in known and n not in found:
                found.append(n)
    if params is None:
        params = sorted(found)
    else:
        params = list(params)
        missing = [n for n in found if n not in params]
        if missing:
            raise ValueError(
                f"the equations use {missing}, which are neither states "
                f"{states}, inputs {inputs} nor params {params}"
            )
    xs = [sp.Symbol(n) for n in states]
    ps = [sp.Symbol(n) for n in params]
    us = [sp.Symbol(n) for n in inputs]
    f_num = sp.lambdify([xs, ps, us], rhs_e, modules="jax")
    h_num = sp.lambdify([xs, ps], out_e, modules="jax")

    def f(x, p, u):
        return jnp.stack(
            [
                jnp.asarray(v, dtype=jnp.float64) * jnp.ones(())
                for v in f_num(list(x), list(p), list(u))
            ]
        )

    def h(x, p):
        return jnp.stack(
            [jnp.asarray(v, dtype=jnp.float64) * jnp.ones(()) for v in h_num(list(x), list(p))]
        )

    f.equations = dict(zip(states, map(str, rhs_e), strict=True))  # type: ignore[attr-defined]
    h.equations = dict(zip(output, map(str, out_e), strict=True))  # type: ignore[attr-defined]
    return Model(
        rhs=f,
        output=h,
        states=states,
        params=params,
        inputs=inputs,
        outputs=list(output),
        name=name,
    )
