"""What `tensorid simulate` and `tensorid compare` start from: a fit.json read and
checked against the model file, the parameters (the fit's, --params' NAME=VALUE
pairs, the model file's p0), the integration settings and the initial states (--x0,
the fit's, the model file's, an expression of the record's inputs evaluated on it)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from ..engine.modelling import initial
from ..engine.schemes.discretisation import Discretisation
from .argtypes import tolerances_as_flags
from .files import ModelSpec


def assignments(items: list[str], what: str) -> dict[str, float]:
    out: dict[str, float] = {}
    for it in items:
        if "=" not in it:
            raise ValueError(f"{what} must be NAME=VALUE, got {it!r}")
        k, v = it.split("=", 1)
        try:
            value = float(v)
        except ValueError:
            raise ValueError(f"{what}: {k.strip()}={v!r} is not a number") from None
        if not np.isfinite(value):  # it was refused as "p0 has non-finite values"
            raise ValueError(f"{what}: {k.strip()}={v} is not a finite number")
        if k.strip() in out:  # the last would win silently
            raise ValueError(
                f"{what} gives {k.strip()} twice ({k.strip()}={out[k.strip()]:g} and "
                f"{k.strip()}={value:g}); give it once"
            )
        out[k.strip()] = value
    return out


def _read_json(path: Path):
    """The JSON in ``path``, or one line saying how the file is not a fit.json (empty,
    not text, cut short, text around it), which json's own message did not say."""
    fix = "give the fit.json that tensorid fit --out wrote, or run the fit again"
    try:
        text = path.read_text(encoding="utf-8")
    except UnicodeDecodeError as e:
        raise ValueError(
            f"--params {path} is not a fit.json: not text (byte {e.start} is not UTF-8); {fix}"
        ) from None
    if not text.strip():
        raise ValueError(f"--params {path} is empty, not a fit.json; {fix}")
    try:
        return json.loads(text)
    except json.JSONDecodeError as e:
        where = f"line {e.lineno}, column {e.colno}"
        if e.pos >= len(text.rstrip()):
            what = f"is damaged: its JSON ends unfinished at {where} (the file was cut short)"
        elif e.msg == "Extra data":
            what = f"is damaged: text follows its JSON at {where}"
        elif e.pos == len(text) - len(text.lstrip()):
            first = text.lstrip().splitlines()[0][:30]
            what = f"is not a fit.json: it does not start with JSON ({first!r} at {where})"
        else:
            what = f"is damaged: its JSON breaks at {where} ({e.msg})"
        raise ValueError(f"--params {path} {what}; {fix}") from None


def _same_time(path: Path, fitted: dict, spec: ModelSpec) -> None:
    """A discrete-time fit scored with a continuous-time model file, or the reverse:
    refused (it ran, one's parameters read by the other: GOF -0.59)."""
    scheme = (fitted.get("integration") or {}).get("scheme")
    if scheme is None or (scheme == "discrete") == bool(spec.model.discrete):
        return
    kind = {True: "a discrete-time", False: "a continuous-time"}
    source = ((fitted.get("provenance") or {}).get("model") or {}).get("path")
    raise ValueError(
        f"--params {path} is the fit of {kind[scheme == 'discrete']} model and "
        f"{spec.path} is {kind[bool(spec.model.discrete)]} one: give the model file it "
        f"was fitted with{f' ({source})' if source else ''}"
    )


def fitted_json(path: Path, spec: ModelSpec) -> dict:
    """A fit.json's parameters and initial state, checked against the model."""
    if not path.is_file():
        raise FileNotFoundError(f"--params {path} does not exist")
    fitted = _read_json(path)
    if isinstance(fitted, dict) and "scored_as" in fitted and "x0_source" in fitted:
        raise ValueError(
            f"--params {path} is a compare.json (tensorid compare's scores), not a fit.json: "
            "give the fit.json that tensorid fit --out wrote"
        )
    if not isinstance(fitted, dict) or not isinstance(fitted.get("params"), dict):
        raise ValueError(f"--params {path} holds no params: give a fit.json written by tensorid")
    _same_time(path, fitted, spec)
    bad = [k for k, v in fitted["params"].items() if not isinstance(v, int | float)]
    if bad:
        raise ValueError(f"--params {path}: params {bad} are not numbers")
    bad = [f"{k}={v}" for k, v in fitted["params"].items() if not np.isfinite(v)]
    if bad:  # NaN and Infinity are JSON to Python's reader
        raise ValueError(
            f"--params {path}: params {', '.join(bad)} are not finite (a fit never writes "
            "one): give the fit.json of a finished fit, or correct the file"
        )
    bad = [n for n in fitted.get("free_x0") or [] if n not in spec.model.states]
    if bad:  # a fit of another model file: it said "free_x0 names unknown states"
        raise ValueError(f"--params {path}: its free_x0 {bad} are not states of {spec.path}")
    if "x0" in fitted:
        try:
            x0 = np.atleast_2d(np.asarray(fitted["x0"], dtype=float))
        except (TypeError, ValueError):
            raise ValueError(
                f"--params {path}: its x0 is not a list of numbers (one per state "
                f"{list(spec.model.states)}), got {fitted['x0']!r:.60}"
            ) from None
        if x0.ndim != 2 or x0.shape[1] != spec.model.N:
            raise ValueError(
                f"--params {path}: its x0 has {x0.shape[1]} values, the model has "
                f"{spec.model.N} states {list(spec.model.states)}"
            )
        if not np.isfinite(x0).all():
            raise ValueError(f"--params {path}: its x0 {fitted['x0']} is not finite; correct it")
    return fitted


