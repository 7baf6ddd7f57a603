"""`tensorid simulate` and `tensorid compare`: a model with given (or fitted)
parameters on one record. Both call the library's scoring (``score_record``, the
routine behind ``FitResult.validate``), so a record is simulated, its initial
states estimated and its outputs scored exactly as ``fit --validate`` does."""

from __future__ import annotations

import json
import sys
from functools import partial
from pathlib import Path

import numpy as np

from ..analysis.figures import file_name
from ..analysis.summary import gof_text, metric_notes, score_notes, undefined_gof
from ..analysis.validation import Score, check_init_window, score_record
from ..engine import initial
from ..engine.checks import same_step
from ..engine.diagnostics import describe_failure
from ..engine.discretisation import Discretisation
from ..engine.status import Status
from .after_fit import SIMULATED_HORIZON
from .argtypes import tolerances_as_flags
from .files import ModelSpec, load_data, load_model
from .filter_fits import NOT_SCORED, filter_of, noise_levels, scores_finite
from .output import (
    COMPARE_MANIFEST,
    SIMULATE_MANIFEST,
    check_destination,
    previous_outputs,
    replace_outputs,
    write_atomic,
)
from .provenance import data_entries, other_model, provenance
from .records import one_unit
from .renderer import draw_files
from .reports import write_json


def _assignments(items: list[str], what: str) -> dict[str, float]:
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


def _fitted(path: Path, spec: ModelSpec) -> dict:
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


def _fit_json(spec: ModelSpec, given: list[str]) -> dict | None:
    """The fit.json that --params names (first, NAME=VALUE pairs after it changing
    some of its parameters), read and checked; None for NAME=VALUE pairs alone."""
    files = [g for g in given if g.endswith(".json")]
    if files and (len(files) > 1 or given[0] != files[0]):
        raise ValueError(
            f"--params {' '.join(given)}: give one fit.json, first, and after it any "
            "NAME=VALUE to change"
        )
    return _fitted(Path(given[0]), spec) if files else None


def _parameters(spec: ModelSpec, given: list[str], fitted: dict | None) -> tuple[dict, str]:
    """The parameters: p0 of the model file, updated by the ``fitted`` fit.json and
    the NAME=VALUE pairs ``given``; and a line naming those left to p0 ("" if none):
    a partial NAME=VALUE list (or a fit.json of another model file) is easy to
    mistake for a whole one."""
    m = spec.model
    params = dict(spec.p0 or {})
    if fitted is not None:  # the fit's, then the pairs after the file
        named = {**fitted["params"], **_assignments(given[1:], "--params")}
    else:
        named = _assignments(given, "--params")
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


def _integration(args, fitted: dict | None, spec: ModelSpec | None = None) -> Discretisation:
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


def _start(spec: ModelSpec, args, e, fitted, params) -> tuple[np.ndarray, list[str], str]:
    """(x0 to start from, the states to estimate on the record, where x0 comes from):
    --x0 where given; the states the fit (else the model file) frees are estimated
    when the record has outputs; the others are the fit.json's or the model file's (an
    expression of the inputs and parameters, as a fleet's "Dose * Wt", evaluated on
    this record with ``params``)."""
    m = spec.model
    given = _assignments(getattr(args, "x0", []), "--x0")
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


def _scored_provenance(args, m) -> dict:
    """compare.json's provenance: one role per file entry ("u.mat+y.mat" is two)."""
    entries = data_entries([args.data], [effective_columns(m, args.columns)])
    argv, roles = getattr(args, "argv", None), ["scored"] * len(entries)
    return provenance(args.model, entries, argv, ts=args.ts, roles=roles, fit=args.params[0])


def _record(args, spec: ModelSpec, require_outputs: bool):
    """The one record of DATA, with the init window checked before any work."""
    e = one_unit(args, partial(  # one_unit: --records ID --unit 3 (issue 42)
        load_data, [args.data], spec.model, ts=args.ts, samples=getattr(args, "samples", None),
        require_outputs=require_outputs, columns=args.columns,
        events=getattr(args, "events", None)))  # fmt: skip
    if args.init_window is not None:
        if e.y is None:
            raise ValueError(
                f"--init-window: {args.data} has no measured outputs to score (a record is "
                f"scored only with a column for each of {list(spec.model.outputs)})"
            )
        try:
            check_init_window(args.init_window, e)
        except ValueError as err:
            raise ValueError(f"--init-window: {err}") from None
    horizon = getattr(args, "horizon", None)
    if horizon is not None and horizon >= e.P:
        raise ValueError(
            f"--horizon {horizon}: {args.data} has {e.P} samples; give a horizon below that"
        )
    return e


