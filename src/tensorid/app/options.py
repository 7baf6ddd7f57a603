"""Options that several commands share (reading one record, the integration settings)
and the parsers of the `simulate` and `compare` commands."""

from __future__ import annotations

import argparse

from .. import names
from .argtypes import _count, _mapping, _sample_time, _samples, _value

_TS_HELP = (
    "sampling time TS: the samples are taken at k·TS, whatever time column the files "
    "have (for files without one, or whose time stamps are too uneven for a "
    "discrete-time model); without it, time comes from the column 't', else a "
    "column or variable 'Ts'"
)


EVENTS_HELP = (
    "an event table's columns under NONMEM's names, where the file's differ: "
    "AMT=DOSE,CMT=COMPT (EVID, AMT, CMT, RATE, II, ADDL, SS, MDV, DVID; a file with an AMT "
    "or EVID column is read as doses and observations, each unit's clock from its first row)"
)


def record_options(p: argparse.ArgumentParser) -> None:
    """How simulate and compare read their one record and integrate the model."""
    p.add_argument(
        "--columns",
        type=_mapping,
        default=None,
        metavar="NAME=COLUMN,...",
        help="DATA's column (variable) for each model input/output, e.g. u=uVal,y=yVal; "
        "a number holds an input the record lacks constant (pulses=0)",
    )
    p.add_argument("--ts", type=_sample_time, default=None, help=_TS_HELP)
    p.add_argument(
        "--samples",
        type=_samples,
        default=None,
        metavar="START:STOP",
        help="use samples START:STOP of DATA (as fit's --validate-samples: a record "
        "that holds training and test data in one file)",
    )
    p.add_argument(  # fleets (issue 42)
        "--records",
        default=None,
        metavar="ID_COLUMN",
        help="DATA holds many units, one row per sample: the rows of each value of "
        "ID_COLUMN are one unit's record (as fit's --records); --unit names the one to use",
    )
    p.add_argument(
        "--unit", default=None, metavar="ID", help="with --records: the unit of DATA to use"
    )
    p.add_argument(
        "--ipred",
        action="store_true",
        help="a population fit's fit.json: the unit's own parameters (IPRED), its random "
        "effects η̂ by empirical Bayes from its data with the fitted population held, as "
        "fit --validate scores held-out units; without it the typical unit (PRED)",
    )
    p.add_argument(
        "--events",
        type=_mapping,
        default=None,
        metavar="NAME=COLUMN,...",
        help=EVENTS_HELP,
    )
    p.add_argument(
        "--init-window",
        type=_count,
        default=None,
        metavar="N",
        help="as fit's: the initial states the fit (or model file) frees are estimated "
        "on the first N samples only, with the parameters held, and the record is "
        "scored after them (default: estimated on the whole record, all scored)",
    )
    integration_options(p, inherit=True)


def fleet_options(f: argparse.ArgumentParser) -> None:
    """fit's options for many units (issue 42): --records, --individual, --population."""
    f.add_argument(
        "--records",
        default=None,
        metavar="ID_COLUMN",
        help="each data file holds many units (a fleet, a cohort), one row per sample: "
        "the rows of each value of ID_COLUMN are one unit's record, with its own time "
        "stamps (in increasing order), named by its id; a unit with no observation is "
        "left out with a note. Columns constant within a unit (weight, dose) are read by "
        "inputs of their name",
    )
    f.add_argument(
        "--events", type=_mapping, default=None, metavar="NAME=COLUMN,...", help=EVENTS_HELP
    )
    f.add_argument(
        "--individual",
        nargs="+",
        default=None,
        metavar="NAME",
        help="parameters each unit has its own value of (no distribution); replaces the "
        "model file's individual",
    )
    f.add_argument(
        "--population",
        type=_value,
        nargs="+",
        default=None,
        metavar="NAME=OMEGA",
        help="parameters log-normal over the units (typical value times exp(η), η ~ N(0, "
        "ω²)), each with the start of ω (> 0), e.g. ka=0.5 cl=0.3; replaces the model "
        "file's population",
    )
    f.add_argument(
        "--residual-error",
        nargs="+",
        default=None,
        metavar="KIND",
        help="a population fit's measurement error: additive (default, σ = a), "
        "proportional (σ = b·|prediction|), combined (σ² = a² + b²·prediction²) or "
        "exponential (log y = log prediction + ε), for every output or OUTPUT=KIND each; "
        "replaces the model file's residual_error",
    )
    f.add_argument(
        "--omega",
        choices=["diagonal", "full"],
        default=None,
        help="a population fit's Ω: diagonal (default, independent random effects) or "
        "full (correlated, Ω estimated whole); replaces the model file's omega",
    )


