"""The command line's own commands (fit, simulate, compare), the options of `fit`,
and the one way every command reports a user's mistake: a single line, exit status
2. The value types are in :mod:`.argtypes`; the options shared with simulate and
compare, and their parsers, in :mod:`.options`."""

from __future__ import annotations

import argparse
import os
import sys
import warnings
from collections.abc import Iterator
from contextlib import contextmanager

from .. import _early, names
from .argtypes import (
    _count,
    _level,
    _mapping,
    _non_negative,
    _positive,
    _positive_seconds,
    _range,
    _sample_time,
    _samples,
    _value,
)
from .fit_flags import add_fit_flags
from .options import (
    _TS_HELP,
    FIT_SECTIONS,
    fleet_options,
    integration_options,
    record_options,
    register_compare,
    register_simulate,
    sections,
)

__all__ = [
    "Parser",
    "integration_options",
    "record_options",
    "register",
    "register_compare",
    "register_simulate",
    "run",
]


def _fit(args) -> int:
    from .commands import run_fit

    return run_fit(args)


class Parser(argparse.ArgumentParser):
    """argparse, with a mistake reported as one line (not the whole usage) that
    names the argument and says where the help is."""

    def error(self, message: str):  # type: ignore[override]
        self.exit(2, f"{self.prog}: error: {_nearest_choice(message)} (see {self.prog} --help)\n")


def _nearest_choice(message: str) -> str:
    """argparse's "invalid choice: 'sdrik3' (choose from ...)" with "; did you mean
    'sdirk3'?" after it (Python 3.14's argparse suggests; those before do not)."""
    import re

    from ..engine.modelling.checks import nearest

    taken = re.match(r"argument (--[\w-]+)(?:/[\w-]+)?: expected one argument$", message)
    if taken:  # "--rtol -1e-6": argparse reads -1e-6 as an option (not -1 or -0.5)
        return f"{message} (one that starts with '-', as -1e-6, is written {taken[1]}=VALUE)"
    found = re.search(r"invalid choice: '([^']*)' \(choose from (.*)\)$", message)
    if not found or "did you mean" in message:
        return message
    close = nearest(found[1], re.findall(r"'([^']*)'", found[2]))
    return f"{message}; did you mean {close!r}?" if close and close != found[1] else message


_COLUMNS_HELP = (
    "the data files' column (variable) for each model input/output, e.g. u=uEst,y=yEst; "
    "t=... for the time column; a number holds an input the record lacks constant "
    "(pulses=0). Given once it applies to every file; repeated, one map per data file "
    "in their order (records read from one file with different maps are named "
    "FILE:MAP in the results)"
)


