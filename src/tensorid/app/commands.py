"""`tensorid fit` and `tensorid simulate`: from a model file and data files to fit.json,
report.md and figures, with live progress."""

from __future__ import annotations

import sys
from collections.abc import Iterator
from contextlib import contextmanager
from functools import partial
from pathlib import Path

import numpy as np
from rich.console import Console
from rich.live import Live
from rich.table import Table

from ..engine.adjoint import supports as adjoint_supports
from ..engine.discretisation import Discretisation
from ..engine.integrators import SCHEMES
from ..engine.problem import Problem
from ..engine.shooting import resolve_segments
from ..engine.status import Status
from ..fitting.figures import (
    file_name,
    fit_figures,
    profile_figure,
    save_png,
)
from ..fitting.methods import fit
from ..fitting.registry import exact_derivatives
from ..fitting.residuals import lag_limit
from ..fitting.results import FitInterrupted
from ..fitting.summary import coloured_residuals_line, summary_table
from ..fitting.validation import Score, check_init_window, training_scores
from .files import ModelSpec, load_data, load_model
from .output import (
    check_destination,
    claimed,
    previous_outputs,
    replace_outputs,
    write_atomic,
    write_kept,
    write_text,
)
from .overrides import overridden
from .provenance import data_entries, provenance
from .reports import fit_json, fit_report, json_text
from .simulate import effective_columns


def _progress_table(rows: list[dict]) -> Table:
    t = Table(title="tensorid fit", show_edge=False)
    for c in ("iter", "cost", "grad norm", "trust radius", "step"):
        t.add_column(c, justify="right")
    for h in rows[-12:]:
        t.add_row(
            str(h["iteration"]),
            f"{h['cost']:.8g}",
            f"{h['grad_norm']:.2e}",
            f"{h['radius']:.2e}",
            "accepted" if h["accepted"] else "rejected",
        )
    return t


def discretisation(args) -> Discretisation:
    """The integration settings of the command line, checked once."""
    return Discretisation.of(args.scheme, args.substeps, args.interpolation, args.rtol, args.atol)


def _problem(spec: ModelSpec, train, args) -> Problem:
    if spec.p0 is None:
        raise ValueError(
            f"{spec.path} defines no p0: add p0 = {{name: start value}} for "
            f"{list(spec.model.params)}"
        )
    disc = discretisation(args)
    hessian = getattr(args, "hessian", "auto")
    if hessian == "adjoint" and not adjoint_supports(disc):
        explicit = [n for n in SCHEMES if adjoint_supports(Discretisation.of(n))]
        raise ValueError(
            f"--hessian adjoint needs an explicit scheme ({', '.join(explicit)}) or a "
            f"discrete-time model, not --scheme {disc.scheme.name}: drop --hessian or "
            "give --hessian tensors"
        )
    try:  # the segments are the command line's, not the model file's
        resolve_segments(train, args.segments, args.segment_length)
    except ValueError as e:
        raise ValueError(f"--segments/--segment-length: {e}") from None
    try:
        return Problem(
            spec.model,
            train,
            p0=spec.p0,
            x0=spec.x0_array(),
            free_x0=spec.free_x0,
            fixed=spec.fixed,
            bounds=spec.bounds,
            weights=spec.weights,
            priors=spec.priors or None,
            noise=spec.noise,
            discretisation=disc,
            segments=args.segments,
            segment_length=args.segment_length,
            hessian=hessian,
            **_loss(spec, args),
        )
    except (ValueError, TypeError) as e:  # the settings come from the model file
        raise type(e)(f"{spec.path}: {e}") from None


def _loss(spec: ModelSpec, args) -> dict:
    """loss and loss_scale: the command line's over the model file's."""
    loss = getattr(args, "loss", None) or spec.loss or "squared"
    scale = getattr(args, "loss_scale", None)
    scale = spec.loss_scale if scale is None else scale
    if loss == "squared" and scale is not None:
        raise ValueError("--loss-scale (or loss_scale) is for a robust --loss; drop it or give one")
    return {"loss": loss, "loss_scale": scale}