def integration_options(p: argparse.ArgumentParser, inherit: bool = False) -> None:
    """--scheme, --substeps, --rtol, --atol, --interpolation. With ``inherit`` their
    defaults are those of the fit.json given with --params (then rk4, 4, linear)."""
    default = " (default: the fit.json's, else %s)" if inherit else " (default %s)"
    p.add_argument(
        "--scheme",
        default=None if inherit else "rk4",
        choices=list(names.SCHEMES),  # (names.py: no JAX for --help)
        help="integrator: explicit rk4, rk38, heun, euler; implicit sdirk3, "
        "sdirk2, implicit-euler for stiff models; adaptive dopri5, bosh3 (with "
        "--rtol/--atol)" + default % "rk4",
    )
    p.add_argument(
        "--substeps",
        type=int,
        default=None,  # not given: 4, which a population fit raises where too coarse
        help="steps per sample interval"
        + (default % 4 if inherit else " (default 4; a population fit raises them by "
           "itself where doubling them moves its predictions)"),
    )  # fmt: skip
    p.add_argument("--rtol", type=float, default=None, help="adaptive schemes: relative tolerance")
    p.add_argument("--atol", type=float, default=None, help="adaptive schemes: absolute tolerance")
    p.add_argument(
        "--interpolation",
        default=None,  # the model file's (a fit.json's) where it is not given
        choices=["linear", "zoh", "cubic", "bandlimited", "periodic"],
        help="the input between samples: linear, zoh (held), cubic (spline), bandlimited "
        "(windowed sinc) or periodic (trigonometric: a record of whole periods)"
        + (" (default: the fit.json's, else the model file's, else linear)" if inherit
           else " (default: the model file's, else linear)"),
    )  # fmt: skip


def _simulate(args) -> int:
    from .simulate import run_simulate

    return run_simulate(args)


def register_simulate(sub) -> None:
    """Add the simulate command to the subparsers ``sub``."""
    s = sub.add_parser(
        "simulate",
        help="simulate a model file for given parameters",
        description="Simulate MODEL.py on the inputs of DATA with the given "
        "parameters; write simulation.csv (time, inputs, measured and simulated "
        "outputs, states) and, when DATA has outputs, GOF and figures to --out. "
        "Initial states that the fit.json (else the model file) frees are estimated "
        "on DATA (its first N samples with --init-window) with the parameters held, "
        "unless --x0 gives them; the one used is printed. Integration settings left "
        "out are the fit.json's.",
    )
    s.add_argument("model", help="model file (Python)")
    s.add_argument("data", help="data file (.csv, .mat, .npz) with the inputs (outputs optional)")
    s.add_argument(
        "--params",
        nargs="*",
        default=[],
        metavar="NAME=VALUE",
        help="parameter values (default: p0 of the model file), or a fit.json and after it "
        "any NAME=VALUE to change",
    )
    s.add_argument(
        "--x0", nargs="*", default=[], metavar="STATE=VALUE", help="initial state values"
    )
    record_options(s)
    s.add_argument(
        "--out",
        default="simulation-results",
        help="output folder (default: %(default)s); a path ending in .csv writes only the "
        "table of states and simulated outputs there",
    )
    s.set_defaults(func=_simulate)


def _compare(args) -> int:
    from .simulate import run_compare

    return run_compare(args)


def register_compare(sub) -> None:
    c = sub.add_parser(
        "compare",
        help="score a saved fit on a record, as the benchmarks do (MATLAB's compare)",
        description="Simulate MODEL.py with the parameters of a fit.json on DATA: the "
        "initial states the fit estimated are estimated again on the first N samples "
        "(--init-window), the parameters held, and every output is scored after them "
        "(RMSE, NRMSE, R², fit percent, GOF). Writes compare.json and a figure per "
        "output to --out; the same numbers as fit --validate DATA --init-window N.",
    )
    c.add_argument("model", help="model file (Python)")
    c.add_argument("data", help="data file (.csv, .mat, .npz) with inputs and outputs")
    c.add_argument("--params", required=True, metavar="FIT.json", help="the fit.json of a fit")
    record_options(c)
    c.add_argument(
        "--horizon",
        type=_count,
        default=None,
        metavar="K",
        help="score K-step-ahead prediction (MATLAB's compare with a prediction horizon): "
        "for a fit with --predictor ekf, the filter's state K samples before, run ahead "
        "by the model; for output error every horizon is the simulation. Without it the "
        "record is simulated (an infinite horizon)",
    )
    c.add_argument("--out", default="compare-results", help="output folder (default: %(default)s)")
    c.set_defaults(func=_compare)


# `tensorid fit --help` in sections (54 options in one list were 230 lines to search)
FIT_SECTIONS = {
    "data": ["columns", "ts", "samples", "records", "events", "validate", "validate_columns",
             "validate_samples", "init_window", "horizon"],
    "model and integration": ["fix", "free", "bounds", "start_from", "scheme", "substeps",
                              "rtol", "atol", "interpolation"],
    "method": ["method", "hessian", "starts", "spread", "seed", "maxiter", "gtol", "ftol",
               "xtol", "no_polish", "segments", "segment_length", "workers", "batch"],
    "statistics": ["loss", "loss_scale", "predictor", "process_noise", "measurement_noise",
                   "prior", "noise", "weights", "constraint", "profile", "profile_level",
                   "residual_lags", "data_sensitivity", "no_model_check"],
    "fleets": ["individual", "population", "residual_error", "omega", "scheduler",
               "worker_timeout"],
    "output": ["out", "no_progress"],
}  # fmt: skip


def sections(parser: argparse.ArgumentParser, titled: dict[str, list[str]]) -> None:
    """--help in sections: each option listed under its title (argparse lists an option
    where its group holds it; usage, parsing and mutual exclusions are unchanged)."""
    by_dest = {a.dest: a for a in parser._actions}
    for title, dests in titled.items():
        group = parser.add_argument_group(title)
        for dest in dests:
            action = by_dest[dest]
            for old in parser._action_groups:
                if action in old._group_actions:
                    old._group_actions.remove(action)
            group._group_actions.append(action)
