"""Model files and data files.

A model file is Python. It defines ``model = tensorid.Model(...)`` or, for text
equations, ``rhs = {state: "expr"}`` with optional ``output``, ``inputs``, ``params``
``input_delays`` (dict input -> seconds) and ``discrete`` (True: rhs gives x[k+1]);
and it may define ``p0`` (dict), ``x0``
(dict state -> value), ``free_x0`` (list), ``fixed`` (list), ``bounds`` (dict name ->
(lo, hi)), ``weights`` ("auto" or dict output -> weight), ``priors`` (dict name ->
(mean, sd)), ``constraints`` (a list of inequalities such as "Fs >= Fc") and
``noise`` (the noise standard deviation that weighs the priors; without it, it is
estimated and checked by the fit), ``loss``/``loss_scale`` and, for a
stochastic model, ``predictor = "ekf"`` with ``process_noise`` (dict state -> σ_w)
and ``measurement_noise`` (dict output -> σ_e), and ``interpolation`` (the inputs
between samples, as ``--interpolation``, which overrides it). For many units
(``--records``): ``covariates`` (inputs constant per unit), ``individual`` (parameters
each unit has its own value of), ``population`` (dict parameter -> start of ω,
log-normal over the units) and x0 values that are expressions of the inputs and
parameters ("Dose * Wt", at each unit's first sample). A file that has not finished running
after TENSORID_MODEL_TIMEOUT seconds (default 60) is stopped with a clear message.

Data files are CSV (a time column ``t``, or a sampling time given as ``ts``, plus
columns named after the model's inputs and outputs), MATLAB .mat or NumPy .npz
(variables with those names). Each file is one experiment; ``load_data`` and its
readers live in :mod:`tensorid.app.datafiles`.
"""

from __future__ import annotations

import importlib.util
import os
import signal
import sys
import threading
import time
import traceback
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..engine.modelling.checks import did_you_mean
from ..engine.modelling.equations import model_from_equations
from ..engine.modelling.model import Model
from ..engine.sweeping.losses import REGISTRY as LOSSES
from ..engine.sweeping.predictors import REGISTRY as PREDICTORS
from . import fleets
from .datafiles import load_data

__all__ = ["ModelSpec", "load_data", "load_model"]


@dataclass
class ModelSpec:
    """What a model file defines: the model and the problem settings."""

    model: Model
    p0: dict | None = None
    x0: dict | None = None
    free_x0: list = field(default_factory=list)
    fixed: list = field(default_factory=list)
    bounds: dict = field(default_factory=dict)
    path: Path | None = None
    weights: dict | list | tuple | np.ndarray | str | None = None
    priors: dict = field(default_factory=dict)
    # "Fs >= Fc", ... (engine/assembly/constraints.py)
    constraints: list = field(default_factory=list)
    loss: str | None = None
    loss_scale: float | dict | None = None
    noise: float | None = None
    predictor: str | None = None
    process_noise: dict | None = None
    measurement_noise: dict | None = None
    interpolation: str | None = None
    # fleets (issue 42): inputs constant per unit, parameters per unit (app/fleets.py)
    covariates: list = field(default_factory=list)
    individual: list = field(default_factory=list)
    population: dict = field(default_factory=dict)
    residual_error: str | dict | None = None  # a population fit's: additive, proportional, ...
    omega: str | None = None  # Ω's structure: "diagonal" (default) or "full"
    doses: dict = field(default_factory=dict)  # what a dose puts in a state: {"depot": "F * amt"}
    lags: dict = field(default_factory=dict)  # a dose's lag per state: {"depot": "tlag"}
    durations: dict = field(default_factory=dict)  # RATE = -2's duration: {"central": "D"}

    def events(self) -> dict:
        """{"doses", "lags", "durations"}: what a record's events do, as the file says."""
        return {"doses": self.doses, "lags": self.lags, "durations": self.durations}

    def x0_array(self, given=()) -> np.ndarray:
        """x0 of the model file as an array (N,), states it does not name at 0; a state
        whose x0 is an expression is refused unless ``given`` (names, or --x0's
        NAME=VALUE texts) names it, and is then NaN, for the caller to fill."""
        given = [str(g).split("=")[0].strip() for g in given]
        x0 = dict.fromkeys(self.model.states, 0.0)
        for k, v in (self.x0 or {}).items():
            if k not in x0:
                raise ValueError(
                    f"{self.path}: x0 names unknown state {k!r}; states are "
                    f"{list(self.model.states)}"
                )
            if isinstance(v, str) and k in given:
                v = np.nan
            elif isinstance(v, str):
                raise ValueError(
                    f"{self.path}: x0[{k!r}] = {v!r} is an expression of the unit's data, "
                    "which this command does not evaluate; give --x0 "
                    f"{k}=VALUE, or a number in the model file"
                )
            x0[k] = float(v)
        return np.array([x0[s] for s in self.model.states])

    def x0_given(self):
        """x0 for ti.Problem: the array, or (where a state's start is an expression of
        the unit's inputs and parameters) the dict, every state named, for the Problem
        to evaluate per unit."""
        if not fleets.has_expressions(self.x0):
            return self.x0_array()
        unknown = [k for k in self.x0 or {} if k not in self.model.states]
        if unknown:
            raise ValueError(
                f"{self.path}: x0 names unknown state {unknown[0]!r}; states are "
                f"{list(self.model.states)}"
            )
        return {s: (self.x0 or {}).get(s, 0.0) for s in self.model.states}


