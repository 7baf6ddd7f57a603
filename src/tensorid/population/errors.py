r"""Residual-error models of a population fit, as plug-ins: each a transform h and a
variance σ²(ŷ) on h's scale (rxode2's words: a transform and a variance function),

    h(y_hg) = h(ŷ_hg) + ε_hg,    ε_hg ~ N(0, σ²_g(ŷ_hg)).

Its parameters ("terms") are standard deviations, estimated as their logarithms and
named ``log_<prefix>_<output>`` in ψ. The objective is that of y itself: where h is
not the identity, −2 log|h'(y)| per observation is added (a constant in the
parameters), so that objectives, AIC and BIC of two error models of one data set can
be set side by side.

Adding an error model: a subclass here with its name, terms, variance (and transform),
an entry in ``ERROR_MODELS`` and in ``tensorid.names.RESIDUAL_ERRORS`` (the command
line's list, no JAX), and its test.
"""

from __future__ import annotations

from typing import ClassVar

import jax.numpy as jnp
import numpy as np

_FALLBACK = np.log(0.1)  # a start where the data say nothing: SD 10 % of the scale


class ErrorModel:
    """One output's residual error. Subclasses set ``name``, ``terms`` with their
    ``prefixes`` and ``variance``; ``log_scale`` models take h = log.

    Capability markers: ``constant`` (σ² does not depend on ŷ: the objective then
    leaves Σ log σ² out of the inner problem), ``positive`` (observations and
    predictions must be > 0: refused in one line where they are not)."""

    name: ClassVar[str]
    terms: ClassVar[tuple[str, ...]]
    prefixes: ClassVar[dict[str, str]]  # term -> ψ name's prefix
    formula: ClassVar[str]  # what the reports print
    constant: ClassVar[bool] = False
    log_scale: ClassVar[bool] = False

    @property
    def positive(self) -> bool:
        """Observations and predictions must be > 0 (a log, or no variance at ŷ = 0)."""
        return self.log_scale or self.terms == ("proportional",)

    def variance(self, var: dict, yhat):
        """σ² on h's scale at the predictions ``yhat`` (any shape), from the terms'
        variances ``var`` (their SDs squared)."""
        raise NotImplementedError

    def transform(self, y):
        """h(y): the scale on which the residuals are Gaussian."""
        return jnp.log(y) if self.log_scale else y

    def inverse(self, z):
        """h⁻¹ (a simulated sample back on the data's scale)."""
        return np.exp(z) if self.log_scale else z

    def log_jacobian(self, y):
        """log|h'(y)| per observation (0 for the identity)."""
        return -jnp.log(y) if self.log_scale else jnp.zeros_like(y)

    def log_start(self, y, yhat, seen) -> dict[str, float]:
        """log SD of each term at the start, from the observed ``y`` and the typical
        unit's predictions ``yhat`` at the samples ``seen`` (arrays of one output)."""
        raise NotImplementedError


def _rms(r, seen) -> float:
    """The RMS of ``r`` over the samples ``seen``."""
    return float(np.sqrt(np.sum(np.where(seen, r, 0.0) ** 2) / max(int(seen.sum()), 1)))


def _log_rms(r, seen, floor) -> float:
    """log of the RMS of ``r`` over ``seen``; ``floor`` where it is ~0 or not finite."""
    rms = _rms(r, seen)
    return float(np.log(rms)) if np.isfinite(rms) and rms > 1e-8 else floor


def _additive(y, yhat, seen) -> float:
    scale, rms = _rms(y, seen), _rms(y - yhat, seen)
    if np.isfinite(rms) and rms > 1e-8 * scale:
        return float(np.log(rms))
    return float(np.log(max(0.1 * scale, 1e-12)))


def _relative(y, yhat, seen) -> float:
    seen = seen & (np.abs(yhat) > 1e-12 * max(_rms(y, seen), 1e-300))
    return _log_rms((y - yhat) / np.where(seen, yhat, 1.0), seen, _FALLBACK)


