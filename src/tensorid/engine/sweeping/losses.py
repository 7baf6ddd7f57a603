"""What the data say about a prediction: the per-sample loss, the one place where a
measured sample y and its prediction ŷ = C(x, p) meet.

Every path that turns predictions into a cost consumes a :class:`Loss` through one
call, :meth:`Loss.terms`, which gives, for one sample (outputs s = 1..S, weights w):

    ℓ(ŷ)               the sample's share of J
    ℓ_ŷ   = ∂ℓ/∂ŷ      (S,)    the gradient:   ∇J  = Σ_h D_hᵀ ℓ_ŷ
    ℓ_ŷŷ  = ∂²ℓ/∂ŷ²    (S,)    its curvature:  ∇²J = Σ_h D_hᵀ ℓ_ŷŷ D_h + Σ_h ℓ_ŷ · ŷ''_h
    γ                   (S,)    the Gauss-Newton weights: Σ_h D_hᵀ γ D_h

with D_h = ∂ŷ_h/∂θ and ŷ''_h = ∂²ŷ_h/∂θ² (the transition tensors' output side, or the
adjoint's Lagrangian). The losses are separable across outputs, so ℓ_ŷŷ and γ are
diagonals. The forward tensors, the second-order adjoint, the segments of multiple
shooting, the residuals and the statistics all go through here, so adding a loss is
one class (here, or in a module of one's own) registered with :func:`register_loss`;
the rest of the package asks its markers, never its name.

Each loss acts on the weighted residual e = √w (y − ŷ) of every output, scaled by
that output's scale c (in the weighted residual's units):

    ℓ = Σ_s c_s² ρ(e_s / c_s)

with ρ(z) ≈ z² near 0, so that every loss is the squared loss for small residuals
and J keeps the units of Σ w r². The squared loss is ρ(z) = z² (c drops out);

    huber       ρ = z²            for |z| ≤ 1,   2|z| − 1 beyond   (linear tails)
    cauchy      ρ = log(1 + z²)                                    (log tails)
    student-t   ρ = ν log(1 + z²/ν)    (ν = 4: the t distribution's −2 log density
                                        up to a constant factor)

Their Gauss-Newton weights are the iteratively-reweighted-least-squares weights
γ = w ρ'(z)/z, positive where the exact curvature w ρ''(z) of Cauchy and Student-t
turns negative (past |z| = 1 and √ν): a Gauss-Newton step is then a reweighted
least-squares step, as in IRLS.
"""

from __future__ import annotations

import warnings
from collections.abc import Mapping
from dataclasses import dataclass
from typing import ClassVar, TypeVar

import jax
import jax.numpy as jnp
import jax.scipy.linalg
import numpy as np

from ..modelling.checks import from_registry

# the scale c as a multiple of the noise's standard deviation σ when c is estimated
# (``Loss.tuning``): Huber's 1.345 and Cauchy's 2.385 give 95 % efficiency under
# Gaussian noise (the usual tuning constants); the t distribution's own scale is σ
STUDENT_NU = 4.0

# the losses by name: the one place a loss's name is looked up (``get_loss``); a class
# joins it with @register_loss. tensorid/names.py spells the command line's --loss
# choices out (tests/test_recipes.py checks that they are these)
REGISTRY: dict[str, type[Loss]] = {}


class _ByName(type):
    """``Loss("huber")`` (the spelling from before the losses were classes) gives the
    registered class's object; ``Huber()`` is the same thing."""

    def __call__(cls, *args, **kwargs):
        if cls is Loss and (args or "name" in kwargs):
            name = kwargs.pop("name", None) or args[0]
            return type(get_loss(name))(*args[1:], **kwargs)
        return super().__call__(*args, **kwargs)


