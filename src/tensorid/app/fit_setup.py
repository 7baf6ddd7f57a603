"""What `tensorid fit` makes of its command line before any work: the Problem (model
file, records and options), the validation records, the column maps and the checks
of options that depend on the records. Every mistake is one line (a ValueError)."""

from __future__ import annotations

import dataclasses
import re
import sys

import numpy as np

from ..analysis.residuals import lag_limit, tested_samples
from ..analysis.summary import SIGMA_E_FLOOR
from ..analysis.validation import check_init_window
from ..engine.assembly.problem import Problem
from ..engine.assembly.start import Start
from ..engine.schemes.discretisation import Discretisation
from ..engine.schemes.integrators import SCHEMES
from ..engine.sweeping.hessians import get_hessian
from ..engine.sweeping.losses import get_loss
from ..engine.sweeping.predictors import NOISE_PREFIXES, SIMULATION, get_predictor
from ..engine.sweeping.shooting import resolve_segments
from ..fitting.methods import check_fleet_method, check_method
from ..solve.registry import exact_derivatives
from . import fleets
from .argtypes import tolerances_as_flags
from .files import ModelSpec, load_data
from .fit_flags import statistics
from .overrides import given_once
from .provenance import data_entries, sha256
from .simulate import effective_columns


def discretisation(args, spec: ModelSpec | None = None) -> Discretisation:
    """The integration settings of the command line (the interpolation: else the
    model file's, else linear), checked once."""
    interpolation = args.interpolation or getattr(spec, "interpolation", None) or "linear"
    try:
        return Discretisation.of(args.scheme, args.substeps, interpolation, args.rtol, args.atol)
    except ValueError as e:
        raise ValueError(tolerances_as_flags(str(e))) from None


def _problem(spec: ModelSpec, train, args, held_out: bool = False) -> Problem:
    """The Problem of ``train`` as the model file and flags set it; ``held_out``: a
    fleet's held-out units (--validate), which may be one unit."""
    start = None  # --start-from: an earlier fit's values, --fix's in place of its own
    if getattr(args, "start_from", None):
        given = dict(args.fix) | _noise_given(args)  # what the command line names wins
        start = Start.read(args.start_from).overridden(given, spec.model)
        start = _off_the_floor(start, train, spec.model, args.start_from)
    if spec.p0 is None and start is None:
        raise ValueError(
            f"{spec.path} defines no p0: add p0 = {{name: start value}} for "
            f"{list(spec.model.params)}"
        )
    disc = discretisation(args, spec)
    hessian = getattr(args, "hessian", "auto")
    path = get_hessian(hessian)  # asked, not named: what it can differentiate
    if not path.supports(disc):
        able = [n for n in SCHEMES if path.supports(Discretisation.of(n))]
        raise ValueError(
            f"--hessian {path.name} needs {path.needs} ({', '.join(able)}) or a "
            f"discrete-time model, not --scheme {disc.scheme.name}: drop --hessian or "
            "give --hessian tensors"
        )
    if not held_out:
        fleets.several_units(spec, train, args)
    try:  # the segments are the command line's, not the model file's
        resolve_segments(train, args.segments, args.segment_length)
    except ValueError as e:
        raise ValueError(f"--segments/--segment-length: {e}") from None
    try:
        return Problem(
            spec.model,
            train,
            p0=spec.p0 if start is None else start,  # --start-from: its x0 too
            x0=spec.x0_given() if start is None or start.x0 is None else None,
            free_x0=spec.free_x0,
            fixed=spec.fixed,
            bounds=spec.bounds,
            **statistics(spec, args),  # priors, noise, weights: --prior, --noise, --weights
            discretisation=disc,
            segments=args.segments,
            segment_length=args.segment_length,
            hessian=hessian,
            **_loss(spec, args),
            **_predictor(spec, args),
            **fleets.problem_keywords(spec, Problem),  # individual=, population= where given
        )
    except (ValueError, TypeError) as e:  # the model file's settings, or the flags'
        message = _as_flags(str(e), args)
        raise type(e)(f"{_origin(message, spec, args)}: {message}") from None


