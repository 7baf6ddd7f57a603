"""`tensorid fit`: from a model file and data files to fit.json, report.md and
figures, with live progress. The steps live beside it: the Problem and the checks
before any work in :mod:`.fit_setup`, the Dask cluster in :mod:`.cluster`, the
statistics asked for after the fit in :mod:`.after_fit`, and keeping fit.json through
Ctrl-C and failed writes in :mod:`.keeping`."""

from __future__ import annotations

import sys
from functools import partial
from pathlib import Path

from rich.console import Console, Group
from rich.live import Live

from ..analysis.display import summary_table
from ..analysis.figures import figure_jobs
from ..analysis.results import FitInterrupted
from ..analysis.validation import Score, training_scores
from ..engine.assembly.problem import Problem
from ..engine.modelling.checks import same_step, step
from ..engine.schemes.status import Status
from ..fitting.methods import fit
from ..population import PopulationResult
from ..population.profiles import profile_names
from . import fleets
from .after_fit import _after_fit, _gof_lines, _profile_figures
from .cluster import _workers
from .compile_progress import CompileWatch
from .files import load_data, load_model
from .fit_flags import fit_options
from .fit_setup import (  # _problem and _data_entries are also patched and read by tests here
    _check_options,
    _data_entries,
    _maps,
    _one,
    _problem,
    _validation_data,
    checked_method,
    discretisation,
    no_repeats,
    predictor_origin,
)
from .fleet_flags import check_fleet_flags
from .keeping import (
    _no_interrupt,
    _save_after_interrupt,
    _save_interrupted,
    drawn_here,
    write_folder,
)
from .output import check_destination, claimed, previous_outputs
from .overrides import given_once, overridden
from .population_run import report_population, save_interrupted
from .progress import _log_line, _progress_table
from .provenance import provenance
from .renderer import Renderer
from .reports import fit_json, fit_report

__all__ = ["discretisation", "run_fit"]


def _run(problem: Problem, args, console: Console, executor, timeout, watch: CompileWatch):
    options = dict(
        starts=args.starts,
        spread=args.spread,
        seed=args.seed,
        executor=executor,
        workers=args.workers,
        batch=args.batch,
        timeout=timeout,
        polish=not args.no_polish,
        **fit_options(args),  # --maxiter, --gtol, --ftol, --xtol
    )
    rows: list[dict] = []
    if args.no_progress:
        return fit(problem, args.method, **options)
    fleet = bool(problem.population or problem.individual)
    if args.starts > 1 and fleet:  # one after another here, each one's iterations below
        console.print(f"running {args.starts} starts one after another; each one's "
                      "iterations below", soft_wrap=True, highlight=False)  # fmt: skip
    elif args.starts > 1:  # the starts' own iterations run in the workers, unseen here
        where = "on " + args.scheduler if args.scheduler else "locally"
        console.print(
            f"running {args.starts} starts {where}; the best is then refined here, its "
            "iterations below",
            soft_wrap=True,
            highlight=False,
        )
    if not console.is_terminal:  # a log: one plain line per iteration, no live table
        return fit(problem, args.method, callback=_log_line(console), **options)
    table = [_progress_table(rows)]

    def shown():  # the iterations, and under them what is being compiled
        line = watch.line()
        return Group(table[0], line) if line else table[0]

    watch.hosted = True
    try:
        with Live(get_renderable=shown, console=console, refresh_per_second=8):

            def show(entry):
                rows.append(entry)
                table[0] = _progress_table(rows)

            return fit(problem, args.method, callback=show, **options)
    finally:
        watch.hosted = False