def register(sub) -> None:
    """Add the fit, simulate and compare commands to the subparsers ``sub``."""
    f = sub.add_parser(
        "fit",
        help="fit a model file to data files",
        description="Estimate the unknown parameters and initial states of "
        "MODEL.py from DATA files; write fit.json, report.md and "
        "figures to --out.",
    )
    f.add_argument("model", help="model file (Python)")
    f.add_argument(
        "data",
        nargs="+",
        help="data files (.csv, .mat, .npz), one experiment each; u.mat+y.mat joins files "
        "holding the inputs and the outputs",
    )
    f.add_argument("--out", default="fit-results", help="output folder (default: %(default)s)")
    f.add_argument(
        "--method",
        default="auto",
        choices=[*names.METHODS, *names.FLEET_METHODS],  # (names.py: no JAX for --help)
        help="auto (default): Gauss-Newton while it converges fast, the exact Hessian "
        "where it turns slow or at a saddle; newton: exact Hessian; newton-cg: exact "
        "Hessian-vector products with truncated CG, for many unknowns; gauss-newton; "
        "fd-bfgs and fd-lsq: finite-difference baselines; for a population fit, auto "
        "or focei (first-order conditional estimation) or laplace",
    )
    f.add_argument(
        "--hessian",
        default="auto",
        choices=list(names.HESSIANS),
        help="how exact Hessians are computed: tensors (the paper's transition tensors), "
        "adjoint (second-order adjoints, parallel in time: faster for many states or "
        "unknowns; explicit schemes only) or auto (default): the faster one by a cost "
        "model of N, K and the record length",
    )
    f.add_argument(
        "--loss",
        default=None,
        choices=list(names.LOSSES),
        help="what a sample's misfit costs: squared (default: least squares) or a robust "
        "loss that lets outliers and glitches pull less: huber (linear beyond the scale), "
        "cauchy or student-t (logarithmic beyond it); overrides the model file's loss",
    )
    f.add_argument(
        "--loss-scale",
        type=_positive,
        default=None,
        metavar="SCALE",
        help="a robust loss's scale in the outputs' units (default: from the data, a "
        "multiple of each output's noise level; fit.json records it)",
    )
    f.add_argument(
        "--predictor",
        default=None,
        choices=list(names.PREDICTORS),
        help="how the state is carried between samples: simulation (default: output "
        "error) or ekf (an extended Kalman filter: prediction error, with process and "
        "measurement noise estimated); overrides the model file's predictor",
    )
    f.add_argument(
        "--process-noise",
        type=_value,
        nargs="+",
        default=None,
        metavar="STATE=VALUE",
        help="with --predictor ekf: the states driven by process noise, each with the "
        "start of its intensity (a standard deviation per square root of time); "
        "overrides the model file's process_noise",
    )
    f.add_argument(
        "--measurement-noise",
        type=_value,
        nargs="+",
        default=None,
        metavar="OUTPUT=VALUE",
        help="with --predictor ekf: the start of an output's measurement noise (standard "
        "deviation; default: its noise level in the data); overrides the model file's",
    )
    f.add_argument(
        "--validate", nargs="+", default=[], metavar="DATA", help="validation data files"
    )
    f.add_argument(
        "--horizon",
        type=_count,
        default=None,
        metavar="K",
        help="score the validation records as K-step-ahead prediction (MATLAB's compare "
        "with a prediction horizon): with --predictor ekf, the filter's state K samples "
        "before, run ahead by the model; for output error every horizon is the simulation",
    )
    f.add_argument("--ts", type=_sample_time, default=None, help=_TS_HELP)
    f.add_argument(
        "--samples",
        type=_samples,
        default=None,
        metavar="START:STOP",
        help="use samples START:STOP of each training file",
    )
    f.add_argument(
        "--validate-samples",
        type=_samples,
        default=None,
        metavar="START:STOP",
        help="use samples START:STOP of each validation file",
    )
    f.add_argument(
        "--columns",
        type=_mapping,
        action="append",
        default=None,
        metavar="NAME=COLUMN,...",
        help="the training files' columns: " + _COLUMNS_HELP,
    )
    f.add_argument(
        "--validate-columns",
        type=_mapping,
        action="append",
        default=None,
        metavar="NAME=COLUMN,...",
        help="as --columns, for the validation files (default: --columns, when it is given once)",
    )
    f.add_argument(
        "--init-window",
        type=_count,
        default=None,
        metavar="N",
        help="validation as the benchmarks do it: initial states estimated on the first N "
        "samples (rows) of each validation record (parameters held), scored after them; "
        "on a record with unmeasured rows, the window holds a measurement and leaves two",
    )
    seg = f.add_mutually_exclusive_group()
    seg.add_argument(
        "--segments",
        type=_count,
        default=None,
        metavar="S",
        help="multiple shooting: cut each record into S segments, each with its own "
        "initial state, joined by continuity constraints; for long, oscillating or "
        "poorly initialised records (method auto, newton or gauss-newton)",
    )
    seg.add_argument(
        "--segment-length",
        type=_count,
        default=None,
        metavar="N",
        help="multiple shooting with segments of about N samples (instead of --segments)",
    )
    f.add_argument(
        "--no-polish",
        action="store_true",
        help="with segments: report the multiple-shooting solution without the final "
        "single-shooting polish",
    )
    f.add_argument(
        "--fix",
        type=_value,
        action="append",
        default=[],
        metavar="NAME=VALUE",
        help="hold parameter NAME at VALUE (overrides the model file's p0 and fixed; "
        "repeat for more; with --predictor ekf also a noise intensity's log, e.g. "
        "log_sigma_e_y=-7)",
    )
    f.add_argument(
        "--free",
        action="append",
        default=[],
        metavar="NAME",
        help="estimate parameter NAME although the model file fixes it, or initial "
        "state NAME although the model file does not free it (repeat for more)",
    )
    f.add_argument(
        "--bounds",
        type=_range,
        action="append",
        default=[],
        metavar="NAME=LO:HI",
        help="bounds of parameter NAME, replacing the model file's (an empty end: no "
        "bound there, e.g. c=0:)",
    )
    f.add_argument("--starts", type=_count, default=1, help="number of starts (multi-start)")
    f.add_argument(
        "--spread",
        type=_non_negative,
        default=None,
        help="starts drawn within ±SPREAD (relative) of p0, inside the bounds; for a "
        "positive parameter whose bounds span a decade or more, within a factor 1+SPREAD "
        "of p0, log-uniformly. Default: across the whole box where both bounds are given "
        "(log-uniformly where they span a decade or more), else ±0.2",
    )
    f.add_argument("--seed", type=int, default=0, help="seed of the starts")
    f.add_argument(
        "--workers", type=_count, default=None,
        help="local worker processes (for --starts, or a fleet's units)",
    )  # fmt: skip
    f.add_argument(
        "--batch",
        type=_count,
        default=None,
        help="starts fitted together in lock-step per task, vectorised (auto, newton, "
        "gauss-newton; default: the starts shared evenly over the local workers)",
    )
    f.add_argument(
        "--scheduler",
        default=None,
        metavar="ADDRESS",
        help="run the starts (or a fleet's units) on a Dask distributed cluster at ADDRESS",
    )
    f.add_argument(
        "--worker-timeout",
        type=_positive_seconds,
        default=None,
        metavar="SECONDS",
        help="give up on the workers when no start has finished for this long (lost "
        "workers); the starts that finished are kept (default: 300 with --scheduler, "
        "no limit locally)",
    )
    f.add_argument(
        "--profile",
        nargs="*",
        default=None,
        metavar="NAME",
        help="profile likelihood of the named unknowns (all free parameters when none "
        "is named): likelihood-ratio intervals (ci95_profile in fit.json) and a figure each",
    )
    f.add_argument(
        "--profile-level",
        type=_level,
        default=0.95,
        metavar="LEVEL",
        help="confidence level of the profile intervals (default 0.95)",
    )
    f.add_argument(
        "--residual-lags",
        type=_count,
        default=None,
        metavar="M",
        help="lags of the residual tests (whiteness, independence from the inputs; "
        "default 25, as MATLAB's resid, or a quarter of the samples if fewer; at most a "
        "quarter of the samples)",
    )
    f.add_argument(
        "--data-sensitivity",
        action="store_true",
        help="which samples drive each estimate: a figure of dθ/dy per noise level, and "
        "the samples that pulled each estimate most (influential_samples in fit.json)",
    )
    fleet_options(f)  # fleets (issue 42): --records, --individual, --population
    integration_options(f)
    add_fit_flags(f)  # --maxiter, --gtol, --ftol, --xtol, --prior, --noise, --weights
    f.add_argument("--no-progress", action="store_true", help="no live progress display")
    honest_options(f)
    sections(f, FIT_SECTIONS)
    f.set_defaults(func=_fit)

    register_simulate(sub)
    register_compare(sub)


