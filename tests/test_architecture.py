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
    "_state": 0,
    "engine": 1,
    "functions": 1,
    "datasets": 1,
    # the solvers: they return plain records and know nothing of the statistics
    "solve": 2,
    # the statistics, tables and figures of a fit (they may run small inner solves)
    "analysis": 3,
    "population": 3,
    # the composition: fit(), FitResult, the staged pipelines (robust loss, priors)
    "fitting": 4,
    "app": 5,
    "paper": 6,
    # the top: the package itself and the names that gather every layer
    "__init__": 7,
    "__main__": 7,
    "cli": 7,
    "benchmarks": 7,
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


# the packages that keep old module paths as aliases (a MOVED literal in their
# __init__.py, old name -> new home), and where those homes are
ALIASING = {"fitting": "tensorid", "engine": "tensorid.engine"}


def _moved() -> dict[str, str]:
    """The MOVED literals of fitting/__init__.py (the modules that moved to solve/ and
    analysis/) and engine/__init__.py (the engine's modules, moved into its
    subpackages): the old paths that stay importable as aliases, old -> new."""
    out = {}
    for package, homes in ALIASING.items():
        tree = ast.parse((SRC / package / "__init__.py").read_text())
        literals = [
            ast.literal_eval(node.value)
            for node in tree.body
            if isinstance(node, ast.Assign) and getattr(node.targets[0], "id", None) == "MOVED"
        ]
        assert literals, f"{package}/__init__.py has no MOVED"
        out |= {f"tensorid.{package}.{k}": f"{homes}.{v}.{k}" for k, v in literals[0].items()}
    return out


MOVED = _moved()


def _layer(module: str) -> int:
    parts = module.split(".")
    return LAYERS[parts[1] if len(parts) > 1 else "__init__"]


def _named(module: str, path: Path) -> set[str]:
    """Every tensorid module (or old path of one) that ``module`` imports, at any
    depth of its code, as written."""
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
                f"{base}.{a.name}"
                if f"{base}.{a.name}" in MODULES or f"{base}.{a.name}" in MOVED
                else base
                for a in node.names
            ]
        else:
            continue
        found |= {n for n in names if (n in MODULES or n in MOVED) and n != module}
    return found


def _imports(module: str, path: Path) -> set[str]:
    """Every tensorid module that ``module`` imports; an old path counts as the module
    it names (an upward import through an alias is still upward)."""
    return {MOVED.get(n, n) for n in _named(module, path)} - {module}


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


def test_src_uses_the_new_paths():
    """The old paths (tensorid.fitting.trust_region, ...) are for users' code; the
    package itself imports the modules where they are."""
    old = {m: sorted(_named(m, p) & set(MOVED)) for m, p in MODULES.items()}
    aliasing = {f"tensorid.{package}" for package in ALIASING}
    old = {m: o for m, o in old.items() if o and m not in aliasing}
    assert not old, old


def test_the_solver_layer_imports_no_statistics():
    """solve/ returns plain records: nothing of analysis/, fitting/ or above, even
    inside a function (the layer check says the same; this says it by name)."""
    bad = {m: sorted(n for n in deps if _layer(n) > _layer("tensorid.solve"))
           for m, deps in GRAPH.items() if m.startswith("tensorid.solve")}  # fmt: skip
    assert not {m: b for m, b in bad.items() if b}, bad


# the engine's subpackages, lowest first (engine/__init__.py and docs/architecture.md
# say what each holds): a module of the engine imports its own subpackage or a lower one
ENGINE = {"compiling": 0, "modelling": 1, "schemes": 2, "sweeping": 3, "assembly": 4}


def _engine_level(module: str) -> int | None:
    """A module's place in ENGINE; the engine's own __init__ (which gathers them all)
    above every one; None outside the engine."""
    parts = module.split(".")
    if parts[:2] != ["tensorid", "engine"]:
        return None
    return ENGINE[parts[2]] if len(parts) > 2 else len(ENGINE)


def test_every_engine_module_sits_in_a_subpackage_with_a_place():
    folders = {p.parent.name for p in (SRC / "engine").glob("*/__init__.py")}
    assert folders == set(ENGINE), f"engine/'s subpackages {sorted(folders)}, ENGINE {ENGINE}"
    loose = [p.name for p in (SRC / "engine").glob("*.py") if p.name != "__init__.py"]
    assert not loose, f"engine/ holds {loose} outside its subpackages"


def test_the_engines_subpackages_import_only_downward():
    """compiling < modelling < schemes < sweeping < assembly, inside functions too; an
    old path (tensorid.engine.X) counts as the module it names."""
    upward = [
        f"{m} ({_engine_level(m)}) imports {n} ({_engine_level(n)})"
        for m, deps in GRAPH.items()
        if m != "tensorid.engine" and _engine_level(m) is not None
        for n in deps
        if _engine_level(n) is not None and _engine_level(n) > _engine_level(m)
    ]
    assert not upward, "\n".join(upward)


@pytest.mark.parametrize("old", sorted(MOVED))
def test_the_old_paths_still_import(old):
    """``from tensorid.fitting.X import Y`` is a contract: the same module object."""
    import importlib

    assert importlib.import_module(old) is importlib.import_module(MOVED[old])


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


def test_the_fitting_layers_folders_hold_at_most_20_modules():
    # issue 39: fitting/ had grown to 33 modules; solve/, analysis/ and the
    # composition left in fitting/ each stay a folder one can hold in mind
    for folder in ("solve", "analysis", "fitting"):
        n = len(list((SRC / folder).glob("*.py")))
        assert n <= 20, f"{folder}/ holds {n} modules"


def test_the_engines_folders_hold_at_most_20_modules():
    # issue 49 item 5: engine/ had grown to 39 modules; it splits along its seams (the
    # compiled programs, the model and its records, the schemes, the sweeps, the Problem)
    for folder in ENGINE:
        n = len(list((SRC / "engine" / folder).glob("*.py")))
        assert n <= 20, f"engine/{folder}/ holds {n} modules"


def test_global_statements_only_in_the_configuration():
    """Run-wide state is one object (tensorid/_state.py), not module globals that
    functions reassign: ``global`` appears in _config.py alone."""
    found = [
        f"{m}: global {', '.join(node.names)}"
        for m, p in MODULES.items()
        if m != "tensorid._config"
        for node in ast.walk(ast.parse(p.read_text()))
        if isinstance(node, ast.Global)
    ]
    assert not found, found


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
