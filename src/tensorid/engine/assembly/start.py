"""Starting a fit where an earlier one ended: its parameters, initial states and noise
intensities (``Problem(..., p0=res)`` with a FitResult, ``p0=Start.read("fit.json")``,
``tensorid fit ... --start-from fit.json``).

A start gives every parameter of the model (an earlier fit's names checked against
the model, one line naming what differs), the initial states of every record (unless
``x0`` is given as well) and, for a filter, the noise intensities of the states and
outputs that the new problem puts noise on: with the same model, data and settings,
the new fit's cost at iteration 0 is the earlier fit's cost.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..sweeping.predictors import NOISE_PREFIXES


@dataclass(frozen=True)
class Start:
    """Start values from an earlier fit.

    params: {parameter: value} of the model (noise intensities apart).
    x0: the initial states, (N,) or (E, N), or None.
    process, measurement: {state or output: σ}, a filter's noise intensities.
    source: where they come from, for messages ("fit.json", "a FitResult").
    """

    params: dict[str, float]
    x0: np.ndarray | None = None
    process: dict[str, float] = field(default_factory=dict)
    measurement: dict[str, float] = field(default_factory=dict)
    source: str = "the earlier fit"

    @classmethod
    def of(cls, res, source: str = "the earlier fit (a FitResult)") -> Start:
        """From a FitResult (or anything with ``params`` and ``x0``)."""
        return cls._split(dict(res.params), res.x0, source)

    @classmethod
    def read(cls, path) -> Start:
        """From a fit.json that ``tensorid fit`` wrote; one line naming the file and
        what is wrong with it otherwise."""
        path = Path(path)
        try:
            data = json.loads(path.read_text())
        except OSError as e:
            raise ValueError(
                f"{path}: cannot read it ({e.strerror or e}); give a fit.json"
            ) from None
        except ValueError:
            raise ValueError(f"{path}: not JSON; give the fit.json a fit wrote") from None
        params = data.get("params") if isinstance(data, dict) else None
        if not isinstance(params, dict) or not params:
            raise ValueError(f"{path}: no 'params' in it; give the fit.json a fit wrote")
        try:
            values = {str(k): float(v) for k, v in params.items()}
            x0 = None if data.get("x0") is None else np.asarray(data["x0"], dtype=float)
        except (TypeError, ValueError):
            raise ValueError(f"{path}: its params or x0 are not numbers") from None
        return cls._split(values, x0, str(path))

    @classmethod
    def _split(cls, params: dict, x0, source: str) -> Start:
        noise: dict[str, dict[str, float]] = {"process": {}, "measurement": {}}
        plain = {}
        for name, value in params.items():
            kind = next((k for k, p in NOISE_PREFIXES.items() if name.startswith(p)), None)
            if kind is None:
                plain[name] = float(value)
            else:
                noise[kind][name[len(NOISE_PREFIXES[kind]) :]] = float(np.exp(value))
        x0 = None if x0 is None else np.asarray(x0, dtype=float)
        return cls(plain, x0, noise["process"], noise["measurement"], source)

    def overridden(self, values: dict, model) -> Start:
        """This start with ``values`` {parameter, noise parameter (its log σ) or state:
        value} in place of its own (the command line's --fix)."""
        params, x0 = dict(self.params), None if self.x0 is None else self.x0.copy()
        noise = {"process": dict(self.process), "measurement": dict(self.measurement)}
        for name, value in values.items():
            kind = next((k for k, p in NOISE_PREFIXES.items() if name.startswith(p)), None)
            if kind is not None:
                noise[kind][name[len(NOISE_PREFIXES[kind]) :]] = float(np.exp(value))
            elif name in model.states and x0 is not None:
                x0[..., model.states.index(name)] = value
            else:
                params[name] = float(value)
        return Start(params, x0, noise["process"], noise["measurement"], self.source)

    def check(self, model) -> None:
        """One line where the start's parameters are not the model's."""
        extra = [n for n in self.params if n not in model.params]
        missing = [n for n in model.params if n not in self.params]
        if extra or missing:
            parts = ([f"has {extra}, which the model lacks"] if extra else []) + (
                [f"lacks {missing}"] if missing else []
            )
            raise ValueError(
                f"start from {self.source}: its parameters do not match the model's "
                f"{list(model.params)}: it {' and '.join(parts)}; start from a fit of this "
                "model (or give p0 by name)"
            )


def resolve_start(model, p0, x0, predictor, process_noise, measurement_noise) -> tuple:
    """(p0, x0, (process_noise, measurement_noise)) for a Problem whose p0 may be a
    :class:`Start` or a FitResult: the start's parameters, its initial states where
    ``x0`` is None, and for a filter its noise intensities (on the states and outputs
    given, or the start's own where none are given); anything else passes through."""
    if not isinstance(p0, Start):
        if not (hasattr(p0, "params") and hasattr(p0, "x0") and hasattr(p0, "theta")):
            return p0, x0, (process_noise, measurement_noise)
        p0 = Start.of(p0)
    p0.check(model)
    if x0 is None and p0.x0 is not None:
        x0 = p0.x0
    if predictor.has_noise_model:  # a Predictor
        process_noise = _merged(process_noise, p0.process)
        measurement_noise = _merged(measurement_noise, p0.measurement)
    return dict(p0.params), x0, (process_noise, measurement_noise)


def _merged(given, earlier: dict[str, float]):
    """The noise intensities: the earlier fit's on the keys given (or all of its own
    where none are given), the given ones elsewhere."""
    if not given:
        return dict(earlier) or given
    if not isinstance(given, dict):
        return given  # the Problem's check says what is wrong with it
    return {k: earlier.get(k, v) for k, v in given.items()}
