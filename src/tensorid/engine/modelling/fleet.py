"""A fleet: one model, many units (one experiment each), and the kinds of parameter
they have. Shared (the default): one value for the fleet. Population
(``Problem(population={"ka": 0.6})``): each unit's value is the typical value times
exp(η), η ~ N(0, ω²) per unit (a random effect, log-normal), ω estimated from its start.
This module checks what a Problem is told of them; the estimation lives in
:mod:`tensorid.population`."""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from ...names import RESIDUAL_ERRORS  # (population/errors.py holds the models)
from .checks import did_you_mean


def check_population(problem, population, segments) -> dict[str, float]:
    """{parameter: ω start} checked against the model and the other settings; {} for
    none. One line for each mistake, before anything compiles."""
    if population is None:
        return {}
    if not isinstance(population, Mapping) or not population:
        raise TypeError(
            "population must be a dict {parameter: ω} (the start of each random effect's "
            f"standard deviation, e.g. {{'ka': 0.5}}), got {population!r}"
        )
    m = problem.model  # (a fit of one unit is refused by the fit: one unit is a new
    # unit to estimate η̂ of, population/validation.py)
    out: dict[str, float] = {}
    for name, omega in population.items():
        if name not in m.params or str(name).startswith("log_sigma_"):
            raise ValueError(
                f"population names {name!r}, which is not a parameter of the model "
                f"{list(m.params)}{did_you_mean(str(name), list(m.params))}"
            )
        if name in problem.fixed:
            raise ValueError(
                f"{name!r} is both fixed and in population: a random effect needs a "
                "typical value to estimate; drop it from one of them"
            )
        ok = isinstance(omega, int | float | np.floating) and not isinstance(omega, bool)
        if not ok or not np.isfinite(omega) or omega <= 0:
            raise ValueError(
                f"population[{name!r}] = {_plain(omega)!r}: ω (the standard deviation of the "
                "unit-to-unit variation on the log scale) must be a finite number > 0, "
                "e.g. 0.3 for about 30 % variation"
            )
        if not problem.p0[m.params.index(name)] > 0:
            raise ValueError(
                f"population[{name!r}]: its start value p0 = "
                f"{float(problem.p0[m.params.index(name)]):g} must be > 0 (the unit's value is "
                "the typical value times exp(η))"
            )
        out[str(name)] = float(omega)
    _fleet_settings(problem, "population", segments)
    if not np.all(problem.weights == 1.0):
        raise ValueError(
            "a population fit estimates each output's residual SD, which is its weight: "
            "leave weights out"
        )
    return out


def _fleet_settings(problem, what: str, segments) -> None:
    """What a fleet's fit does not (yet) combine with, one line each."""
    # asked of the Problem's predictor and loss (their markers), not of the names given
    predictor, loss = problem.predictor, problem.loss
    if not predictor.supports_fleet or segments not in (None, 1) or not loss.squared:
        raise ValueError(
            f"a fit with {what} parameters is of output error with Gaussian noise: leave "
            "predictor, segments and loss at their defaults"
        )
    if problem.priors:
        raise ValueError(f"a fit with {what} parameters takes no priors")
    if problem.discretisation.interpolation not in ("linear", "zoh"):
        raise ValueError(
            f"a fit with {what} parameters reads its units' inputs between samples as "
            "'linear' or 'zoh' (its units are padded to one length): interpolation "
            f"{problem.discretisation.interpolation!r} is not supported there yet"
        )
    names = [e.name for e in problem.experiments]
    twice = sorted({n for n in names if n and names.count(n) > 1})
    if twice:
        raise ValueError(f"units {twice} are named twice: give each unit its own name")
    if problem.free_x0:
        raise ValueError(
            f"a fit with {what} parameters starts each unit from its x0 (a number or an "
            "expression such as 'Dose * Wt'): free_x0 is not supported there; drop it"
        )


