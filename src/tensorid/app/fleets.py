"""The file side of fleets (issue 42): the model-file keys ``covariates``,
``individual`` and ``population``, initial states given as expressions of the unit's
inputs and parameters (``x0 = {"depot": "Dose * Wt"}``), and the command line's
``--individual`` and ``--population`` over them. Every mistake is one line (a
ValueError or TypeError) before any work.

Three kinds of parameters: shared (the default, one value for every unit),
individual (each unit its own value) and population (each unit's value is the
typical value times exp(η), η ~ N(0, ω²); the number given is ω's start). They are
passed to ``ti.Problem(..., individual=..., population=...)`` only when given, so
that a fit without them is the fit it always was.
"""

from __future__ import annotations

import ast
import math

from ..engine.modelling.equations import _FUNCTIONS
from ..engine.modelling.model import Model


def did_you_mean(name, choices) -> str:
    """ " (did you mean 'Wt'?)" for the choice nearest to ``name``, capitals aside."""
    import difflib

    lower = {str(c).lower(): c for c in choices}
    close = difflib.get_close_matches(str(name).lower(), list(lower), n=1, cutoff=0.6)
    return f" (did you mean {lower[close[0]]!r}?)" if close else ""


def _names(key: str, value) -> list[str]:
    """A list of names (one name may be given as a string)."""
    if isinstance(value, str):
        return [value]
    if not isinstance(value, list | tuple) or not all(isinstance(v, str) for v in value):
        raise TypeError(f"{key} must be a list of names, got {value!r}")
    return list(value)


def _known(key: str, names, known, kind: str) -> None:
    for n in names:
        if n not in known:
            raise ValueError(
                f"{key} names {n!r}, which is not one of the model's {kind} {list(known)}"
                f"{did_you_mean(n, known)}"
            )
    repeated = sorted({n for n in names if list(names).count(n) > 1})
    if repeated:
        raise ValueError(f"{key} repeats {repeated}; give each name once")


def covariates(value, model: Model) -> list[str]:
    """``covariates = ["Wt", "Dose"]``: model inputs constant within each unit."""
    names = _names("covariates", value)
    _known("covariates", names, model.inputs, "inputs")
    return names


def individual(value, model: Model, key: str = "individual") -> list[str]:
    """``individual = ["k"]``: parameters each unit has its own value of."""
    names = _names(key, value)
    _known(key, names, model.params, "parameters")
    return names


def population(value, model: Model, key: str = "population") -> dict[str, float]:
    """``population = {"ka": 0.5}``: parameters log-normal over the units, each with
    the start of ω (the standard deviation of η), finite and > 0."""
    if isinstance(value, list | tuple) and all(isinstance(v, tuple) and len(v) == 2 for v in value):
        value = dict(value)  # the command line's NAME=VALUE pairs
    if not isinstance(value, dict):
        raise TypeError(
            f"{key} must be a dict {{parameter: start of ω}}, e.g. {{'ka': 0.5}}; got {value!r}"
        )
    _known(key, list(value), model.params, "parameters")
    out = {}
    for name, omega in value.items():
        try:
            w = float(omega)
        except (TypeError, ValueError):
            w = math.nan
        if not (0 < w < math.inf):
            raise ValueError(
                f"{key}: {name}={omega!r}: ω (the standard deviation of the log of "
                f"{name} over the units) must start at a finite number > 0, e.g. 0.3"
            )
        out[name] = w
    return out


def residual_error(value, model: Model, key: str = "residual_error") -> str | dict:
    """``residual_error = "combined"`` (every output) or ``{"cp": "proportional"}``;
    on the command line ``combined`` or ``cp=proportional`` (NAME=KIND pairs)."""
    from ..names import RESIDUAL_ERRORS

    if isinstance(value, list | tuple):  # the command line's words
        if len(value) == 1 and "=" not in value[0]:
            value = value[0]
        elif all("=" in v for v in value):
            pairs = [v.split("=", 1) for v in value]
            names = [n for n, _ in pairs]
            twice = sorted({n for n in names if names.count(n) > 1})
            if twice:  # the last would win without a word
                raise ValueError(
                    f"{key}: {twice[0]!r} is given {names.count(twice[0])} times "
                    f"({' '.join(v for v in value if v.split('=', 1)[0] == twice[0])}); "
                    "give each output's kind once"
                )
            value = dict(pairs)
    chosen = (
        [value]
        if isinstance(value, str)
        else list(value.values())
        if isinstance(value, dict)
        else [None]
    )
    if not all(k in RESIDUAL_ERRORS for k in chosen):
        raise ValueError(
            f"{key} = {value!r}: give one of {list(RESIDUAL_ERRORS)} for every output, or "
            "OUTPUT=KIND per output (e.g. cp=combined)"
        )
    if isinstance(value, dict):
        _known(key, list(value), model.outputs, "outputs")
    return value


def omega(value, key: str = "omega") -> str:
    """``omega = "full"``: the random effects correlated (Ω estimated whole)."""
    from ..engine.modelling.fleet import OMEGAS

    if value not in OMEGAS:
        raise ValueError(f"{key} = {value!r}: give one of {list(OMEGAS)}")
    return str(value)