@dataclass(frozen=True)
class Loss(metaclass=_ByName):
    """A per-sample loss ℓ = Σ_s c_s² ρ(√w_s r_s / c_s) (see the module docstring): a
    subclass gives ``rho`` and ``_dpsi`` (or ``terms``, ``value`` and ``residual``
    whole, as :class:`Gaussian`), its ``name`` and its markers.

    Hashable, and part of the compiled sweeps' key; the numbers it is evaluated with,
    the weights w and scales c (in units of the weighted residual √w r, ignored by
    the squared loss), come at run time as one array ``lw`` = [w; c] (2, S), so that
    a new scale compiles nothing.

    Markers (what the rest of the package asks instead of the name):
        squared: weighted least squares: the Gauss-Newton part is the exact Hessian's
            first term, and the statistics' Gaussian formulas hold (``is_gaussian``).
        robust: a robust loss with a scale c (``needs_scale``); ``tuning`` is c in
            units of the noise's σ when c is estimated.
        likelihood: J is −2 log-likelihood with the noise among the unknowns (a
            filter's Gaussian loss): then cov(θ) = 2 H⁻¹, with no residual variance.
        quadratic_inside: ρ'' is 2 inside the scale and 0 beyond (Huber): the
            expected curvature is the share of residuals inside (the sandwich's
            small-scale fallback).
    """

    name: ClassVar[str] = "squared"
    squared: ClassVar[bool] = True
    robust: ClassVar[bool] = False
    likelihood: ClassVar[bool] = False
    quadratic_inside: ClassVar[bool] = False
    tuning: ClassVar[float] = 1.0

    @property
    def is_gaussian(self) -> bool:
        """The marker ``squared``: the statistics' Gaussian formulas hold."""
        return self.squared

    @property
    def needs_scale(self) -> bool:
        """The marker ``robust``: the loss has a scale c (given, or estimated)."""
        return self.robust

    # -- ρ and its derivatives, on z = e / c -------------------------------------------
    def rho(self, z):
        return z * z

    def _dpsi(self, z):
        """(ρ'(z), ρ''(z), ρ'(z)/z), each in closed form (no 0/0 at z = 0)."""
        return 2.0 * z, 2.0 + 0.0 * z, 2.0 + 0.0 * z

    # -- what the sweeps call --------------------------------------------------------------
    def terms(self, y, yhat, lw):
        """(ℓ, ℓ_ŷ (S,), ℓ_ŷŷ (S,), γ (S,)) of one sample: y, ŷ per output, lw = [w; c]
        (w may be 0: that output, or a sample a shooting segment shares, does not
        count)."""
        w, r = lw[0], y - yhat
        if self.squared:  # J = Σ w r², written as it always was (bit-identical results)
            wr = w * r
            return jnp.sum(wr * r), -2.0 * wr, 2.0 * w, 2.0 * w
        c, sw = lw[1], jnp.sqrt(w)
        z = sw * r / c
        d1, d2, irls = self._dpsi(z)
        # ℓ_ŷ = −√w c ρ'(z), ℓ_ŷŷ = w ρ''(z), γ = w ρ'(z)/z
        return jnp.sum(c * c * self.rho(z)), -sw * c * d1, w * d2, w * irls

    def value(self, y, yhat, lw):
        """ℓ alone (a plain simulation's cost; y and ŷ may hold several samples)."""
        w, r = lw[0], y - yhat
        if self.squared:
            return jnp.sum(w * r * r)
        c = lw[1]
        return jnp.sum(c * c * self.rho(jnp.sqrt(w) * r / c))

    def residual(self, y, yhat, lw):
        """The signed square root of each output's share of ℓ, so that the sum of their
        squares is J: √w (y − ŷ) for the squared loss (what least-squares solvers and
        residual statistics see)."""
        e = jnp.sqrt(lw[0]) * (y - yhat)
        if self.squared:
            return e
        c = lw[1]
        return jnp.sign(e) * c * jnp.sqrt(self.rho(e / c))


_L = TypeVar("_L", bound=type[Loss])


def register_loss(cls: _L) -> _L:
    """Class decorator: ``cls`` chosen by its ``name`` wherever a loss is named
    (``Problem(loss=...)``, the model file's ``loss``)."""
    REGISTRY[cls.name] = cls
    return cls


def get_loss(loss) -> Loss:
    """The loss called ``loss`` (a Loss object is returned as it is); one line for
    anything else."""
    return from_registry(loss, REGISTRY, Loss, "loss")


@register_loss
@dataclass(frozen=True)
class Squared(Loss):
    """ρ(z) = z²: weighted least squares, J = Σ w r² (c drops out)."""


class _Robust(Loss):
    """A loss with a scale (the markers of every robust loss)."""

    squared: ClassVar[bool] = False
    robust: ClassVar[bool] = True


@register_loss
@dataclass(frozen=True)
class Huber(_Robust):
    """ρ = z² for |z| ≤ 1, 2|z| − 1 beyond (linear tails)."""

    name: ClassVar[str] = "huber"
    tuning: ClassVar[float] = 1.345
    quadratic_inside: ClassVar[bool] = True

    def rho(self, z):
        a = jnp.abs(z)
        return jnp.where(a <= 1.0, z * z, 2.0 * a - 1.0)

    def _dpsi(self, z):
        inside = jnp.abs(z) <= 1.0
        d1 = jnp.where(inside, 2.0 * z, 2.0 * jnp.sign(z))
        return d1, jnp.where(inside, 2.0, 0.0), jnp.where(inside, 2.0, 2.0 / jnp.abs(z))