def _connect(address: str, timeout: float):
    """A Dask client for the scheduler at ``address``, or one line saying why not."""
    import socket
    from urllib.parse import urlsplit

    fix = "check the address and that `dask scheduler` runs there"
    url = urlsplit(address if "://" in address else "tcp://" + address)
    if url.scheme == "tcp":
        try:
            host, port = url.hostname, url.port
            if not host or not port:
                raise ValueError("it has no host:port")
            # a plain connect first: distributed's own failure leaves tracebacks behind
            socket.create_connection((host, port), timeout=min(timeout, 10)).close()
        except (OSError, ValueError) as e:
            raise ValueError(f"--scheduler {address}: cannot connect ({e}); {fix}") from None
    from distributed import Client

    try:
        return Client(address, timeout=min(timeout, 30), set_as_default=False)
    except (OSError, ValueError, TimeoutError) as e:
        raise ValueError(f"--scheduler {address}: cannot connect ({e}); {fix}") from None


@contextmanager
def _workers(args) -> Iterator[tuple]:
    """(executor, timeout) for the starts: a Dask cluster's with --scheduler
    (connected before any work, closed after), else none (a local pool)."""
    timeout = args.worker_timeout
    if not args.scheduler:
        yield None, timeout
        return
    timeout = 300.0 if timeout is None else timeout
    client = _connect(args.scheduler, timeout)
    try:
        yield client.get_executor(), timeout
    finally:
        client.close()


def _run(problem: Problem, args, console: Console, executor, timeout):
    options = dict(
        starts=args.starts,
        spread=args.spread,
        seed=args.seed,
        executor=executor,
        workers=args.workers,
        batch=args.batch,
        timeout=timeout,
        polish=not args.no_polish,
    )
    rows: list[dict] = []
    if args.no_progress:
        return fit(problem, args.method, **options)
    if not console.is_terminal:  # a log: one plain line per iteration, no live table
        return fit(problem, args.method, callback=_log_line(console), **options)
    if args.starts > 1:
        where = "on " + args.scheduler if args.scheduler else "locally"
        console.log(f"running {args.starts} starts {where}...")
    with Live(_progress_table(rows), console=console, refresh_per_second=8) as live:

        def show(entry):
            rows.append(entry)
            live.update(_progress_table(rows))

        return fit(problem, args.method, callback=show, **options)


def _log_line(console: Console):
    def show(h: dict) -> None:
        parts = [f"iteration {h['iteration']}: cost {h['cost']:.8g}"]
        for key, label in (("grad_norm", "gradient norm"), ("radius", "trust radius")):
            if np.isfinite(h[key]):  # the finite-difference baselines have neither
                parts.append(f"{label} {h[key]:.2e}")
        if h["iteration"] > 0:
            parts.append("accepted" if h["accepted"] else "rejected")
        console.print(", ".join(parts), soft_wrap=True, highlight=False)

    return show


def _gof_lines(scores: list[Score]) -> list[str]:
    kinds = {"training": "train", "validation": "validation"}
    out = []
    for s in scores:
        label = s.label.replace(s.kind, kinds[s.kind], 1)
        label = label.replace("'", "")
        per = ", ".join(f"{o} {v:.4f}" for o, v in s.gof.items())
        out.append(f"GOF {label}: {per}")
    return out


def _keep(out: Path, data: dict, kept: dict) -> list[str]:
    """fit.json into ``out`` or, where that fails, into a fallback file; its path goes
    to kept["fit.json"]. Where nothing can be written the JSON goes to the console.
    Returns the failures, one line each, naming the file and where the result went."""
    text = json_text(data)
    try:
        where, why = write_kept(out / "fit.json", text)
    except OSError as e:
        print(text)  # the last place left: the console
        return [f"{e}; fit.json is printed above"]
    kept["fit.json"] = where
    return [f"{why}; the results are in {where}"] if why else []


