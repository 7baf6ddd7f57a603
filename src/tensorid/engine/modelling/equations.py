"""Models written as text equations, turned into the same JAX functions a
hand-written model has:

    model_from_equations(rhs={"y": "v", "v": "(u - d*v - a*y - b*y**3)/m"},
                         output={"y": "y"}, inputs=["u"])

States are the keys of ``rhs`` (in order), outputs the keys of ``output``, inputs
must be named, and every other symbol is a parameter (in alphabetical order, unless
``params`` gives the order).

Equations in plain arithmetic (+ − × / **, numbers, the declared names, pi and the
usual functions: sin, exp, sqrt, tanh, Abs, Min, Max, ...) with ``params`` given are
translated directly and evaluated as written (a few milliseconds); anything else goes
through SymPy, which costs 0.3-0.5 s to import and simplifies before it evaluates
(x/x is 1 there; sums may differ in the last digit). Both parse the text alike.
"""

from __future__ import annotations

import ast
import keyword
from collections.abc import Mapping, Sequence
from typing import TYPE_CHECKING

import jax.numpy as jnp

from .model import Model

if TYPE_CHECKING:
    import sympy as sp

# names SymPy would otherwise read as its own constants or functions
_LOCALS = ("beta", "gamma", "zeta", "lambda", "E", "I", "N", "O", "Q", "S")


def _parse(where: str, text: str, symbols: dict) -> sp.Expr:
    import sympy as sp  # here, not at the top: sympy costs 0.2-0.5 s to import

    if not isinstance(text, str | int | float):
        raise TypeError(f"{where} must be a string like 'a*x - b', got {type(text).__name__}")
    try:
        names = {n: sp.Symbol(n) for n in _LOCALS}
        expr = sp.sympify(str(text), locals={**names, **symbols})
    except (sp.SympifyError, SyntaxError, TypeError) as e:
        # SymPy's message spans lines; its last line says what was wrong
        why = [ln.strip() for ln in str(e).splitlines() if ln.strip()][-1:] or ["invalid"]
        fix = "write it as a Python expression such as 'a*x - b*u**2'"
        if "truth value of Relational" in why[0]:  # x if x > 0 else ..., and, or, max(...)
            fix = (
                "a condition on a state, input or parameter cannot be Python's if, and, "
                "or: write it with Piecewise((a*x, x > 0), (b*u, True)) or Heaviside(x)"
            )
        raise ValueError(f"cannot parse {where} = {text!r} ({why[0]}); {fix}") from None
    if not isinstance(expr, sp.Expr):
        raise ValueError(f"{where} = {text!r} is not an expression")
    return expr


def _known_functions(fn, exprs: list, keys: list[str]) -> None:
    """One line for a function the equations call that SymPy does not know and JAX's
    printer does not either (heaviside, arctan): it failed at the first call, as a
    NameError that spoke of jax.numpy and math. (log10, log1p, hypot ... print fine.)"""
    import builtins
    import inspect

    import sympy as sp

    # the functions the generated code calls by a bare name it does not have (those
    # it knows it calls qualified: jax.numpy.log10)
    tree = ast.parse(inspect.getsource(fn))
    called = {n.func.id for n in ast.walk(tree) if isinstance(n, ast.Call)
              and isinstance(n.func, ast.Name)}  # fmt: skip
    missing = called - set(fn.__globals__) - set(dir(builtins))
    for key, e in zip(keys, exprs, strict=True):
        calls = {str(f.func) for f in e.atoms(sp.core.function.AppliedUndef)}
        unknown = sorted(calls & missing)
        if unknown:
            raise ValueError(
                f"{key} = {str(e)!r} calls {', '.join(unknown)}, which text equations do "
                f"not know; they know {', '.join(sorted(_FUNCTIONS, key=str.lower))}, "
                "SymPy's functions by their names (Heaviside, Piecewise, floor, log10 ...), "
                "or write the model as a tensorid.Model with jax.numpy"
            )


