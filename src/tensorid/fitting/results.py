"""FitResult: what a fit found and how it ended, in scipy.optimize.OptimizeResult's
vocabulary, with a ``Status`` for every ending.

Results know nothing of reports: the application layer reads them. They write files
only when asked (``plot(folder)``).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field, replace

import numpy as np

from ..engine.metrics import gof
from ..engine.problem import Problem
from ..engine.status import Status
from .priors import NoiseCheck, move_lines, prior_moves
from ..solve.stats import Stats
from ..analysis.summary import Tabular, collapsed_noise
from ..analysis.uncertainty import Information, Uncertainty, information, uncertainty


def _squeeze(a: np.ndarray) -> np.ndarray:
    return a[:, 0] if a.ndim == 2 and a.shape[1] == 1 else a


@dataclass(frozen=True)
class FitResult(Tabular):
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
        :mod:`tensorid.fitting.priors`); ``problem`` is then the Problem as last fitted.
    shooting : for a multiple-shooting problem, its stage: segments (per experiment),
        nit, outer (augmented-Lagrangian iterations), nfev, cost (of the segments,
        defects aside), max_defect (largest continuity defect relative to the state
        scale), defect_tol, status, seconds, polished (and polish_nit). None for
        single shooting.

    A result is immutable: it is built once, where its run ends (``fitting/endings.py``);
    a later stage (a refit, a polish, the best of many starts) makes a new one with
    ``dataclasses.replace``.
    """

    problem: Problem  # None only on its way back from a worker (see detached)
    method: str
    theta: np.ndarray
    params: dict[str, float]
    x0: np.ndarray
    cost: float
    jac: np.ndarray
    hess: np.ndarray
    grad_norm: float
    status: Status
    message: str
    seconds: float
    scale: np.ndarray
    history: list[dict] = field(default_factory=list)
    starts: list[dict] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)
    stats: Stats = field(default_factory=Stats)
    compile_seconds: float = 0.0
    derivatives: bool = True  # jac and hess hold the exact derivatives at theta
    shooting: dict | None = None  # multiple shooting: segments, defects, its own counts
    hybrid: dict | None = None  # method "auto": evaluations of each kind, mode switches
    noise_check: NoiseCheck | None = None  # priors: their noise variance against the residuals
    # the summary, the warnings, fit.json and report.md all read the same uncertainty;
    # keyed on what it depends on, so a result made by replace shares it (but not
    # across Problems: detached and attached start afresh)
    _uncertainty: dict = field(default_factory=dict, repr=False, compare=False)

    @classmethod
    def at(
        cls,
        problem: Problem,
        method: str,
        theta: np.ndarray,
        scale: np.ndarray,
        status: Status,
        *,
        message: str | None = None,
        stats: Stats | None = None,
        started: float | None = None,
        history: list | None = None,
        evaluate: bool = True,
        cost: float = np.inf,
        known: tuple | None = None,
        **more,
    ) -> FitResult:
        """The result at θ, with the exact gradient and Hessian there. A point whose
        simulation is not finite gets cost inf and zero derivatives, never NaN.
        Without ``evaluate`` nothing is computed (an interrupted fit must end at
        once): the result holds the ``cost`` already known and no derivatives.
        ``known`` = (θ, J, g, H) spares the evaluation when it was at this θ;
        ``stats`` defaults to one evaluation; ``more``: the other fields (notes,
        hybrid, shooting, starts)."""
        K = theta.size
        if evaluate and known is not None and np.array_equal(known[0], theta):
            J, g, H = known[1:]
        else:
            J, g, H = problem.cost_grad_hess(theta) if evaluate else (cost, None, None)
        if np.isfinite(J) and g is not None and H is not None:
            phi = theta / scale
            pg = np.clip(phi - g * scale, problem.lower / scale, problem.upper / scale) - phi
            grad_norm = float(np.linalg.norm(pg, np.inf))
        else:
            J = J if not evaluate and np.isfinite(J) else np.inf
            g, H, grad_norm = np.zeros(K), np.zeros((K, K)), np.inf
        p, x0 = problem.unpack(theta)
        return cls(
            problem=problem,
            method=method,
            theta=theta,
            params=dict(zip(problem.model.params, map(float, p), strict=True)),
            x0=x0[0] if len(problem.experiments) == 1 else x0,
            cost=float(J),
            jac=g,
            hess=H,
            grad_norm=grad_norm,
            status=status,
            message=status.message if message is None else message,
            seconds=0.0 if started is None else time.perf_counter() - started,
            scale=scale,
            history=history or [],
            stats=Stats(nfev=1) if stats is None else stats,
            derivatives=evaluate,
            **more,
        )

    def detached(self) -> FitResult:
        """This result without its Problem, to travel back from a worker process (a
        Problem holds compiled code); :meth:`attached` gives it one again."""
        return replace(self, problem=None, _uncertainty={})  # type: ignore[arg-type]

    def attached(self, problem: Problem) -> FitResult:
        return replace(self, problem=problem, _uncertainty={})

    def history_then(self, more: list[dict]) -> list[dict]:
        """This history followed by ``more`` (a run from this end point), whose
        iterations are numbered on from its last (or from ``nit`` without one);
        ``more``'s iteration 0, this end point again, is left out where it is here."""
        own = self.history
        offset = own[-1]["iteration"] if own else self.nit
        return own + [dict(h, iteration=h["iteration"] + offset) for h in more
                      if h["iteration"] or not own]  # fmt: skip

    # the counters, read-only (public names since the first release)
    nit = property(lambda self: self.stats.nit, doc="Iterations (``stats['nit']``).")
    nfev = property(lambda self: self.stats.nfev, doc="Cost evaluations (``stats['nfev']``).")
    nhev = property(lambda self: self.stats.nhev, doc="Hessian-vector products.")
    nit_total = property(lambda self: self.stats.nit_total, doc="Every start's iterations.")
    nfev_best = property(lambda self: self.stats.nfev_best, doc="The best start's evaluations.")

    @property
    def has_uncertainty(self) -> bool:
        """Whether error bars can be given: a finite cost with the exact derivatives
        there (an interrupted fit keeps its best point but not its derivatives)."""
        return bool(np.isfinite(self.cost)) and self.derivatives

    @property
    def success(self) -> bool:
        """Whether the fit converged (``status.success``)."""
        return self.status.success

    @property
    def x(self) -> np.ndarray:
        """Alias of theta (scipy.optimize.OptimizeResult's name)."""
        return self.theta

    @property
    def fun(self) -> float:
        """Alias of cost (scipy.optimize.OptimizeResult's name)."""
        return self.cost

    def simulate(self):
        """Simulations of every experiment at the estimate."""
        return self.problem.simulate(self.theta)

    def gof(self) -> list:
        """Goodness of fit per experiment (per output for several outputs): a list with
        a float per experiment, or an (S,) array for S outputs, in the order of
        ``problem.experiments``. (``validate()`` instead returns Scores, whose ``gof``
        is a dict keyed by output; ``training_scores`` in
        :mod:`tensorid.fitting.validation` gives the training records that way.)"""
        sims = self.simulate()
        return [
            gof(_squeeze(e.measured), _squeeze(s.y))
            for e, s in zip(self.problem.experiments, sims, strict=True)
        ]

    def uncertainty(self, kind: str = "hessian") -> Uncertainty:
        """Standard errors, 95 % intervals, correlations (see tensorid.fitting.uncertainty);
        ``kind`` "hessian" uses the exact Hessian, "gauss-newton" its first-order form,
        "robust" the sandwich H⁻¹ B H⁻¹ with the scores' Newey-West covariance B
        (honest when the residuals are coloured; see tensorid.fitting.sandwich; for a
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
            from ..analysis.sandwich import score_covariance, unresolved_scale

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
        return out + move_lines(self.prior_moves())

    def prior_moves(self) -> list[dict]:
        """How far the priors moved the estimates, in standard errors of the data alone
        (see :func:`tensorid.fitting.priors.prior_moves`); empty without priors."""
        key = ("prior moves", self.cost, self.theta.tobytes(), self.hess.tobytes())
        if key not in self._uncertainty:
            self._uncertainty[key] = prior_moves(self)
        return self._uncertainty[key]

    @property
    def convergence_warnings(self) -> list[str]:
        """The warnings that need no statistics: how the fit ended, if not converged, and
        a multiple-shooting stage that left defects before a polish that converged."""
        out = [] if self.success else [f"the fit did not converge: {self.message}", *self.notes]
        sh = self.shooting or {}
        if self.success and sh.get("status") == str(Status.DEFECTS_REMAIN):
            out.append(
                f"the multiple-shooting stage ended with a continuity defect of "
                f"{sh['max_defect']:.1e} (tolerance {sh['defect_tol']:.0e}), so the single-"
                "shooting polish started from a discontinuous trajectory; it converged, but "
                "compare with a fit of fewer segments or more iterations"
            )
        return out

    def validate(self, data, init_window: int | None = None, horizon: int | None = None) -> list:
        """Score the fitted model on new records (an Experiment or a list of them), as
        MATLAB's compare does: initial states that were free in the fit are
        estimated on each record with the parameters held, on its first
        ``init_window`` samples only when given (the benchmarks' protocol; without it,
        a record's own ``init_window``, as ``Experiment.from_benchmark`` sets it), and
        the model is scored on the samples after them. Returns a list of
        :class:`tensorid.fitting.validation.Score`. With ``horizon`` k, each record is
        scored as k-step-ahead prediction instead (MATLAB's compare with a prediction
        horizon): a filter's (predictor="ekf") state after sample h − k, run k samples
        ahead by the model; for output error, the simulation at every horizon."""
        from ..analysis.validation import validate

        return validate(self, data, init_window, horizon)

    def information(self) -> Information:
        """Observed (exact Hessian) against expected (Gauss-Newton) information: the
        standard errors from each side by side, their condition numbers and the least
        determined direction (see :class:`tensorid.fitting.uncertainty.Information`)."""
        key = ("information", self.cost, self.theta.tobytes(), self.hess.tobytes())
        if key not in self._uncertainty:
            H_gn = self.problem.cost_grad_gn(self.theta)[2]
            observed, expected = self.uncertainty(), self.uncertainty("gauss-newton")
            self._uncertainty[key] = information(observed, expected, self.hess, H_gn)
        return self._uncertainty[key]

    def residual_tests(self, max_lag: int = 25, level: float = 0.99):
        """Whiteness of the residuals and their independence from the inputs, as
        MATLAB's ``resid`` (see :mod:`tensorid.fitting.residuals`), on the samples
        the likelihood uses; a verdict the series cannot carry is "cannot be trusted"."""
        from ..analysis.residuals import residual_tests

        key = ("residual tests", max_lag, level, self.cost, self.theta.tobytes())
        if key not in self._uncertainty:
            self._uncertainty[key] = residual_tests(self, max_lag, level)
        return self._uncertainty[key]

    def model_check(self, level: float = 0.99, **options):
        """Whether the estimates from separate parts of the record (its halves, or the
        given records) agree within their robust error bars: where they do not, no
        error bar covers the model's error (see :mod:`tensorid.fitting.model_check`).
        Fits each part from this estimate; kept, so that the summary shows it."""
        from ..analysis.model_check import model_check

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
        from ..analysis.residuals import information_criteria

        return information_criteria(self)

    def data_sensitivity(self):
        """dθ̂/dy for every measured sample: which samples drive each estimate (see
        :class:`tensorid.fitting.influence.DataSensitivity`)."""
        from ..analysis.influence import data_sensitivity

        return data_sensitivity(self)

    def profile(self, names=None, level: float = 0.95, **options) -> dict:
        """Profile likelihood of each unknown in ``names`` (default: every free
        parameter) with its likelihood-ratio interval: see :func:`tensorid.profile`."""
        from ..analysis.profiles import profile

        return profile(self, names, level, **options)

    def summary(self) -> str:
        """A plain-text table of the estimates with standard errors and intervals, the
        residual tests' verdicts and, where the residuals are not shown white, the
        robust standard errors beside the white ones and which to trust."""
        from ..analysis.display import summary_table

        return summary_table(self)

    def blocks(self) -> list:
        """The summary's content (headline, estimates, information, criteria, residual
        verdicts, warnings) as text and tables, for ``str()`` and ``_repr_html_``."""
        from ..analysis.display import fit_blocks

        return fit_blocks(self)

    def plot(self, path=None, validation=None):
        """Measured against simulated outputs with residuals, and the convergence
        history. With ``path`` (a folder) the figures are written there as PNG files
        and their paths returned; without, the matplotlib figures are returned and
        nothing is written. ``validation``: scores from :meth:`validate`."""
        from ..analysis.figures import fit_figures

        return fit_figures(self, path, validation)

    def __repr__(self) -> str:
        ps = ", ".join(f"{k}={v:.6g}" for k, v in self.params.items())
        return (
            f"FitResult(method={self.method!r}, status={self.status}, cost={self.cost:.6g}, "
            f"nit={self.nit}, params={{{ps}}}, message={self.message!r})"
        )


class FitInterrupted(KeyboardInterrupt):
    """Ctrl-C during :func:`tensorid.fit`. Still a KeyboardInterrupt (a script stops
    as it always did), but ``result`` holds the best point found so far, with status
    ``INTERRUPTED``; its ``starts`` list the starts that had finished. From
    :func:`tensorid.fit_batch`, ``results`` holds every start's result."""

    def __init__(self, result: FitResult, results: list[FitResult] | None = None):
        super().__init__(result.message)
        self.result = result
        self.results = [result] if results is None else results
