"""What `tensorid fit` computes after the fit on request: validation scores, profile
likelihoods, data sensitivity and the residual tests, each printed as it comes. A
failure or Ctrl-C in one of them does not lose the fit."""

from __future__ import annotations

import sys
from functools import partial

import numpy as np

from ..analysis.figures import file_name, profile_figure
from ..analysis.residuals import default_lags
from ..analysis.summary import gof_text
from ..analysis.validation import Score
from ..engine.assembly.diagnostics import describe_failure
from ..engine.schemes.status import Status


def _gof_lines(scores: list[Score]) -> list[str]:
    kinds = {"training": "train", "validation": "validation"}
    out = []
    for s in scores:
        label = s.label.replace(s.kind, kinds[s.kind], 1)
        label = label.replace("'", "")
        per = ", ".join(f"{o} {gof_text(s, o)}" for o in s.gof)
        out.append(f"GOF {label}: {per}")
    return out


# --horizon on an output-error fit (fit --validate, compare)
SIMULATED_HORIZON = (
    "tensorid: note: --horizon {horizon}: by output error (not a --predictor ekf fit) "
    "every horizon's prediction is the simulation: scored as the simulation"
)


def _after_fit(res, val, args) -> tuple[list, dict, list[str], bool]:
    """Validation, profiles and data sensitivity: (scores, extras, what could not be
    computed, whether Ctrl-C stopped them). Neither Ctrl-C nor a failure here loses
    the fit: the results are written without what is missing."""
    scores: list = []
    extras: dict = {}
    horizon = getattr(args, "horizon", None)
    if horizon is not None and val and not res.problem.loss.likelihood:
        print(SIMULATED_HORIZON.format(horizon=horizon), file=sys.stderr)
    steps = [("validation", lambda: res.validate(val, args.init_window, horizon) if val else [])]
    steps += [("profiles", lambda: _profiles(res, args))]
    steps += [("data sensitivity", lambda: _influence(res, args))]
    steps += [("residual tests", lambda: _residual_tests(res, args))]
    steps += [("model-error check", lambda: _model_check(res, args, extras.get("residual")))]
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
            _blown_up(res, scores)
        else:
            keys = {"profiles": "profiles", "data sensitivity": "influence",
                    "model-error check": "model_check"}  # fmt: skip
            extras[keys.get(name, "residual")] = value
    return scores, extras, missing, False


def _blown_up(res, scores: list[Score]) -> None:
    """A warning line for each validation record whose simulation is not finite (its
    scores are not available; the table said GOF -inf without a word why)."""
    for s in scores:
        if s.simulation.status is not Status.OK:
            name = s.experiment.name or "validation"
            why = describe_failure(s.simulation, res.problem.discretisation.scheme, name)
            print(f"tensorid: warning: {s.label}: not scored, the simulation is not finite: "
                  f"{why}", file=sys.stderr)  # fmt: skip


def _residual_tests(res, args):
    """Whiteness and independence of the residuals (a fit with a finite cost only);
    the summary prints them, one line each."""
    if not np.isfinite(res.cost):
        return None
    # the default shrinks on a short record; below 4 samples the tests say not available
    return res.residual_tests(args.residual_lags or default_lags(res.problem))


def _model_check(res, args, residual):
    """The model-error check (analysis/model_check.py), where the residuals are not
    shown white (the robust error bars are then offered) and not --no-model-check."""
    if getattr(args, "no_model_check", False) or not res.has_uncertainty:
        return None
    if residual is None or residual.not_available or not residual.not_shown_white:
        return None
    return res.model_check()


def _profiles(res, args) -> dict | None:
    """--profile: the profile likelihood of the named unknowns (all free parameters
    when none is named), one line each."""
    if args.profile is None:
        return None
    if not res.has_uncertainty:
        print(f"tensorid: no profiles: the fit ended as {res.status}", file=sys.stderr)
        return None
    return printed_profiles(res, args)


def printed_profiles(res, args) -> dict:
    """``res.profile`` of --profile's names at --profile-level, each described in a
    line with its notes (a single fit's and a population's alike)."""
    profiles = res.profile(args.profile or None, level=args.profile_level)
    for p in profiles.values():
        print(p.describe())
        for note in p.notes:
            print(f"  {note}")
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
    u = res.uncertainty()  # (stem, builder): each drawn when it is written
    return [
        (f"profile_{file_name(name)}", partial(profile_figure, p, u.sigma2, u.stderr[p.index]))
        for name, p in profiles.items()
    ]
