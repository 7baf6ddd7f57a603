"""`fit`'s flags for what a model file could only say before: how the iterations stop
(--maxiter, --gtol, --ftol, --xtol, as FitOptions has them) and the statistics'
settings (--prior, --noise, --weights). Declared here, in one block, and applied by
:func:`fit_options` and :func:`statistics` (the command line's over the file's)."""

from __future__ import annotations

import argparse

from .argtypes import _count, _non_negative, _positive
from .overrides import given_once


def _prior(text: str) -> tuple[str, tuple[float, float]]:
    """NAME=MEAN,SD (SD > 0)"""
    name, eq, rest = text.partition("=")
    mean, comma, sd = rest.partition(",")
    try:
        m, s = float(mean), float(sd)
    except ValueError:
        m, s = float("nan"), float("nan")
    if not eq or not comma or not name.strip() or not abs(m) < float("inf"):
        raise argparse.ArgumentTypeError(
            f"expected NAME=MEAN,SD (a Gaussian prior, e.g. k=2.0,0.5), got {text!r}"
        )
    if not 0 < s < float("inf"):
        raise argparse.ArgumentTypeError(
            f"a prior's SD is a standard deviation, a finite number > 0: got {text!r}"
        )
    return name.strip(), (m, s)


def _weight(text: str) -> tuple[str, float]:
    """OUTPUT=W (W >= 0), or "auto" (1/variance of each output)"""
    if text.strip() == "auto":
        return "auto", float("nan")
    name, eq, value = text.partition("=")
    try:
        w = float(value)
    except ValueError:
        w = -1.0
    if not eq or not name.strip() or not 0 <= w < float("inf"):
        raise argparse.ArgumentTypeError(
            f"expected OUTPUT=WEIGHT with a finite weight >= 0 (or auto), got {text!r}"
        )
    return name.strip(), w


def add_fit_flags(f: argparse.ArgumentParser) -> None:
    """--maxiter, --gtol, --ftol, --xtol; --prior, --noise, --weights."""
    f.add_argument(
        "--maxiter", type=_count, default=None, metavar="N",
        help="iteration limit of the fit (default 200)",
    )  # fmt: skip
    for name, default, what in (
        ("gtol", "1e-10", "the scaled gradient's ∞-norm (relative to the starting cost)"),
        ("ftol", "1e-12", "an accepted step's relative cost decrease"),
        ("xtol", "1e-12", "the scaled step (relative to 1 + the point's size)"),
    ):
        f.add_argument(
            f"--{name}", type=_non_negative, default=None, metavar="TOL",
            help=f"stop when {what} is below TOL (default {default}; FitOptions.{name})",
        )  # fmt: skip
    f.add_argument(
        "--prior", type=_prior, action="append", default=[], metavar="NAME=MEAN,SD",
        help="a Gaussian prior on parameter NAME (MAP estimation; repeat for more); "
        "added to the model file's priors, replacing one of the same name",
    )  # fmt: skip
    f.add_argument(
        "--constraint", action="append", default=[], metavar="INEQUALITY",
        help="keep an inequality between parameters, e.g. \"Fs >= Fc\" (repeat for more); "
        "joins the model file's constraints",
    )  # fmt: skip
    f.add_argument(
        "--noise", type=lambda text: _positive(text, "a noise standard deviation > 0"),
        default=None, metavar="SIGMA",
        help="the measurement noise's standard deviation that weighs the priors against "
        "the data (default: estimated; overrides the model file's noise)",
    )  # fmt: skip
    f.add_argument(
        "--weights", type=_weight, nargs="+", default=None, metavar="OUTPUT=W",
        help="each output's weight in the cost (OUTPUT=W ..., or auto: 1/variance of each "
        "output); overrides the model file's weights",
    )  # fmt: skip


def fit_options(args) -> dict:
    """The iteration limits the command line gave, as ti.fit's keywords."""
    names = ("maxiter", "gtol", "ftol", "xtol")
    return {n: getattr(args, n) for n in names if getattr(args, n, None) is not None}


def statistics(spec, args) -> dict:
    """priors, noise and weights for the Problem: the command line's over the model
    file's; constraints: the model file's and --constraint's together."""
    m = spec.model
    given = given_once("--prior", getattr(args, "prior", None))
    unknown = [n for n in given if n not in m.params]
    if unknown:
        raise ValueError(f"--prior names {unknown}, not parameters; they are {list(m.params)}")
    priors = {**(spec.priors or {}), **given}
    noise = getattr(args, "noise", None)
    weights = getattr(args, "weights", None)
    if weights:
        names = [n for n, _ in weights]
        if "auto" in names and len(names) > 1:
            raise ValueError("--weights auto weighs every output: give it alone")
        weights = "auto" if names == ["auto"] else given_once("--weights", weights)
        unknown = [n for n in weights if n not in m.outputs] if weights != "auto" else []
        if unknown:
            raise ValueError(f"--weights names {unknown}, not outputs; they are {list(m.outputs)}")
    constraints = list(spec.constraints or []) + list(getattr(args, "constraint", None) or [])
    return {
        "constraints": constraints or None,
        "priors": priors or None,
        "noise": spec.noise if noise is None else noise,
        "weights": spec.weights if weights is None else weights,
    }
