"""Runge-Kutta schemes: small classes that carry their Butcher tableau as data and
cover one sample interval with ``interval``.

Three kinds:

* ``ExplicitRungeKutta`` (euler, heun, rk4, rk38): ``substeps`` equal steps per
  sample interval.
* ``DiagonallyImplicitRungeKutta`` (implicit-euler, sdirk2, sdirk3): L-stable, for
  stiff models; each stage equation is solved by Newton's method to round-off
  (``NewtonStageSolver``).
* ``AdaptiveRungeKutta`` (bosh3, dopri5): an embedded explicit pair whose step size
  is chosen from a local error estimate against ``rtol``/``atol``
  (``StepSizeController``).

A Runge-Kutta map commutes with differentiation: differentiating the stage
equations of the scheme applied to x' = F(x) gives the same scheme applied to the
augmented system (x, S, T). So stepping (x, S, T) with the scheme gives the exact
first and second derivatives of the discretised trajectory, also for implicit
stages (whose augmented stage equations are linear in S and T with the same matrix
I - Δ γ F_x as the state's Newton iteration (Δ the step size)). For the adaptive schemes the step
sizes are chosen from the states alone and held fixed under differentiation, as in
CVODES and diffrax: the derivatives are those of the discretisation on the steps
taken.

The stepped state is either the state vector x (N,) or a tuple whose first entry is
x and whose other entries have N leading rows (S (N, K), T (N, K(K+1)/2)).
Each ``interval`` returns an integer failure code (``Status.code``) beside the
state, so that a failure is reported by the integrator itself.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Protocol, runtime_checkable

import jax
import jax.numpy as jnp

from ... import _config  # noqa: F401
from ..modelling.checks import did_you_mean
from .adaptive import AdaptiveRungeKutta, StepSizeController
from .implicit import DiagonallyImplicitRungeKutta, NewtonStageSolver
from .tableau import Field, _axpy, _check_tableau, _explicit_stages, _n_levels, _x

# the parts of a scheme live beside this module (tableau, implicit, adaptive); their
# names stay importable from here, as before
__all__ = [
    "BOSH3",
    "DISCRETE",
    "DOPRI5",
    "EULER",
    "HEUN",
    "IMPLICIT_EULER",
    "RK4",
    "RK38",
    "RTOL_FLOOR",
    "SCHEMES",
    "SDIRK2",
    "SDIRK3",
    "AdaptiveRungeKutta",
    "DiagonallyImplicitRungeKutta",
    "DiscreteMap",
    "ExplicitRungeKutta",
    "Field",
    "NewtonStageSolver",
    "RungeKuttaScheme",
    "Scheme",
    "StepSizeController",
    "_axpy",
    "_check_tableau",
    "_explicit_stages",
    "_n_levels",
    "_x",
    "get_scheme",
    "register_scheme",
]


@dataclass(frozen=True)
class ExplicitRungeKutta:
    """Butcher tableau of an explicit scheme: k_i = f(y + Δ Σ_{j<i} a_ij k_j, t + c_i Δ),
    y_next = y + Δ Σ b_i k_i, Δ the step size."""

    name: str
    a: tuple[tuple[float, ...], ...]
    b: tuple[float, ...]
    c: tuple[float, ...]
    order: int

    def __post_init__(self) -> None:
        _check_tableau(self.name, self.a, self.b, self.c, self.order, implicit=False)

    def step(self, f: Field, y, step, s0, ds):
        """One step of size ``step`` covering the fraction ds of the interval from s0."""
        ks = _explicit_stages(self.a, self.c, f, y, step, s0, ds)
        return _axpy(y, step, zip(self.b, ks, strict=True))

    def interval(self, f: Field, fs: Field, y, dt, carry, substeps: int | jax.Array):
        """Cover one sample interval of length dt with ``substeps`` equal steps (a
        traced integer where they are read at run time: Discretisation.at_run_time);
        returns (y, carry, failure code)."""
        step, ds = dt / substeps, 1.0 / substeps
        # the stages call one jitted field: traced once, not once per stage (XLA inlines
        # it; a population fit's third-order trace of the sweeps: 1.3 -> 1.0 s). A fresh
        # closure: jit's cache is keyed on the function, which a caller's own callable
        # (unhashable, or equal to another with other state) must not be
        g = jax.jit(lambda yy, s: f(yy, s))
        y = jax.lax.fori_loop(0, substeps, lambda i, yy: self.step(g, yy, step, i * ds, ds), y)
        return y, carry, jnp.int32(0)


@dataclass(frozen=True)
class DiscreteMap:
    """A discrete-time model, x[k+1] = f(x[k], p, u[k]): one application of the map
    per sample interval, the input taken at the interval's start.

    The sweeps' augmented fields become maps too, and stay exact: for z = (x, p),
    ∂x[k+1]/∂θ = f_z Z and ∂²x[k+1]/∂θ² = f_zz[Z, Z] + f_x ∂²x[k]/∂θ², the same
    expressions that the continuous-time sweeps integrate (the chain rule of the map
    in place of the variational equations)."""

    name: str = "discrete"
    order: int = 1

    def interval(self, f: Field, fs: Field, y, dt, carry, substeps: int):
        return f(y, 0.0), carry, jnp.int32(0)


DISCRETE = DiscreteMap()


@runtime_checkable
class RungeKuttaScheme(Protocol):
    """What the march needs of a scheme: its name and order, and ``interval``, which
    covers one sample interval and returns (y, carry, failure code). The carry is
    the scheme's own state between intervals (the adaptive schemes' trial step)."""

    name: str
    order: int

    def interval(self, f: Field, fs: Field, y, dt, carry, substeps: int): ...


Scheme = ExplicitRungeKutta | DiagonallyImplicitRungeKutta | AdaptiveRungeKutta | DiscreteMap

EULER = ExplicitRungeKutta("euler", ((),), (1.0,), (0.0,), 1)
HEUN = ExplicitRungeKutta("heun", ((), (1.0,)), (0.5, 0.5), (0.0, 1.0), 2)
RK4 = ExplicitRungeKutta(
    "rk4",
    ((), (0.5,), (0.0, 0.5), (0.0, 0.0, 1.0)),
    (1 / 6, 1 / 3, 1 / 3, 1 / 6),
    (0.0, 0.5, 0.5, 1.0),
    4,
)
RK38 = ExplicitRungeKutta(
    "rk38",
    ((), (1 / 3,), (-1 / 3, 1.0), (1.0, -1.0, 1.0)),
    (1 / 8, 3 / 8, 3 / 8, 1 / 8),
    (0.0, 1 / 3, 2 / 3, 1.0),
    4,
)

IMPLICIT_EULER = DiagonallyImplicitRungeKutta("implicit-euler", ((1.0,),), (1.0,), (1.0,), 1)
# Alexander (1977), SIAM J. Numer. Anal. 14(6): L-stable, stiffly accurate.
_G2 = 1.0 - 1.0 / math.sqrt(2.0)
SDIRK2 = DiagonallyImplicitRungeKutta(
    "sdirk2", ((_G2,), (1.0 - _G2, _G2)), (1.0 - _G2, _G2), (_G2, 1.0), 2
)
_G3 = 0.435866521508458999416019
_T3 = (1.0 + _G3) / 2.0
_B31 = -(6.0 * _G3**2 - 16.0 * _G3 + 1.0) / 4.0
_B32 = (6.0 * _G3**2 - 20.0 * _G3 + 5.0) / 4.0
SDIRK3 = DiagonallyImplicitRungeKutta(
    "sdirk3",
    ((_G3,), (_T3 - _G3, _G3), (_B31, _B32, _G3)),
    (_B31, _B32, _G3),
    (_G3, _T3, 1.0),
    3,
)

# Bogacki & Shampine (1989) 3(2); Dormand & Prince (1980) 5(4).
BOSH3 = AdaptiveRungeKutta(
    "bosh3",
    ((), (0.5,), (0.0, 0.75), (2 / 9, 1 / 3, 4 / 9)),
    (2 / 9, 1 / 3, 4 / 9, 0.0),
    (0.0, 0.5, 0.75, 1.0),
    3,
    e=(7 / 24, 1 / 4, 1 / 3, 1 / 8),
)
DOPRI5 = AdaptiveRungeKutta(
    "dopri5",
    (
        (),
        (1 / 5,),
        (3 / 40, 9 / 40),
        (44 / 45, -56 / 15, 32 / 9),
        (19372 / 6561, -25360 / 2187, 64448 / 6561, -212 / 729),
        (9017 / 3168, -355 / 33, 46732 / 5247, 49 / 176, -5103 / 18656),
        (35 / 384, 0.0, 500 / 1113, 125 / 192, -2187 / 6784, 11 / 84),
    ),
    (35 / 384, 0.0, 500 / 1113, 125 / 192, -2187 / 6784, 11 / 84, 0.0),
    (0.0, 1 / 5, 3 / 10, 4 / 5, 8 / 9, 1.0, 1.0),
    5,
    e=(5179 / 57600, 0.0, 7571 / 16695, 393 / 640, -92097 / 339200, 187 / 2100, 1 / 40),
)

SCHEMES: dict[str, Scheme] = {
    s.name: s for s in (EULER, HEUN, RK4, RK38, IMPLICIT_EULER, SDIRK2, SDIRK3, BOSH3, DOPRI5)
}


def register_scheme(scheme: Scheme) -> Scheme:
    """``scheme`` (an object with ``name``, ``order`` and ``interval``, e.g. an
    ``ExplicitRungeKutta`` of a new tableau) chosen by its name wherever a scheme is
    named (``Problem(scheme=...)``, ``simulate``); tensorid/names.py spells the
    command line's --scheme choices out."""
    SCHEMES[scheme.name] = scheme
    return scheme