def _write_results(res, out: Path, scores: list[Score], old, extras, kept: dict, drawn):
    """fit.json, the figures and report.md by the one writer (keeping.write_folder).
    ``drawn`` is (renderer, the stems of the figures it was given, in their order).
    Returns (figures written, failures as one line each)."""
    profiles, influence = extras.get("profiles"), extras.get("influence")
    residual = extras.get("residual")
    data = fit_json(res, scores, profiles, influence, residual)
    recorded = ("provenance", "overrides", "samples", "validate_samples")  # _recorded's
    data.update({k: extras[k] for k in recorded if k in extras})
    renderer, stems = drawn
    # in the report's order: the fit's figures, profiles, residual tests, sensitivity
    figures = [(s, partial(renderer.collect, s)) for s in stems if s != "residual_tests"]
    figures += [(stem, drawn_here(out / f"{stem}.png", build))
                for stem, build in _profile_figures(res, profiles)]  # fmt: skip
    figures += [(s, partial(renderer.collect, s)) for s in stems if s == "residual_tests"]
    if influence is not None:
        figures.append(("data_sensitivity", drawn_here(out / "data_sensitivity.png",
                                                       influence.figure)))  # fmt: skip
    everything = training_scores(res) + scores

    def report(made: list[Path]) -> str:
        return fit_report(res, data, everything, made, profiles, residual)

    return write_folder(out, old, data, kept, figures, report)


def run_fit(args) -> int:
    check_destination(args.out)
    # the figures are drawn in a second process, started now so that its imports
    # overlap the fit's; it is ended however the command ends
    renderer = Renderer()
    try:
        return _fit_command(args, renderer)
    finally:
        renderer.close()


def _fit_command(args, renderer: Renderer) -> int:
    console = Console(stderr=True)
    spec = load_model(args.model)
    m = spec.model
    train_maps = _maps(args.columns, args.data, "--columns")
    no_repeats(args.data, train_maps)
    train = load_data(
        args.data,
        m,
        ts=args.ts,
        samples=args.samples,
        columns=train_maps,
        records=getattr(args, "records", None),  # fleets (issue 42)
        covariates=spec.covariates,
        events=getattr(args, "events", None),  # an event table's column names
    )
    val_maps = _maps(
        args.validate_columns or _one(args.columns), args.validate, "--validate-columns"
    )
    val = _validation_data(args, m, val_maps, spec)
    _check_options(args, train, val)
    for e in val:  # a discrete-time model at another rate: refused before the fit
        same_step(m, e, step(train[0]), f"the validation record {e.name!r}")
    args.provenance = _provenance(args, m, train_maps, val_maps)
    fix, bounds = given_once("--fix", args.fix), given_once("--bounds", args.bounds)
    spec, args.overrides = overridden(spec, fix, args.free, bounds)
    spec = fleets.from_command_line(spec, args)  # --individual, --population
    if spec.population or spec.individual:  # before the Problem: the flag is named
        check_fleet_flags(args)
    problem = _problem(spec, train, args)
    held = None  # a fleet's --validate: held-out units (population/validation.py)
    is_fleet = bool(problem.population or problem.individual)
    if is_fleet:
        held = _problem(spec, val, args, held_out=True) if val else None
    if problem.loss.likelihood and args.data_sensitivity:
        raise ValueError(
            f"--data-sensitivity is for output error, not a filter fit "
            f"({predictor_origin(spec, args)}): drop it, or fit with --predictor simulation"
        )
    if problem.loss.robust and (args.profile is not None or args.data_sensitivity):
        raise ValueError(
            f"--profile and --data-sensitivity assume the squared loss, not --loss "
            f"{problem.loss.name} (its error bars are the sandwich form): drop them, or fit "
            "with --loss squared"
        )
    # a method that cannot serve it: refused before the folder is touched
    checked_method(problem, args.method, predictor_origin(spec, args))
    known = profile_names(problem) if is_fleet else problem.theta_names
    if is_fleet and args.profile is not None and not known:
        raise ValueError(
            "--profile: a fit with individual parameters alone (least squares over every "
            "unit's own values) is not profiled yet; drop --profile and read its error bars"
        )
    unknown = [n for n in args.profile or [] if n not in known]
    if unknown:
        raise ValueError(f"--profile: unknown names {unknown}; the unknowns are {known}")
    out = Path(args.out)
    watch = CompileWatch(console, enabled=not args.no_progress)  # what XLA compiles
    with _workers(args) as (executor, timeout), claimed(out), watch:
        old = previous_outputs(out)
        try:
            res = _run(problem, args, console, executor, timeout, watch)
        except FitInterrupted as stop:
            with _no_interrupt():  # a second Ctrl-C while saving would lose it
                if isinstance(stop.result, PopulationResult):
                    return save_interrupted(stop.result, out, old, _recorded(args))
                return _save_interrupted(stop.result, out, old, _recorded(args))
        kept: dict = {}  # where the complete fit.json went, once it is written
        fleet = isinstance(res, PopulationResult)  # a fleet's population fit
        try:
            if fleet:
                return report_population(res, out, old, _recorded(args), args, held, renderer,
                                         kept)  # fmt: skip
            return _report(res, val, args, out, old, kept, renderer)
        except KeyboardInterrupt:  # Ctrl-C after the fit: the estimates are kept
            with _no_interrupt():
                if fleet:
                    return save_interrupted(res, out, old, _recorded(args), kept, after=True)
                return _save_after_interrupt(res, out, old, kept, _recorded(args))