def _simulation_table(m, e, sim, table_only: bool) -> tuple[list[str], np.ndarray]:
    """(header, rows): as one table (.csv --out) the states and simulated outputs;
    in a folder also the inputs and the measured outputs."""
    states = [f"state_{n}" for n in m.states]
    sims = [f"{o}_sim" for o in m.outputs]
    if table_only:
        return ["t", *states, *sims], np.column_stack([e.t, sim.x, sim.y])
    measured = list(m.outputs) if e.y is not None else []
    parts = [e.t[:, None], e.u] + ([e.y] if e.y is not None else []) + [sim.y, sim.x]
    return ["t", *m.inputs, *measured, *sims, *states], np.column_stack(parts)


def _score(args, require_outputs: bool):
    """(spec, parameters, Score, where x0 came from, discretisation, the line naming
    the parameters left to p0): the model
    simulated on DATA as the options say (with ``args.horizon``, predicted that many
    samples ahead by the fit's predictor)."""
    spec = load_model(args.model)
    e = _record(args, spec, require_outputs)
    fitted = _fit_json(spec, args.params)
    same_step(spec.model, e, (fitted or {}).get("sample_time"), f"{args.data}")
    if fitted is not None and other_model(fitted, args.model):
        print(other_model(fitted, args.model), file=sys.stderr)
    try:
        spec, predictor = filter_of(spec, fitted, e)
    except ValueError as err:  # a fit.json of another model: say which file
        raise ValueError(f"--params {args.params[0]}, a filter fit's noise: {err}") from None
    params, defaults = _parameters(spec, args.params, fitted)
    if predictor is not None:  # (a filter's fit.json)
        noise_levels(params, _assignments(args.params[1:], "--params"), args.params[0])
    disc = _integration(args, fitted, spec)
    x0, free, source = _start(spec, args, e, fitted, params)
    horizon = getattr(args, "horizon", None)
    if horizon is not None and predictor is None:
        print(SIMULATED_HORIZON.format(horizon=horizon), file=sys.stderr)
    score = score_record(spec.model, params, x0, free, e, disc, args.init_window, horizon=horizon,
                         predictor=predictor, events=spec.events())  # fmt: skip
    return spec, params, score, source, disc.for_model(spec.model), defaults


def run_simulate(args) -> int:
    out = Path(args.out)
    table_only = out.suffix.lower() == ".csv"
    check_destination(out.parent if table_only else out)
    spec, _, score, source, disc, defaults = _score(args, require_outputs=False)
    m, e, sim = spec.model, score.experiment, score.simulation
    header, table = _simulation_table(m, e, sim, table_only)
    target = out if table_only else out / "simulation.csv"
    target.parent.mkdir(parents=True, exist_ok=True)
    old = set() if table_only else previous_outputs(out, SIMULATE_MANIFEST)
    write_atomic(target, partial(_savetxt, table, header))
    written = [target]
    if not table_only and e.y is not None and sim.status is Status.OK:
        written += _figures(score, out, "simulation")
    if not table_only:  # an earlier simulate's figures of outputs this one lacks: gone
        replace_outputs(out, old, written, SIMULATE_MANIFEST)
    if e.y is not None:
        for o in score.gof:
            print(f"GOF {o}: {gof_text(score, o)}" + _after(score))
        for note in score_notes([score]):
            print(note)
    if defaults:
        print(defaults)
    _print_x0(m, score.x0, source)
    print("wrote " + ", ".join(map(str, written)))
    return _finite(score, disc, args.data)


def _after(score: Score) -> str:
    ahead = f", {score.horizon}-step prediction" if score.horizon else ""
    after = f" (scored after the first {score.start} samples)" if score.start else ""
    return ahead + after


def _print_x0(m, x0, source: str) -> None:
    values = ", ".join(f"{k}={v:.6g}" for k, v in zip(m.states, x0, strict=True))
    print(f"initial state {values} ({source})")


def _finite(score: Score, disc: Discretisation, data: str) -> int:
    """0, or 1 with one line saying where the simulation stopped being finite."""
    sim = score.simulation
    if sim.status is Status.OK:
        return 0
    why = describe_failure(sim, disc.scheme, data)
    print(f"tensorid: error: the simulation is not finite: {why}", file=sys.stderr)
    return 1


def _savetxt(table: np.ndarray, header: list[str], path: Path) -> None:
    # 17 significant digits: every double read back exactly, without %.18e's noise
    np.savetxt(path, table, fmt="%.17g", delimiter=",", header=",".join(header), comments="")


