"""What a predictor made of a Problem's records at θ (``Problem.predict``): the
one-step (or k-step) ahead outputs, a filter's innovation covariances and the
standardised innovations, per record."""

from __future__ import annotations

import functools
from dataclasses import dataclass

import jax
import jax.numpy as jnp
import numpy as np

from ..compiling.compiled import on_device


@dataclass
class Prediction:
    """What a predictor made of one record at θ, per sample (P leading).

    Arguments:
        t: the sample times.
        measured: y (P, S).
        predicted: the one-step-ahead outputs ŷ_{h|h−1} (output error: the simulation),
            or with ``horizon`` k, ŷ_{h|h−k}.
        covariance: the filter's innovation covariances S_h (P, S, S); None for output
            error.
        innovations: standardised innovations L_h⁻¹ (y_h − ŷ_h), L_h L_hᵀ = S_h: white
            with unit variance where the model and its noise are right (output error:
            the plain residuals y − ŷ).
        horizon: k (1: one step ahead).
    """

    t: np.ndarray
    measured: np.ndarray
    predicted: np.ndarray
    covariance: np.ndarray | None
    innovations: np.ndarray
    horizon: int = 1


def check_horizon(horizon, samples: int) -> None:
    """A prediction horizon of at least one sample and below a record's length."""
    whole = isinstance(horizon, int | np.integer) and not isinstance(horizon, bool)
    if not (whole and 1 <= horizon < samples):
        raise ValueError(
            f"horizon must be a whole number of samples from 1 to {samples - 1}, got {horizon!r}"
        )


def predictions(problem, theta, horizon: int = 1) -> list[Prediction]:
    """Per experiment of ``problem``, its :class:`Prediction` at θ (see
    :meth:`tensorid.Problem.predict`)."""
    for e in problem.experiments:
        check_horizon(horizon, e.P)
    theta = problem.check_theta(theta)
    sw, out = problem.sweeps, []
    S = problem.model.S
    for e, (t, u, y) in enumerate(problem.arrays):
        x0, p = on_device(problem.x0[e]), on_device(problem.p0)
        local = on_device(theta[problem._slices(e)])
        _, pis = (np.asarray(a) for a in sw.predictions(local, x0, p, t, u, y))
        yhat, cov = pis[:, :S], None
        meas = np.asarray(y["y"] if isinstance(y, dict) else y)  # a record with gaps: its y
        if sw.loss.likelihood:  # π = (ŷ, vec S): the loss reads the covariance
            cov = pis[:, S:].reshape(-1, S, S)
            innov = np.asarray(_residual(sw.loss, sw.predictor, y, on_device(pis)))
        else:
            innov = meas - yhat
        if horizon > 1:
            yhat = np.asarray(sw.k_step(local, x0, p, t, u, y, k=int(horizon)))
        out.append(Prediction(np.asarray(t), meas, yhat, cov, innov, int(horizon)))
    return out


@functools.partial(jax.jit, static_argnums=(0, 1))
def _residual(loss, predictor, y, pi):
    """The loss's standardised residuals as one small program, not one per operation
    (a filter's Cholesky factors and solves: seven programs to compile); a record
    with gaps: of the measured outputs (``predictor.masked``), 0 elsewhere."""
    if not isinstance(y, dict):
        return loss.residual(y, pi, None)
    seen = y["mask"] > 0
    r = loss.residual(y["y"], jax.vmap(predictor.masked)(pi, seen, y["y"]), None)
    return jnp.where(seen, r, 0.0)