_FLAGS = {
    "loss": "--loss", "loss_scale": "--loss-scale", "predictor": "--predictor",
    "process_noise": "--process-noise", "measurement_noise": "--measurement-noise",
    "fix": "--fix", "segments": "--segments", "segment_length": "--segment-length",
    "hessian": "--hessian",
}  # fmt: skip
_UNSET: tuple = (None, [], {}, "auto")  # a flag left at its default


# settings a refusal may name, and the flag that gives each on the command line
_SETTING_FLAGS = {"constraints": ("constraint", "--constraint"), "priors": ("prior", "--prior"),
                  "noise": ("noise", "--noise"), "weights": ("weights", "--weights"),
                  "free_x0": ("free", "--free")}  # fmt: skip


def _origin(message: str, spec: ModelSpec, args) -> str:
    """Where a refused value came from: the flags that gave the settings the refusal
    names (--start-from's file for a start value p0), else the model file (and the
    flags given that override its settings)."""
    named = [
        f"{flag} {_text(getattr(args, attr))}"
        for key, (attr, flag) in _SETTING_FLAGS.items()
        if getattr(args, attr, None) not in _UNSET and re.search(rf"(?<![\w-]){key}\b", message)
    ]
    if getattr(args, "start_from", None) and re.search(r"\bp0 = ", message):
        named.insert(0, f"--start-from {args.start_from}")
    return f"{' '.join(named)} (model {spec.path})" if named else f"{spec.path}{_flags_given(args)}"


def _flags_given(args) -> str:
    """ " with --loss huber ..." for the flags given that override the model file's
    settings (an error may come from either), or ""."""
    given = [
        f"{flag} {_text(getattr(args, key))}"
        for key, flag in _FLAGS.items()
        if getattr(args, key, None) not in _UNSET
    ]
    return f" with {' '.join(given)}" if given else ""


def _as_flags(message: str, args) -> str:
    """``message`` with the Python names of the settings that the command line gave
    spelled as its flags ("loss='huber'" as "--loss huber", "drop loss=" as "drop
    --loss"); a setting from the model file keeps the name the file gives it."""
    for key, flag in _FLAGS.items():
        if getattr(args, key, None) in _UNSET:
            continue
        name = rf"(?<![\w-]){key}="
        message = re.sub(name + r"'([^']*)'", rf"{flag} \1", message)  # key='value'
        message = re.sub(name + r"([^\s'():,;]+)", rf"{flag} \1", message)  # key=4
        message = re.sub(name + r"(?=[)\s,;]|$)", flag, message)  # drop key=
        entry = rf"(?<![\w-]){key}\['([^']*)'\] = ([^\s:;,]+)"  # key['y'] = 0.0
        message = re.sub(entry, rf"{flag} \1=\2", message)
        message = re.sub(rf"(?<![\w-]){key} names", f"{flag} names", message)
    # a hint to give a noise: on the command line, its flag (given or not)
    return re.sub(r"measurement_noise=\{'([^']*)': σ\}", r"--measurement-noise \1=σ", message)


def predictor_origin(spec: ModelSpec, args) -> str:
    """Where a filter fit's predictor was chosen: "--predictor ekf", or the model file's
    setting (a refusal that blamed --predictor ekf sent the user to a flag not given)."""
    if getattr(args, "predictor", None):
        return f"--predictor {args.predictor}"
    return f'predictor = "{spec.predictor}" in {spec.path}'


def checked_method(problem, method: str, origin: str = "--predictor ekf") -> None:
    """``check_method`` before any work, its refusal spelled in the command line's
    flags ("method 'fd-lsq' ... (predictor='ekf')" as "--method fd-lsq ... (--predictor
    ekf)"); ``origin``: where the filter was chosen (:func:`predictor_origin`)."""
    try:
        if problem.population or problem.individual:  # a fleet's own methods
            check_fleet_method(problem, method)
        else:
            check_method(problem, method)
    except ValueError as e:
        message = re.sub(r"^method '([\w-]+)'", r"--method \1", str(e))
        message = re.sub(r"predictor='[\w-]+'", origin, message)
        message = message.replace("drop the segments", "drop --segments or --segment-length")
        names = r"use ('[\w-]+'(?:(?:, | or )'[\w-]+')*)"
        message = re.sub(names, lambda m: "use --method " + m[1].replace("'", ""), message)
        raise ValueError(message) from None