def _figures(score: Score, out: Path, stem: str) -> list[Path]:
    """One figure per output: measured against simulated, the window shaded."""
    e, s = score.experiment, score.simulation
    jobs = []
    for j, name in enumerate(s.model.outputs):
        title = f"{stem} on {e.name or 'data'}, output {name}: GOF {gof_text(score, name)}"
        arguments = dict(
            t=np.asarray(e.t),
            y_meas=np.asarray(e.measured[:, j]),
            y_sim=np.asarray(s.y[:, j]),
            ylabel=name,
            title=title + _after(score),
            window=float(e.t[score.start]) if score.start else None,
        )
        jobs.append((f"{stem}_{file_name(name)}", "compare", arguments))
    return draw_files(out, jobs)


def effective_columns(model, columns: dict | None) -> dict:
    """The column each model signal was read from ("t" too): the map's, else its own
    name (a number: held constant)."""
    columns = columns or {}
    return {n: columns.get(n, n) for n in ("t", *model.inputs, *model.outputs)}


def run_compare(args) -> int:
    """`tensorid compare`: a fit.json scored on a record (compare.json, figures)."""
    if not str(args.params).endswith(".json"):
        raise ValueError(f"--params {args.params}: give the fit.json of a fit")
    out = check_destination(args.out)
    args.params = [args.params]
    spec, params, score, source, disc, defaults = _score(args, require_outputs=True)
    m, sim = spec.model, score.simulation
    data = {
        "record": score.experiment.name,
        "outputs": score.metrics(),
        "init_window": args.init_window,
        "samples": list(args.samples) if getattr(args, "samples", None) else None,
        "horizon": args.horizon,
        # what the outputs were scored as: an output-error fit's every horizon is its
        # simulation, so "horizon" (the one asked for) alone did not say
        "scored_as": f"{score.horizon}-step prediction" if score.horizon else "simulation",
        "scored_samples": score.experiment.P - score.start,
        "x0": dict(zip(m.states, score.x0.tolist(), strict=True)),
        "x0_source": source,
        "x0_fit_status": score.x0_fit,  # how the initial states' fit ended
        "params": {n: float(params[n]) for n in m.params},
        "integration": disc.as_dict(),
        "status": str(sim.status) if scores_finite(score) else NOT_SCORED,
        # why a gof is null although the simulation is finite (a constant output)
        "gof_notes": [n.removeprefix("note: ") for n in metric_notes([score])],
        "provenance": _scored_provenance(args, m),
    }
    out.mkdir(parents=True, exist_ok=True)
    old = previous_outputs(out, COMPARE_MANIFEST)
    written = [write_json(out / "compare.json", data)]
    if sim.status is Status.OK:
        written += _figures(score, out, "compare")
    # an earlier compare's figures (of another model's outputs) are not left beside these
    replace_outputs(out, old, written, COMPARE_MANIFEST)
    _print_scores(score)
    if defaults:  # a fit.json of another model file: say what it did not give
        print(defaults)
    _print_x0(m, score.x0, source)
    print("wrote " + ", ".join(map(str, written)))
    if sim.status is Status.OK and not scores_finite(score):
        print(
            f"tensorid: error: the scores are not finite although the simulation is "
            f"(compare.json status {NOT_SCORED!r}): the {score.horizon}-step predictions of "
            f"--params {args.params[0]} are not finite; check its noise terms",
            file=sys.stderr,
        )
        return 1
    return _finite(score, disc, args.data)


def _print_scores(score: Score) -> None:
    n = score.experiment.P - score.start
    scored = f"{n} samples" + (f" after the first {score.start}" if score.start else "")
    scored += f", {score.horizon}-step prediction" if score.horizon else ""
    flat = undefined_gof(score)
    for o, v in score.metrics().items():
        shown = {k: "undefined" if o in flat else format(x, spec) for k, x, spec in (
            ("nrmse", v["nrmse"], ".6g"), ("r2", v["r2"], ".9g"),
            ("fit_percent", v["fit_percent"], ".4f"), ("gof", v["gof"], ".6f"),
        )}  # fmt: skip
        fit = "undefined" if o in flat else f"{shown['fit_percent']} %"
        print(
            f"{o}: RMSE {v['rmse']:.6g}, NRMSE {shown['nrmse']}, R² {shown['r2']}, "
            f"fit {fit}, GOF {shown['gof']} ({scored})"
        )
    for note in score_notes([score]):
        print(note)