class _TooSlow(BaseException):
    """Raised into a model file that runs past the time limit (a BaseException, so
    that the file's own ``except Exception`` cannot swallow it)."""


@contextmanager
def _time_limit(seconds: float) -> Iterator[None]:
    """Interrupt the code inside after ``seconds`` (POSIX main thread; elsewhere no
    limit). An alarm set by the caller is put back, less the time spent."""
    if (
        not hasattr(signal, "setitimer")
        or threading.current_thread() is not threading.main_thread()
    ):
        yield
        return

    def expired(*_):
        raise _TooSlow

    before = signal.signal(signal.SIGALRM, expired)
    outer, _ = signal.setitimer(signal.ITIMER_REAL, seconds)
    started = time.monotonic()
    try:
        yield
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, before)
        if outer:
            signal.setitimer(signal.ITIMER_REAL, max(outer - (time.monotonic() - started), 1e-3))


def _where(exc: BaseException, path: Path) -> str:
    """Where in the user's file an exception arose: ", line N (code)"."""
    if isinstance(exc, SyntaxError) and exc.lineno:
        return f", line {exc.lineno} ({(exc.text or '').strip()})"
    frames = [
        f
        for f in traceback.extract_tb(exc.__traceback__)
        if Path(f.filename).resolve() == path.resolve()
    ]
    return f", line {frames[-1].lineno} ({frames[-1].line})" if frames else ""


def _run(path: Path):
    """Import the model file as a fresh module, within the time limit."""
    name = f"_tensorid_model_{abs(hash(path.resolve()))}"
    spec = importlib.util.spec_from_file_location(name, path)
    if spec is None or spec.loader is None or path.suffix != ".py":
        raise ValueError(f"{path} is not a Python file; a model file is Python (.py)")
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    # worker processes cannot import this file by name: ship its functions by value
    import cloudpickle

    cloudpickle.register_pickle_by_value(module)
    limit = float(os.environ.get("TENSORID_MODEL_TIMEOUT", "60"))
    try:
        with _time_limit(limit):
            spec.loader.exec_module(module)
    except _TooSlow:
        raise ValueError(
            f"the model file {path} did not finish running within {limit:g} s (an endless "
            "loop at its top level?); fix it, or set TENSORID_MODEL_TIMEOUT to more seconds"
        ) from None
    except Exception as e:
        raise ValueError(
            f"the model file {path} failed{_where(e, path)}: {type(e).__name__}: {e}"
        ) from e
    return vars(module)


def _names(value):
    """A list of names, where one name may be given as a string."""
    return [value] if isinstance(value, str) else value