def _recorded(args) -> dict:
    """What fit.json records of the command itself: the files' provenance, the
    command line's overrides of the model file and the slices of the records used."""
    return {
        "provenance": args.provenance,
        "overrides": args.overrides,
        "samples": _window(getattr(args, "samples", None)),
        "validate_samples": _window(getattr(args, "validate_samples", None)),
    }


def _window(samples) -> list[int] | None:
    return list(samples) if samples else None


def _provenance(args, m, train_maps, val_maps) -> dict:
    """The files' provenance: each data file's role (training or validation), the
    slice of it used (--samples, --validate-samples) and its time base."""
    train = _data_entries(m, args.data, train_maps)
    val = _data_entries(m, args.validate, val_maps)
    for entries, window in ((train, args.samples), (val, args.validate_samples)):
        for entry in entries:
            entry["samples"] = _window(window)
    roles = ["training"] * len(train) + ["validation"] * len(val)
    argv = getattr(args, "argv", None)
    start = getattr(args, "start_from", None)  # (issue 51: fit.json did not say)
    return provenance(args.model, train + val, argv, ts=args.ts, roles=roles, start_from=start)


def _report(res, val, args, out: Path, old: set[Path], kept: dict, renderer) -> int:
    """Everything after a fit: validation, statistics, the console, the files. Each
    figure goes to the renderer as soon as its data are known, so that it is drawn
    while the statistics are computed."""
    early = renderer.submit(out, figure_jobs(res))  # the training records, convergence
    # what follows the fit may be stopped or fail; the fit itself is kept
    scores, extras, missing, stopped = _after_fit(res, val, args)
    late = renderer.submit(out, figure_jobs(res, scores, training=False, convergence=False))
    # in fit_figures' order: training, validation, convergence; then the residual tests
    stems = [s for s in early if s != "convergence"] + late
    stems += [s for s in early if s == "convergence"]
    residual = extras.get("residual")
    job = residual.figure_job() if residual is not None else None
    if job is not None:  # None: no test was made (too many lags)
        stems += renderer.submit(out, [job])
    everything = training_scores(res) + scores
    # the estimates reach the terminal before any file is written
    print(summary_table(res, everything, residual, extras.get("model_check")))
    for line in _gof_lines(everything):
        print(line)
    extras.update(_recorded(args))
    figures, failures = _write_results(res, out, scores, old, extras, kept, (renderer, stems))
    failures = missing + failures
    if failures or stopped:
        for f in failures:
            print(f"tensorid: error: {f}", file=sys.stderr)
        if kept.get("fit.json"):
            print(f"tensorid: {kept['fit.json']} was written", file=sys.stderr)
        return 130 if stopped else 1
    print(f"wrote {out}/fit.json, report.md and {len(figures)} figures")
    if res.status is Status.WORKERS_LOST:
        print(f"tensorid: error: {res.message}", file=sys.stderr)
    return 0 if res.success else 1