class Additive(ErrorModel):
    """σ = a."""

    name, terms, prefixes = "additive", ("additive",), {"additive": "sigma"}
    formula = "σ = additive"
    constant = True

    def variance(self, var, yhat):
        return var["additive"] * jnp.ones_like(yhat)

    def log_start(self, y, yhat, seen):
        return {"additive": _additive(y, yhat, seen)}


class Proportional(ErrorModel):
    """σ = b·|ŷ|."""

    name, terms, prefixes = "proportional", ("proportional",), {"proportional": "prop"}
    formula = "σ = proportional · |prediction|"

    def variance(self, var, yhat):
        return var["proportional"] * yhat**2

    def log_start(self, y, yhat, seen):
        return {"proportional": _relative(y, yhat, seen)}


class Combined(ErrorModel):
    """σ² = a² + b²ŷ²; each term starts at half its size alone."""

    name, terms = "combined", ("additive", "proportional")
    prefixes = {"additive": "sigma", "proportional": "prop"}
    formula = "σ² = additive² + (proportional · prediction)²"

    def variance(self, var, yhat):
        return var["additive"] + var["proportional"] * yhat**2

    def log_start(self, y, yhat, seen):
        half = np.log(0.5)
        return {"additive": _additive(y, yhat, seen) + half,
                "proportional": _relative(y, yhat, seen) + half}  # fmt: skip


class Exponential(ErrorModel):
    """log y = log ŷ + ε, SD(ε) = σ (log-additive; y = ŷ·e^ε, NONMEM's exponential
    error, nlmixr2's lnorm): for data whose scatter grows with their size and which
    are never ≤ 0."""

    name, terms, prefixes = "exponential", ("exponential",), {"exponential": "exp"}
    formula = "log y = log prediction + ε, SD(ε) = exponential"
    constant = True
    log_scale = True

    def variance(self, var, yhat):
        return var["exponential"] * jnp.ones_like(yhat)

    def log_start(self, y, yhat, seen):
        seen = seen & (y > 0) & (yhat > 0)
        ratio = np.log(np.where(seen, y, 1.0)) - np.log(np.where(seen, yhat, 1.0))
        return {"exponential": _log_rms(ratio, seen, _FALLBACK)}


ERROR_MODELS: dict[str, ErrorModel] = {
    m.name: m for m in (Additive(), Proportional(), Combined(), Exponential())
}
# every term in one order (the order of ψ's residual-error entries: all outputs'
# first term, then all outputs' second, ...)
TERMS: tuple[str, ...] = tuple(dict.fromkeys(t for m in ERROR_MODELS.values() for t in m.terms))