def fit_json(spec: ModelSpec, given: list[str]) -> dict | None:
    """The fit.json that --params names (first, NAME=VALUE pairs after it changing
    some of its parameters), read and checked; None for NAME=VALUE pairs alone."""
    files = [g for g in given if g.endswith(".json")]
    if files and (len(files) > 1 or given[0] != files[0]):
        raise ValueError(
            f"--params {' '.join(given)}: give one fit.json, first, and after it any "
            "NAME=VALUE to change"
        )
    return fitted_json(Path(given[0]), spec) if files else None


def parameters(spec: ModelSpec, given: list[str], fitted: dict | None) -> tuple[dict, str]:
    """The parameters: p0 of the model file, updated by the ``fitted`` fit.json and
    the NAME=VALUE pairs ``given``; and a line naming those left to p0 ("" if none):
    a partial NAME=VALUE list (or a fit.json of another model file) is easy to
    mistake for a whole one."""
    m = spec.model
    params = dict(spec.p0 or {})
    if fitted is not None:  # the fit's, then the pairs after the file
        named = {**fitted["params"], **assignments(given[1:], "--params")}
    else:
        named = assignments(given, "--params")
    params.update(named)
    unknown = sorted(set(params) - set(m.params))
    if unknown:
        raise ValueError(
            f"--params names {unknown}, which the model does not have; its parameters are "
            f"{list(m.params)}"
        )
    missing = [n for n in m.params if n not in params]
    if missing:
        raise ValueError(
            f"no value for the parameters {missing}: give them with --params NAME=VALUE, "
            "a fit.json, or p0 in the model file"
        )
    rest = ", ".join(f"{n}={params[n]:.6g}" for n in m.params if n not in named)
    note = f"parameters {rest} (the model file's p0{', not in --params' if named else ''})"
    note = note if rest else ""
    if fitted is not None and fitted.get("population"):  # which of a fleet's values
        typical = "the population's typical values (each fitted unit's own are in its units)"
        note = "; ".join([f"parameters: {typical}", *([note] if note else [])])
    return params, note


def integration(args, fitted: dict | None, spec: ModelSpec | None = None) -> Discretisation:
    """The command line's integration settings, else the fit.json's (a fit is scored as
    it was fitted), else the model file's interpolation, else the defaults."""
    saved = dict((fitted or {}).get("integration") or {})
    if saved.get("scheme") == "discrete":  # a discrete-time model: the defaults say so
        saved = {}
    scheme = args.scheme or saved.get("scheme", "rk4")
    same = scheme == saved.get("scheme")
    rtol = args.rtol if args.rtol is not None else saved.get("rtol") if same else None
    atol = args.atol if args.atol is not None else saved.get("atol") if same else None
    substeps = args.substeps or saved.get("substeps", 4)
    own = getattr(spec, "interpolation", None) or "linear"
    interpolation = args.interpolation or saved.get("interpolation", own)
    try:
        return Discretisation.of(scheme, substeps, interpolation, rtol, atol)
    except ValueError as e:  # named as the flags (the fit.json's are valid)
        raise ValueError(tolerances_as_flags(str(e))) from None