def honest_options(f) -> None:
    """fit's options for what its error bars can be trusted with (issue 40)."""
    f.add_argument(
        "--no-model-check",
        action="store_true",
        help="skip the model-error check (the estimates of the record's halves, or of "
        "each record, compared with their robust error bars), which a fit whose "
        "residuals are not white makes by default: two or more extra fits",
    )
    f.add_argument(
        "--start-from",
        default=None,
        metavar="FIT.json",
        help="start from an earlier fit's fit.json: its parameters (checked against the "
        "model file's), initial states and noise intensities, in place of the model "
        "file's p0 and x0 (the same model, data and settings start at its cost)",
    )


def _one_line(message, category, filename, lineno, file=None, line=None) -> None:
    """A warning as the tool's own line: the message, not the file and code that raised
    it (a numerical corner that reaches here is named by its message)."""
    print(f"tensorid: warning: {message}", file=sys.stderr if file is None else file)


@contextmanager
def _notes() -> Iterator[None]:
    """Warnings as the tool's own lines, never Python's two lines with a source path:
    what the data files' reader did to a record (DataNote) as a note, anything else as
    a warning."""
    from .datafiles import DataNote

    def show(message, category, filename, lineno, file=None, line=None):
        if issubclass(category, DataNote):
            print(f"tensorid: note: {message}", file=sys.stderr)
        else:
            _one_line(message, category, filename, lineno, file, line)

    with warnings.catch_warnings():
        warnings.simplefilter("always", DataNote)
        warnings.showwarning = show
        yield