def _names(what: str, names) -> list[str]:
    """A list of names; one name given as a string is one name, not its letters."""
    if isinstance(names, str):
        return [names]
    try:
        out = list(names)
    except TypeError:
        raise TypeError(f"{what} must be a list of names, got {names!r}") from None
    bad = [n for n in out if not isinstance(n, str)]
    if bad:
        raise TypeError(f"{what} must be a list of names (strings), got {bad!r} in it")
    return out


def _unknown_symbols(missing, rhs_e, out_e, states, output, inputs, params) -> str:
    """Say what an unknown symbol most likely is: a state without an equation (used in
    rhs), an output expression with a typo, or a parameter left out of ``params``."""

    def users(exprs, keys, n) -> list[str]:
        return [k for k, e in zip(keys, exprs, strict=True) if n in map(str, e.free_symbols)]

    lines = []
    for n in missing:
        in_rhs, in_out = users(rhs_e, states, n), users(out_e, list(output), n)
        where = ", ".join([f"rhs[{k!r}]" for k in in_rhs] + [f"output[{k!r}]" for k in in_out])
        lines.append(
            f"{n!r} (used in {where}) is not a state, input or parameter: if it is a state, "
            f"add its equation rhs[{n!r}] = '...'; if a typo, correct it "
            f"(states {states}, inputs {inputs}); if a parameter, add it to params {params}"
        )
    return "; ".join(lines)


def model_from_equations(
    rhs: Mapping[str, str],
    output: Mapping[str, str] | None = None,
    inputs: Sequence[str] = (),
    params: Sequence[str] | None = None,
    name: str = "model",
    input_delays: Mapping[str, float] | None = None,
    discrete: bool = False,
) -> Model:
    """A Model from text equations: ``rhs`` {state: "dx/dt expression"}, ``output``
    {output: "expression"} (default: every state), ``inputs`` the input names,
    ``input_delays`` {input: seconds} and ``discrete`` (rhs gives x[k+1]; see Model)."""
    if not isinstance(rhs, Mapping) or not rhs:
        raise TypeError("rhs must be a dict {state: 'expression for its derivative'}")
    if output is not None and not isinstance(output, Mapping):
        raise TypeError(
            f"output must be a dict {{output name: 'expression'}}, got {type(output).__name__}"
        )
    states = list(rhs)
    output = dict(output) if output is not None else {s: s for s in states}
    inputs = _names("inputs", inputs)
    fns = None if params is None else _direct(rhs, output, states, inputs, _names("params", params))
    if fns is None:
        fns = _with_sympy(rhs, output, states, inputs, params)
    f, h, params = fns
    return Model(
        rhs=f,
        output=h,
        states=states,
        params=params,
        inputs=inputs,
        outputs=list(output),
        name=name,
        input_delays=dict(input_delays) if input_delays else None,
        discrete=discrete,
    )


def _stacked(fn):
    """The model's function: the list of expressions ``fn`` gives, as one float array."""

    def stacked(*args):
        values = fn(*(list(a) for a in args))
        return jnp.stack([jnp.asarray(v, dtype=jnp.float64) * jnp.ones(()) for v in values])

    return stacked


def _with_sympy(rhs, output, states, inputs, params):
    """(f, h, params) by SymPy's parser and lambdify."""
    import sympy as sp  # here, not at the top: see _parse

    known = {n: sp.Symbol(n) for n in states + inputs}
    rhs_e = [_parse(f"rhs[{s!r}]", rhs[s], known) for s in states]
    out_e = [_parse(f"output[{o!r}]", output[o], known) for o in output]
    reads = any(str(v) in inputs for e in out_e for v in e.free_symbols)
    found: list[str] = []
    for e in rhs_e + out_e:
        for s in sorted(e.free_symbols, key=str):
            n = str(s)
            if n not in known and n not in found:
                found.append(n)
    if params is None:
        params = sorted(found)
    else:
        params = _names("params", params)
        missing = [n for n in found if n not in params]
        if missing:
            raise ValueError(
                _unknown_symbols(missing, rhs_e, out_e, states, output, inputs, params)
            )
    xs = [sp.Symbol(n) for n in states]
    ps = [sp.Symbol(n) for n in params]
    us = [sp.Symbol(n) for n in inputs]
    f_num = sp.lambdify([xs, ps, us], rhs_e, modules="jax")
    h_num = sp.lambdify([xs, ps, us] if reads else [xs, ps], out_e, modules="jax")
    _known_functions(f_num, rhs_e, [f"rhs[{s!r}]" for s in states])
    _known_functions(h_num, out_e, [f"output[{o!r}]" for o in output])
    f, h = _stacked(f_num), _stacked(h_num)
    f.equations = dict(zip(states, map(str, rhs_e), strict=True))  # type: ignore[attr-defined]
    h.equations = dict(zip(output, map(str, out_e), strict=True))  # type: ignore[attr-defined]
    h.reads_inputs = reads  # type: ignore[attr-defined]
    return f, h, params


