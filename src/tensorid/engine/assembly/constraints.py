"""Inequality constraints between unknowns ("Fs >= Fc", "k <= 2*m"): read by a small
restricted parser (numbers, pi, + − × / **, the functions text equations know, and
the names of the parameters, or of a single record's free initial states), each
turned into c(θ) >= 0 with its exact Jacobian and Hessian from JAX; and, while a fit
keeps them (solve/constrained.py), their augmented-Lagrangian terms in J, ∇J, ∇²J.

For c >= 0 with multiplier estimate λ >= 0 and penalty μ > 0, J gains the
Powell-Hestenes-Rockafellar term ψ = (max(0, λ − μc)² − λ²) / (2μ), so that
∇ψ = −λ̂ ∇c and ∇²ψ = μ ∇c ∇cᵀ [λ − μc > 0] − λ̂ ∇²c with λ̂ = max(0, λ − μc): the
exact Hessian of the penalised cost is the Lagrangian's Hessian ∇²J − λ̂ ∇²c plus
μ ∇c ∇cᵀ on the constraints that bind. Where c >= λ/μ the term is 0: a constraint
that does not bind leaves the cost as it was.

A strict inequality (>) is kept as its closure (>=): a minimiser that would cross it
ends on it. Fixed parameters are constants in the expressions.
"""

from __future__ import annotations

import ast
from dataclasses import dataclass
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from ..modelling.checks import did_you_mean
from ..modelling.equations import _ARITY, _FUNCTIONS, _OPERATORS, _ToJax

_SENSES = {ast.GtE: ">=", ast.Gt: ">=", ast.LtE: "<=", ast.Lt: "<="}
EXAMPLE = "write an inequality of parameter names such as 'Fs >= Fc' or 'k <= 2*m'"


@dataclass(frozen=True)
class Constraint:
    """One inequality as written (``text``), kept as c(θ) = ``expr`` >= 0 (``expr``:
    left − right for >=, right − left for <=), with the θ names it involves."""

    text: str
    expr: str
    names: tuple[str, ...]


class Constraints:
    """The checked constraints of a Problem, evaluated together: c(θ) (m,), its
    Jacobian (m, K) and Hessians (m, K, K) at θ or at each row of θ (..., K)."""

    def __init__(self, items: list[Constraint], source: str, constants: dict):
        self.items, self._source, self._constants = items, source, constants
        self._jitted: Any = None

    def __len__(self) -> int:
        return len(self.items)

    def __getstate__(self):  # compiled code does not travel to workers
        return {**self.__dict__, "_jitted": None}

    def function(self):
        """c as a traceable JAX function of θ (K,) -> (m,)."""
        scope: dict = {"_jnp": jnp, **self._constants}
        exec(compile(self._source, "<tensorid constraints>", "exec"), scope)  # checked
        return scope["c"]

    def evaluate(self, theta) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(c, ∇c, ∇²c) at θ (K,) or at every row of θ (..., K)."""
        if self._jitted is None:
            c = self.function()
            self._jitted = jax.jit(jax.vmap(lambda t: (c(t), jax.jacfwd(c)(t), jax.hessian(c)(t))))
        theta = np.asarray(theta, dtype=float)
        flat = theta.reshape(-1, theta.shape[-1])
        out = [np.asarray(a) for a in self._jitted(jnp.asarray(flat))]
        return tuple(a.reshape(theta.shape[:-1] + a.shape[1:]) for a in out)  # type: ignore[return-value]

    def values(self, theta) -> np.ndarray:
        """c(θ) (m,): each constraint holds where its value is >= 0."""
        return self.evaluate(theta)[0]


def check_constraints(problem, constraints) -> Constraints | None:
    """The constraints of ``problem`` (texts), checked and compiled; None for none."""
    if constraints is None or (not isinstance(constraints, str) and len(constraints) == 0):
        return None
    texts = [constraints] if isinstance(constraints, str) else constraints
    if not isinstance(texts, list | tuple):
        raise TypeError(
            f"constraints must be a list of inequalities, got {constraints!r}; {EXAMPLE}"
        )
    if problem.population or problem.individual:
        raise ValueError(
            "constraints are not kept in a fleet's fit (population=, individual=): drop "
            "the constraints, or fit the units one by one"
        )
    names = _names(problem)
    items, exprs, constants = [], [], {}
    for i, text in enumerate(texts):
        if not isinstance(text, str):
            raise TypeError(f"constraints[{i}] = {text!r} is not a string; {EXAMPLE}")
        where = f"constraint {text!r}"  # as written: in a model file or --constraint
        pairs = _inequalities(where, text)
        for lhs, sense, rhs in pairs:
            used: set[str] = set()
            sides = [_checked(where, side, names, problem, used) for side in (lhs, rhs)]
            free = tuple(n for n in names if n in used and names[n] is not None)
            if not free:
                raise ValueError(
                    f"{where} involves no estimated unknown (only fixed parameters or "
                    "numbers), so a fit cannot keep it; drop it, or free a parameter in it"
                )
            a, b = sides if sense == ">=" else sides[::-1]
            exprs.append(f"({a}) - ({b})")
            shown = (
                text.strip()
                if len(pairs) == 1
                else f"{ast.unparse(lhs)} {sense} {ast.unparse(rhs)}"
            )
            items.append(Constraint(shown, ast.unparse(ast.parse(exprs[-1])), free))
        constants.update({f"_{n}": float(v) for n, v in _fixed(problem).items()})
    body = ", ".join(_to_jax(e, names) for e in exprs)
    source = f"def c(_t):\n    return _jnp.stack([{body}])\n"
    out = Constraints(items, source, constants)
    c0 = np.asarray(out.function()(jnp.asarray(problem.theta0)))  # (no compilation)
    bad = [items[k].text for k in range(len(items)) if not np.isfinite(c0[k])]
    if bad:
        raise ValueError(f"constraint {bad[0]!r} is not finite at the start p0; give another p0")
    return out


def _names(problem) -> dict[str, int | None]:
    """Every name a constraint may use: θ index for an unknown, None for a fixed
    parameter (a constant). A single record's free initial states by state name."""
    out: dict[str, int | None] = dict.fromkeys(problem.fixed)
    entries = problem.theta_entries
    for k, (n, e) in enumerate(entries):
        if e is None or len(problem.experiments) == 1:
            out[n] = k
    return out


