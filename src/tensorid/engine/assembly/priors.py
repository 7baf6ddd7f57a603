"""Gaussian priors on free parameters (MAP estimation): their check, the noise level
that weighs them, and their terms in J, ∇J and ∇²J.

J gains σ² Σ ((θ_i − mean)/sd)², σ² the variance of a unit-weight residual, so that
J/σ² is −2 log posterior. Each function takes the Problem (its ``priors`` {θ index:
(mean, sd)} and ``noise_variance``)."""

from __future__ import annotations

from collections.abc import Mapping
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from ..sweeping.losses import Loss


def check_priors(problem, priors, noise) -> tuple[dict, float]:
    """{θ index: (mean, sd)} for the priors, and the noise variance that weighs them."""
    if not priors:
        if noise is not None:
            raise ValueError("noise is only used with priors; give priors={name: (mean, sd)}")
        return {}, float("nan")
    if not isinstance(priors, Mapping):
        raise TypeError(f"priors must be a dict {{parameter: (mean, sd)}}, got {priors!r}")
    out = {}
    for name, spec in priors.items():
        if name not in problem.free_params:
            why = "fixed" if name in problem.fixed else "not a parameter of the model"
            raise ValueError(
                f"priors[{name!r}]: {name!r} is {why}; priors go on free parameters "
                f"{problem.free_params}"
            )
        try:
            mean, sd = (float(v) for v in spec)
        except (TypeError, ValueError):
            raise ValueError(f"priors[{name!r}] must be (mean, sd), got {spec!r}") from None
        if not (np.isfinite(mean) and np.isfinite(sd) and sd > 0):
            raise ValueError(f"priors[{name!r}] = ({mean}, {sd}): need a finite mean, sd > 0")
        out[problem.theta_names.index(name)] = (mean, sd)
    if noise is None:
        estimate = noise_from_data(problem)
        if not estimate > 0:
            raise ValueError(
                "priors: the measured outputs show no noise to weigh the priors against "
                "(their second differences vanish); give noise= (a standard deviation)"
            )
        return out, estimate
    if not (isinstance(noise, int | float) and np.isfinite(noise) and noise > 0):
        raise ValueError(f"noise must be a standard deviation > 0, got {noise!r}")
    return out, float(noise) ** 2


def noise_from_data(problem) -> float:
    """The variance of a unit-weight residual, from the measured outputs alone: for
    white noise on a signal that is smooth at the sampling rate, the second
    difference y[k+1] − 2y[k] + y[k−1] has variance 6σ²."""
    num = den = 0.0
    for e in problem.experiments:
        y = e.measured if e.observed is None else e.measured[e.observed.all(axis=1)]
        d2 = np.diff(y, n=2, axis=0)
        num += float((problem.weights * (d2**2).sum(axis=0)).sum()) / 6.0
        den += d2.shape[0] * int((problem.weights > 0).sum())
    return num / max(den, 1.0)


def add_prior_terms(problem, theta, parts: str, more, out: list) -> None:
    """Add the priors' terms to the assembled results (in place)."""
    idx = np.array(list(problem.priors))
    mean = np.array([m for m, _ in problem.priors.values()])
    prec = problem.noise_variance / np.array([sd for _, sd in problem.priors.values()]) ** 2
    d = theta[..., idx] - mean
    seen_g = False
    for k, c in enumerate(parts):
        if c == "J":
            out[k] = out[k] + (prec * d**2).sum(axis=-1)
        elif c == "g" and not seen_g:
            out[k][..., idx] += 2 * prec * d
            seen_g = True
        elif c == "g":  # a Hessian-vector product
            out[k][..., idx] += 2 * prec * np.asarray(more[0])[..., idx]
        elif c in "HP":
            out[k][..., idx, idx] += 2 * prec
        elif c == "r":
            out[k] = np.concatenate([out[k], (np.sqrt(prec) * d).reshape(-1)])


class PriorTerms:
    """The priors' part of a Problem (a Problem is a PriorTerms): it reads
    ``priors`` {θ index: (mean, sd)} and ``noise_variance``."""

    loss: Loss
    priors: dict
    noise_variance: float
    if TYPE_CHECKING:  # from ThetaLayout, beside it in Problem

        @property
        def K(self) -> int: ...

    def _set_priors(self, priors, noise) -> None:
        self.priors, self.noise_variance = check_priors(self, priors, noise)
        # an estimate, not the user's word: a fit may re-estimate it (fitting/priors.py)
        self.noise_estimated = bool(self.priors) and noise is None and not self.loss.likelihood
        if self.loss.likelihood:  # J is −2 log L: a prior adds ((θ − mean)/sd)² as it is
            self.noise_variance = 1.0

    def add_prior_terms(self, theta, parts: str, more, out: list) -> None:
        """Add the priors' terms to results assembled in θ's layout (in place): ``parts``
        as in :meth:`_assemble`, ``more`` its extra arguments (a direction v)."""
        add_prior_terms(self, theta, parts, more, out)

    def prior_cost(self, theta) -> float:
        """The priors' part of J at θ (0 without priors)."""
        theta = np.asarray(theta, dtype=float)
        return float(
            sum(
                self.noise_variance * ((theta[i] - m) / sd) ** 2
                for i, (m, sd) in self.priors.items()
            )
        )

    @property
    def prior_curvature(self) -> np.ndarray:
        """(K,) the priors' contribution to the diagonal of the Hessian (0 without)."""
        out = np.zeros(self.K)
        for i, (_, sd) in self.priors.items():
            out[i] = 2 * self.noise_variance / sd**2
        return out