def load_model(path) -> ModelSpec:
    """Import a model file and return its :class:`ModelSpec`. Every mistake in it is
    one line that names the file."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"model file {path} does not exist")
    ns = _run(path)
    try:
        return _spec(ns, path)
    except (ValueError, TypeError) as e:
        raise type(e)(f"{path}: {e}") from None


def _spec(ns: dict, path: Path) -> ModelSpec:
    if isinstance(ns.get("model"), Model):
        model = ns["model"]
        if ns.get("input_delays") and not model.input_delays:
            raise ValueError(
                "input_delays is set beside a tensorid.Model: pass it to the model, "
                "tensorid.Model(..., input_delays={...})"
            )
    elif "rhs" in ns and not callable(ns["rhs"]):
        if not isinstance(ns["rhs"], dict):
            raise TypeError(
                f"rhs must be a dict {{state: 'expression'}}, got {type(ns['rhs']).__name__}"
            )
        model = model_from_equations(
            ns["rhs"],
            ns.get("output"),
            _names(ns.get("inputs", ())),
            ns.get("params"),
            name=path.stem,
            input_delays=ns.get("input_delays"),
            discrete=ns.get("discrete", False),
        )
    else:
        raise ValueError(
            "it defines neither `model = tensorid.Model(...)` nor text equations "
            "`rhs = {state: 'expression'}`"
        )
    out = ModelSpec(model, path=path)
    kinds = {"p0": dict, "x0": dict, "free_x0": list, "fixed": list, "bounds": dict,
             "priors": dict, "constraints": list}  # fmt: skip
    for key, kind in kinds.items():
        if ns.get(key) is None:
            continue
        value = ns[key]
        if kind is list:
            value = list(value) if isinstance(value, tuple) else _names(value)
        if not isinstance(value, kind):
            raise TypeError(
                f"{key} must be a {kind.__name__}, got {type(value).__name__}"
                + _as_dict(key, value, model)
            )
        setattr(out, key, value)
    weights = ns.get("weights")
    if weights is not None and not (
        (isinstance(weights, str) and weights == "auto")
        or isinstance(weights, dict | list | tuple | np.ndarray)
    ):
        raise ValueError(f"weights must be 'auto' or a dict {{output: weight}}, got {weights!r}")
    out.weights = weights
    loss, scale = ns.get("loss"), ns.get("loss_scale")
    if loss is not None and loss not in LOSSES:
        raise ValueError(
            f"loss must be one of {list(LOSSES)}, got {loss!r}{did_you_mean(loss, list(LOSSES))}"
        )
    if scale is not None and not isinstance(scale, int | float | dict):
        raise TypeError(f"loss_scale must be a number or a dict {{output: scale}}, got {scale!r}")
    out.loss, out.loss_scale = loss, scale
    out.noise = ns.get("noise")  # Problem checks it, naming this file
    predictor = ns.get("predictor")
    if predictor is not None and predictor not in PREDICTORS:
        raise ValueError(
            f"predictor must be one of {list(PREDICTORS)}, got {predictor!r}"
            f"{did_you_mean(predictor, list(PREDICTORS))}"
        )
    out.predictor = predictor
    out.interpolation = _interpolation(ns.get("interpolation"))
    for key in ("process_noise", "measurement_noise"):
        value = ns.get(key)
        if value is not None and not isinstance(value, dict):
            raise TypeError(f"{key} must be a dict {{name: standard deviation}}, got {value!r}")
        setattr(out, key, value)
    _fleet_settings(ns, out)
    _stray_settings(ns, path)
    return out


def _fleet_settings(ns: dict, out: ModelSpec) -> None:
    """covariates, individual, population; x0's expressions (app/fleets.py)."""
    m = out.model
    if ns.get("covariates") is not None:
        out.covariates = fleets.covariates(ns["covariates"], m)
    if ns.get("individual") is not None:
        out.individual = fleets.individual(ns["individual"], m)
    if ns.get("population") is not None:
        out.population = fleets.population(ns["population"], m)
    if ns.get("residual_error") is not None:
        out.residual_error = fleets.residual_error(ns["residual_error"], m)
    if ns.get("omega") is not None:
        out.omega = fleets.omega(ns["omega"])
    if ns.get("doses") is not None:
        out.doses = _doses(ns["doses"], m)
    if ns.get("lags") is not None:
        out.lags = _doses(ns["lags"], m, "lags")
    if ns.get("durations") is not None:
        out.durations = _doses(ns["durations"], m, "durations")
    fleets.x0_expressions(out.x0, m)
    where = {"individual": "individual", "population": "population", "fixed": "fixed"}
    fleets.kinds(out.individual, out.population, out.fixed, where)


# settings a model file does not take (the command line's and the Problem's), and
# those it does: a file that sets the former, or misspells the latter, was fitted
# without them and without a word (interpolation = "zoh" fitted linear)
_ELSEWHERE = {"scheme": "--scheme", "substeps": "--substeps", "rtol": "--rtol",
              "atol": "--atol"}  # fmt: skip