def start_of(spec: ModelSpec, args, e, fitted, params) -> tuple[np.ndarray, list[str], str]:
    """(x0 to start from, the states to estimate on the record, where x0 comes from):
    --x0 where given; the states the fit (else the model file) frees are estimated
    when the record has outputs; the others are the fit.json's or the model file's (an
    expression of the inputs and parameters, as a fleet's "Dose * Wt", evaluated on
    this record with ``params``)."""
    m = spec.model
    given = assignments(getattr(args, "x0", []), "--x0")
    exprs = {k: v for k, v in (spec.x0 or {}).items() if isinstance(v, str) and k not in given}
    x0 = dict(zip(m.states, spec.x0_array([*given, *exprs]), strict=True))
    if exprs:
        values, _ = initial.evaluate(m, [e], exprs, m.params_array(params))
        x0.update({k: float(values[0, m.states.index(k)]) for k in exprs})
    base, free = "the model file's x0", list(spec.free_x0)
    if exprs:
        base += f", {', '.join(f'{k} = {v}' for k, v in exprs.items())} on this record"
    if fitted is not None and "x0" in fitted:
        x0 = dict(zip(m.states, np.atleast_2d(fitted["x0"])[0], strict=True))
        base = f"the x0 of {args.params[0]} (its first training record's)"
        free = list(fitted.get("free_x0", free))
    unknown = sorted(set(given) - set(m.states))
    if unknown:
        raise ValueError(f"--x0 names {unknown}; the model's states are {list(m.states)}")
    x0.update(given)
    free = [n for n in free if n not in given] if e.y is not None else []
    where = "this record" if args.init_window is None else f"its first {args.init_window} samples"
    rest = [n for n in m.states if n not in free and n not in given]
    parts = [f"{', '.join(free)} estimated on {where} with the parameters held"] if free else []
    parts += [f"{', '.join(given)} from --x0"] if given else []
    if rest and parts:
        parts.append(f"{', '.join(rest)} from {base}")
    return m.states_array(x0), free, "; ".join(parts) or base


def unit_estimate(spec: ModelSpec, fitted: dict, e, disc, params: dict, path: str):
    """--ipred: (the unit's own parameter values, its η̂, the line saying so): the
    mode of its random effects given its own data, with the fitted population (typical
    values, Ω, shared values, residual error) held: the empirical Bayes estimate of
    ``fit --validate``'s held-out units, on this one record."""
    from dataclasses import replace

    from ..engine.assembly.problem import Problem
    from ..population.objective import METHODS
    from ..population.validation import empirical_bayes
    from .fleets import problem_keywords

    m = spec.model
    fleet = fitted.get("kind") == "population" or fitted.get("population")
    if not fleet:
        raise ValueError(
            f"--ipred: --params {path} is not a population fit's fit.json (a unit's own "
            "values come from its random effects): drop --ipred"
        )
    if e.y is None:
        raise ValueError(
            f"--ipred: {e.name or 'the record'} has no measured outputs, and a unit's η̂ is "
            f"estimated from them: give a record with {list(m.outputs)}, or drop --ipred "
            "for the typical unit"
        )
    unmeasured = [n for n, v in (fitted.get("population") or {}).items()
                  if not isinstance(v.get("omega"), int | float)]  # fmt: skip
    if unmeasured:
        raise ValueError(
            f"--ipred: --params {path} has no ω of {unmeasured} (a fit that did not end): "
            "give the fit.json of a finished fit"
        )
    pop = {n: float(v["omega"]) for n, v in (fitted.get("population") or {}).items()}
    shared = set(fitted.get("shared") or {})
    own = fitted.get("individual")
    if own is None:  # a fit.json before the key: the values that differ over its units
        units = fitted.get("units") or []
        own = [n for n in m.params if n not in pop and n not in shared
               and len({u["params"].get(n) for u in units}) > 1]  # fmt: skip
    kinds = replace(
        spec, population=pop, individual=list(own), omega=fitted.get("omega_structure") or
        ("full" if fitted.get("omega_correlation") else "diagonal"),
        residual_error={o: v["model"] for o, v in (fitted.get("residual_error") or {}).items()},
    )  # fmt: skip
    fixed = [n for n in m.params if n not in pop and n not in own and n not in shared]
    problem = Problem(m, [e], p0=params, x0=spec.x0_given(), fixed=fixed, discretisation=disc,
                      **problem_keywords(kinds, Problem))  # fmt: skip
    method = str(fitted["method"]) if fitted.get("method") in METHODS else "focei"
    try:
        (unit,) = empirical_bayes(problem, fitted.get("unknowns") or {}, method)
    except ValueError as err:
        raise ValueError(f"--ipred: --params {path}: {err}") from None
    values = ", ".join(f"{n}={v:.6g}" for n, v in unit["params"].items())
    note = (f"parameters: this unit's own ({values}; η̂ by empirical Bayes from its data, "
            "the fitted population held)")  # fmt: skip
    if not unit["converged"]:
        note += "; its η̂ did not converge: read these scores with care"
    return {**params, **unit["params"]}, unit["eta"], note
