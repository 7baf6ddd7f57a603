"""The augmented system: states x, first-order sensitivities dx = ∂x/∂θ and
second-order sensitivities d2x = ∂²x/∂θ², integrated together, with the cost,
gradient and Hessian accumulated sample by sample. (The docs write them S and T;
in the code S is the paper's number of outputs, so the arrays are named dx, d2x.)

θ (for one experiment) is (free initial states, free parameters). In the paper's
notation the columns of dx are the state transition matrix Φ (free x0 columns) and
the parameter transition matrix Θ (parameter columns); the blocks of d2x are Φ¹
(x0, x0), χ¹/χ² (x0, p) and Θ¹ (p, p). With z = (x, p) and Z = ∂z/∂θ = [dx; P]
(P selects the free parameters) the paper's ODEs (7), (9), (13)-(16) read

    d(dx)/dt       = F_z Z                           (Φ and Θ together)
    d(d2x_jk)/dt   = F_zz[Z_j, Z_k] + F_x d2x_jk      (Φ¹, Θ¹, χ¹, χ² together)

The state carried is the predictor's (predictors.py): x itself for output error; a
filter's z = (x̂, vec P), which its measurement update z⁺ = U(z, p, y_h) corrects at
each sample. The sensitivities go through U as through F, by the chain rule of the
map: dz⁺ = U_z Z and d2z⁺_jk = U_zz[Z_j, Z_k] + U_z d2z_jk (``push``), and the loss
sees the predictor's π(z, p) in place of C(x, p).

d2x is symmetric in (j, k), so only the K(K+1)/2 pairs j <= k are carried. F_zz is
never formed: F_zz[a, b] + F_z c is one nested forward-mode derivative
(a jvp of a jvp), so the cost per pair is a small multiple of one F evaluation.
The output side is the same with C in place of F, giving the paper's gradient
(18a-b) and Hessian (19-22), h the sample, for any per-sample loss ℓ(ŷ_h) of the
prediction ŷ_h = C(x_h, p) (see losses.py; the paper's is ℓ = Σ_g w_g r_g²,
r = y_obs − ŷ, with ℓ_ŷ = −2 w r and ℓ_ŷŷ = 2 w):

    J  = Σ_h ℓ(ŷ_h)
    ∇J = Σ (C_z Z)ᵀ ℓ_ŷ
    ∇²J = Σ (C_z Z)ᵀ ℓ_ŷŷ (C_z Z) + Σ ℓ_ŷ · (C_zz[Z, Z] + C_x d2x)
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import jax
import jax.numpy as jnp
import numpy as np

from ... import _config  # noqa: F401
from ..compiling.compiled import Compiled
from ..compiling.programs import Program
from ..modelling.model import Model
from ..schemes.discretisation import Discretisation, march
from . import second_order as orders
from .adjoint import SecondOrderAdjoint
from .dosing import Dosing, jump_hook, maps, rhs
from .losses import SQUARED, Loss
from .moving import march_moving
from .output_sensitivity import output_jacobian
from .packing import quadratic_full
from .packing import unpack_symmetric as unpack_symmetric  # its old home, re-exported
from .predictors import SIMULATION, Predictor, corrected
from .second_order import _observed, layout, second_order
from .steady import settle_map

# numbers of per-sample scores (P·K) a fit's first-order step keeps beside (J, ∇J,
# Gauss-Newton) rather than compiling a program without them (first_order_gn)
SCORES_KEPT_UP_TO = 1 << 18


@dataclass(frozen=True, eq=False)
class Sweeps:
    """The compiled simulation, cost and derivative sweeps for one θ layout and one
    discretisation.

    ``free_states`` and ``free_params`` are indices into the model's states and
    params; θ for one experiment is ``concat(x0[free_states], p[free_params])``.
    Every sweep but ``simulate`` takes ``(theta, x0, p, t, u, y, w)`` where x0 and p
    hold the values of the entries that θ does not set, and w = [weights; scales]
    (2, S) the numbers ``loss`` turns each sample's prediction into its share of J
    with (see losses.py).
    """

    model: Model
    free_states: tuple[int, ...]
    free_params: tuple[int, ...]
    discretisation: Discretisation
    loss: Loss = SQUARED
    predictor: Predictor = SIMULATION
    dosing: Dosing | None = None  # what the records' events do (dosing.py); None: none

    @property
    def K(self) -> int:
        return len(self.free_states) + len(self.free_params)

    # -- pieces shared by all sweeps -------------------------------------------------
    def expand(self, theta, x0, p):
        nx = len(self.free_states)
        x0 = x0.at[jnp.array(self.free_states, dtype=int)].set(theta[:nx]) if nx else x0
        p = p.at[jnp.array(self.free_params, dtype=int)].set(theta[nx:]) if self.free_params else p
        return x0, p

    def seeds(self):
        """dz(t0) (carried state's size, K): unit columns for free initial states (the
        predictor's own part of z, a filter's covariance, starts at 0); P (M, K): the
        parameter rows of Z, constant in time."""
        N, M, K, nx = self._size, self.model.M, self.K, len(self.free_states)
        dx0 = np.zeros((N, K))
        dx0[list(self.free_states), list(range(nx))] = 1.0
        Psel = np.zeros((M, K))
        Psel[list(self.free_params), list(range(nx, K))] = 1.0
        return dx0, Psel

    _size = property(lambda self: self.predictor.size(self.model))  # len(z); N for OE

    def _start(self, theta, x0, p):
        """(z0, p): the carried state at t0 and the parameters, θ written in."""
        x0, p = self.expand(theta, x0, p)
        return self.predictor.start(x0), p

    def _f(self, p, uu):
        """z ↦ the predictor's field (the model's F for output error)."""
        if self.dosing is not None:
            rhs = self._rhs(uu)
            return lambda z, p_=p: rhs(z, p_)
        return lambda z, p_=p: self.predictor.field(self.model, z, p_, uu)

    def _rhs(self, uu):
        """(x, p) ↦ the model's F with the events' infusions (dosing.rhs)."""
        return rhs(self.model, self.dosing, uu)

    def _pi(self, z, p, u_h=None):
        """The loss's prediction at a sample (ŷ for output error), u_h where C reads u."""
        return self.predictor.predict(self.model, z, p, *self._seen(u_h))

    def _seen(self, u_h) -> tuple:
        return (u_h,) if self.model.reads_inputs else ()

    def _update(self, push=None):
        """``march``'s update hook: None for output error; for a filter, the measurement
        update of the carried state, with ``push(fn, state)`` carrying the sensitivities
        of an augmented state through the map z ↦ fn(z, p)."""
        pr, m = self.predictor, self.model
        if pr.update is None:
            return None

        def update(state, obs_h, u_h, p):
            y_h = obs_h[0] if isinstance(obs_h, tuple) else obs_h

            def fn(z, p_):
                return corrected(pr, m, z, p_, y_h, *self._seen(u_h))

            return fn(state, p) if push is None else push(fn, state)

        return update

    def _march(
        self, field, observe, y0, acc0, t, u, obs, p, end=False, update=None, own=None, push=None
    ):
        """``march`` with the predictor's field (``own``: the field of the unaugmented
        state, when it is not the predictor's); with ``end``, the accumulator comes
        back as (accumulator, the augmented state at the last sample); ``update(state,
        obs_h, p)`` corrects the state at each sample (a filter); ``push(fn, state)``
        carries an augmented state through the events' jumps (None: a plain state)."""

        def state_field(x, uu):
            return self._f(p, uu)(x) if own is None else own(x, uu)

        if end:
            inner = observe

            def observe(acc, y, obs_h, u_h):
                acc, out = inner(acc[0], y, obs_h, u_h)
                return (acc, y), out

            acc0 = (acc0, y0)
        kw = dict(
            field=field,
            observe=observe,
            y0=y0,
            acc0=acc0,
            discretisation=self.discretisation,
            state_field=state_field,
            update=None if update is None else (lambda st, o, uh: update(st, o, uh, p)),
            # a filter starts with P0 = 0: where the initial state is an unknown, it can
            # match the first sample exactly, whose term log det R + 0 then has no
            # minimum in σ_e (→ −∞): it is left out (its gain is zero: it had no other use)
            skip_first=update is not None and bool(self.free_states),
            jump=jump_hook(self.dosing, p, push, settle_map(self)),
        )
        if self.dosing is not None and self.dosing.moving:  # events that move with p
            return march_moving(march, self.dosing, maps(self.dosing)[2], p, t, u, obs, **kw)
        return march(t=t, u=u, obs=obs, held=0 if self.dosing is None else self.dosing.width, **kw)

    # -- plain simulation --------------------------------------------------------------
    def _simulate(self, x0, p, t, u):
        """(xs (P, N), ys (P, outputs), failure code, sample of the first failure)."""
        m = self.model

        def field(x, uu):
            return self._rhs(uu)(x, p)

        def observe(acc, x, _, u_h):
            return acc, (x, m.h(x, p, u_h))

        _, (xs, ys), (code, at) = self._march(
            field, observe, x0, 0.0, t, u, jnp.zeros(t.shape), p, own=field
        )
        return xs, ys, code, at

    def _cost(self, theta, x0, p, t, u, y, w):
        z0, p = self._start(theta, x0, p)

        def field(z, uu):
            return self._f(p, uu)(z)

        def observe(J, z, obs_h, u_h):
            pi_h = functools.partial(self._pi, u_h=u_h)
            y_h, w_h, pi = _observed(obs_h, w, pi_h, self.predictor.masked, True)
            return J + self.loss.value(y_h, pi(z, p), w_h), None

        J, _, _ = self._march(field, observe, z0, jnp.zeros(()), t, u, y, p, update=self._update())
        return J

    def _predictions(self, theta, x0, p, t, u, y):
        """(z, π) at every sample, before each sample's update: the carried states and
        the predictions the loss sees (for output error, the simulation)."""
        z0, p = self._start(theta, x0, p)

        def field(z, uu):
            return self._f(p, uu)(z)

        def observe(acc, z, _, u_h):
            return acc, (z, self._pi(z, p, u_h))

        _, (zs, pis), _ = self._march(field, observe, z0, 0.0, t, u, y, p, update=self._update())
        return zs, pis

    _output_jacobian = output_jacobian  # ∂ŷ/∂θ (P, S, K) of the simulation

    def _k_step(self, theta, x0, p, t, u, y, k: int):
        """ŷ_{h|h−k} (P, S): each sample's output predicted k intervals ahead from the
        state the predictor had after sample h − k's update, by the model alone (for
        output error, the simulation); for h < k, from x0 (the simulation)."""
        zs, _ = self._predictions(theta, x0, p, t, u, y)
        x0, p = self.expand(theta, x0, p)
        m, pr = self.model, self.predictor
        if pr.update is not None:
            zs = jax.vmap(lambda z, yy, *uu: corrected(pr, m, z, p, yy, *uu))(zs, y, *self._seen(u))
        xs = pr.states(zs)

        def field(x, uu):
            return m.f(x, p, uu)

        def ahead(h):
            window = [jax.lax.dynamic_slice_in_dim(a, h, k + 1) for a in (t, u)]
            _, ys, _ = march(
                field, lambda acc, x, _, uh: (acc, m.h(x, p, uh)), xs[h], 0.0, *window,
                jnp.zeros(k + 1), discretisation=self.discretisation,
            )  # fmt: skip
            return ys[-1]

        sim = self._simulate(x0, p, t, u)[1]
        return jnp.concatenate([sim[:k], jax.vmap(ahead)(jnp.arange(t.shape[0] - k))])

    def _residuals(self, theta, x0, p, t, u, y, w):
        _, pis = self._predictions(theta, x0, p, t, u, y)
        return orders._residuals(self.loss, y, pis, w, self.predictor.masked).reshape(-1)

    # -- first order: (J, ∇J) and the Gauss-Newton Hessian -----------------------------
    def _first_order(self, theta, x0, p, t, u, y, w, gauss_newton=True, end=False, scores=False):
        """(J, ∇J, Σ (C_z Z)ᵀ γ (C_z Z)) with γ the loss's Gauss-Newton weights (2w for
        the squared loss); the last is None when not ``gauss_newton``.
        With ``end``, also (x, dx) at the last sample (see _weighted for y and w).
        With ``scores``, also each sample's share (C_z Z)ᵀ ℓ_π of ∇J (P, K), last."""
        x0, p = self._start(theta, x0, p)
        K = self.K
        dx0, Psel = self.seeds()
        Pt = jnp.asarray(Psel.T)
        lay = layout(self, second=False)  # one flat vector where small (second_order.py)

        def columns(fn, x, dxT):
            """(fn_z Z)ᵀ, one row per column of Z = [dx; Psel], by forward mode."""
            return jax.vmap(lambda sx, sp: jax.jvp(fn, (x, p), (sx, sp))[1])(dxT, Pt)

        def push(fn, state):  # (fn, fn_z Z) of z ↦ fn(z, p)
            x, dxT, _ = lay.split(state)
            return lay.pack(fn(x, p), columns(fn, x, dxT))

        def field(state, uu):
            return push(self._f(p, uu), state)

        def observe(acc, state, obs_h, u_h):
            J, g, H = acc
            x, dxT, _ = lay.split(state)
            pi_h = functools.partial(self._pi, u_h=u_h)
            y_h, w, pi = _observed(obs_h, w_all, pi_h, self.predictor.masked)
            ell, l1, _, gamma = self.loss.terms(y_h, pi(x, p), w)
            D = columns(pi, x, dxT)  # (K, outputs) = (C_z Z)ᵀ
            if gauss_newton:
                H = H + quadratic_full(D, gamma)
            return (J + ell, g + D @ l1, H), (D @ l1 if scores else None)

        acc0 = (jnp.zeros(()), jnp.zeros(K), jnp.zeros((K, K)) if gauss_newton else None)
        w_all = w
        state0 = lay.pack(x0, jnp.asarray(dx0.T))
        update = self._update(push)
        acc, shares, _ = self._march(
            field, observe, state0, acc0, t, u, y, p, end, update, push=push
        )
        if scores:  # (0 for an output not measured, whatever its prediction: _observed)
            return (*acc, shares)
        return (*acc[0], lay.tuple(acc[1])) if end else acc

    # -- second order: (J, ∇J, ∇²J) or (J, ∇J, ∇²J v) by transition tensors ------------
    def _second_order(self, theta, x0, p, t, u, y, w, v=None, end=False, both=False):
        """With v None: the packed Hessian (pairs j <= k, see pair_indices), d2x carried
        for every pair. With a direction v (K,): the product ∇²J v, carrying only
        d2x_v = Σ_k d2x_jk v_k, whose ODE is d(d2x_v)_j/dt = F_zz[Z_j, Z v] + F_x (d2x_v)_j: 2K + 1
        copies of the state instead of 1 + K + K(K+1)/2. With ``end``, also
        (x, dx, d2x) at the last sample (see _weighted for y and w). With ``both``
        (v None), also the packed Gauss-Newton part: it is a term of the sum anyway,
        and the hybrid method compares the two models. (second_order.py)"""
        return second_order(self, theta, x0, p, t, u, y, w, v, end, both)

    def _second_order_both(self, theta, x0, p, t, u, y, w):
        """(J, ∇J, packed ∇²J, packed Gauss-Newton Hessian)."""
        return self._second_order(theta, x0, p, t, u, y, w, both=True)

    def _hessp(self, theta, v, x0, p, t, u, y, w):
        return self._second_order(theta, x0, p, t, u, y, w, v=v)

    # -- one shooting segment: per-sample loss weights W (P, 2, S), and the end state -----
    def _segment(self, theta, x0, p, t, u, y, W):
        """(J, ∇J, packed ∇²J, (x, dx, d2x) at the last sample) over one segment."""
        return self._second_order(theta, x0, p, t, u, (y, W), None, end=True)

    def _segment_gn(self, theta, x0, p, t, u, y, W):
        """(J, ∇J, Gauss-Newton Hessian, (x, dx) at the last sample) over one segment."""
        return self._first_order(theta, x0, p, t, u, (y, W), None, end=True)

    def _gradient(self, theta, x0, p, t, u, y, w):
        return self._first_order(theta, x0, p, t, u, y, w, gauss_newton=False)[:2]

    def _first_order_scores(self, theta, x0, p, t, u, y, w):
        """(J, ∇J, Gauss-Newton Hessian, each sample's share of ∇J (P, K)): the fit's
        first-order sweep and the error bars' scores as one program. The shares are
        the terms of ∇J's sum, kept as they are made: the sweep runs as fast with them
        (±5 %: Silverbox, two-tank, its filter) and one program fewer is compiled."""
        return self._first_order(theta, x0, p, t, u, y, w, scores=True)

    def first_order_gn(self, theta, x0, p, t, u, y, w):
        """(J, ∇J, Gauss-Newton Hessian) for a fit's step: from the program that keeps
        the scores too (one program fewer to compile), unless the record is so long
        that its (P, K) scores would cost every step memory and time (P = 131,072, K =
        7: 18 MB more and 5 % slower a call); then from the program without them."""
        if t.shape[-1] * self.K > SCORES_KEPT_UP_TO:
            return self.first_order_only(theta, x0, p, t, u, y, w)
        return self.first_order(theta, x0, p, t, u, y, w)[:3]

    def scores(self, theta, x0, p, t, u, y, w):
        """(P, K): each sample's share of ∇J, through the predictor (a filter's update
        included); a sample the march leaves out of J (skip_first) is still a row."""
        return self.first_order(theta, x0, p, t, u, y, w)[3]

    # -- compiled entry points ---------------------------------------------------------
    _own_simulate = Compiled("_simulate")

    @functools.cached_property
    def simulate(self):
        """Compiled :meth:`_simulate` (the model's and discretisation's alone): every
        Sweeps of a model shares its plain Sweeps' (nothing free), compiled or read
        once (a fit with validation had read it three times, 0.02 s each)."""
        try:
            hash(self.discretisation)
        except TypeError:  # an unhashable user scheme: not shared
            return self._own_simulate
        plain = shared_sweeps(self.model, (), (), self.discretisation, dosing=self.dosing)
        return plain._own_simulate

    cost = Compiled("_cost")
    predictions = Compiled("_predictions")
    residuals = Compiled("_residuals")
    output_jacobian = Compiled("_output_jacobian")
    first_order = Compiled("_first_order_scores")  # (J, ∇J, Gauss-Newton, scores)
    first_order_only = Compiled("_first_order")  # (J, ∇J, Gauss-Newton): long records
    second_order = Compiled("_second_order")
    gradient = Compiled("_gradient")
    hessp = Compiled("_hessp")
    # one start per row of theta: multi-start in lock-step, one call for all
    first_order_batch = Compiled("_first_order", batched=True)
    second_order_batch = Compiled("_second_order", batched=True)
    second_order_both = Compiled("_second_order_both")
    second_order_both_batch = Compiled("_second_order_both", batched=True)
    # the segments of a multiple-shooting problem, one per row (each its own x0 and data)
    segments = Compiled("_segment", batched=True, axes=(0, 0, None, 0, 0, 0, 0))
    segments_gn = Compiled("_segment_gn", batched=True, axes=(0, 0, None, 0, 0, 0, 0))

    # each Hessian path's sweep of these Sweeps, made once (HessianPath.made)
    made = functools.cached_property(lambda self: {})  # type: ignore[var-annotated]

    @functools.cached_property
    def k_step(self):
        """Compiled :meth:`_k_step`, one program per horizon k (each kept: programs.py);
        called as ``k_step(theta, x0, p, t, u, y, k=k)``."""
        programs: dict = {}

        def run(theta, x0, p, t, u, y, k: int):
            if k not in programs:
                fn = jax.jit(functools.partial(self._k_step, k=k))
                programs[k] = Program(fn, self, f"_k_step k={k}")
            return programs[k](theta, x0, p, t, u, y)

        return run

    @functools.cached_property  # (J, ∇J, ∇²J, Gauss-Newton part) by second-order adjoints
    def adjoint(self) -> SecondOrderAdjoint:
        return SecondOrderAdjoint(self)

    @functools.cached_property
    def adjoint_batch(self) -> SecondOrderAdjoint:
        return SecondOrderAdjoint(self, batched=True)

    def __getstate__(self):
        return {
            k: v
            for k, v in self.__dict__.items()
            if not isinstance(_entry(k), Compiled | functools.cached_property)
        }

    def __setstate__(self, state):
        self.__dict__.update(state)


def _entry(name: str):
    return Sweeps.__dict__.get(name)


def shared_sweeps(
    model: Model,
    free_states: tuple[int, ...],
    free_params: tuple[int, ...],
    discretisation: Discretisation,
    loss: Loss = SQUARED,
    predictor: Predictor = SIMULATION,
    dosing: Dosing | None = None,
) -> Sweeps:
    """The Sweeps for this structure, compiled once per process and data shape: every
    Problem (and simulation) with the same model, θ layout, discretisation and loss
    shares them, and jit recompiles only for new data shapes. The cache lives on the
    model, so it goes when the model goes (and is not pickled with it)."""
    key = (tuple(free_states), tuple(free_params), discretisation, loss, predictor, dosing)
    try:
        return model.compiled_sweeps.setdefault(key, Sweeps(model, *key))
    except TypeError:  # an unhashable user scheme: not shared
        return Sweeps(model, *key)