def kinds(individual: list[str], population: dict, fixed, where: dict[str, str]) -> None:
    """A parameter in both kinds, or fixed and varying over the units: one line each.
    ``where`` says where each setting came from ("--individual", "population in m.py")."""
    both = [n for n in individual if n in population]
    if both:
        raise ValueError(
            f"{both} in both {where['individual']} and {where['population']}: a "
            "parameter is individual (its own value per unit) or population (log-normal "
            "over the units), not both; keep it in one"
        )
    held = [n for n in [*individual, *population] if n in fixed]
    if held:
        kind = "individual" if held[0] in individual else "population"
        raise ValueError(
            f"{held} is fixed ({where['fixed']}) and also varies over the units "
            f"({where[kind]}): drop it from one of them (--free NAME frees it)"
        )


def x0_expressions(x0: dict | None, model: Model) -> None:
    """Initial states given as text (``"Dose * Wt"``): expressions of the model's
    inputs (at the unit's first sample) and parameters; an unknown name is one line."""
    known = [*model.inputs, *model.params]
    for state, value in (x0 or {}).items():
        if not isinstance(value, str):
            continue
        try:
            tree = ast.parse(value.strip(), mode="eval")
        except SyntaxError:
            raise ValueError(
                f"x0[{state!r}] = {value!r} is not an expression (write e.g. 'Dose * Wt')"
            ) from None
        for node in ast.walk(tree):
            if isinstance(node, ast.Name) and node.id not in [*known, *_FUNCTIONS, "pi"]:
                raise ValueError(
                    f"x0[{state!r}] = {value!r} uses {node.id!r}, which is none of the "
                    f"model's inputs {list(model.inputs)} or parameters {list(model.params)}"
                    f"{did_you_mean(node.id, known)}"
                )


def has_expressions(x0: dict | None) -> bool:
    return any(isinstance(v, str) for v in (x0 or {}).values())


def from_command_line(spec, args):
    """The model file's settings with ``--individual`` and ``--population`` (each,
    where given, replaces the file's), checked against each other and ``fixed`` (after
    --fix and --free)."""
    from dataclasses import replace

    m, path = spec.model, spec.path
    given_i = getattr(args, "individual", None)
    given_p = getattr(args, "population", None)
    ind = spec.individual if given_i is None else individual(given_i, m, "--individual")
    if given_p is None:
        pop = spec.population
    else:
        names = [n for n, _ in given_p]
        repeated = sorted({n for n in names if names.count(n) > 1})
        if repeated:
            raise ValueError(f"--population gives {repeated} twice; give each once")
        pop = population(given_p, m, "--population")
    where = {
        "individual": "--individual" if given_i is not None else f"individual in {path}",
        "population": "--population" if given_p is not None else f"population in {path}",
        "fixed": f"fixed in {path}",
    }
    if set(dict(getattr(args, "fix", None) or [])) & {*ind, *pop}:
        where["fixed"] = "--fix"
    kinds(ind, pop, spec.fixed, where)
    om = spec.omega if getattr(args, "omega", None) is None else omega(args.omega, "--omega")
    given_e = getattr(args, "residual_error", None)
    err = spec.residual_error
    if given_e is not None:
        err = residual_error(given_e, m, "--residual-error")
    return replace(spec, individual=list(ind), population=dict(pop), residual_error=err, omega=om)


def problem_keywords(spec, problem: type) -> dict:
    """``individual=`` and ``population=`` for ``problem`` (ti.Problem), only those
    given (a fit without them passes neither, so that it runs where the Problem lacks
    them; one that has them and meets a Problem without is one line)."""
    import inspect

    out: dict = {}
    if spec.individual:
        out["individual"] = list(spec.individual)
    if spec.population:
        out["population"] = dict(spec.population)
    if spec.residual_error:
        out["residual_error"] = spec.residual_error
    if spec.omega:
        out["omega"] = spec.omega
    if spec.doses:
        out["doses"] = dict(spec.doses)
    for key in ("lags", "durations"):  # events that move with the parameters
        if getattr(spec, key):
            out[key] = dict(getattr(spec, key))
    taken = inspect.signature(problem).parameters
    lacking = [k for k in out if k not in taken]
    if lacking:
        raise ValueError(
            f"{lacking[0]} parameters need the fleet estimator, which this version of "
            f"tensorid lacks (ti.Problem takes no {lacking[0]}=): drop {lacking[0]} from the "
            f"model file (and --{lacking[0]}) to fit every unit with shared parameters"
        )
    return out


def several_units(spec, train, args) -> None:
    """Parameters that vary over the units need more than one unit: one line naming
    --records where the data were read as a single record. A unit with fewer
    observations than its own unknowns (its individual parameters and free initial
    states) cannot determine them: refused, naming it. (Population parameters are no
    unit's own: a sparse unit's η is drawn towards 0, and it is kept.)"""
    if not (spec.individual or spec.population):
        return
    own = [*spec.individual, *spec.free_x0]
    for e in train if spec.individual else []:
        seen = 0 if e.y is None else e.observations
        if seen < len(own):
            raise ValueError(
                f"unit {e.name!r} has {seen} observation(s) for its {len(own)} own unknowns "
                f"(individual {list(spec.individual)}"
                + (f", free_x0 {list(spec.free_x0)}" if spec.free_x0 else "")
                + "), too few to determine them: make some of them population parameters "
                "(--population NAME=OMEGA), or leave the unit out"
            )
    if len(train) > 1:
        return
    kind = "population" if spec.population else "individual"
    hint = (
        "give --records ID_COLUMN (the column naming each row's unit) or one file per unit"
        if getattr(args, "records", None) is None
        else "the file holds one unit only"
    )
    raise ValueError(
        f"{kind} parameters vary over the units, but the data ({', '.join(args.data)}) "
        f"are one record: {hint}"
    )
