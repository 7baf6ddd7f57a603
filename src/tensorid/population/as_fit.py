"""A population fit's result in a single fit's vocabulary (``tensorid.FitResult``):
each of its names with the population meaning, or one line saying what to use
instead, so that code written for a fit reads a fleet's without a traceback from deep
inside (tests/test_population.py walks every public name of FitResult).

The error bars are of ψ, the unknowns in ``res.names`` (log typical values, log ω,
shared values, log residual-error terms): "hessian" is 2 H⁻¹ with H the exact Hessian
of −2 log L (NONMEM's R⁻¹ form), "robust" the sandwich H⁻¹ (Σ_i g_i g_iᵀ) H⁻¹ over the
units' gradients g_i of their share of −2 log L (NONMEM's default R⁻¹SR⁻¹), which
holds where the random effects or the residual error are not as the model says.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from ..analysis.uncertainty import Uncertainty

if TYPE_CHECKING:  # what the mixin reads is FitResult's (it precedes it in the bases)
    from ..analysis.results import FitResult as _Base
else:
    _Base = object


@dataclass(repr=False)
class PopulationUncertainty(Uncertainty):
    """:class:`tensorid.analysis.uncertainty.Uncertainty` of ψ, said as a population
    fit's (no residual variance: −2 log L carries its own); ``joint``: a fit of
    individual parameters alone (least squares, 2 s² H⁻¹)."""

    joint: bool = False

    def blocks(self) -> list:
        out = super().blocks()
        cost = "the least-squares cost, 2 s² H⁻¹" if self.joint else "−2 log L, R⁻¹"
        how = {"hessian": f"exact Hessian of {cost}",
               "robust": "sandwich H⁻¹ (Σ g_i g_iᵀ) H⁻¹ over the units"}[self.kind]  # fmt: skip
        head = self.not_available or f"standard errors of ψ ({how}), {self.dof} units"
        return [head, *out[1:]]


class AsFit(_Base):
    """FitResult's methods with their population meaning, for :class:`PopulationResult`
    (a mixin before FitResult in its bases: it reads the result's own fields)."""

    if TYPE_CHECKING:  # (PopulationResult's fields; not fields of this class)
        names: list[str]
        objective: float
        cov: np.ndarray
        etas: np.ndarray
        units: list
        objective_function: Any

        def unit_influence(self, refits: int = 5) -> list[dict]: ...

    @property
    def covariance(self) -> np.ndarray:
        """Covariance of ψ: 2 H⁻¹ (``cov``; NaN where a direction is not measured)."""
        return self.cov

    @property
    def warnings(self) -> list[str]:
        """How the fit ended, where it did not converge, and its notes."""
        return self.convergence_warnings if not self.success else list(self.notes)

    def prior_moves(self) -> list[dict]:
        return []  # a fleet's fit takes no priors

    def uncertainty(self, kind: str = "hessian") -> PopulationUncertainty:
        """Standard errors, 95 % intervals (on ψ's scale: log for typical values and ω)
        and correlations of ψ; ``kind`` "hessian" (2 H⁻¹, as ``cov``) or "robust"
        (the sandwich over the units, NONMEM's default; see the module docstring)."""
        if kind not in ("hessian", "robust"):
            raise ValueError(
                f"kind={kind!r}: a population fit's error bars are 'hessian' (R⁻¹) or "
                "'robust' (R⁻¹SR⁻¹); −2 log L has no Gauss-Newton form"
            )
        if not self.has_uncertainty:
            raise ValueError(
                f"no error bars for a fit that ended as {self.status}: its Hessian was not "
                "measured; fit again from its estimate to get them"
            )
        cov = self.cov if kind == "hessian" else self._sandwich()
        d = np.diag(cov)
        se = np.sqrt(np.where(d < 0, np.inf, d))
        with np.errstate(invalid="ignore", divide="ignore"):
            corr = cov / np.outer(se, se)
        x, names = np.asarray(self.x, float), list(self.names)
        return PopulationUncertainty(
            names=names, theta=x, covariance=cov, stderr=se,
            ci95=np.column_stack([x - 1.959963984540054 * se, x + 1.959963984540054 * se]),
            correlation=corr, sigma2=1.0, dof=len(self.units), kind=kind,
            warnings=list(self.notes), forms=[kind] * len(names),
            lags=0 if kind == "robust" else None,  # (the units: independent)
            joint=self.method == "joint",
        )  # fmt: skip

    def _sandwich(self) -> np.ndarray:
        """H⁻¹ (Σ_i g_i g_iᵀ) H⁻¹ at the estimate, g_i unit i's gradient of its share of
        the objective and H its exact Hessian, over the directions measured (NaN on
        those held: no error bar there, and none spread to the others)."""
        g = self.objective_function.evaluation(np.asarray(self.x), np.asarray(self.etas))[1]
        H = np.asarray(self.hess, dtype=float)
        seen = np.isfinite(np.diag(self.cov))
        out = np.full_like(H, np.nan)
        if seen.any():
            Hi = np.linalg.inv(H[np.ix_(seen, seen)])
            gs = np.asarray(g)[:, seen]
            out[np.ix_(seen, seen)] = Hi @ (gs.T @ gs) @ Hi
        return out

    def data_sensitivity(self) -> list[dict]:
        """For a fleet, which unit moves the estimates: ``unit_influence()`` (a Newton
        step per unit, the five ranked first refitted without their data)."""
        return self.unit_influence()

    def residual_tests(self, *args, **kwargs):
        raise ValueError(
            "residual_tests() tests one record's residuals for whiteness; a population "
            "fit's residuals are read as CWRES and NPDE: res.table(), res.plot()"
        )

    def model_check(self, *args, **kwargs):
        raise ValueError(
            "model_check() splits one record in parts; for a fleet, res.validate(held-out "
            "units) and res.unit_influence() say whether the population holds"
        )

    def information(self):
        raise ValueError(
            "information() compares the exact and Gauss-Newton Hessians of a least-squares "
            "cost; for −2 log L use res.uncertainty('hessian') and res.uncertainty('robust')"
        )

    def simulate(self):
        raise ValueError(
            "simulate(): a fleet's units each have their own values; res.table() holds "
            "every unit's IPRED and PRED at its samples, res.plot() draws them through "
            "dense times, and tensorid simulate --ipred one unit"
        )