def _fixed(problem) -> dict[str, float]:
    params = list(problem.model.params)
    return {n: float(problem.p0[params.index(n)]) for n in problem.fixed}


def _inequalities(where: str, text: str) -> list[tuple[ast.expr, str, ast.expr]]:
    """(left, ">=" or "<=", right) for each comparison of ``text`` (a chain such as
    '0 <= a - b <= 1' gives two)."""
    try:
        tree = ast.parse(text.strip(), mode="eval").body
    except SyntaxError as e:
        raise ValueError(f"cannot parse {where} ({e.msg}); {EXAMPLE}") from None
    if not isinstance(tree, ast.Compare):
        raise ValueError(f"{where} is not an inequality (no >= or <=); {EXAMPLE}")
    out: list[tuple[ast.expr, str, ast.expr]] = []
    left = tree.left
    for op, right in zip(tree.ops, tree.comparators, strict=True):
        if type(op) not in _SENSES:
            what = "an equality" if isinstance(op, ast.Eq | ast.NotEq) else "not an inequality"
            raise ValueError(
                f"{where} is {what}; constraints are inequalities (>=, <=); for an "
                "equality, fix a parameter or write the model with one parameter fewer"
            )
        out.append((left, _SENSES[type(op)], right))
        left = right
    return out


def _checked(where: str, node: ast.AST, names: dict, problem, used: set) -> str:
    """The side ``node`` as text, after checking that it is plain arithmetic on known
    names (each name used is added to ``used``)."""
    for sub in ast.walk(node):
        if isinstance(sub, ast.Name) and sub.id != "pi" and not _is_call_name(node, sub):
            if sub.id not in names:
                raise ValueError(f"{where}: {_unknown(sub.id, names, problem)}")
            used.add(sub.id)
        elif isinstance(sub, ast.Call):
            fn = sub.func.id if isinstance(sub.func, ast.Name) else ast.unparse(sub.func)
            lo, hi = _ARITY.get(fn, (1, 1))
            if fn not in _FUNCTIONS or sub.keywords or not lo <= len(sub.args) <= hi:
                raise ValueError(
                    f"{where}: {fn}(...) is not a function constraints know; they know "
                    f"{', '.join(sorted(_FUNCTIONS, key=str.lower))}"
                )
        elif isinstance(sub, ast.BinOp | ast.UnaryOp) and not isinstance(sub.op, _OPERATORS):
            raise ValueError(f"{where}: operator {type(sub.op).__name__} is not arithmetic")
        elif isinstance(sub, ast.Constant) and type(sub.value) not in (int, float):
            raise ValueError(f"{where}: {sub.value!r} is not a number; {EXAMPLE}")
        elif not isinstance(sub, _ALLOWED):
            raise ValueError(f"{where}: {ast.unparse(sub)!r} is not arithmetic; {EXAMPLE}")
    return ast.unparse(node)