class ResidualErrors:
    """Every output's error model of one fleet, and where their terms sit in ψ's
    residual-error part ``noise`` (all outputs' first term, then their second, ...).

    Arguments:
        kinds: each output's error model's name (``ERROR_MODELS``), in output order.
        outputs: the outputs' names (for ψ's names)."""

    def __init__(self, kinds, outputs):
        self.models = tuple(ERROR_MODELS[k] for k in kinds)
        self.terms = [(t, g) for t in TERMS for g, e in enumerate(self.models) if t in e.terms]
        self.names = [f"log_{self.models[g].prefixes[t]}_{outputs[g]}" for t, g in self.terms]
        self.constant = all(e.constant for e in self.models)  # σ² never depends on ŷ
        self.logs = [g for g, e in enumerate(self.models) if e.log_scale]
        # each output's first term's place in ``noise`` (an output with a constant σ has one)
        self.first = np.array(
            [
                next(j for j, (_, h) in enumerate(self.terms) if h == g)
                for g in range(len(self.models))
            ],
            dtype=int,
        )

    def constant_sd(self, noise) -> np.ndarray:
        """Each output's σ on its scale (S,) where every σ is constant (``constant``):
        its one term's."""
        return np.exp(np.asarray(noise)[self.first])

    def variance(self, noise, yhat):
        """σ²_hg on each output's scale (…, S) at the predictions ``yhat`` (…, S)."""
        var: list[dict] = [{} for _ in self.models]
        for j, (t, g) in enumerate(self.terms):
            var[g][t] = jnp.exp(2 * noise[j])
        cols = [e.variance(var[g], yhat[..., g]) for g, e in enumerate(self.models)]
        return jnp.stack(cols, axis=-1)

    def scaled(self, y, seen):
        """h(y) of each output (…, S): a log-scale output's log where ``seen`` and > 0
        (elsewhere 0, never −∞ or NaN)."""
        if not self.logs:
            return y
        g, y = jnp.asarray(self.logs), jnp.asarray(y)
        keep = (seen[..., g] > 0) & (y[..., g] > 0)
        return y.at[..., g].set(jnp.where(keep, jnp.log(jnp.where(keep, y[..., g], 1.0)), 0.0))

    def residuals(self, y, f, seen):
        """((h(y) − h(ŷ))·seen, whether a log-scale output predicts ≤ 0 at a sample
        ``seen``: the likelihood is then 0, the objective +∞)."""
        if not self.logs:
            return (y - f) * seen, False
        g = jnp.asarray(self.logs)
        bad = jnp.any((seen[..., g] > 0) & (f[..., g] <= 0))
        return (self.scaled(y, seen) - self.scaled(f, seen)) * seen, bad

    def censored_z(self, y, f, c, V):
        """(h(limit) − h(ŷ)) / σ of the censored samples ``c`` (y holding the limit);
        where a log-scale output predicts ≤ 0 every value of it lies below the limit
        (P = 1: z = 40, whose log Φ is 0)."""
        r, _ = self.residuals(y, f, c)
        z = jnp.where(c > 0, r / jnp.sqrt(V), 0.0)
        if not self.logs:
            return z
        g = jnp.asarray(self.logs)
        return z.at[..., g].set(jnp.where(f[..., g] <= 0, 40.0, z[..., g]))

    def jacobian(self, y, mask):
        """−2 Σ log|h'(y)| over the observations: what makes the objective that of y
        (0 where every h is the identity)."""
        if not self.logs:
            return 0.0
        total = 0.0
        for g in self.logs:
            seen = mask[..., g]
            total = total - 2 * jnp.sum(
                seen * self.models[g].log_jacobian(jnp.where(seen > 0, y[..., g], 1.0))
            )
        return total

    def log_start(self, y, yhat, mask) -> np.ndarray:
        """``noise`` at the start, from the data ``y`` and the typical unit's
        predictions ``yhat`` (E, P, S)."""
        starts = [e.log_start(y[..., g], yhat[..., g], mask[..., g] > 0)
                  for g, e in enumerate(self.models)]  # fmt: skip
        return np.array([starts[g][t] for t, g in self.terms], dtype=float)

    def sample(self, yhat, sd, z, g: int):
        """Simulated observations of output ``g``: h⁻¹(h(ŷ) + σ z), σ on h's scale."""
        e = self.models[g]
        if not e.log_scale:
            return yhat + sd * z
        return e.inverse(np.log(np.maximum(yhat, 1e-300)) + sd * z)


def positive_observations(errors: ResidualErrors, units, outputs) -> None:
    """A log-scale error model's observations (and quantification limits) must be
    > 0: one line naming the first that is not, before any work."""
    for g in errors.logs:
        seen = units.mask[..., g] > 0
        if units.cens is not None:
            seen = seen | (units.cens[..., g] > 0)
        low = seen & ~(units.y[..., g] > 0)
        if low.any():
            i, h = np.argwhere(low)[0]
            raise ValueError(
                f"residual_error {errors.models[g].name!r} for {outputs[g]}: unit "
                f"{units.names[i]}'s observation at t = {units.t[i, h]:g} is "
                f"{units.y[i, h, g]:g}, which has no logarithm; drop or censor the rows "
                f"≤ 0 (CENS), or use 'combined' for {outputs[g]}"
            )