def _text(value) -> str:
    """A flag's value as typed: name=value pairs, words, numbers (MEAN,SD)."""
    if isinstance(value, tuple) and all(isinstance(v, int | float) for v in value):
        return ",".join(_text(v) for v in value)
    if isinstance(value, list | tuple | dict):
        items = value.items() if isinstance(value, dict) else value
        return " ".join(f"{i[0]}={_text(i[1])}" if isinstance(i, tuple) and len(i) == 2
                        else _text(i) for i in items)  # fmt: skip
    return f"{value:g}" if isinstance(value, float) else str(value)


def _loss(spec: ModelSpec, args) -> dict:
    """loss and loss_scale: the command line's over the model file's."""
    loss = getattr(args, "loss", None) or spec.loss or "squared"
    scale = getattr(args, "loss_scale", None)
    scale = spec.loss_scale if scale is None else scale
    if not get_loss(loss).robust and scale is not None:  # (its marker: a scale to take)
        raise ValueError("--loss-scale (or loss_scale) is for a robust --loss; drop it or give one")
    return {"loss": loss, "loss_scale": scale}


def _predictor(spec: ModelSpec, args) -> dict:
    """predictor, process_noise and measurement_noise: the command line's over the
    model file's."""
    flag = getattr(args, "predictor", None)
    out: dict = {"predictor": flag or spec.predictor or SIMULATION.name}
    noisy = get_predictor(out["predictor"]).has_noise_model  # (its marker, not its name)
    for key in ("process_noise", "measurement_noise"):
        given = getattr(args, key, None)
        out[key] = given_once(_FLAGS[key], given) if given else getattr(spec, key)
        if not given and flag and not noisy:
            out[key] = None  # the file's filter noise goes with the file's predictor
    if noisy:  # before --fix's σ join it
        _process_noise_named(args, out["process_noise"] or {})
    for name, value in dict(getattr(args, "fix", None) or []).items():
        for kind, prefix in NOISE_PREFIXES.items():  # --fix log_sigma_e_y=-7: σ_e = e^-7
            key = f"{kind}_noise"
            if name.startswith(prefix):
                out[key] = {**(out[key] or {}), name[len(prefix) :]: float(np.exp(value))}
    if not noisy:
        _no_noise_flags(args)
    return out


def _off_the_floor(start: Start, train, model, path) -> Start:
    """A --start-from file's σ_e at its floor (under 1e-6 of its output's spread, or 0
    once its log is exponentiated) is no start for a filter (the corner the earlier fit
    stopped in; at 0 it was refused, blamed on the model file): that output starts from
    its noise level in the data instead, as one not named does, with a note."""
    low = {}
    for o, sigma in start.measurement.items():
        if o in model.outputs:
            j = model.outputs.index(o)
            ys = np.concatenate([np.asarray(e.measured)[:, j] for e in train])
            if not sigma > SIGMA_E_FLOOR * float(np.nanstd(ys)):
                low[o] = sigma
    for o, sigma in low.items():
        print(
            f"tensorid: note: --start-from {path}: its σ_e({o}) = {sigma:.2g} sits at its "
            f"floor; {o}'s measurement noise starts from its noise level in the data "
            f"instead (--measurement-noise {o}=σ to give the start)",
            file=sys.stderr,
        )
    kept = {o: v for o, v in start.measurement.items() if o not in low}
    return dataclasses.replace(start, measurement=kept) if low else start


def _noise_given(args) -> dict:
    """{log_sigma_<kind>_<name>: log σ} of the noise starts the command line gives
    (--process-noise, --measurement-noise): they win over a --start-from file's, which
    set them without a word (and a fit at its σ_e floor then advised the flag given)."""
    out: dict[str, float] = {}
    for kind, prefix in NOISE_PREFIXES.items():
        flag = f"{kind}_noise"
        given = given_once(_FLAGS[flag], getattr(args, flag, None) or [])
        out |= {f"{prefix}{name}": float(np.log(sigma)) for name, sigma in given.items()}
    return out