@register_loss
@dataclass(frozen=True)
class StudentT(_Robust):
    """ρ = ν log(1 + z²/ν), ν = 4: the t distribution's −2 log density up to a
    constant factor (log tails)."""

    name: ClassVar[str] = "student-t"
    tuning: ClassVar[float] = 1.0
    nu: float = STUDENT_NU

    def rho(self, z):
        return self.nu * jnp.log1p(z * z / self.nu)

    def _dpsi(self, z):
        nu = self.nu
        q = 1.0 + z * z / nu
        return 2.0 * z / q, 2.0 * (1.0 - z * z / nu) / (q * q), 2.0 / q


@register_loss
@dataclass(frozen=True)
class Cauchy(_Robust):
    """ρ = log(1 + z²) (log tails): Student-t's ρ with ν = 1, written as before."""

    name: ClassVar[str] = "cauchy"
    tuning: ClassVar[float] = 2.385

    def rho(self, z):
        return jnp.log1p(z * z)

    def _dpsi(self, z):
        nu = 1.0
        q = 1.0 + z * z / nu
        return 2.0 * z / q, 2.0 * (1.0 - z * z / nu) / (q * q), 2.0 / q


# the command line's order (tensorid/names.py); a loss registered later joins REGISTRY
LOSSES = ("squared", "huber", "cauchy", "student-t")
REGISTRY.update({n: REGISTRY.pop(n) for n in LOSSES})
TUNING = {n: cls.tuning for n, cls in REGISTRY.items() if cls.robust}


SQUARED = Squared()


@dataclass(frozen=True)
class Gaussian(Loss):
    """The Gaussian negative log-likelihood of a prediction with its own covariance,
    π = (ŷ (S), vec Σ (S²)) (an extended Kalman filter's predicted output and
    innovation covariance, see predictors.py), up to the constant S log 2π:

        ℓ = log det Σ + εᵀ Σ⁻¹ ε,    ε = y − ŷ       (−2 log-likelihood)

    so that J = Σ_h ℓ_h is −2 log L and cov(θ) ≈ 2 H⁻¹ (no residual variance to
    estimate: the noise intensities are unknowns of θ). Its curvature in π is a full
    matrix, and its Gauss-Newton weights are the Fisher information of (ŷ, Σ):
    2 Σ⁻¹ for ŷ and Σ⁻¹ ⊗ Σ⁻¹ for vec Σ (Fisher scoring). ``lw`` is not used."""

    name: ClassVar[str] = "gaussian"
    squared: ClassVar[bool] = False
    likelihood: ClassVar[bool] = True

    @staticmethod
    def _split(y, pi):
        S = y.shape[-1]
        return y - pi[..., :S], pi[..., S:].reshape(pi.shape[:-1] + (S, S))

    def _whitened(self, y, pi):
        """(L⁻¹ ε, L) with L L ᵀ = Σ (Cholesky)."""
        eps, Sig = self._split(y, pi)
        L = jnp.linalg.cholesky(Sig)
        return jax.scipy.linalg.solve_triangular(L, eps[..., None], lower=True)[..., 0], L

    def value(self, y, pi, lw):
        z, L = self._whitened(y, pi)
        logdet = 2.0 * jnp.sum(jnp.log(jnp.diagonal(L, axis1=-2, axis2=-1)), axis=-1)
        return jnp.sum(logdet + jnp.sum(z * z, axis=-1))

    def terms(self, y, pi, lw):
        def ell(q):
            return self.value(y, q, lw)

        value, l1 = jax.value_and_grad(ell)(pi)
        _, Sig = self._split(y, pi)
        Si = jnp.linalg.inv(Sig)
        Si = 0.5 * (Si + Si.T)
        S = y.shape[-1]
        fisher = jnp.zeros((S + S * S, S + S * S), dtype=pi.dtype)
        fisher = fisher.at[:S, :S].set(2.0 * Si).at[S:, S:].set(jnp.kron(Si, Si))
        return value, l1, jax.hessian(ell)(pi), fisher

    def residual(self, y, pi, lw):
        """The standardised innovations L⁻¹ ε (L L ᵀ = Σ): white with unit variance
        where the model and its noise are right (what the whiteness tests see)."""
        return self._whitened(y, pi)[0]


GAUSSIAN = Gaussian()


def robust_noise(y: np.ndarray) -> np.ndarray:
    """(S,) the noise standard deviation of each measured output from its second
    differences, robustly: for white noise on a signal that is smooth at the sampling
    rate, y[k+1] − 2y[k] + y[k−1] has standard deviation √6 σ, and the median
    absolute deviation (× 1.4826, consistent for Gaussian noise) ignores the few
    differences a gross outlier touches, where a variance would not."""
    # each output's own sequence: NaN marks a sample not measured (outputs sampled at
    # other times); without NaN, the same medians as over the columns at once
    cols = [np.diff(a[~np.isnan(a)], n=2) for a in np.asarray(y, dtype=float).T]
    return np.array([robust_sd(d) / np.sqrt(6.0) if d.size else 0.0 for d in cols])


