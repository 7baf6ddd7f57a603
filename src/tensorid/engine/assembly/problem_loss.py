"""The part of a :class:`tensorid.Problem` that knows its loss: the robust scale per
output, a copy with another loss (``with_loss``), and the rounding floor of the cost;
and the one other copy a Problem is made into after construction, with another
thread limit (``with_threads``): a Problem is never changed once made.
It reads ``loss``, ``loss_weights``, ``weights``, ``model``, ``experiments``,
``discretisation``, ``predictor``, ``shooting``, ``threads`` and the sweeps of the
Problem."""

from __future__ import annotations

import copy
from collections.abc import Mapping
from dataclasses import replace
from typing import Any

import numpy as np

from ..modelling.checks import check_filter_options, check_threads, no_noise_without_filter
from ..modelling.model import Model
from ..sweeping.hessians import get_hessian
from ..sweeping.losses import Loss, get_loss, make_loss
from ..sweeping.predictors import Predictor, get_predictor
from ..sweeping.shooting import Shooting
from ..sweeping.sweeps import shared_sweeps


class LossSettings:
    """A Problem's loss (see the module docstring)."""

    loss: Loss
    loss_weights: np.ndarray
    loss_scale_estimated: bool
    weights: np.ndarray
    model: Any
    experiments: list
    discretisation: Any
    predictor: Any
    shooting: Any
    _sweeps: Any
    _arrays: list
    dosing: Any  # the records' events (dosing.Dosing), or None
    threads: int | None

    @property
    def loss_scale(self) -> dict[str, float] | None:
        """A robust loss's scale per output, in the outputs' units (None: squared loss)."""
        if not self.loss.robust:
            return None
        w = np.where(self.weights > 0, self.weights, 1.0)
        c = self.loss_weights[1] / np.sqrt(w)
        return dict(zip(self.model.outputs, c.tolist(), strict=True))

    def with_loss(self, loss: str | Loss, scale: Mapping[str, float] | None = None,
                  estimated: bool | None = None):  # fmt: skip
        """This problem with another loss, or another scale {output: value} (outputs'
        units) for a robust one: a copy that shares the data and settings (and the
        compiled sweeps, where the loss is the same). ``estimated``: whether that scale
        was estimated from residuals (default: where none is given)."""
        measured = observed_rows(self.experiments)
        loss, c = make_loss(loss, scale, list(self.model.outputs), self.weights, measured)
        by_residuals = (scale is None) if estimated is None else bool(estimated)
        return self._copy_with(loss=loss, loss_weights=np.stack([self.weights, c]),
                               loss_scale_estimated=loss.robust and by_residuals)  # fmt: skip

    def with_substeps(self, substeps: int):
        """This problem with ``substeps`` steps per sample interval, as the fit's own
        refinement of the default (a copy sharing the data and the settings)."""
        return self._copy_with(discretisation=replace(self.discretisation, substeps=int(substeps)))

    def _copy_with(self, **changed):
        """A copy with the attributes ``changed``, its sweeps (shared where the same)
        and shooting segments made for them."""
        new = copy.copy(self)
        for name, value in changed.items():
            setattr(new, name, value)
        sw = self._sweeps
        new._sweeps = shared_sweeps(
            self.model, sw.free_states, sw.free_params, new.discretisation, new.loss,
            self.predictor, self.dosing,
        )  # fmt: skip
        new.shooting = Shooting(new, self.shooting.counts) if self.shooting else None
        return new

    def with_threads(self, threads: int | None):
        """This problem with another thread limit for the adjoint's stretches (a copy:
        a local pool's worker, one core each, gets 1)."""
        new = copy.copy(self)
        new.threads = check_threads(threads)
        return new

    @property
    def rounding_floor(self) -> float:
        """The cost of residuals at 1e-13 of the data (double precision leaves a few
        digits to the simulation): a fit that reaches it has matched the data exactly
        (-inf for a likelihood, which has no floor)."""
        if self.loss.likelihood:
            return -np.inf
        return 1e-26 * sum(
            float(np.sum(self.weights * np.asarray(y["y"] if isinstance(y, dict) else y) ** 2))
            for _, _, y in self._arrays
        )


def checked_predictor(predictor, model, fixed, bounds, **options) -> Predictor:
    """The predictor (by name or object) with the options checked against its markers,
    one line each, before any work; ``loss`` and ``hessian`` as their registries'
    objects where their names are known; the model first."""
    if not isinstance(model, Model):
        raise TypeError(f"model must be a tensorid.Model, got {type(model).__name__}")
    predictor = get_predictor(predictor)
    options.update(loss=_known(get_loss, options["loss"]))
    options.update(hessian=_known(get_hessian, options["hessian"]))
    check_filter_options(predictor, **options)
    no_noise_without_filter(model, predictor, fixed, bounds)
    return predictor


def _known(get, value):
    """``value`` as its registry's object where its name is known (else as given: the
    check that reads it, or the registry later, says what is wrong with it)."""
    try:
        return get(value)
    except (ValueError, TypeError):
        return value


def observed_rows(experiments) -> list:
    """Each record's y with NaN where a sample was not measured (a record with gaps:
    the rows of a dose alone hold zeros, which would pull a noise level or a scale
    towards 0; outputs sampled at different times each keep their own samples)."""
    return [e.y if e.observed is None else e.measured_with_gaps for e in experiments]