def _process_noise_named(args, process: dict) -> None:
    """--free or --bounds on log σ_w of a state without process noise: one line with
    the way out (--free was ignored without a word, --bounds named no flag)."""
    prefix = NOISE_PREFIXES["process"]
    for flag in ("free", "bounds", "fix"):
        names = [n if isinstance(n, str) else n[0] for n in getattr(args, flag, None) or []]
        for name in names:
            state = name[len(prefix) :]
            if name.startswith(prefix) and state not in process:
                raise ValueError(
                    f"--{flag} {name}: the state {state} has no process noise to "
                    f"{'fix' if flag == 'fix' else 'estimate'}; "
                    f"give it a start with --process-noise {state}=σ (or process_noise in "
                    f"the model file), or drop --{flag} {name}"
                )


def _no_noise_flags(args) -> None:
    """Noise given on the command line for an output-error fit: one line naming the
    flag and ``--predictor ekf`` (the Problem's own error spoke of keywords)."""
    flags = [("process_noise", "--process-noise"), ("measurement_noise", "--measurement-noise")]
    given = [flag for key, flag in flags if getattr(args, key, None)]
    noise = tuple(NOISE_PREFIXES.values())
    for flag in ("fix", "free", "bounds"):  # --free NAME; --fix, --bounds NAME=...
        names = [n if isinstance(n, str) else n[0] for n in getattr(args, flag, None) or []]
        given += [f"--{flag} {n}" for n in names if n.startswith(noise)]
    if given:
        raise ValueError(
            f"{' and '.join(given)}: a noise intensity is for --predictor ekf (output error "
            'has no noise model): add --predictor ekf, or predictor = "ekf" in the model file'
        )


def _validation_data(args, model, columns, spec=None) -> list:
    """The --validate records, read with their column maps (--validate-columns,
    default: --columns where it is one map for all files), covariates and events as
    the training files'."""
    if not args.validate:
        return []
    try:
        return load_data(
            args.validate,
            model,
            ts=args.ts,
            samples=args.validate_samples,
            columns=columns,
            records=getattr(args, "records", None),  # fleets (issue 42)
            covariates=getattr(spec, "covariates", None),
            events=getattr(args, "events", None),
        )
    except ValueError as e:
        if "(--samples)" in str(e):  # the validation files' own flag
            raise ValueError(str(e).replace("(--samples)", "(--validate-samples)")) from None
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
    if getattr(args, "validate_samples", None) is not None and not val:
        raise ValueError("--validate-samples applies to validation files: give --validate FILE")
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
    horizon = getattr(args, "horizon", None)
    if horizon is not None and not val:
        raise ValueError("--horizon applies to validation records: give --validate FILE")
    for e in val if horizon is not None else []:
        if horizon >= e.P:
            raise ValueError(
                f"--horizon {horizon}: the validation record {e.name!r} has {e.P} samples; "
                "give a horizon below that"
            )
    for e in val if args.init_window is not None else []:
        try:
            check_init_window(args.init_window, e)
        except ValueError as err:
            raise ValueError(f"--init-window: {err}") from None
    samples = tested_samples(train)
    if args.residual_lags is not None and args.residual_lags > lag_limit(samples):
        raise ValueError(
            f"--residual-lags {args.residual_lags}: the training records have {samples} "
            f"measured samples (of the output measured least often); the residual tests "
            f"take at most N/4 = {lag_limit(samples)} lags"
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


def no_repeats(files: list, maps) -> None:
    """A training file given twice with the same columns: refused, one line. Read
    twice it counted twice, and every standard error shrank by √2 without a word."""
    from pathlib import Path

    per_file = maps if isinstance(maps, list) else [maps] * len(files)
    seen: dict = {}
    for f, m in zip(files, per_file, strict=True):
        key = (sha256(f) or str(Path(f).resolve()), repr(sorted((m or {}).items())))
        if key in seen:
            same = "is given twice" if Path(seen[key]).resolve() == Path(f).resolve() else (
                "holds the same bytes as another file")  # fmt: skip
            raise ValueError(
                f"the training data {f} {same} ({seen[key]} and {f}): its samples "
                "would count twice and every standard error shrink by √2; give it once"
            )
        seen[key] = f


def _one(maps: list | None):
    """--columns as the validation files' default: only when it is one map for all."""
    return maps if maps and len(maps) == 1 else None


def _data_entries(m, files: list, maps) -> list[dict]:
    per_file = maps if isinstance(maps, list) else [maps] * len(files)
    return data_entries(files, [effective_columns(m, c) for c in per_file])