_SETTINGS = ("model", "rhs", "output", "inputs", "params", "input_delays", "discrete", "p0",
             "x0", "free_x0", "fixed", "bounds", "weights", "priors", "constraints", "noise",
             "loss", "loss_scale", "predictor", "process_noise", "measurement_noise",
             "interpolation", "covariates", "individual", "population",
             "residual_error", "omega", "doses", "lags", "durations")  # fmt: skip
# read only beside text equations: beside a tensorid.Model, ``outputs = [...]`` or
# ``param = ...`` are the file's own variables (passed to the Model), not misspellings
_TEXT_ONLY = ("rhs", "output", "inputs", "params", "input_delays", "discrete")


def _doses(value, model, key: str = "doses") -> dict:
    """``doses = {"depot": "F * amt"}``: what a record's dose puts into a state (an
    expression of amt, the parameters and the inputs); ``lags = {"depot": "tlag"}``:
    how long after its time a dose takes effect; checked before any work."""
    from ..engine.sweeping.dosing import dosing_of

    if not isinstance(value, dict):
        raise TypeError(
            f"{key} must be a dict {{state: expression}} such as "
            f"{{'depot': {'F * amt' if key == 'doses' else 'tlag'!r}}}, got {type(value).__name__}"
        )
    dosing_of(model, [], **{key: value})  # one line for a state or a name the model lacks
    return dict(value)


def _interpolation(value) -> str | None:
    """The file's ``interpolation`` (how its records' inputs behave between samples),
    checked; ``--interpolation`` overrides it."""
    from ..engine.schemes.discretisation import INTERPOLATIONS

    if value is not None and value not in INTERPOLATIONS:
        raise ValueError(
            f"interpolation must be one of {list(INTERPOLATIONS)}, got {value!r}"
            f"{did_you_mean(value, INTERPOLATIONS)}"
        )
    return value


def _as_dict(key: str, value, model: Model) -> str:
    """ "; write x0 = {'y': 0.0, 'v': 0.0}" for a list of start values in the model's
    order (a list is what ti.Problem takes; a model file names them), or ""."""
    names = {"p0": model.params, "x0": model.states}.get(key)
    if names is None or not isinstance(value, list | tuple) or len(value) != len(names):
        return ""
    return f"; write {key} = {dict(zip(names, value, strict=True))!r}"


def _not_a_choice(name: str, value) -> tuple[str, str]:
    """(", and 'sdrik3' is no scheme (...)", the value to suggest) where a scheme
    set in a model file is no valid one: the flag the refusal suggests
    would be refused in turn. ("", value) otherwise."""
    from ..engine.modelling.checks import nearest
    from ..engine.schemes.integrators import SCHEMES

    choices = {"scheme": sorted(SCHEMES)}.get(name)
    if choices is None or value in choices:
        return "", value
    close = nearest(value, choices)
    hint = f"did you mean {close!r}? " if close else ""
    return (
        f", and {value!r} is no {name} ({hint}the {name}s: {', '.join(choices)})",
        close or name.upper(),
    )


def _stray_settings(ns: dict, path: Path) -> None:
    """One line for an integration setting set in the file (refused: it would be
    ignored), a warning for a name one letter or so from a setting's (``bound``);
    not for a constant in capitals (``X0``, ``PARAMS``: the file's own, by convention)."""
    import difflib
    import warnings

    settings: tuple[str, ...] = _SETTINGS
    if isinstance(ns.get("model"), Model):
        settings = tuple(s for s in _SETTINGS if s not in _TEXT_ONLY)

    for name, flag in _ELSEWHERE.items():
        value = ns.get(name)
        if isinstance(value, str | int | float) and not isinstance(value, bool):
            invalid, value = _not_a_choice(name, value)
            raise ValueError(
                f"{name} = {ns[name]!r} is not a model-file setting and would be ignored"
                f"{invalid}: give it on the command line ({flag} {value}) or to "
                f"ti.Problem({name}=...); rename the variable if it is one of your own"
            )
    for name, value in ns.items():
        if (
            name.startswith("_")
            or name in _SETTINGS
            or name.isupper()
            or not isinstance(value, dict | list | tuple | str | int | float)
        ):
            continue
        close = difflib.get_close_matches(name.lower(), settings, n=1, cutoff=0.85)
        if close:
            warnings.warn(
                f"{path}: {name} is not a model-file setting and is ignored: did you mean "
                f"{close[0]}? (rename it if it is a variable of your own)",
                stacklevel=4,
            )
