"""FitResult: what a fit found and how it ended, in scipy.optimize.OptimizeResult's
vocabulary, with a ``Status`` for every ending.

Results know nothing of reports: the application layer reads them. They write files
only when asked (``plot(folder)``).
"""

from __future__ import annotations

from dataclasses import dataclass, fields, replace

import numpy as np

from ..solve.constrained import ConstraintOutcome
from ..solve.solution import FitInterrupted, Solution
from ..solve.stats import Stats
from .constraint_report import ConstraintReport
from .prior_effects import NoiseCheck, move_lines, prior_moves
from .summary import Tabular, collapsed_noise
from .uncertainty import Information, Uncertainty, information, uncertainty

__all__ = ["FitInterrupted", "FitResult", "NoiseCheck", "Stats"]


@dataclass(frozen=True, repr=False)
class FitResult(Solution, Tabular):
    """Outcome of :func:`fit`, with scipy.optimize.OptimizeResult's names where they fit.
    ``print(res)`` shows :meth:`summary`; a notebook shows the same as HTML tables.

    theta : (K,) estimate in natural units, θ layout of ``problem`` (alias ``x``).
    params : {name: value} for every parameter (fixed ones included).
    x0 : (N,) initial state, or (E, N) for several experiments.
    cost : J at theta (alias ``fun``); jac (K,) and hess (K, K) are the exact
        gradient and Hessian there, whatever the method (``derivatives`` is False
        where they were not computed: an interrupted fit, lost workers).
    grad_norm : ∞-norm of the projected gradient with respect to θ / scale, in cost
        units (components pushing against an active bound are dropped).
    status : how the fit ended (a :class:`tensorid.Status`); ``success`` and the
        start of ``message`` derive from it.
    stats : the counters (:class:`Stats`), also read as attributes:
    nit, nfev : iterations and cost evaluations (finite-difference ones included).
        With several starts, ``nit`` counts the best start's own iterations (and its
        refinement's) and ``nfev`` every start's evaluations; ``nit_total`` counts
        every start's iterations and ``nfev_best`` the best start's evaluations.
    nhev : Hessian-vector products (method "newton-cg").
    seconds : wall time of the fit, compilation included; ``compile_seconds`` is the
        part JAX spent compiling in this process (0 when every sweep was compiled
        already: Problems with the same model, θ layout and discretisation share them).
    history : one dict per iteration: iteration, cost, grad_norm, radius, ...
    notes : what happened on the way, e.g. trial points where the simulation blew up.
    noise_check : with priors, the noise variance that weighed them against the
        residual variance at the optimum, and the refits that re-estimated it (see
        :mod:`tensorid.fitting.priors`; a :class:`tensorid.analysis.prior_effects.NoiseCheck`);
        ``problem`` is then the Problem as last fitted.
    shooting : for a multiple-shooting problem, its stage: segments (per experiment),
        nit, outer (augmented-Lagrangian iterations), nfev, cost (of the segments,
        defects aside), max_defect (largest continuity defect relative to the state
        scale), defect_tol, status, seconds, polished (and polish_nit). None for
        single shooting.
    constraints : with ``Problem(constraints=...)``, each constraint's value at theta,
        whether it binds, and its Lagrange multiplier (see
        :class:`tensorid.analysis.constraint_report.ConstraintReport`); None without.

    A result is immutable: the solver's record (``tensorid.solve.solution.Solution``)
    is built once, where its run ends (``solve/endings.py``), and made a FitResult by
    :meth:`of` once the solver has returned; a later stage (a refit, a polish, the
    best of many starts) makes a new one with ``dataclasses.replace``. Its fields and
    the methods that need no statistics (``x``, ``fun``, ``nit``, ``simulate``, ``gof``,
    ...) are the record's; the statistics' methods below delegate to
    :mod:`tensorid.analysis`.
    """

    @classmethod
    def of(cls, solution: Solution) -> FitResult:
        """The FitResult of a solver's record (itself if it is one already)."""
        if isinstance(solution, cls):
            return solution
        res = cls(**{f.name: getattr(solution, f.name) for f in fields(solution)})
        if isinstance(res.constraints, ConstraintOutcome):  # its statistics, once
            return replace(res, constraints=ConstraintReport.of(res))
        return res

    def uncertainty(self, kind: str = "hessian") -> Uncertainty:
        """Standard errors, 95 % intervals, correlations (see tensorid.analysis.uncertainty);
        ``kind`` "hessian" uses the exact Hessian, "gauss-newton" its first-order form,
        "robust" the sandwich H⁻¹ B H⁻¹ with the scores' Newey-West covariance B
        (honest when the residuals are coloured; see tensorid.analysis.sandwich; for a
        filter, the scores of −2 log L, for innovations that are not white). With
        a robust loss every kind is a sandwich (the 2σ² H⁻¹ form assumes the squared
        loss), with independent samples for "hessian" and "gauss-newton"."""
        if kind not in ("hessian", "gauss-newton", "robust"):
            raise ValueError("kind must be 'hessian', 'gauss-newton' or 'robust'")
        if not self.has_uncertainty:
            raise ValueError(
                f"no error bars for a fit that ended as {self.status}: its derivatives "
                "were not computed; fit again from result.theta to get them"
            )
        # keyed on what it depends on, so a result changed by hand is not served stale
        key = (kind, self.cost, self.theta.tobytes(), self.hess.tobytes())
        if key not in self._uncertainty:
            self._uncertainty[key] = self._compute_uncertainty(kind)
        return self._uncertainty[key]

    def _compute_uncertainty(self, kind: str) -> Uncertainty:
        problem, theta = self.problem, self.theta

        def gauss_newton():
            return problem.cost_grad_gn(theta)[2]

        meat, lags = None, None
        bread, why = None, None
        if kind == "robust" or problem.loss.robust:
            from .sandwich import score_covariance, unresolved_scale

            meat, lags = score_covariance(problem, theta, "auto" if kind == "robust" else 0)
            bread, why = unresolved_scale(problem, theta)
        H = gauss_newton() if kind == "gauss-newton" else self.hess
        H = H if bread is None else bread
        u = uncertainty(
            problem,
            theta,
            self.cost,
            H,
            "hessian" if kind == "robust" else kind,
            gauss_newton=gauss_newton,
            grad=self.jac,
            scale=self.scale,
            meat=meat,
            refused=why if bread is None else None,
        )
        if bread is not None and why:
            u.warnings.insert(0, why)
        u.kind, u.lags = kind, lags
        return u

    @property
    def covariance(self) -> np.ndarray:
        """Covariance of theta from the exact Hessian, scaled by the residual variance."""
        return self.uncertainty().covariance

    @property
    def warnings(self) -> list[str]:
        """Plain-language warnings: no convergence (with why, e.g. where the simulation
        blew up), unknowns the data cannot separate, an optimum that is not a strict
        minimum, a noise level for the priors that the residuals contradict, a prior
        that moved an estimate by more than two standard errors of the data alone."""
        out = self.convergence_warnings
        if self.has_uncertainty:
            out += self.uncertainty().warnings
        noise = self.noise_check.message() if self.noise_check is not None else None
        out += ([noise] if noise else []) + collapsed_noise(self)
        out += self.constraints.warnings() if self.constraints is not None else []
        return out + move_lines(self.prior_moves())

    def prior_moves(self) -> list[dict]:
        """How far the priors moved the estimates, in standard errors of the data alone
        (see :func:`tensorid.analysis.prior_effects.prior_moves`); empty without priors."""
        key = ("prior moves", self.cost, self.theta.tobytes(), self.hess.tobytes())
        if key not in self._uncertainty:
            self._uncertainty[key] = prior_moves(self)
        return self._uncertainty[key]

    def validate(self, data, init_window: int | None = None, horizon: int | None = None) -> list:
        """Score the fitted model on new records (an Experiment or a list of them), as
        MATLAB's compare does: initial states that were free in the fit are
        estimated on each record with the parameters held, on its first
        ``init_window`` samples only when given (the benchmarks' protocol; without it,
        a record's own ``init_window``, as ``Experiment.from_benchmark`` sets it), and
        the model is scored on the samples after them. Returns a list of
        :class:`tensorid.analysis.validation.Score`. With ``horizon`` k, each record is
        scored as k-step-ahead prediction instead (MATLAB's compare with a prediction
        horizon): a filter's (predictor="ekf") state after sample h − k, run k samples
        ahead by the model; for output error, the simulation at every horizon."""
        from .validation import validate

        return validate(self, data, init_window, horizon)

    def information(self) -> Information:
        """Observed (exact Hessian) against expected (Gauss-Newton) information: the
        standard errors from each side by side, their condition numbers and the least
        determined direction (see :class:`tensorid.analysis.uncertainty.Information`)."""
        key = ("information", self.cost, self.theta.tobytes(), self.hess.tobytes())
        if key not in self._uncertainty:
            H_gn = self.problem.cost_grad_gn(self.theta)[2]
            observed, expected = self.uncertainty(), self.uncertainty("gauss-newton")
            self._uncertainty[key] = information(observed, expected, self.hess, H_gn)
        return self._uncertainty[key]

    def residual_tests(self, max_lag: int | None = None, level: float = 0.99):
        """Whiteness of the residuals and their independence from the inputs, as
        MATLAB's ``resid`` (see :mod:`tensorid.analysis.residuals`), on the samples
        the likelihood uses; a verdict the series cannot carry is "cannot be trusted".
        ``max_lag`` None: MATLAB's 25, fewer on a short record (as the command line)."""
        from .residuals import default_lags, residual_tests

        max_lag = default_lags(self.problem) if max_lag is None else max_lag
        key = ("residual tests", max_lag, level, self.cost, self.theta.tobytes())
        if key not in self._uncertainty:
            self._uncertainty[key] = residual_tests(self, max_lag, level)
        return self._uncertainty[key]

    def model_check(self, level: float = 0.99, **options):
        """Whether the estimates from separate parts of the record (its halves, or the
        given records) agree within their robust error bars: where they do not, no
        error bar covers the model's error (see :mod:`tensorid.analysis.model_check`).
        Fits each part from this estimate; kept, so that the summary shows it."""
        from .model_check import model_check

        key = ("model check", self.cost, self.theta.tobytes())
        if key not in self._uncertainty or self._uncertainty[key].level != level or options:
            self._uncertainty[key] = model_check(self, level, **options)
        return self._uncertainty[key]

    def cached_model_check(self):
        """The model-error check if :meth:`model_check` was made at this estimate, else None."""
        return self._uncertainty.get(("model check", self.cost, self.theta.tobytes()))

    def criteria(self) -> dict:
        """AIC, AICc and BIC (Gaussian residuals of unknown variance), with n and K:
        for comparing model structures fitted to the same data."""
        from .residuals import information_criteria

        return information_criteria(self)

    def data_sensitivity(self):
        """dθ̂/dy for every measured sample: which samples drive each estimate (see
        :class:`tensorid.analysis.influence.DataSensitivity`)."""
        from .influence import data_sensitivity

        return data_sensitivity(self)

    def profile(self, names=None, level: float = 0.95, **options) -> dict:
        """Profile likelihood of each unknown in ``names`` (default: every free
        parameter) with its likelihood-ratio interval: see :func:`tensorid.profile`."""
        from .profiles import profile

        return profile(self, names, level, **options)

    def summary(self) -> str:
        """A plain-text table of the estimates with standard errors and intervals, the
        residual tests' verdicts and, where the residuals are not shown white, the
        robust standard errors beside the white ones and which to trust."""
        from .display import summary_table

        return summary_table(self)

    def blocks(self) -> list:
        """The summary's content (headline, estimates, information, criteria, residual
        verdicts, warnings) as text and tables, for ``str()`` and ``_repr_html_``."""
        from .display import fit_blocks

        return fit_blocks(self)

    def plot(self, path=None, validation=None):
        """Measured against simulated outputs with residuals, and the convergence
        history. With ``path`` (a folder) the figures are written there as PNG files
        and their paths returned; without, the matplotlib figures are returned and
        nothing is written. ``validation``: scores from :meth:`validate`."""
        from .figures import fit_figures

        return fit_figures(self, path, validation)