# SymPy's function names (as sympify reads them) and the jax.numpy function of each
_FUNCTIONS = {
    **{n: n for n in ("sin", "cos", "tan", "sinh", "cosh", "tanh", "exp", "sqrt", "sign")},
    **{n: "arc" + n[1:] for n in ("asin", "acos", "atan", "asinh", "acosh", "atanh")},
    "atan2": "arctan2",
    "log": "log",
    "Abs": "abs",
    "abs": "abs",
    "Min": "minimum",
    "Max": "maximum",
}
_ARITY = {"atan2": (2, 2), "Min": (2, 99), "Max": (2, 99)}
_OPERATORS = (ast.Add, ast.Sub, ast.Mult, ast.Div, ast.Pow, ast.USub, ast.UAdd)


def _plain(node: ast.AST, names: set[str]) -> bool:
    """Whether the expression ``node`` is plain arithmetic on ``names``, numbers, pi
    and the functions above: then Python reads it as SymPy does."""
    if isinstance(node, ast.Expression):
        return _plain(node.body, names)
    if isinstance(node, ast.BinOp):
        return (
            isinstance(node.op, _OPERATORS)
            and _plain(node.left, names)
            and _plain(node.right, names)
        )
    if isinstance(node, ast.UnaryOp):
        return isinstance(node.op, _OPERATORS) and _plain(node.operand, names)
    if isinstance(node, ast.Constant):
        return type(node.value) in (int, float)
    if isinstance(node, ast.Name):
        return node.id in names or node.id == "pi"
    if isinstance(node, ast.Call) and isinstance(node.func, ast.Name):
        lo, hi = _ARITY.get(node.func.id, (1, 1))
        return (
            node.func.id in _FUNCTIONS
            and not node.keywords
            and lo <= len(node.args) <= hi
            and all(not isinstance(a, ast.Starred) and _plain(a, names) for a in node.args)
        )
    return False


class _ToJax(ast.NodeTransformer):
    """f(a, b) → _jnp.f(a, b) (Min/Max of several: nested pairs); pi → _jnp.pi; integer
    numbers → floats (10**20 is a float, as SymPy evaluates it), except exponents
    (x**3 stays an integer power, as SymPy prints it)."""

    def visit_Name(self, node):
        if node.id == "pi":
            return ast.copy_location(
                ast.Attribute(ast.Name("_jnp", ast.Load()), "pi", ast.Load()), node
            )
        return node

    def visit_Constant(self, node):
        return ast.copy_location(ast.Constant(float(node.value)), node)

    def visit_BinOp(self, node):
        node.left = self.visit(node.left)
        if not (isinstance(node.op, ast.Pow) and _integer(node.right)):
            node.right = self.visit(node.right)
        return node

    def visit_Call(self, node):
        self.generic_visit(node)
        fn = ast.Attribute(ast.Name("_jnp", ast.Load()), _FUNCTIONS[node.func.id], ast.Load())
        args = node.args
        while len(args) > 2:
            args = [ast.Call(fn, args[:2], []), *args[2:]]
        return ast.copy_location(ast.Call(fn, args, []), node)