def _write_results(res, out: Path, scores: list[Score], old: set[Path], extras, kept: dict):
    """fit.json first (the estimates are what matters), then the figures and
    report.md, each atomically; what an earlier run wrote and this one did not is
    removed. Returns (figures written, failures as one line each). A failing figure,
    report or folder does not lose fit.json (see _keep)."""
    profiles, influence = extras.get("profiles"), extras.get("influence")
    residual = extras.get("residual")
    data = fit_json(res, scores, profiles, influence, residual)
    data.update({k: extras[k] for k in ("provenance", "overrides") if k in extras})
    failures = _keep(out, data, kept)
    if kept.get("fit.json") != out / "fit.json":
        return [], failures  # the folder cannot be written: the rest would fail as well
    written, figures = [kept["fit.json"]], []
    more = _profile_figures(res, profiles)
    residual_figure = residual.figure() if residual is not None else None
    if residual_figure is not None:  # None: no test was made (too many lags)
        more.append(("residual_tests", residual_figure))
    if influence is not None:
        more.append(("data_sensitivity", influence.figure()))
    for stem, fig in fit_figures(res, None, scores, named=True) + more:
        try:
            figures.append(write_atomic(out / f"{stem}.png", partial(save_png, fig)))
        except OSError as e:
            failures.append(f"could not write {out / (stem + '.png')}: {e.strerror or e}")
    everything = training_scores(res) + scores
    try:
        report = fit_report(res, data, everything, figures, profiles, residual)
        written.append(write_text(out / "report.md", report))
    except OSError as e:
        failures.append(f"could not write {out / 'report.md'}: {e.strerror or e}")
    _replace_quietly(out, old, written + figures, failures)
    return figures, failures


def run_fit(args) -> int:
    console = Console(stderr=True)
    check_destination(args.out)
    spec = load_model(args.model)
    m = spec.model
    train_maps = _maps(args.columns, args.data, "--columns")
    train = load_data(args.data, m, ts=args.ts, samples=args.samples, columns=train_maps)
    val_maps = _maps(
        args.validate_columns or _one(args.columns), args.validate, "--validate-columns"
    )
    val = _validation_data(args, m, val_maps)
    _check_options(args, train, val)
    args.provenance = provenance(
        args.model,
        _data_entries(m, args.data, train_maps) + _data_entries(m, args.validate, val_maps),
        getattr(args, "argv", None),
    )
    spec, args.overrides = overridden(spec, dict(args.fix), args.free, dict(args.bounds))
    problem = _problem(spec, train, args)
    if not problem.loss.squared and (args.profile is not None or args.data_sensitivity):
        raise ValueError(
            f"--profile and --data-sensitivity assume the squared loss, not --loss "
            f"{problem.loss.name} (its error bars are the sandwich form): drop them, or fit "
            "with --loss squared"
        )
    unknown = [n for n in args.profile or [] if n not in problem.theta_names]
    if unknown:
        raise ValueError(
            f"--profile: unknown names {unknown}; the unknowns are {problem.theta_names}"
        )
    out = Path(args.out)
    with _workers(args) as (executor, timeout), claimed(out):
        old = previous_outputs(out)
        try:
            res = _run(problem, args, console, executor, timeout)
        except FitInterrupted as stop:
            with _no_interrupt():  # a second Ctrl-C while saving would lose it
                return _save_interrupted(stop.result, out, old)
        kept: dict = {}  # where the complete fit.json went, once it is written
        try:
            return _report(res, val, args, out, old, kept)
        except KeyboardInterrupt:  # Ctrl-C after the fit: the estimates are kept
            with _no_interrupt():
                return _save_after_interrupt(res, out, old, kept)


def _report(res, val, args, out: Path, old: set[Path], kept: dict) -> int:
    """Everything after a fit: validation, statistics, the console, the files."""
    # what follows the fit may be stopped or fail; the fit itself is kept
    scores, extras, missing, stopped = _after_fit(res, val, args)
    everything = training_scores(res) + scores
    # the estimates reach the terminal before any file is written
    print(summary_table(res, everything))
    for line in _gof_lines(everything):
        print(line)
    residual = extras.get("residual")
    if residual is not None and res.has_uncertainty and False in residual.whiteness_passed:
        print(f"residuals: {coloured_residuals_line(res)}")
    extras.update(provenance=args.provenance, overrides=args.overrides)
    figures, failures = _write_results(res, out, scores, old, extras, kept)
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


