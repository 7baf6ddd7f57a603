"""A population fit's outcome, in a population user's words (nlmixr2/NONMEM): typical
values with standard errors, ω (the standard deviation of η) and the CV it means,
η shrinkage, the residual SD per output, and each unit's empirical Bayes estimates
with their own error bars."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, ClassVar

import jax
import jax.numpy as jnp
import numpy as np

from ..analysis.results import FitResult
from ..solve.stats import Stats
from .as_fit import AsFit
from .errors import ERROR_MODELS


def _inverse(H: np.ndarray) -> np.ndarray:
    """H⁻¹ where H is positive definite; inf where it is not (no error bars)."""
    if not np.isfinite(H).all():
        return np.full_like(H, np.nan)
    try:
        np.linalg.cholesky(H)
        return np.linalg.inv(H)
    except np.linalg.LinAlgError:
        return np.full_like(H, np.inf)


def _measured(r, status) -> np.ndarray:
    """The outer Hessian where the fit measured one at a finite cost; NaN otherwise (a
    failed evaluation's placeholder must not become error bars)."""
    H = np.asarray(r.hess, dtype=float)
    if not (np.isfinite(r.fun) and status.success and np.isfinite(H).all()):
        return np.full_like(H, np.nan)
    return H


def _unmeasured(cov: np.ndarray, flat) -> np.ndarray:
    """``cov`` with the directions ``flat`` NaN: the data say nothing about them (their
    held unit curvature is no measurement)."""
    if flat is None or not np.any(flat):
        return cov
    cov = cov.copy()
    cov[flat, :] = np.nan
    cov[:, flat] = np.nan
    return cov


def _residual_error(obj, x, se) -> dict:
    """{output: {"model", "additive", "additive_stderr", "proportional", ...}}."""
    out: dict = {o: {"model": k} for o, k in zip(obj.problem.model.outputs, obj.errors,
                                                  strict=True)}  # fmt: skip
    first = obj.first_shared + obj.ns
    for j, (what, g) in enumerate(obj.error.terms):
        v = float(np.exp(x[first + j]))
        out[obj.problem.model.outputs[g]].update(
            {what: v, f"{what}_stderr": v * float(se[first + j])}
        )
    return out


def _omega(obj, x, cov, se) -> tuple[np.ndarray, np.ndarray, dict]:
    """(ω (qp,), their standard errors, {"a,b": correlation with its SE}) from ψ's Ω
    parameters, by the delta method through Ω = L Lᵀ where Ω is full."""
    qp, lpar = obj.qp, x[obj.qp : obj.first_shared]
    if not obj.full:
        om = np.exp(lpar)
        return om, om * se[qp : obj.first_shared], {}
    pairs = obj.effects.lower_pairs()
    rows, cols = np.tril_indices(qp, -1)

    def stats(lp):
        L = obj.effects.cholesky(lp)
        Om = L @ L.T
        w = jnp.sqrt(jnp.diag(Om))
        return jnp.concatenate([w, Om[rows, cols] / (w[rows] * w[cols])])

    value = np.asarray(stats(jnp.asarray(lpar)))
    D = np.asarray(jax.jacfwd(stats)(jnp.asarray(lpar)))
    block = cov[qp : obj.first_shared, qp : obj.first_shared]
    var = np.einsum("ij,jk,ik->i", D, block, D)
    err = np.sqrt(np.where(var >= 0, var, np.nan))
    corr = {
        f"{a},{b}": {"value": float(value[qp + j]), "stderr": float(err[qp + j])}
        for j, (a, b) in enumerate(pairs)
    }
    return value[:qp], err[:qp], corr


def _record(obj, r, H, status, seconds, method: str, population, shared) -> dict:
    """The fields every fit's result has (``tensorid.FitResult``'s), of ψ."""
    x = np.asarray(r.x, dtype=float)
    m, p0 = obj.problem.model, obj.problem.p0
    given = {n: float(p0[m.params.index(n)]) for n in obj.problem.fixed}  # fixed values
    given |= {n: v["typical"] for n, v in population.items()}  # typical values, shared
    given |= {n: v["value"] for n, v in shared.items()}
    params = {n: given[n] for n in m.params if n in given}  # (individual: in .units)
    jac = np.asarray(r.jac, dtype=float)
    return dict(
        problem=obj.problem, method=method, theta=x, params=params,
        x0=np.asarray(obj.problem.x0, dtype=float), cost=float(r.fun), jac=jac, hess=H,
        grad_norm=float(np.max(np.abs(jac), initial=0.0)), status=status,
        message=status.describe(), seconds=seconds, scale=np.ones_like(x),
        history=list(getattr(r, "history", [])), stats=Stats(nit=r.nit, nfev=r.nfev),
        derivatives=bool(np.isfinite(H).all()),
    )  # fmt: skip


@dataclass(frozen=True, repr=False, kw_only=True)
class PopulationResult(AsFit, FitResult):
    """The outcome of :func:`tensorid.population.fit_population` (``tensorid.fit`` of a
    Problem with ``population``): a :class:`tensorid.FitResult` (its ``theta``, alias
    ``x``, is ψ, the unknowns in ``names``; ``cost`` is ``objective``; ``params`` the
    typical values and shared ones) with the population's own part.

    ``objective`` is −2 log L (Laplace/FOCEI, constants included); nlmixr2 and NONMEM
    print it less N log 2π (``objective_nlmixr``). ``population`` holds per random
    effect ``typical``, ``typical_stderr`` (same units), ``omega`` (SD of η),
    ``omega_stderr``, ``cv_percent`` (√(exp(ω²) − 1)) and ``shrinkage_percent``
    (1 − SD(η̂)/ω); ``shared`` the fleet's other parameters; ``residual_sd`` each
    output's additive σ (0 where its error is proportional alone); ``residual_error``
    each output's error model and estimates; ``units`` per unit its ``id``, ``params``
    (random effects' values and individual ones) and their ``stderr`` (conditional on
    the population estimates)."""

    names: list[str]
    objective: float
    cov: np.ndarray
    etas: np.ndarray
    population: dict
    shared: dict
    residual_sd: dict
    units: list
    observations: int
    # the objective it was fitted with (its compiled programs: predictions, figures)
    objective_function: Any = field(repr=False, default=None)
    # per output: its model ("additive", "proportional", "combined") and the estimates
    # "additive" (SD) and "proportional" (SD relative to the prediction), with stderrs
    residual_error: dict = field(default_factory=dict)
    # full Ω: {"cl,v": {"value": correlation of η_cl and η_v, "stderr": ...}}
    omega_correlation: dict = field(default_factory=dict)
    _table: dict | None = field(default=None, init=False, repr=False, compare=False)
    # a capability: ti.profile(res) hands the work to res.profile (profiles.py)
    profiles_itself: ClassVar[bool] = True

    def table(self) -> dict:
        """The per-observation table {column: array}: ID, TIME, OUTPUT, DV, PRED,
        IPRED, RES, IRES, IWRES, CWRES, NPDE (population/diagnostics.py), computed
        once."""
        if self._table is None:
            from .diagnostics import table

            object.__setattr__(self, "_table", table(self))  # (frozen: kept once)
        assert self._table is not None
        return self._table

    @property
    def objective_nlmixr(self) -> float:
        return self.objective - self.observations * float(np.log(2 * np.pi))

    @property
    def stderr(self) -> np.ndarray:
        return np.sqrt(np.diag(self.cov))

    @classmethod
    def build(cls, obj, r, etas, status, seconds, flat=None) -> PopulationResult:
        """The result at ``r``'s point; ``flat``: the directions of ψ the objective does
        not change in at all (held by the fit, without error bars)."""
        if obj.joint:
            return cls._joint(obj, r, etas, status, seconds, flat)
        qp, f, x = obj.qp, obj.first_shared, np.asarray(r.x, dtype=float)
        H = _measured(r, status)
        cov = _unmeasured(2.0 * _inverse(H), flat)  # O = −2 log L: the information is H / 2
        se = np.sqrt(np.where(np.diag(cov) < 0, np.inf, np.diag(cov)))  # NaN: not measured
        population = {}
        omega, omega_se, correlation = _omega(obj, x, cov, se)
        for k, n in enumerate(obj.pop[:qp]):
            typ, om = float(np.exp(x[k])), float(omega[k])
            sd = float(np.std(etas[:, k], ddof=1)) if len(etas) > 1 else float("nan")
            population[n] = {
                "typical": typ,
                "typical_stderr": typ * float(se[k]),
                "omega": om,
                "omega_stderr": float(omega_se[k]),
                "cv_percent": 100.0 * float(np.sqrt(np.expm1(om**2))),
                "shrinkage_percent": 100.0 * (1.0 - sd / om),
            }
        shared = {
            n: {"value": float(x[f + j]), "stderr": float(se[f + j])}
            for j, n in enumerate(obj.shared)
        }
        residual_error = _residual_error(obj, x, se)
        inner = obj.evaluation(x, etas)[3]  # ∇²ℓ_i(η̂): its inverse, unit i's η covariance
        units = []
        for i, uid in enumerate(obj.units.names):
            ci = _inverse(inner[i])
            vals, errs = {}, {}
            for k, n in enumerate(obj.pop):  # a random effect's value, or its own
                vals[n] = float(np.exp(x[k] + etas[i, k]) if k < qp else etas[i, k])
                errs[n] = (vals[n] if k < qp else 1.0) * float(np.sqrt(ci[k, k]))
            vals.update({n: v["value"] for n, v in shared.items()})
            errs.update({n: v["stderr"] for n, v in shared.items()})
            eta = {n: float(etas[i, k]) for k, n in enumerate(obj.pop[:qp])}
            units.append({"id": uid, "params": vals, "stderr": errs, "eta": eta})
        residual_sd = {o: v.get("additive", 0.0) for o, v in residual_error.items()}
        return cls(
            **_record(obj, r, H, status, seconds, obj.method, population, shared),
            names=list(obj.names), objective=float(r.fun), cov=cov, etas=np.asarray(etas),
            population=population, shared=shared, residual_sd=residual_sd,
            residual_error=residual_error, omega_correlation=correlation, units=units,
            observations=_observations(obj.units), objective_function=obj,
        )  # fmt: skip

    @classmethod
    def _joint(cls, obj, r, etas, status, seconds, flat=None) -> PopulationResult:
        """Individual parameters: least squares over the shared and every unit's own
        parameters. Covariance 2 s² H⁻¹ of the joint problem (s² = J / (N − K)), by
        blocks: the shared ones' from the Schur complement (the outer Hessian), each
        unit's s² (∇²_bb ℓ)⁻¹ + Z cov_s Zᵀ with Z = dη̂/dψ = −(∇²_bb ℓ)⁻¹ ∇²_bs ℓ."""
        x, H = np.asarray(r.x, dtype=float), _measured(r, status)
        u = obj.units
        N, K = int(u.mask.sum()), obj.ns + len(u.names) * obj.q
        s2 = float(r.fun) / (N - K) if N > K else float("nan")
        cov = _unmeasured(2.0 * s2 * _inverse(H), flat) if obj.ns else np.zeros((0, 0))
        se = np.sqrt(np.where(np.diag(cov) >= 0, np.diag(cov), np.nan))
        shared = {
            n: {"value": float(x[j]), "stderr": float(se[j])} for j, n in enumerate(obj.shared)
        }
        # (the model's own ŷ: −∞ where an output such as log c has no observation)
        resid = np.where(u.mask > 0, u.y - np.asarray(obj.predict_all(x, etas)), 0.0)
        n_out = np.maximum(u.mask.sum((0, 1)), 1)
        sd = np.sqrt((resid**2).sum((0, 1)) / n_out * (N / (N - K) if N > K else np.nan))
        Hb, L = obj.inner_blocks(x, etas)
        units = []
        for i, uid in enumerate(u.names):
            Hi = _inverse(Hb[i])
            Z = -Hi @ L[i]
            ci = s2 * Hi + Z @ np.where(np.isnan(cov), 0.0, cov) @ Z.T  # (a flat one: Z's 0)
            vals = {n: float(etas[i, k]) for k, n in enumerate(obj.pop)}
            errs = {
                n: float(np.sqrt(ci[k, k])) if ci[k, k] >= 0 else np.nan
                for k, n in enumerate(obj.pop)
            }
            vals.update({n: v["value"] for n, v in shared.items()})
            errs.update({n: v["stderr"] for n, v in shared.items()})
            units.append({"id": uid, "params": vals, "stderr": errs, "eta": {}})
        return cls(
            **_record(obj, r, H, status, seconds, "joint", {}, shared),
            names=list(obj.names), objective=float(r.fun), cov=cov, etas=np.asarray(etas),
            population={}, shared=shared,
            residual_sd=dict(zip(obj.problem.model.outputs, sd.tolist(), strict=True)),
            units=units, observations=N, objective_function=obj,
        )  # fmt: skip

    def blocks(self) -> list:
        """The summary as the one block (FitResult's are a single record's tables)."""
        return [self.summary()]

    def summary(self) -> str:
        """The population table, the shared parameters and the residual SD."""
        if self.method == "joint":
            return self._joint_summary()
        lines = [
            f"Population fit ({self.method.upper()}), {len(self.units)} units, "
            f"{self.observations} observations: {self.message}",
            f"  -2 log L = {self.objective:.4f} (nlmixr2's OBJF convention, less N log 2π: "
            f"{self.objective_nlmixr:.4f}); {self.nit} iterations, {self.seconds:.1f} s",
            f"  {'parameter':<12}{'typical':>12}{'SE':>11}{'omega':>9}{'SE':>9}"
            f"{'CV %':>8}{'shrink %':>10}",
        ]
        for n, v in self.population.items():
            lines.append(
                f"  {n:<12}{v['typical']:>12.5g}{v['typical_stderr']:>11.3g}{v['omega']:>9.4f}"
                f"{v['omega_stderr']:>9.3g}{v['cv_percent']:>8.1f}{v['shrinkage_percent']:>10.1f}"
            )
        for n, v in self.shared.items():
            lines.append(f"  {n:<12}{v['value']:>12.5g}{v['stderr']:>11.3g}   (shared)")
        lines += self._own_lines()
        for pair, c in self.omega_correlation.items():
            a, b = pair.split(",")
            r, se = c["value"], c["stderr"]
            lines.append(f"  correlation of η_{a} and η_{b}: {r:.4f} (SE {se:.3g})")
        for o, e in self.residual_error.items():
            if e["model"] == "additive":
                lines.append(f"  residual SD of {o}: {e['additive']:.5g}")
                continue
            parts = [
                f"{what} {e[what]:.5g} (SE {e[what + '_stderr']:.3g})"
                for what in ERROR_MODELS[e["model"]].terms
            ]
            lines.append(f"  residual error of {o} ({e['model']}): {', '.join(parts)}")
        lines += self._starts_lines()
        return "\n".join(lines + [f"  note: {n}" for n in self.notes])

    def _starts_lines(self) -> list[str]:
        if not self.starts:
            return []
        J = np.array([s["objective"] for s in self.starts], dtype=float)
        near = int(np.sum(np.abs(J - J.min()) <= 0.01))
        return [f"  best of {len(J)} starts: -2 log L from {J.min():.4f} to {J.max():.4f}; "
                f"{near} within 0.01 of the best"]  # fmt: skip

    def _own_lines(self) -> list[str]:
        """The individual parameters' spread over the units (each unit's in .units)."""
        if not self.units:
            return []
        own = [n for n in self.units[0]["params"] if n not in self.shared]
        lines = []
        for n in (k for k in own if k not in self.population):
            vals = np.array([u["params"][n] for u in self.units])
            lines.append(
                f"  {n:<12} per unit: median {np.median(vals):.5g}, range "
                f"{vals.min():.5g} to {vals.max():.5g} (each unit's in .units)"
            )
        return lines

    def _joint_summary(self) -> str:
        own = [n for n in self.units[0]["params"] if n not in self.shared] if self.units else []
        lines = [
            f"Fleet fit (individual {', '.join(own)}), {len(self.units)} units, "
            f"{self.observations} observations: {self.message}",
            f"  cost {self.objective:.6g}; {self.nit} iterations, {self.seconds:.1f} s",
        ]
        for n, v in self.shared.items():
            lines.append(f"  {n:<12}{v['value']:>12.5g} ± {v['stderr']:.3g}   (shared)")
        lines += self._own_lines()
        for o, s in self.residual_sd.items():
            lines.append(f"  residual SD of {o}: {s:.5g}")
        return "\n".join(lines + [f"  note: {n}" for n in self.notes])

    def __str__(self) -> str:
        return self.summary()

    def __repr__(self) -> str:  # (the dataclass's printed every unit's arrays)
        typical = {n: round(v["typical"], 6) for n, v in self.population.items()}
        return (
            f"PopulationResult(method={self.method!r}, status={self.status.name}, "
            f"objective={self.objective:.6g}, units={len(self.units)}, typical={typical})"
        )

    def _repr_html_(self) -> str:
        import html

        return f"<pre>{html.escape(self.summary())}</pre>"

    def criteria(self) -> dict:
        """AIC and BIC of −2 log L, with n (observations) and k (every estimated
        entry of ψ: typical values, ω, shared parameters, residual error), and the
        objective in both conventions: for comparing models of one data set."""
        k, n = len(self.names), self.observations
        return {"objective": self.objective, "objective_nlmixr": self.objective_nlmixr,
                "aic": self.objective + 2 * k, "bic": self.objective + np.log(max(n, 1)) * k,
                "n": n, "k": k}  # fmt: skip

    @property
    def correlation(self) -> np.ndarray:
        """The estimates' correlation matrix, in ψ's order (``names``); NaN where an
        error bar was not measured."""
        se = np.sqrt(np.abs(np.diag(self.cov)))
        with np.errstate(invalid="ignore", divide="ignore"):
            return self.cov / np.outer(se, se)

    def gof(self) -> list:
        """Goodness of fit of each unit's own predictions (IPRED) on its observations:
        a float per unit, or an (S,) array for S outputs, as ``FitResult.gof``."""
        from ..engine.modelling.metrics import gof

        obj = self.objective_function
        own = np.asarray(obj.predict_all(self.x, self.etas))
        u, out = obj.units, []
        for i in range(len(u.names)):
            seen = u.mask[i] > 0
            v = np.array([gof(u.y[i, seen[:, g], g], own[i, seen[:, g], g])
                          for g in range(own.shape[-1])])  # fmt: skip
            out.append(float(v[0]) if v.size == 1 else v)
        return out

    def profile(self, names=None, level: float = 0.95, **options) -> dict:
        """Profile likelihood of typical values, ω and shared parameters (each named,
        or all) with their likelihood-ratio intervals: population/profiles.py."""
        from .profiles import profile

        return profile(self, names, level, **options)

    def validate(self, problem) -> list[dict]:  # type: ignore[override]  # (new units: a Problem)
        """Held-out units (a Problem over them, built as the fitted one): each one's η̂
        by empirical Bayes and its IPRED and PRED scores: population/validation.py."""
        from .validation import held_out

        return held_out(self, problem)

    def unit_influence(self, refits: int = 5) -> list[dict]:
        """Which unit moves the estimates most if left out: population/influence.py."""
        from .influence import unit_influence

        return unit_influence(self, refits)

    def plot(self, path=None) -> list:  # type: ignore[override]  # (no validation records)
        """The fit's figures: every unit's data and fits, observed against predicted,
        and (random effects) the visual predictive check and the residuals. With
        ``path`` (a folder) written there as PNG files and their paths returned;
        without, the matplotlib figures returned."""
        from pathlib import Path

        from ..analysis.figures import save_png
        from . import figures as f

        figs = [(stem, f.figure(self, kind)) for stem, kind, _ in f.figure_jobs(self)]
        if path is None:
            return [fig for _, fig in figs]
        Path(path).mkdir(parents=True, exist_ok=True)
        return [save_png(fig, Path(path) / f"{stem}.png") for stem, fig in figs]


def _observations(units) -> int:
    """The samples measured, those below their limit (censored) included."""
    return int(units.mask.sum()) + (0 if units.cens is None else int(units.cens.sum()))
