r"""The marginal likelihood of a fleet and its exact derivatives.

ψ = (μ, log ω, s, log σ): μ_k = log of the typical value of population parameter k,
ω_k the standard deviation of its random effect η_k, s the shared free parameters
(natural units), σ the terms of each output's residual-error model (errors.py: a
transform h and a variance σ²_hg(ŷ) on h's scale; σ² = a_g² + b_g² ŷ_hg² for a
combined one). Unit i's parameters are exp(μ + η_i) for the population ones, its own
values b_i for individual ones (found beside η̂_i, no distribution), and s for the
rest. Below, y and ŷ stand for h(y) and h(ŷ) where h is not the identity.

Each unit's inner problem (its empirical Bayes estimate η̂_i, with b̂_i) minimises

    ℓ_i(η) = ½ Σ_h Σ_g [(y_hg − ŷ_hg)² / σ²_hg + log σ²_hg] + ½ ηᵀ Ω⁻¹ η,

solved by damped Newton steps with the exact Hessian. The outer objective is −2 log
of the Laplace approximation of the unit's marginal likelihood ∫ p(y_i | η) p(η) dη:

    O_i(ψ) = 2 ℓ_i(η̂_i) + N_i log 2π + log det Ω + log det M_i,

with M_i = ∇²_ηη ℓ_i(η̂_i) (``"laplace"``) or its first-order part
Σ_h A_hᵀ diag(σ_h⁻²) A_h + Ω⁻¹, A = ∂ŷ/∂η (``"focei"``: first-order conditional
estimation with interaction, σ² evaluated at η̂_i, as NONMEM's FOCE INTER; with
additive error alone σ does not depend on η, so FOCE and FOCEI agree).
FOCEI is the default (one order of ŷ's derivatives fewer than Laplace everywhere, and
what NONMEM and nlmixr2 report for the same model: approximations.py).

The outer gradient is exact through the inner optimum (implicit-function theorem):
dO/dψ = ∂O/∂ψ + ∂O/∂η · dη̂/dψ with dη̂/dψ = −(∇²_ηη ℓ)⁻¹ ∇²_ηψ ℓ; the outer Hessian its
derivative along η = η̂(ψ), by forward mode. Every model derivative comes from the
sweeps (units.py) through ŷ's Taylor polynomial about (ψ, η̂) (units.taylor)."""

from __future__ import annotations

import copy
import dataclasses
import threading

import jax
import jax.numpy as jnp
import jax.scipy.linalg
import jax.scipy.special
import numpy as np

from ..engine.compiling.programs import KeptStructures, Program
from ..engine.modelling.initial import moving
from ..engine.sweeping.sweeps import shared_sweeps
from .approximations import APPROXIMATIONS
from .errors import ResidualErrors, positive_observations
from .inner import solve_units
from .random_effects import RandomEffects
from .units import Units, block, blocked, outputs, simulated_at, taylor

METHODS = tuple(APPROXIMATIONS)  # (approximations.py)
_PROGRAMS = KeptStructures()  # compiled programs per structure (Objective._key_of)
_LOCK = threading.Lock()
LOG_2PI = float(np.log(2 * np.pi))


