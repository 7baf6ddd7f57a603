"""`tensorid simulate` and `tensorid compare`: a model with given (or fitted)
parameters on one record. Both call the library's scoring (``score_record``, the
routine behind ``FitResult.validate``), so a record is simulated, its initial
states estimated and its outputs scored exactly as ``fit --validate`` does."""

from __future__ import annotations

import sys
from functools import partial
from pathlib import Path

import numpy as np

from ..analysis.figures import file_name
from ..analysis.summary import gof_text, metric_notes, score_notes, undefined_gof
from ..analysis.validation import Score, check_init_window, score_record
from ..engine.assembly.diagnostics import describe_failure
from ..engine.modelling.checks import same_step
from ..engine.schemes.discretisation import Discretisation
from ..engine.schemes.status import Status
from .after_fit import SIMULATED_HORIZON
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
from .scored_start import (
    assignments,
    fit_json,
    integration,
    parameters,
    start_of,
    unit_estimate,
)


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
    measured_y = [e.measured_with_gaps] if e.y is not None else []  # NaN: not measured
    parts = [e.t[:, None], e.u] + measured_y + [sim.y, sim.x]
    return ["t", *m.inputs, *measured, *sims, *states], np.column_stack(parts)


def _score(args, require_outputs: bool):
    """(spec, parameters, Score, where x0 came from, discretisation, the line naming
    the parameters left to p0): the model
    simulated on DATA as the options say (with ``args.horizon``, predicted that many
    samples ahead by the fit's predictor)."""
    spec = load_model(args.model)
    e = _record(args, spec, require_outputs)
    fitted = fit_json(spec, args.params)
    same_step(spec.model, e, (fitted or {}).get("sample_time"), f"{args.data}")
    if fitted is not None and other_model(fitted, args.model):
        print(other_model(fitted, args.model), file=sys.stderr)
    try:
        spec, predictor = filter_of(spec, fitted, e)
    except ValueError as err:  # a fit.json of another model: say which file
        raise ValueError(f"--params {args.params[0]}, a filter fit's noise: {err}") from None
    params, defaults = parameters(spec, args.params, fitted)
    if predictor is not None:  # (a filter's fit.json)
        noise_levels(params, assignments(args.params[1:], "--params"), args.params[0])
    disc = integration(args, fitted, spec)
    eta = None  # --ipred: the unit's own values, η̂ by empirical Bayes from its data
    if getattr(args, "ipred", False):
        if fitted is None:
            raise ValueError(
                "--ipred estimates a unit's own values from a population fit: give its "
                "fit.json with --params FIT.json"
            )
        if len(args.params) > 1:
            raise ValueError(
                "--ipred estimates the unit's own values from the fit's population: drop "
                f"the NAME=VALUE pairs after {args.params[0]}"
            )
        params, eta, defaults = unit_estimate(spec, fitted, e, disc, params, args.params[0])
    if fitted is not None and fitted.get("population") and "integration" not in fitted:
        print(f"note: --params {args.params[0]} does not record the fit's integration (a "
              f"fit.json before 2026-12-07): integrated at {disc.substeps} substeps; give "
              "--substeps as the fit's", file=sys.stderr)  # fmt: skip
    x0, free, source = start_of(spec, args, e, fitted, params)
    horizon = getattr(args, "horizon", None)
    if horizon is not None and predictor is None:
        print(SIMULATED_HORIZON.format(horizon=horizon), file=sys.stderr)
    score = score_record(spec.model, params, x0, free, e, disc, args.init_window, horizon=horizon,
                         predictor=predictor, events=spec.events())  # fmt: skip
    return spec, params, score, source, disc.for_model(spec.model), defaults, eta


def run_simulate(args) -> int:
    out = Path(args.out)
    table_only = out.suffix.lower() == ".csv"
    check_destination(out.parent if table_only else out)
    spec, _, score, source, disc, defaults, _ = _score(args, require_outputs=False)
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
    # the shortest text that reads back as the same double (Python's repr): exact, and
    # a time snapped to 0.1 reads 0.1, not %.17g's 0.10000000000000001
    with open(path, "w") as f:
        f.write(",".join(header) + "\n")
        f.writelines(",".join(map(repr, row)) + "\n" for row in np.asarray(table, float).tolist())


def _figures(score: Score, out: Path, stem: str) -> list[Path]:
    """One figure per output: measured against simulated, the window shaded."""
    e, s = score.experiment, score.simulation
    jobs = []
    for j, name in enumerate(s.model.outputs):
        title = f"{stem} on {e.name or 'data'}, output {name}: GOF {gof_text(score, name)}"
        arguments = dict(
            t=np.asarray(e.t),
            y_meas=np.asarray(e.measured_with_gaps[:, j]),  # (a dose's row: no point)
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
    spec, params, score, source, disc, defaults, eta = _score(args, require_outputs=True)
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
        "scored_samples": score.samples,
        "x0": dict(zip(m.states, score.x0.tolist(), strict=True)),
        "x0_source": source,
        "x0_fit_status": score.x0_fit,  # how the initial states' fit ended
        "params": {n: float(params[n]) for n in m.params},
        # --ipred: the unit's random effects by empirical Bayes (params are at them)
        "eta": eta,
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
    after = f" after the first {score.start}" if score.start else ""
    after += f", {score.horizon}-step prediction" if score.horizon else ""
    flat = undefined_gof(score)
    for o, v in score.metrics().items():
        scored = f"{score.scored[o]} samples{after}"  # its own (outputs measured apart)
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