def robust_sd(a: np.ndarray) -> np.ndarray:
    """Per column, 1.4826 × the median absolute deviation: the standard deviation for
    Gaussian samples, untouched by a few gross outliers."""
    return 1.4826 * np.median(np.abs(a - np.median(a, axis=0)), axis=0)


def make_loss(
    loss, scale, outputs: list[str], weights: np.ndarray, measured: list
) -> tuple[Loss, np.ndarray]:
    """The Problem's Loss and its scale per output in the weighted residual's units
    (ones for the squared loss), from the arguments: ``loss`` a name or a Loss;
    ``scale`` None (estimated: TUNING × the outputs' robust noise level,
    :func:`robust_noise`), a number (every output) or {output: value}, in the
    outputs' own units."""
    loss = get_loss(loss)
    name = loss.name
    S = len(outputs)
    if not loss.robust:
        if scale is not None:
            raise ValueError("loss_scale is for a robust loss; the squared loss has none")
        return loss, np.ones(S)
    if scale is None:
        y = np.concatenate([np.asarray(m, dtype=float) for m in measured])
        counts = (~np.isnan(y)).sum(axis=0)  # (NaN: not measured)
        # an output measured nowhere adds nothing: any scale serves it (1)
        sigma = np.where(counts > 0, robust_noise(y), 1.0 / loss.tuning)
        n = int(counts[counts > 0].min()) if counts.any() else 0
        if n < 4:
            raise ValueError(
                f"loss={name!r}: {n} samples are too few to set the loss scale from "
                "(the noise level from second differences needs at least 4); give a scale "
                "in the outputs' units (loss_scale=; --loss-scale on the command line), or "
                "fit a longer record"
            )
        if not (sigma > 0).all():
            flat = [o for o, s in zip(outputs, sigma, strict=True) if not s > 0]
            raise ValueError(
                f"loss={name!r}: the measured outputs {flat} show no noise to set the loss "
                "scale from (their second differences vanish); give loss_scale= (in the "
                "outputs' units)"
            )
        c = loss.tuning * sigma
    elif isinstance(scale, Mapping):
        unknown = [k for k in scale if k not in outputs]
        if unknown:
            raise ValueError(f"loss_scale names unknown outputs {unknown}; outputs: {outputs}")
        missing = [o for o in outputs if o not in scale]
        if missing:
            raise ValueError(f"loss_scale gives no scale for outputs {missing}")
        c = np.array([float(scale[o]) for o in outputs])
    else:
        try:
            c = np.full(S, float(scale))
        except (TypeError, ValueError):
            raise ValueError(
                f"loss_scale must be a number or {{output: value}}, got {scale!r}"
            ) from None
    if not (np.isfinite(c).all() and (c > 0).all()):
        raise ValueError(f"loss_scale must be finite and > 0 for every output, got {c.tolist()}")
    if scale is not None:
        _check_resolvable(name, c, outputs, measured)
    # in the weighted residual's units; an output of weight 0 never counts
    return loss, np.where(weights > 0, np.sqrt(np.where(weights > 0, weights, 1.0)) * c, 1.0)


# c² must be a normal float: beyond these a robust loss's ℓ = c² ρ(e/c) is 0 or ∞
SCALE_RANGE = (1e-150, 1e150)


def _check_resolvable(name: str, c: np.ndarray, outputs: list[str], measured: list) -> None:
    """A given scale the data can resolve: not below the outputs' rounding (about 1e-15
    of their size, where no residual could lie inside it: the cost would be the
    outputs' rounding), nor so large that c² overflows (the loss is then the squared
    loss, computed as ∞ · 0)."""
    y = np.concatenate([np.asarray(m, dtype=float) for m in measured])  # NaN: not measured
    with np.errstate(all="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # (an output never measured: NaN)
        size = np.nanmax(np.abs(np.where(np.isfinite(y), y, np.nan)), axis=0)
        noise = robust_noise(y)
    size = np.where(np.isfinite(size), size, 0.0)
    floor = np.maximum(8 * np.finfo(float).eps * size, SCALE_RANGE[0])
    for k, o in enumerate(outputs):
        hint = f" (the data's noise level is about {noise[k]:.3g})" if noise[k] > 0 else ""
        if c[k] < floor[k]:
            raise ValueError(
                f"loss_scale={c[k]:g} for {o} is below what the data resolve (their rounding "
                f"is about {floor[k]:.2g}): give a scale near the noise level{hint}, or "
                f"drop loss_scale= to have it estimated"
            )
        if c[k] > SCALE_RANGE[1]:
            raise ValueError(
                f"loss_scale={c[k]:g} for {o} is too large to compute with (c² overflows); a "
                f"scale far above every residual makes {name!r} the squared loss: use "
                f"loss='squared', or a scale near the noise level{hint}"
            )