def check_individual(problem, individual, population, segments) -> list[str]:
    """The parameters each unit has its own value of, checked; [] for none."""
    if individual is None or (not isinstance(individual, str) and len(individual) == 0):
        return []
    if isinstance(individual, str) or not all(isinstance(n, str) for n in individual):
        raise TypeError(f"individual must be a list of parameter names, got {individual!r}")
    m = problem.model
    for name in individual:
        if name not in m.params or name.startswith("log_sigma_"):
            raise ValueError(
                f"individual names {name!r}, which is not a parameter of the model "
                f"{list(m.params)}{did_you_mean(name, list(m.params))}"
            )
        if name in problem.fixed:
            raise ValueError(f"{name!r} is both fixed and individual: drop it from one of them")
        if name in population:
            raise ValueError(
                f"{name!r} is both individual (each unit its own value, no distribution) "
                "and in population (log-normal over the units): choose one"
            )
    if len(set(individual)) != len(individual):
        raise ValueError(f"individual names a parameter twice: {list(individual)}")
    bounded = [n for n in individual if n in problem.theta_names and (
        np.isfinite(problem.lower[problem.theta_names.index(n)])
        or np.isfinite(problem.upper[problem.theta_names.index(n)]))]  # fmt: skip
    if bounded:
        raise ValueError(
            f"bounds on the individual parameters {bounded} are not kept by each unit's "
            "own fit: drop the bounds, or make them population parameters (positive by "
            "construction)"
        )
    _fleet_settings(problem, "individual", segments)
    return list(individual)


def fixed_x0_parameters(problem, fleet: bool) -> None:
    """An initial-state expression may name estimated parameters in a fleet's fit
    (whose sweeps carry every state's sensitivity), elsewhere only fixed ones."""
    moving = sorted(getattr(problem, "x0_uses", set()) & set(problem.free_params))
    if moving and not fleet:
        raise ValueError(
            f"an x0 expression names {moving}, which are estimated: outside a fleet's fit "
            "(individual or population parameters) an initial state that moves with an "
            "estimated parameter is not supported; add them to fixed, free the state "
            "itself (free_x0), or write the dependence into the model's equations"
        )


def check_residual_error(problem, residual_error, population) -> dict[str, str]:
    """{output: an error model's name (RESIDUAL_ERRORS)} of a population fit, from one
    kind for every output or a dict per output (the others additive); {} for the
    default (additive everywhere)."""
    if residual_error is None:
        return {}
    outs = list(problem.model.outputs)
    given = {o: residual_error for o in outs} if isinstance(residual_error, str) else None
    if given is None and isinstance(residual_error, Mapping):
        given = dict(residual_error)
    if given is None:
        raise TypeError(
            f"residual_error must be one of {RESIDUAL_ERRORS} or a dict {{output: kind}}, "
            f"got {residual_error!r}"
        )
    for o, kind in given.items():
        if o not in outs:
            raise ValueError(
                f"residual_error names {o!r}, which is not an output of the model {outs}"
                f"{did_you_mean(str(o), outs)}"
            )
        if kind not in RESIDUAL_ERRORS:
            raise ValueError(
                f"residual_error[{o!r}] = {kind!r}: it must be one of {RESIDUAL_ERRORS} "
                "(σ = a, σ = b·|ŷ|, σ² = a² + b²ŷ² or log y = log ŷ + ε)"
            )
    if not population and any(k != "additive" for k in given.values()):
        raise ValueError(
            "residual_error other than 'additive' is estimated by a population fit: give "
            "population (random effects), or leave residual_error out"
        )
    return {o: str(k) for o, k in given.items() if k != "additive"}


OMEGAS = ("diagonal", "full")


def check_omega(omega, population) -> str:
    """Ω's structure: "diagonal" (independent random effects) or "full" (correlated)."""
    if omega not in OMEGAS:
        raise ValueError(
            f"omega must be one of {OMEGAS} (Ω's structure: independent or correlated "
            f"random effects), got {omega!r}"
        )
    if omega == "full" and len(population) < 2:
        raise ValueError(
            'omega="full" correlates the random effects: it needs two or more of them in '
            "population (or leave omega at 'diagonal')"
        )
    return omega


def check_fleet(problem, population, individual, residual_error, omega, segments):
    """(population, individual, residual_error, omega) checked, and the x0
    expressions' parameters fixed."""
    pop = check_population(problem, population, segments)
    ind = check_individual(problem, individual, pop, segments)
    fixed_x0_parameters(problem, bool(pop or ind))
    errors = check_residual_error(problem, residual_error, pop)
    return pop, ind, errors, check_omega(omega, pop)


def _plain(value):
    """A NumPy scalar as the Python number it holds (its repr is np.float64(...))."""
    return value.item() if isinstance(value, np.generic) else value