RTOL_FLOOR = 100 * math.ulp(1.0)  # 2.2e-14: below it, steps chase round-off


def get_scheme(
    scheme: str | Scheme, rtol: float | None = None, atol: float | None = None
) -> Scheme:
    """The scheme named ``scheme`` (or the one given), with error tolerances set for
    an adaptive one."""
    if isinstance(scheme, str):
        try:
            scheme = SCHEMES[scheme]
        except KeyError:
            raise ValueError(
                f"unknown integration scheme {scheme!r}{did_you_mean(scheme, list(SCHEMES))}; "
                f"choose one of {sorted(SCHEMES)}"
            ) from None
    elif not isinstance(scheme, RungeKuttaScheme):
        raise TypeError(
            f"scheme must be a name or a scheme object (name, order, interval(...)), got "
            f"{type(scheme).__name__}"
        )
    if rtol is None and atol is None:
        return scheme
    if not isinstance(scheme, AdaptiveRungeKutta):
        adaptive = sorted(n for n, s in SCHEMES.items() if isinstance(s, AdaptiveRungeKutta))
        raise ValueError(
            f"rtol/atol apply to the adaptive schemes {adaptive}; {scheme.name!r} takes a "
            "fixed number of substeps per sample (set substeps instead)"
        )
    rtol = scheme.rtol if rtol is None else float(rtol)
    atol = scheme.atol if atol is None else float(atol)
    if not (rtol > 0 and atol >= 0 and math.isfinite(rtol) and math.isfinite(atol)):
        raise ValueError(f"need rtol > 0 and atol >= 0, finite; got rtol={rtol}, atol={atol}")
    if rtol < RTOL_FLOOR:
        raise ValueError(
            f"rtol={rtol:g} is below double-precision round-off; use rtol >= {RTOL_FLOOR:.3g} "
            "(100 machine epsilons, the floor MATLAB's solvers raise smaller values to)"
        )
    return replace(scheme, rtol=rtol, atol=atol)