def _unrecognized(parser: argparse.ArgumentParser, args, extra: list[str]) -> None:
    """Arguments no option takes, refused by the command's own parser ("tensorid
    simulate: error: ... (see tensorid simulate --help)", where argparse's top parser
    sent the user to tensorid --help), with the option nearest to a misspelt one."""
    from ..engine.modelling.checks import nearest

    command = parser
    for action in parser._actions:  # the subcommand's parser, where there is one
        if isinstance(action, argparse._SubParsersAction):
            command = action.choices.get(str(getattr(args, "command", "")), parser)
    options = [o for a in command._actions for o in a.option_strings if o.startswith("--")]
    flag = next((x.split("=")[0] for x in extra if x.startswith("--")), None)
    close = nearest(flag, options) if flag else None
    hint = f"; did you mean {close}?" if close and close != flag else ""
    command.error(f"unrecognized arguments: {' '.join(extra)}{hint}")


def run(parser: argparse.ArgumentParser, argv: list[str] | None = None) -> int:
    """Parse ``argv`` and run the chosen command. Our errors say what is wrong and how
    to fix it; a traceback only hides that (set TENSORID_TRACEBACK=1 to see it)."""
    args, extra = parser.parse_known_args(argv)
    if extra:  # named by the command's parser, as its other mistakes are
        _unrecognized(parser, args, extra)
    args.argv = sys.argv[1:] if argv is None else list(argv)  # for the results' provenance
    from .._config import default_compilation_cache

    default_compilation_cache()  # on unless TENSORID_CACHE=0
    _early.settle()  # the command's imports are done: the garbage collector runs again
    try:
        with _notes():
            return args.func(args)
    except (ValueError, TypeError, FileNotFoundError) as e:
        if os.environ.get("TENSORID_TRACEBACK"):
            raise
        print(f"tensorid: error: {e}", file=sys.stderr)
        return 2
    except OSError as e:  # a write failed after the work: say which file and why
        if os.environ.get("TENSORID_TRACEBACK"):
            raise
        where = f"{e.filename}: {e.strerror or e}" if e.filename else str(e)
        print(f"tensorid: error: {where}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:  # Ctrl-C: one line, not forty of traceback
        if os.environ.get("TENSORID_TRACEBACK"):
            raise
        print("tensorid: interrupted", file=sys.stderr)
        return 130