def _integer(node) -> bool:
    """A literal integer exponent such as 3 or -1."""
    if isinstance(node, ast.UnaryOp) and isinstance(node.op, ast.USub | ast.UAdd):
        node = node.operand
    return isinstance(node, ast.Constant) and type(node.value) is int and abs(node.value) < 64


def direct_function(text, names: Sequence[str], module=jnp):
    """(fn(*values, in the order of ``names``) by ``module``'s functions (JAX's, or
    NumPy's for plain numbers), the names the text uses), or None where ``text`` is not
    plain arithmetic on ``names`` (then SymPy reads it, and says what is wrong). As
    ``_direct``: evaluated as written, without importing SymPy (a fleet's x0 = "Dose *
    Wt" had imported it, 0.35 s of a warm fit's 3.2 s)."""
    names = list(names)
    if len(set(names)) != len(names) or not all(_usable(n) for n in names):
        return None
    if not isinstance(text, str):
        return None
    try:
        tree = ast.parse(text.strip(), mode="eval")
        if not _plain(tree, set(names)):
            return None
        used = {n.id for n in ast.walk(tree) if isinstance(n, ast.Name) and n.id in names}
        body = ast.unparse(_ToJax().visit(tree))
        scope: dict = {"_jnp": module}
        code = f"def _fn({', '.join(names)}):\n    return {body}\n"
        exec(compile(code, "<tensorid expression>", "exec"), scope)  # only checked arithmetic
    except (SyntaxError, ValueError, RecursionError, MemoryError):  # SymPy will say
        return None
    return scope["_fn"], used


def _direct(rhs, output, states, inputs, params):
    """(f, h, params) from the text as written, or None where it is not plain arithmetic
    on the declared names (then SymPy reads it, and says what is wrong). The text is
    evaluated as written: SymPy simplifies first (x/x is 1 there, NaN at x = 0 here),
    and sums may differ in the last digit."""
    declared = states + inputs + params
    if len(set(declared)) != len(declared) or not all(_usable(n) for n in declared):
        return None
    try:
        trees = []
        for texts in (rhs, output):
            for text in texts.values():
                if not isinstance(text, str | int | float):
                    return None
                tree = ast.parse(str(text).strip(), mode="eval")
                if not _plain(tree, set(declared)):
                    return None  # SymPy reads it (and says what is wrong)
                trees.append(_ToJax().visit(tree))
        # an output that names an input reads the inputs at each sample: h(x, p, u)
        reads = any(
            isinstance(n, ast.Name) and n.id in inputs
            for t in trees[len(states) :]
            for n in ast.walk(t)
        )
        source = [ast.unparse(t) for t in trees]
        ns = len(states)

        def unpack(arg: str, names: list[str]) -> str:
            return f"    ({', '.join(names)},) = {arg}\n" if names else ""

        code = (
            "def f(_x, _p, _u):\n"
            + unpack("_x", states)
            + unpack("_p", params)
            + unpack("_u", inputs)
            + f"    return [{', '.join(source[:ns])}]\n"
            + ("def h(_x, _p, _u):\n" if reads else "def h(_x, _p):\n")
            + unpack("_x", states)
            + unpack("_p", params)
            + (unpack("_u", inputs) if reads else "")
            + f"    return [{', '.join(source[ns:])}]\n"
        )
        scope: dict = {"_jnp": jnp}
        exec(compile(code, "<tensorid equations>", "exec"), scope)  # only checked arithmetic
    except (SyntaxError, ValueError, RecursionError, MemoryError):  # SymPy will say
        return None
    f, h = _stacked(scope["f"]), _stacked(scope["h"])
    f.equations = {s: str(rhs[s]).strip() for s in states}  # type: ignore[attr-defined]
    h.equations = {o: str(output[o]).strip() for o in output}  # type: ignore[attr-defined]
    h.reads_inputs = reads  # type: ignore[attr-defined]
    return f, h, params


def _usable(name) -> bool:
    """A declared name the generated function can bind as it is."""
    return (
        isinstance(name, str)
        and name.isidentifier()
        and not keyword.iskeyword(name)
        and name not in _FUNCTIONS
        and name != "pi"
        and not name.startswith("_")
    )