def _save_after_interrupt(res, out: Path, old: set[Path], kept: dict) -> int:
    """Ctrl-C while the statistics, the console or the files of a finished fit were
    being made: a complete fit.json already written stays; otherwise the estimates
    go to fit.json without the statistics (no further computation). Exit status 130."""
    if kept.get("fit.json"):
        _tidy(out, old, kept, [])
        print(f"tensorid: interrupted; {kept['fit.json']} was written", file=sys.stderr)
        return 130
    why = "interrupted after the fit, before its statistics were written: run it again for them"
    for name, value in res.params.items():  # the estimates on the console first
        print(f"{name} = {value!r}")
    where = _save_now(out, old, lambda: fit_json(res, [], missing=why))
    print(f"tensorid: interrupted after the fit; the estimates are in {where}", file=sys.stderr)
    return 130


def _save_now(out: Path, old: set[Path], data) -> Path | str:
    """fit.json from ``data()`` at once (under _no_interrupt), the failures printed.
    Returns where it went ("the console" where nowhere else)."""
    kept: dict = {}
    _tidy(out, old, kept, _keep(out, data(), kept))
    return kept.get("fit.json", "the console")


def _tidy(out: Path, old: set[Path], kept: dict, failures: list[str]) -> None:
    """After an interrupt: with fit.json in ``out``, the earlier run's files removed
    (no mix of two runs); the failures printed."""
    if kept.get("fit.json") == out / "fit.json":
        _replace_quietly(out, old, [kept["fit.json"]], failures)
    for f in failures:
        print(f"tensorid: error: {f}", file=sys.stderr)


@contextmanager
def _no_interrupt() -> Iterator[None]:
    """SIGINT ignored inside (main thread only: elsewhere signals are not ours)."""
    import signal
    import threading

    if threading.current_thread() is not threading.main_thread():
        yield
        return
    before = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, before)


def _replace_quietly(out: Path, old: set[Path], written: list[Path], failures: list):
    """replace_outputs, a failure appended to ``failures`` instead of raised."""
    try:
        replace_outputs(out, old, written)
    except OSError as e:
        failures.append(f"could not remove the earlier results in {out}: {e.strerror or e}")


def _validation_data(args, model, columns) -> list:
    """The --validate records, read with their column maps (--validate-columns,
    default: --columns where it is one map for all files)."""
    if not args.validate:
        return []
    try:
        return load_data(
            args.validate, model, ts=args.ts, samples=args.validate_samples, columns=columns
        )
    except ValueError as e:
        if "column" not in str(e) or args.validate_columns:
            raise
        hint = "--columns applies to them too" if args.columns else "they are read by name"
        raise ValueError(
            f"{e} ({hint}: name their columns with --validate-columns NAME=COLUMN,...)"
        ) from None


def _check_options(args, train, val) -> None:
    """The options that depend on the records, checked before any work."""
    if args.init_window is not None and not val:
        raise ValueError("--init-window applies to validation records: give --validate FILE")
    if args.init_window is not None and args.init_window < 2:
        raise ValueError(
            f"--init-window {args.init_window}: the initial states are estimated on at least "
            "2 samples; give 2 or more"
        )
    if args.validate_columns and not val:
        raise ValueError("--validate-columns applies to validation files: give --validate FILE")
    if args.no_polish and args.segments is None and args.segment_length is None:
        raise ValueError(
            "--no-polish applies to multiple shooting (the polish follows the segments): "
            "give --segments or --segment-length, or drop --no-polish"
        )
    if getattr(args, "hessian", "auto") != "auto" and not exact_derivatives(args.method):
        raise ValueError(
            f"--hessian {args.hessian}: --method {args.method} is a finite-difference "
            "baseline and computes no exact Hessian; drop --hessian or choose another method"
        )
    for e in val if args.init_window is not None else []:
        try:
            check_init_window(args.init_window, e)
        except ValueError as err:
            raise ValueError(f"--init-window: {err}") from None
    samples = sum(e.P for e in train)
    if args.residual_lags is not None and args.residual_lags > lag_limit(samples):
        raise ValueError(
            f"--residual-lags {args.residual_lags}: the training records have {samples} "
            f"samples; the residual tests take at most N/4 = {lag_limit(samples)} lags"
        )


def _maps(given: list | None, files: list, option: str):
    """The column maps of the command line for ``files``: one for all (a dict), one
    per file (a list), or none."""
    if not given:
        return None
    if len(given) == 1:
        return given[0]
    if len(given) != len(files):
        raise ValueError(
            f"{option} is given {len(given)} times for {len(files)} data files: give it "
            "once for all files, or once per file in their order"
        )
    return list(given)


