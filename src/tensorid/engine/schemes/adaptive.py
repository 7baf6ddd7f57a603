"""Adaptive Runge-Kutta schemes (bosh3, dopri5): an embedded explicit pair whose step
size is chosen from a local error estimate against ``rtol``/``atol``
(``StepSizeController``). The step sizes come from the states alone and are held
fixed under differentiation, as in CVODES and diffrax: the derivatives are those of
the discretisation on the steps taken."""

from __future__ import annotations

from dataclasses import dataclass

import jax
import jax.numpy as jnp

from .status import Status
from .tableau import Field, _axpy, _check_tableau, _explicit_stages, _x


@dataclass(frozen=True)
class StepSizeController:
    """Accept a step when the RMS of err / (atol + rtol max(|x|, |x_next|)) is at most
    1; the next step aims at 0.9 of the tolerance (the estimate is O(Δ^order)),
    changing by a factor between 0.2 and 5."""

    rtol: float
    atol: float
    order: int

    def error_norm(self, x0, x1, err):
        sc = self.atol + self.rtol * jnp.maximum(jnp.abs(x0), jnp.abs(x1))
        return jnp.sqrt(jnp.mean((err / sc) ** 2))

    def factor(self, en):
        f = jnp.clip(0.9 * jnp.where(en > 0, en, 1e-10) ** (-1.0 / self.order), 0.2, 5.0)
        return jnp.where(jnp.isfinite(en), f, 0.2)


@dataclass(frozen=True)
class AdaptiveRungeKutta:
    """An explicit pair: y_next = y + Δ Σ b_i k_i, error estimate Δ Σ (b_i - e_i) k_i
    with the embedded weights ``e`` (order ``order - 1``). A step is accepted when
    the RMS of err / (atol + rtol max(|x|, |x_next|)) over the states is at most 1;
    at most ``max_steps`` steps per sample interval."""

    name: str
    a: tuple[tuple[float, ...], ...]
    b: tuple[float, ...]
    c: tuple[float, ...]
    order: int
    e: tuple[float, ...]
    rtol: float = 1e-6
    atol: float = 1e-9
    max_steps: int = 10_000

    def __post_init__(self) -> None:
        _check_tableau(self.name, self.a, self.b, self.c, self.order, implicit=False)
        if len(self.e) != len(self.b) or abs(sum(self.e) - 1.0) > 1e-12:
            raise ValueError(f"scheme {self.name!r}: e needs one weight per stage, summing to 1")

    @property
    def controller(self) -> StepSizeController:
        return StepSizeController(self.rtol, self.atol, self.order)

    def step(self, f: Field, y, step, s0, ds):
        """One trial step: (y_next, local error estimate of the states)."""
        ks = _explicit_stages(self.a, self.c, f, y, step, s0, ds)
        y1 = _axpy(y, step, zip(self.b, ks, strict=True))
        errs = [bi - ei for bi, ei in zip(self.b, self.e, strict=True)]
        err = _axpy(jnp.zeros_like(_x(y)), step, zip(errs, [_x(k) for k in ks], strict=True))
        return y1, err

    def interval(self, f: Field, fs: Field, y, dt, step0, substeps: int):
        """Cover one sample interval of length dt with error-controlled steps from the
        trial step ``step0`` (the carry); returns (y, next trial step, failure code). Step
        sizes come from the states only, through stop_gradient: they are the
        discretisation, not a function of θ to differentiate."""
        ctl = self.controller
        tiny = 1e-14 * dt

        def cond(c):
            _, s, step, n = c
            return (s < 1.0) & (n < self.max_steps) & (step > tiny)

        def body(c):
            y, s, step, n = c
            step = jnp.minimum(step, (1.0 - s) * dt)
            ds = step / dt
            y1, err = self.step(f, y, step, s, ds)
            en = jax.lax.stop_gradient(ctl.error_norm(_x(y), _x(y1), err))
            ok = (en <= 1.0) & jnp.all(jnp.isfinite(_x(y1)))
            step_next = jax.lax.stop_gradient(step * ctl.factor(en))
            y = jax.tree_util.tree_map(lambda a, b: jnp.where(ok, a, b), y1, y)
            # land exactly on the sample: the last accepted step ends at s = 1
            s = jnp.where(ok, jnp.where(step >= (1.0 - s) * dt, 1.0, s + ds), s)
            return y, jax.lax.stop_gradient(s), step_next, n + 1

        step0 = jax.lax.stop_gradient(step0)
        y, s, step, _ = jax.lax.while_loop(cond, body, (y, jnp.zeros_like(dt), step0, 0))
        code = jnp.where(
            step <= tiny,
            Status.STEP_UNDERFLOW.code,
            jnp.where(s < 1.0, Status.STEP_LIMIT.code, 0),
        ).astype(jnp.int32)
        y = jax.tree_util.tree_map(lambda a: jnp.where(code != 0, jnp.nan, a), y)
        return y, step, code
