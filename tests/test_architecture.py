"""The shape of the code, enforced: the layers import only downward, no import cycles,
short functions and fitting modules (docs/architecture.md)."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

SRC = Path(__file__).resolve().parents[1] / "src" / "tensorid"

# lowest first; a module may import its own layer or a lower one
LAYERS = {
    "_config": 0,
    "_early": 0,
    "names": 0,  # the command line's choices, no imports at all (tests/test_recipes.py)
    "engine": 1,
    "functions": 1,
    "datasets": 1,
    "fitting": 2,
    "population": 2,
    "app": 3,
    "paper": 4,
    # the top: the package itself and the names that gather every layer
    "__init__": 5,
    "__main__": 5,
    "cli": 5,
    "benchmarks": 5,
}


def _modules() -> dict[str, Path]:
    out = {}
    for path in sorted(SRC.rglob("*.py")):
        parts = list(path.relative_to(SRC).with_suffix("").parts)
        if parts[-1] == "__init__" and len(parts) > 1:
            parts = parts[:-1]
        out[".".join(["tensorid", *parts])] = path
    return out


MODULES = _modules()


def _layer(module: str) -> int:
    parts = module.split(".")
    return LAYERS[parts[1] if len(parts) > 1 else "__init__"]


def _imports(module: str, path: Path) -> set[str]:
    """Every tensorid module that ``module`` imports, at any depth of its code."""
    package = module if path.name == "__init__.py" else module.rsplit(".", 1)[0]
    found = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            names = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                anchor = package.split(".")
                anchor = anchor[: len(anchor) - node.level + 1]
                base = ".".join(anchor + ([base] if base else []))
            names = [
                f"{base}.{a.name}" if f"{base}.{a.name}" in MODULES else base for a in node.names
            ]
        else:
            continue
        found |= {n for n in names if n in MODULES and n != module}
    return found


GRAPH = {m: _imports(m, p) for m, p in MODULES.items()}


def test_every_module_has_a_layer():
    for m in MODULES:
        _layer(m)


def test_no_layer_imports_a_higher_one():
    upward = [
        f"{m} (layer {_layer(m)}) imports {n} (layer {_layer(n)})"
        for m, deps in GRAPH.items()
        for n in deps
        if _layer(n) > _layer(m)
    ]
    assert not upward, "\n".join(upward)


def test_no_import_cycles():
    # a package's __init__ gathers its modules; it is not part of a cycle through them
    graph = {m: {n for n in deps if not m.startswith(n + ".")} for m, deps in GRAPH.items()}
    state: dict[str, int] = {}
    cycles = []

    def visit(m, stack):
        state[m] = 1
        stack.append(m)
        for n in graph[m]:
            if state.get(n) == 1:
                cycles.append(" -> ".join(stack[stack.index(n) :] + [n]))
            elif n not in state:
                visit(n, stack)
        stack.pop()
        state[m] = 2

    for m in graph:
        if m not in state:
            visit(m, [])
    assert not cycles, "\n".join(cycles)


def _functions(path: Path):
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef):
            yield node.name, node.end_lineno - node.lineno + 1


# argument-parser construction is a list of declarations, long by nature
PARSERS = {"register"}


@pytest.mark.parametrize("module", sorted(MODULES))
def test_functions_are_at_most_80_lines(module):
    long = [
        f"{name}: {n} lines"
        for name, n in _functions(MODULES[module])
        if n > 80 and name not in PARSERS
    ]
    assert not long, f"{module}: " + ", ".join(long)


def test_modules_are_at_most_450_lines():
    # the seams issue's bar for every module: a newcomer reads each in one sitting
    sizes = {m: len(p.read_text().splitlines()) for m, p in MODULES.items()}
    long = {m: n for m, n in sizes.items() if n > 450}
    assert not long, long


def test_the_command_lines_spelled_out_choices_are_the_registries():
    """--method, --loss, --predictor, --hessian and --scheme take their choices from
    tensorid/names.py, so that the parser imports no JAX; they must stay the
    registries' (tests/test_recipes.py checks names.py against them)."""
    from tensorid import names
    from tensorid.cli import build_parser

    fit = build_parser()._subparsers._group_actions[0].choices["fit"]
    choices = {a.dest: a.choices for a in fit._actions if a.choices}
    assert list(choices["method"]) == list(names.METHODS) + list(names.FLEET_METHODS)
    assert list(choices["loss"]) == list(names.LOSSES)
    assert list(choices["predictor"]) == list(names.PREDICTORS)
    assert list(choices["hessian"]) == list(names.HESSIANS)
    assert list(choices["scheme"]) == list(names.SCHEMES)


def test_architecture_md_names_every_module():
    """docs/architecture.md lists every module (issue 39): a newcomer finds each one
    there, by its file name."""
    import re

    text = (SRC.parents[1] / "docs" / "architecture.md").read_text()
    words = set(re.findall(r"[\w]+", text))
    missing = [m for m, p in MODULES.items() if p.stem not in words and p.stem != "__init__"]
    assert not missing, f"docs/architecture.md does not name {missing}"