class Objective:
    """The population objective of a Problem with ``population`` set (see the module
    docstring); every program compiled once, vmapped over the units."""

    def __init__(self, problem, method: str = "focei"):
        if method not in METHODS:
            raise ValueError(f"a population fit's method is one of {METHODS}, not {method!r}")
        m = problem.model
        self.problem, self.method = problem, method
        self.approximation = APPROXIMATIONS[method]
        # individual parameters alone (no distribution): the joint least-squares problem,
        # reduced to the shared ones (variable projection; see fit_population). Beside
        # random effects they are each unit's own fixed effects, found with its η̂
        self.joint = bool(problem.individual) and not problem.population
        # the inner unknowns per unit: the random effects' η, then the individual values
        self.pop = list(problem.population) + list(problem.individual)
        self.qp = 0 if self.joint else len(problem.population)
        # Ω diagonal (log ω per random effect) or full: Ω = L Lᵀ, L lower triangular
        # with log diagonal (log ω where uncorrelated) and the entries below it
        self.full = getattr(problem, "omega", "diagonal") == "full" and self.qp > 1
        self.effects = RandomEffects(self.pop[: self.qp], self.full)  # Ω (random_effects.py)
        self.n_omega = self.effects.size
        self.first_shared = self.qp + self.n_omega
        self.shared = [n for n in problem.free_params if n not in self.pop]
        free = [m.params.index(n) for n in problem.free_params]
        # initial states that are expressions of estimated parameters ("Dose * F"):
        # every state's sensitivity seeded, chained through the expression by JAX
        exprs = getattr(problem, "x0_expressions", None) or {}
        uses = set(getattr(problem, "x0_uses", set())) & set(problem.free_params)
        self.moving = moving(m, exprs) if uses else None
        states = tuple(range(m.N)) if self.moving else ()
        d, dosing = problem.discretisation, getattr(problem, "dosing", None)
        self.sweeps = shared_sweeps(m, states, tuple(free), d, dosing=dosing)
        # the predictions' program serves every fixed-step substeps: kept as at 1
        one = dataclasses.replace(d, substeps=1) if d.fixed_steps else d
        self.run_time_sweeps = shared_sweeps(m, states, tuple(free), one, dosing=dosing)
        self.free = jnp.array(free, dtype=int)
        self.own_index = [m.params.index(n) for n in self.pop]
        self.pop_pos = jnp.array([problem.free_params.index(n) for n in self.pop], dtype=int)
        self.sh_pos = jnp.array([problem.free_params.index(n) for n in self.shared], dtype=int)
        self.q, self.ns, self.S = len(self.pop), len(self.shared), m.S
        # each output's residual-error model (errors.py): σ² and the scale it is on
        kinds = getattr(problem, "residual_error", None) or {}
        self.errors = tuple(kinds.get(o, "additive") for o in m.outputs)
        self.error = ResidualErrors(self.errors, m.outputs)
        self.units = Units.of(problem)
        positive_observations(self.error, self.units, m.outputs)
        # samples below their limit (Beal's M3): P(y < limit) in ℓ, which moves with σ
        self.censored = self.units.cens is not None
        self.plain = self.error.constant and not self.censored  # σ constant in η
        if self.censored and not self.approximation.censored:
            raise ValueError(
                "records with samples below their quantification limit (CENS, Beal's M3) "
                f"are fitted by method='laplace' (as NONMEM's M3), not {method!r}: "
                "FOCEI's curvature takes every residual as Gaussian"
            )
        # per unit (t, u, y, mask, x0, p[, cens]): the fixed parameters travel with the
        # data, so that a fleet of another size or other fixed values reuses the programs
        p = np.tile(np.asarray(problem.p0, dtype=float), (len(self.units.names), 1))
        self.data = (*self.units.arrays(), jnp.asarray(p))
        if self.censored:
            self.data += (jnp.asarray(self.units.cens),)
        self.weights = tuple(float(w) for w in problem.weights)
        moves = tuple((k, str(v)) for k, v in exprs.items()) if self.moving else ()
        self.key: tuple = (self.sweeps, tuple(self.pop), self.qp, self.full, tuple(self.shared),
                           method, moves, self.weights if self.joint else self.errors)  # fmt: skip
        self.key += ("censored",) if self.censored else ()
        self.Y = outputs(self.sweeps)
        random = self.pop[: self.qp]
        self.names = self.shared if self.joint else (  # ψ's, in order
            [f"log_{n}" for n in random] + [f"log_omega_{n}" for n in random]
            + [f"omega_chol_{a}_{b}" for a, b in self.effects.lower_pairs()]
            + self.shared + self.error.names)  # fmt: skip
        self.size = len(self.names)
        self._evaluated: dict = {}  # (ψ, η̂) → evaluation(): the last few

    # -- pieces -----------------------------------------------------------------------
    def split(self, psi):
        """(log typical values, log ω, shared, residual error) of ψ."""
        if self.joint:  # ψ holds the shared parameters alone
            return psi[:0], psi[:0], psi, psi[:0]
        qp, f = self.qp, self.first_shared
        return psi[:qp], psi[qp:f], psi[f : f + self.ns], psi[f + self.ns :]

    def theta(self, psi, eta):
        """The unit's free parameters (natural units, model order)."""
        mu, _, s, _ = self.split(psi)
        th = jnp.zeros(self.q + self.ns, dtype=jnp.result_type(psi, eta))
        qp = self.qp
        own = eta if self.joint else jnp.concatenate([jnp.exp(mu + eta[:qp]), eta[qp:]])
        return th.at[self.pop_pos].set(own).at[self.sh_pos].set(s)

    def start(self, theta, unit):
        """(x0, p) of the unit at its free parameters θ: x0's expressions evaluated
        where they move with θ."""
        x0, p = unit[4], unit[5].at[self.free].set(theta)
        return (x0 if self.moving is None else self.moving(x0, unit[1][0], p)), p

    def predict(self, psi, eta, unit):
        """ŷ (P, S) of the unit at (ψ, η) as the likelihood reads it: y, with derivatives
        0, where nothing was measured (units.outputs; predict_all: the model's own)."""
        return self.Y(self._argument(psi, eta, unit), *self._data(unit))

    def _data(self, unit):
        """Y's data: x0, p, t, u, y and where ŷ is read (measured, or censored for M3)."""
        seen = jnp.maximum(unit[3], unit[6]) if self.censored else unit[3]
        return unit[4], unit[5], unit[0], unit[1], unit[2], seen

    def _argument(self, psi, eta, unit):
        """Y's argument: θ, after the initial states where x0's expressions move."""
        theta = self.theta(psi, eta)
        if self.moving is None:
            return theta
        return jnp.concatenate([self.start(theta, unit)[0], theta])

    def local(self, psi, eta, unit, order: int) -> Objective:
        """This objective with the unit's ŷ its Taylor polynomial of ``order`` about
        (ψ, η) (units.taylor): the same value and derivatives there, cheaper to trace."""
        new = copy.copy(self)
        a0 = jax.lax.stop_gradient(self._argument(psi, eta, unit))
        new.Y = taylor(self.Y, a0, self._data(unit), order)
        return new

    def ell(self, eta, psi, unit):
        """ℓ_i(η): half the unit's weighted squared residuals plus half its prior (and,
        where σ depends on ŷ, half Σ log σ², which then moves with η)."""
        _, logw, _, noise = self.split(psi)
        y, mask = unit[2], unit[3]
        f = self.predict(psi, eta, unit)
        if self.joint:  # least squares, J_i / 2 with the Problem's weights
            return 0.5 * jnp.sum(((y - f) * mask) ** 2 * jnp.asarray(self.weights))
        r, bad = self.error.residuals(y, f, mask)  # on each error model's scale
        prior = self.effects.prior(eta[: self.qp], logw)
        if self.plain:
            out = 0.5 * (jnp.sum(r**2 * jnp.exp(-2 * noise[self.error.first])) + prior)
            return jnp.where(bad, jnp.inf, out)
        V = jnp.where(mask > 0, self.error.variance(noise, f), 1.0)  # 1: no observation
        out = 0.5 * (jnp.sum(r**2 / V + mask * jnp.log(V)) + prior)
        if self.censored:  # −log P(y < limit) = −log Φ((limit − ŷ)/σ), y holding the limit
            c = unit[6]
            Vc = jnp.where(c > 0, self.error.variance(noise, f), 1.0)  # (σ² = 0 where ŷ = 0)
            z = self.error.censored_z(y, f, c, Vc)
            out = out - jnp.sum(jnp.where(c > 0, jax.scipy.special.log_ndtr(z), 0.0))
        return jnp.where(bad, jnp.inf, out)

    def curvature(self, eta, psi, unit):
        """M_i over the random effects: the matrix whose log determinant the
        approximation adds (individual values are the unit's own optimum, not
        integrated over)."""
        qp = self.qp
        if self.approximation.exact_curvature:
            return jax.hessian(self.ell)(eta, psi, unit)[:qp, :qp]
        _, logw, _, noise = self.split(psi)
        A = self.unit_slopes(psi, eta, unit)
        if self.plain:
            Aw = A * (jnp.sqrt(unit[3]) * jnp.exp(-noise[self.error.first]))[..., None]
        else:  # FOCE with interaction: σ² at the unit's η̂
            f = self.predict(psi, eta, unit)
            V = jnp.where(unit[3] > 0, self.error.variance(noise, f), 1.0)
            Aw = A * jnp.sqrt(unit[3] / V)[..., None]
        return jnp.einsum("psj,psk->jk", Aw, Aw) + self.effects.inverse(logw)

    def unit_slopes(self, psi, eta, unit):
        """A = ∂h(ŷ)/∂η (P, S, random effects) of the unit at η: FOCEI's and CWRES's."""
        fitted = lambda e: self.error.scaled(self.predict(psi, e, unit), unit[3])  # noqa: E731
        return jax.jacfwd(fitted)(eta)[..., : self.qp]

    def unit_objective(self, psi, eta, unit):
        """O_i: −2 log of the unit's approximate marginal likelihood (for individual
        parameters alone, the unit's least-squares cost J_i)."""
        if self.joint:
            return 2 * self.ell(eta, psi, unit)
        _, logw, _, noise = self.split(psi)
        n = jnp.sum(unit[3], axis=0)  # observations per output
        sign, logdet = jnp.linalg.slogdet(self.curvature(eta, psi, unit))
        if self.plain:  # ℓ leaves out Σ log σ², constant in η
            O = 2 * self.ell(eta, psi, unit) + jnp.sum(n * (LOG_2PI + 2 * noise[self.error.first]))
            O = O + 2 * jnp.sum(logw[: self.qp]) + logdet
        else:
            O = 2 * self.ell(eta, psi, unit) + jnp.sum(n * LOG_2PI) + logdet
            O = O + 2 * jnp.sum(logw[: self.qp])  # log det Ω
        O = O + self.error.jacobian(unit[2], unit[3])  # the objective of y, not of h(y)
        return jnp.where(sign > 0, O, jnp.inf)

    def curvature_blocks(self, eta, psi, unit):
        """(∇²_ηη ℓ_i (q, q), ∇²_ηψ ℓ_i (q, ψ)): both from one derivative of ∇_η ℓ."""
        return jax.jacfwd(jax.grad(self.ell), argnums=(0, 1))(eta, psi, unit)

    def unit_value_grad(self, psi, eta, unit, local: bool = True):
        """(O_i, dO_i/dψ) with η = η̂_i(ψ) (the implicit-function theorem: dη̂/dψ =
        −(∇²_ηη ℓ)⁻¹ ∇²_ηψ ℓ)."""
        me = self.local(psi, eta, unit, self.approximation.gradient_order) if local else self
        O, (O_psi, O_eta) = jax.value_and_grad(me.unit_objective, argnums=(0, 1))(psi, eta, unit)
        H, L = me.curvature_blocks(eta, psi, unit)
        return O, O_psi - O_eta @ jnp.linalg.solve(H, L)

    def unit_evaluation(self, psi, eta, unit):
        """(O_i, dO_i/dψ, d²O_i/dψ², ∇²_ηη ℓ_i, ∂h(ŷ)/∂η) at η̂, in one program (what
        every outer evaluation asks; the last, of the random effects, for CWRES). The
        Hessian differentiates the gradient along η̂ + M (ψ' − ψ), M = dη̂/dψ: a point
        equal to η̂ to the last bit (O is value_grad's) whose derivative is M. ŷ is its
        polynomial about η̂ (exact there); a unit whose inner problem did not converge
        is named in the fit's notes."""
        me = self.local(psi, eta, unit, self.approximation.hessian_order)
        H, L = me.curvature_blocks(eta, psi, unit)
        M = -jnp.linalg.solve(H, L)
        M = jnp.where(jnp.isfinite(M), M, 0.0)  # (a singular H: O stays finite, g not)

        def grad_along(psi_):
            O, g = me.unit_value_grad(psi_, eta + M @ (psi_ - jax.lax.stop_gradient(psi_)),
                                      unit, False)  # fmt: skip
            return g, (O, g)

        outer, (O, g) = jax.jacfwd(grad_along, has_aux=True)(psi)
        return O, g, outer, H, me.unit_slopes(psi, eta, unit)

    def inner_step(self, eta, lam, psi, unit):
        """One damped Newton step on ℓ_i: (η, λ, ℓ, |step|)."""
        f = self.ell(eta, psi, unit)
        g = jax.grad(self.ell)(eta, psi, unit)
        H = jax.hessian(self.ell)(eta, psi, unit)
        scale = jnp.maximum(jnp.max(jnp.abs(jnp.diag(H))), 1e-300)
        d = jnp.linalg.solve(H + lam * scale * jnp.eye(self.q), -g)
        # steps kept within reach: an e-fold of a random effect, half an individual
        # parameter's size (its start's where it is near 0), so that a far Newton step
        # cannot throw a unit onto a flat plateau (an oscillator stiffened past its input)
        size_of = self._sizes(eta, unit)
        d = d * jnp.minimum(1.0, 1.0 / jnp.maximum(jnp.max(jnp.abs(d) / size_of), 1e-300))
        f_new = self.ell(eta + d, psi, unit)
        # rounding may lift ℓ by an ulp at the optimum: that step is still taken
        ok = jnp.isfinite(f_new) & (f_new <= f + 1e-14 * jnp.abs(f)) & jnp.all(jnp.isfinite(d))
        eta = jnp.where(ok, eta + d, eta)
        lam = jnp.where(ok, lam * 0.1, jnp.maximum(lam * 10, 1e-6))
        lam = jnp.where(lam < 1e-12, 0.0, lam)
        # how far the optimum is: the undamped Newton step where the Hessian is positive
        # definite (rounding in ℓ may refuse a step that small, at the optimum itself)
        newton = -jax.scipy.linalg.cho_solve((jnp.linalg.cholesky(H), True), g)
        small = jnp.max(jnp.abs(newton) / size_of)  # relative to each entry's own size
        size = jnp.where(jnp.all(jnp.isfinite(newton)), small, jnp.inf)
        return eta, lam, jnp.where(ok, f_new, f), size

    def _sizes(self, eta, unit):
        """The size a step on η is measured against: 1 for random effects (log scale),
        half the larger of |value| and |its start| for individual parameters."""
        qp = self.qp
        start = unit[5][jnp.asarray(self.own_index[qp:], dtype=int)]
        own = 0.5 * jnp.maximum(jnp.maximum(jnp.abs(eta[qp:]), jnp.abs(start)), 1e-300)
        return jnp.concatenate([jnp.ones_like(eta[:qp]), own])

    # -- compiled, over all units -------------------------------------------------------
    # kept per structure (model, discretisation, which parameters are random effects,
    # method): each function reads only that structure from self, the rest from its
    # arguments, so a later Objective of the same structure reuses them
    def _program(self, name: str | tuple, build):
        """The program ``build()`` makes, kept per structure here and on disk as the
        sweeps' are (engine/compiling/programs.py): a later process reads it, not traces it (the
        outer Hessian's trace alone was 10 s of a 17 s theophylline fit, cache warm).
        The predictions' serves every substeps: kept as at 1 (units.simulated_at)."""
        with _LOCK:  # (one Program per name, also where ahead.py's threads ask)
            programs = _PROGRAMS.programs(self._key_of(name))
            if name not in programs:
                label = name if isinstance(name, str) else "_".join(map(str, name))
                entry = f"population_{label} {self._structure_text()}"
                programs[name] = Program(build(), self._key_of(name)[0], entry)
            return programs[name]

    def _key_of(self, name) -> tuple:
        return (self.run_time_sweeps if name == "predict_all" else self.sweeps, *self.key[1:])

    def _structure_text(self) -> str:
        """What a program traces beyond its sweeps' (the random effects, Ω's form, the
        method, x0's expressions, the error models): text for its key."""
        return repr(self.key[1:])

    def structure(self) -> Objective:
        """This objective without its units' data or Problem: what a kept program may
        hold on to (the programs outlive the fit; its data need not)."""
        bare = copy.copy(self)
        bare.units = bare.data = bare.problem = None  # type: ignore[assignment]
        bare._evaluated = {}
        return bare

    def _blocked(self, name: str, *args, units: tuple[int, ...]):
        """The program ``name`` over every unit, in blocks of at most BLOCK units;
        ``units``: the positions of the arguments with a leading unit axis."""
        return blocked(self._compiled(name), args, units)

    def _compiled(self, name: str):
        """The program ``_build_<name>`` makes, kept per structure."""
        programs = _PROGRAMS.get(self._key_of(name), {})
        if name in programs:
            return programs[name]
        return self._program(name, getattr(self.structure(), f"_build_{name}"))

    def predict_all(self, psi, etas, substeps: int | None = None):
        """ŷ (E, P, S) of every unit at (ψ, η (E, q)), by the scheme at ``substeps`` per
        interval (None: the fit's; another number for a fixed-step scheme alone)."""
        d = self.sweeps.discretisation
        if substeps is not None:  # (checked as any discretisation's)
            if not d.fixed_steps:
                raise ValueError(f"the {d.scheme.name} scheme takes no number of substeps")
            d = dataclasses.replace(d, substeps=substeps)
        steps = jnp.asarray(d.substeps, jnp.int32)
        return self._blocked("predict_all", jnp.asarray(psi), jnp.asarray(etas), self.data,
                             steps, units=(1, 2))  # fmt: skip

    def _build_predict_all(self):
        def at(psi, eta, unit, steps):
            return simulated_at(self.sweeps, self._argument(psi, eta, unit), unit, steps)

        return jax.jit(jax.vmap(at, in_axes=(None, 0, 0, None)))

    def _build_steps(self):
        return jax.jit(jax.vmap(self.inner_step, in_axes=(0, 0, None, 0)))

    def _build_value_grad(self):
        return jax.jit(jax.vmap(self.unit_value_grad, in_axes=(None, 0, 0)))

    def _build_evaluation(self):
        return jax.jit(jax.vmap(self.unit_evaluation, in_axes=(None, 0, 0)))

    def _build_inner_blocks(self):
        return jax.jit(jax.vmap(self.curvature_blocks, in_axes=(0, None, 0)))

    def inner_blocks(self, psi, etas) -> tuple[np.ndarray, np.ndarray]:
        """(∇²_ηη ℓ_i (E, q, q), ∇²_ηψ ℓ_i (E, q, ψ)) at η̂."""
        H, L = self._blocked("inner_blocks", jnp.asarray(etas), jnp.asarray(psi), self.data,
                             units=(0, 2))  # fmt: skip
        return np.asarray(H), np.asarray(L)

    def start_etas(self) -> np.ndarray:
        """The inner problems' start: η = 0, and each individual parameter's p0."""
        E, pr, qp = len(self.units.names), self.problem, self.qp
        p0 = [0.0] * qp + [pr.p0[pr.model.params.index(n)] for n in self.pop[qp:]]
        return np.tile(np.asarray(p0, dtype=float), (E, 1)).reshape(E, self.q)

    def residual_sd(self, psi, etas, yhat=None) -> np.ndarray:
        """σ_hg (E, P, S) of every unit's residual error at (ψ, η) (predictions: ``yhat``)."""
        yhat = self.predict_all(psi, etas) if yhat is None else yhat
        return np.asarray(self._compiled("residual_sd")(jnp.asarray(psi), jnp.asarray(yhat)))

    def _build_residual_sd(self):
        return jax.jit(lambda psi, yhat: jnp.sqrt(self.error.variance(self.split(psi)[3], yhat)))

    def solve_inner(self, psi, etas, maxiter: int = 100, tol: float = 1e-11):
        """Each unit's η̂ from ``etas``: (η̂ (E, q), whether every unit converged);
        by damped Newton steps through the one loop (inner.py)."""
        eta, done, failed = solve_units(self, psi, etas, maxiter, tol)
        names = self.units.names
        self.unconverged = [n for n, d, x in zip(names, done, failed, strict=True) if not (d or x)]
        self.unfinite = [n for n, x in zip(names, failed, strict=True) if x]
        return eta, bool(done.all())

    def value_grad(self, psi, etas) -> tuple[np.ndarray, np.ndarray]:
        """(O_i (E,), dO_i/dψ (E, ψ)) per unit at η̂."""
        O, g = self._blocked("value_grad", jnp.asarray(psi), jnp.asarray(etas), self.data,
                             units=(1, 2))  # fmt: skip
        return np.asarray(O), np.asarray(g)

    def evaluation(self, psi, etas) -> tuple[np.ndarray, ...]:
        """(O_i (E,), dO_i/dψ (E, ψ), d²O_i/dψ² (E, ψ, ψ), ∇²ℓ_i (E, q, q)) per unit at
        η̂: an outer evaluation's value, gradient and Hessian, and each unit's inner
        Hessian (its inverse: the unit's η covariance). The last four are remembered,
        the newest with its slopes: a fit's result asks again for its best point's."""
        return self._remembered(psi, etas, slopes=False)[:4]

    def slopes(self, psi, etas) -> np.ndarray:
        """A = ∂h(ŷ)/∂η (E, P, S, random effects) at η̂ (CWRES's), from the evaluation
        (the newest point's remembered; another point's costs an outer evaluation)."""
        return self._remembered(psi, etas, slopes=True)[4]

    def _remembered(self, psi, etas, slopes: bool) -> tuple:
        key = (np.asarray(psi, float).tobytes(), np.asarray(etas, float).tobytes())
        got = self._evaluated.get(key)  # (read once: another thread may replace the memo)
        if got is None or (slopes and len(got) < 5):
            out = self._blocked("evaluation", jnp.asarray(psi), jnp.asarray(etas), self.data,
                                units=(1, 2))  # fmt: skip
            got = tuple(map(np.asarray, out))
            kept = [(k, v[:4]) for k, v in self._evaluated.items() if k != key][-3:]
            self._evaluated = dict(kept + [(key, got)])
        return got

    def evaluation_program(self, psi, etas):
        """(its Program, the first block's arguments): what ahead.py prepares."""
        args = (jnp.asarray(psi), jnp.asarray(etas), self.data)
        return self._compiled("evaluation"), block(args, (1, 2))

    def hessian(self, psi, etas, per_unit: bool = False) -> np.ndarray:
        """Σ_i d²O_i/dψ² at η̂ (each unit's, (E, ψ, ψ), with ``per_unit``)."""
        H = self.evaluation(psi, etas)[2]
        return H if per_unit else H.sum(0)