def _one(maps: list | None):
    """--columns as the validation files' default: only when it is one map for all."""
    return maps if maps and len(maps) == 1 else None


def _data_entries(m, files: list, maps) -> list[dict]:
    per_file = maps if isinstance(maps, list) else [maps] * len(files)
    return data_entries(files, [effective_columns(m, c) for c in per_file])


def _after_fit(res, val, args) -> tuple[list, dict, list[str], bool]:
    """Validation, profiles and data sensitivity: (scores, extras, what could not be
    computed, whether Ctrl-C stopped them). Neither Ctrl-C nor a failure here loses
    the fit: the results are written without what is missing."""
    scores: list = []
    extras: dict = {}
    steps = [("validation", lambda: res.validate(val, args.init_window) if val else [])]
    steps += [("profiles", lambda: _profiles(res, args))]
    steps += [("data sensitivity", lambda: _influence(res, args))]
    steps += [("residual tests", lambda: _residual_tests(res, args))]
    missing: list[str] = []
    for name, step in steps:
        try:
            value = step()
        except KeyboardInterrupt:
            return scores, extras, [f"interrupted during the {name}: written without it"], True
        except (ValueError, ArithmeticError) as e:  # LinAlgError is a ValueError
            missing.append(f"could not compute the {name} ({e}): written without it")
            continue
        if name == "validation":
            scores = value
        else:
            keys = {"profiles": "profiles", "data sensitivity": "influence"}
            extras[keys.get(name, "residual")] = value
    return scores, extras, missing, False


DEFAULT_LAGS = 25  # MATLAB resid's


def _residual_tests(res, args):
    """Whiteness and independence of the residuals, one line each (a fit with a
    finite cost only)."""
    if not np.isfinite(res.cost):
        return None
    samples = sum(e.P for e in res.problem.experiments)
    # the default shrinks on a short record; below 4 samples the tests say not available
    lags = args.residual_lags or max(min(DEFAULT_LAGS, lag_limit(samples)), 1)
    tests = res.residual_tests(lags)
    for line in tests.lines():
        print(f"residuals: {line}")
    return tests


def _profiles(res, args) -> dict | None:
    """--profile: the profile likelihood of the named unknowns (all free parameters
    when none is named), one line each."""
    if args.profile is None:
        return None
    if not res.has_uncertainty:
        print(f"tensorid: no profiles: the fit ended as {res.status}", file=sys.stderr)
        return None
    profiles = res.profile(args.profile or None, level=args.profile_level)
    for p in profiles.values():
        print(p.describe())
    return profiles


def _influence(res, args):
    """--data-sensitivity: dθ/dy, and the samples that pulled each estimate most."""
    if not args.data_sensitivity:
        return None
    if not res.has_uncertainty:
        print(f"tensorid: no data sensitivity: the fit ended as {res.status}", file=sys.stderr)
        return None
    influence = res.data_sensitivity()
    for name in influence.names:
        record, k, output, pull = influence.most_influential(name, 1)[0]
        print(f"{name}: pulled most by {record} sample {k} ({output}), by {pull:.3g}")
    return influence


def _profile_figures(res, profiles) -> list:
    if not profiles:
        return []
    u = res.uncertainty()
    return [
        (f"profile_{file_name(name)}", profile_figure(p, u.sigma2, u.stderr[p.index]))
        for name, p in profiles.items()
    ]


def _save_interrupted(res, out: Path, old: set[Path]) -> int:
    """Ctrl-C: the best point so far goes to fit.json (status "interrupted") at once;
    no figures or report (the user is waiting); older results are removed, not
    mixed in. Exit status 130, as for any interrupted command."""
    if not np.isfinite(res.cost):  # nothing worth more than what the folder holds
        print(
            f"tensorid: interrupted before any start finished; {out} is as it was", file=sys.stderr
        )
        return 130
    print(summary_table(res, []))
    where = _save_now(out, old, lambda: fit_json(res, []))
    print(
        f"tensorid: interrupted; the best point so far (cost {res.cost:.6g}) is in {where}",
        file=sys.stderr,
    )
    return 130