_ALLOWED = (ast.Name, ast.Call, ast.BinOp, ast.UnaryOp, ast.Constant, ast.Load,
            ast.operator, ast.unaryop)  # fmt: skip


def _is_call_name(root: ast.AST, name: ast.Name) -> bool:
    return any(isinstance(n, ast.Call) and n.func is name for n in ast.walk(root))


def _unknown(name: str, names: dict, problem) -> str:
    """Why ``name`` cannot be used, and what can."""
    if name in problem.model.states:
        if len(problem.experiments) > 1 and name in problem.free_x0:
            why = "an initial state of several records (one value each)"
        else:
            why = "a state whose initial value is not estimated (free_x0)"
        return f"{name!r} is {why}; constraints relate parameters {list(names)}"
    return (
        f"{name!r} is not a parameter of the model{did_you_mean(name, list(names))}; "
        f"constraints relate parameters {list(names)}"
    )


def _to_jax(expr: str, names: dict) -> str:
    """``expr`` with each unknown read from θ (``_t[k]``), each fixed parameter its
    constant, and the functions those of jax.numpy."""

    class Bind(_ToJax):
        def visit_Name(self, node):
            if node.id in names:
                k = names[node.id]
                if k is None:
                    return ast.copy_location(ast.Name(f"_{node.id}", ast.Load()), node)
                t = ast.Subscript(ast.Name("_t", ast.Load()), ast.Constant(k), ast.Load())
                return ast.copy_location(t, node)
            return super().visit_Name(node)

        def visit_Call(self, node):
            node.args = [self.visit(a) for a in node.args]
            return _jax_call(node)

    return ast.unparse(ast.fix_missing_locations(Bind().visit(ast.parse(expr, mode="eval"))))


def _jax_call(node: ast.Call) -> ast.AST:
    fn = ast.Attribute(ast.Name("_jnp", ast.Load()), _FUNCTIONS[node.func.id], ast.Load())  # type: ignore[attr-defined]
    args = node.args
    while len(args) > 2:
        args = [ast.Call(fn, args[:2], []), *args[2:]]
    return ast.copy_location(ast.Call(fn, args, []), node)


# -- the augmented-Lagrangian terms ----------------------------------------------------
def penalty_terms(problem, theta) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(ψ, ∇ψ, ∇²ψ) of the augmented-Lagrangian terms at θ (..., K) for the
    problem's ``penalty`` (λ, μ): see the module docstring."""
    lam, mu = problem.penalty
    c, A, Hc = problem.constraints.evaluate(theta)
    shifted = lam - mu * c
    lh = np.maximum(shifted, 0.0)
    psi = ((lh**2 - lam**2) / (2.0 * mu)).sum(axis=-1)
    grad = -np.einsum("...i,...ij->...j", lh, A)
    on = np.where(shifted > 0, mu, 0.0)
    hess = np.einsum("...i,...ij,...ik->...jk", on, A, A) - np.einsum("...i,...ijk->...jk", lh, Hc)
    return psi, grad, hess


def add_penalty_terms(problem, theta, parts: str, more, out: list) -> None:
    """Add the augmented-Lagrangian terms to the assembled results (in place), as
    add_prior_terms does the priors' (residuals "r" have none: J's penalty is not a
    sum of squares; the fitting methods that keep constraints do not use them)."""
    psi, grad, hess = penalty_terms(problem, theta)
    seen_g = False
    for k, c in enumerate(parts):
        if c == "J":
            out[k] = out[k] + (psi if np.ndim(psi) else float(psi))
        elif c == "g" and not seen_g:
            out[k] = out[k] + grad
            seen_g = True
        elif c == "g":  # a Hessian-vector product
            out[k] = out[k] + np.einsum("...jk,...k->...j", hess, np.asarray(more[0]))
        elif c in "HP":
            out[k] = out[k] + hess


def penalty_jax(problem, theta):
    """ψ(θ) as a traceable JAX function (Problem.jax_cost's share of it)."""
    lam, mu = (jnp.asarray(a) for a in problem.penalty)
    lh = jnp.maximum(lam - mu * problem.constraints.function()(theta), 0.0)
    return jnp.sum((lh**2 - lam**2) / (2.0 * mu))
