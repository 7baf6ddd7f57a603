"""fit(): estimate θ with exact-derivative trust-region methods, or with the
finite-difference baselines the paper compares against.

Every method works on scaled variables φ = θ / scale and a cost normalised by its
value at the start, so that the Silverbox parameters (5e-6 .. 4) look alike to the
optimiser; results are reported in natural units. Whatever a method does, the
result holds the best finite point it evaluated: a fit never returns NaN.
"""

from __future__ import annotations

import os
import time
import warnings
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import scipy.optimize

from .metrics import gof
from .problem import Problem
from .trust_region import minimize_trust_region, trust_region_steps

METHODS = ("newton", "newton-cg", "gauss-newton", "fd-bfgs", "fd-lsq")


@dataclass
class FitResult:
    """Outcome of :func:`fit`, with scipy.optimize.OptimizeResult's names where they fit.

    theta : (K,) estimate in natural units, θ layout of ``problem`` (alias ``x``).
    params : {name: value} for every parameter (fixed ones included).
    x0 : (N,) initial state, or (E, N) for several experiments.
    cost : J at theta (alias ``fun``); jac (K,) and hess (K, K) are the exact
        gradient and Hessian there, whatever the method.
    grad_norm : ∞-norm of the projected gradient with respect to θ / scale, in cost
        units (components pushing against an active bound are dropped).
    nit, nfev : iterations and cost evaluations (finite-difference ones included).
    nhev : Hessian-vector products (method "newton-cg").
    seconds : wall time of the fit, compilation included.
    history : one dict per iteration: iteration, cost, grad_norm, radius, ...
    notes : what happened on the way, e.g. trial points where the simulation blew up.
    """

    problem: Problem
    method: str
    theta: np.ndarray
    params: dict[str, float]
    x0: np.ndarray
    cost: float
    jac: np.ndarray
    hess: np.ndarray
    grad_norm: float
    nit: int
    nfev: int
    success: bool
    message: str
    seconds: float
    scale: np.ndarray
    history: list[dict] = field(default_factory=list)
    starts: list[dict] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)
    nhev: int = 0

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
        """Goodness of fit per experiment (per output for several outputs)."""
        sims = self.simulate()
        return [
            gof(_squeeze(e.measured), _squeeze(s.y))
            for e, s in zip(self.problem.experiments, sims, strict=True)
        ]

    def uncertainty(self, kind: str = "hessian"):
        """Standard errors, 95 % intervals, correlations (see tensorid.uncertainty);
        ``kind`` "hessian" uses the exact Hessian, "gauss-newton" its first-order form."""
        from .uncertainty import uncertainty

        if kind not in ("hessian", "gauss-newton"):
            raise ValueError("kind must be 'hessian' or 'gauss-newton'")
        H = self.hess if kind == "hessian" else self.problem.cost_grad_gn(self.theta)[2]
        return uncertainty(self.problem, self.theta, self.cost, H, kind)

    @property
    def covariance(self) -> np.ndarray:
        """Covariance of theta from the exact Hessian, scaled by the residual variance."""
        return self.uncertainty().covariance

    @property
    def warnings(self) -> list[str]:
        """Plain-language warnings: no convergence (with why, e.g. where the simulation
        blew up), unknowns the data cannot separate, an optimum that is not a strict
        minimum."""
        out = [] if self.success else [f"the fit did not converge: {self.message}", *self.notes]
        if np.isfinite(self.cost):
            out += self.uncertainty().warnings
        return out

    def summary(self) -> str:
        """A plain-text table of the estimates with standard errors and intervals."""
        from .report import summary_table

        return summary_table(self)

    def plot(self, path=None, validation=None):
        """Measured against simulated outputs with residuals; saved to ``path`` (PNG)
        when given. Returns the list of written files or the matplotlib figures."""
        from .report import fit_figures

        return fit_figures(self, path, validation)

    def __repr__(self) -> str:
        ps = ", ".join(f"{k}={v:.6g}" for k, v in self.params.items())
        return (
            f"FitResult(method={self.method!r}, success={self.success}, cost={self.cost:.6g}, "
            f"nit={self.nit}, params={{{ps}}}, message={self.message!r})"
        )


def _squeeze(a: np.ndarray) -> np.ndarray:
    return a[:, 0] if a.ndim == 2 and a.shape[1] == 1 else a


class _Tracker:
    """Wraps evaluations in scaled variables; remembers the best finite point."""

    def __init__(self, problem: Problem, scale: np.ndarray, J_ref: float):
        self.problem, self.scale, self.J_ref = problem, scale, J_ref
        self.nfev = 0
        self.best_phi: np.ndarray | None = None
        self.best_J = np.inf
        self.nonfinite = 0
        self.first_nonfinite: np.ndarray | None = None

    def theta(self, phi) -> np.ndarray:
        """Natural units; clipped because θ/scale·scale may miss a bound by an ulp."""
        return np.clip(self.scale * phi, self.problem.lower, self.problem.upper)

    def _seen(self, phi, J):
        self.nfev += 1
        if np.isfinite(J) and J < self.best_J:
            self.best_J, self.best_phi = J, np.array(phi, dtype=float)
        elif not np.isfinite(J):
            self.nonfinite += 1
            if self.first_nonfinite is None:
                self.first_nonfinite = self.theta(phi)

    def notes(self) -> list[str]:
        """What the user should know about trial points that were rejected."""
        if not self.nonfinite:
            return []
        why = self.problem.diagnose(self.first_nonfinite) or "the simulation was not finite"
        return [
            f"{self.nonfinite} trial point(s) were rejected because the simulation blew "
            f"up there; the first: {why}"
        ]

    def scaled(self, phi, J, g, H):
        """(J, g, H) at θ(φ) in scaled variables, relative to the starting cost."""
        self._seen(phi, J)
        if not np.isfinite(J):
            return np.inf, g, H
        s = self.scale
        return J / self.J_ref, g * s / self.J_ref, H * np.outer(s, s) / self.J_ref

    def derivs(self, fn):
        def wrapped(phi):
            return self.scaled(phi, *fn(self.theta(phi)))

        return wrapped

    def derivs_hessp(self, phi):
        """(J, g, v -> Hv) in scaled units, for truncated-CG steps."""
        theta = self.theta(phi)
        J, g = self.problem.cost_grad(theta)
        self._seen(phi, J)
        if not np.isfinite(J):
            return np.inf, g, None
        s = self.scale

        def hessp(v):
            Hv = self.problem.cost_grad_hessp(theta, s * v)[2]
            return np.where(np.isfinite(Hv), Hv, 0.0) * s / self.J_ref

        return J / self.J_ref, g * s / self.J_ref, hessp

    def cost(self, phi):
        J = self.problem.cost(self.theta(phi))
        self._seen(phi, J)
        return J / self.J_ref if np.isfinite(J) else np.inf

    def residuals(self, phi):
        r = self.problem.residuals(self.theta(phi))
        J = float(r @ r)
        self._seen(phi, J if np.isfinite(J) else np.inf)
        return r / np.sqrt(self.J_ref)


def _auto_scale(problem: Problem, theta0: np.ndarray, J0: float, g_h: np.ndarray) -> np.ndarray:
    """Typical magnitudes: |θ0| where it is not zero; otherwise the step that changes
    the cost by about its own size according to the Gauss-Newton curvature."""
    scale = np.abs(theta0).astype(float)
    zero = scale == 0
    if zero.any():
        with np.errstate(divide="ignore", invalid="ignore"):
            curv = np.sqrt(max(J0, 1e-300) / np.diag(g_h))
        scale[zero] = np.where(np.isfinite(curv[zero]) & (curv[zero] > 0), curv[zero], 1.0)
    return scale


def fit(
    problem: Problem,
    method: str = "newton",
    *,
    theta0=None,
    starts: int | None = None,
    spread: float = 0.2,
    sampling: str = "lhs",
    seed: int = 0,
    executor=None,
    workers: int | None = None,
    batch: int | None = None,
    x_scale="auto",
    maxiter: int = 200,
    gtol: float = 1e-10,
    ftol: float = 1e-12,
    xtol: float = 1e-12,
    callback: Callable[[dict], None] | None = None,
) -> FitResult:
    """Estimate the free initial states and parameters of ``problem``.

    method:
      "newton"        trust-region Newton with the exact Hessian from transition tensors
      "newton-cg"     trust-region Newton with truncated conjugate gradients on exact
                      Hessian-vector products (one forward-over-forward sweep of 2K + 1
                      state copies each, against 1 + K + K(K+1)/2 for the full
                      Hessian): for many unknowns; the final Hessian for the error
                      bars is still computed once
      "gauss-newton"  trust-region Gauss-Newton (Levenberg-Marquardt) with the exact
                      Jacobian from first-order sensitivities
      "fd-bfgs"       BFGS (L-BFGS-B with bounds) with a finite-difference gradient
      "fd-lsq"        scipy least_squares (trf) with a finite-difference Jacobian, as
                      MATLAB's grey-box toolbox does
    theta0 : start (K,), natural units; default ``problem.theta0``.
    x_scale : "auto" or an array (K,) of typical magnitudes.
    gtol, ftol, xtol : stopping tolerances on the scaled projected gradient, the
        relative cost decrease and the scaled step.
    callback : called with each iteration's history entry (a dict).
    starts : with N > 1, fit from theta0 and N - 1 further starts (within the bounds
        where both are finite, else within ±spread of theta0; Latin hypercube or
        uniform ``sampling``, seeded), in parallel through ``executor`` (any
        concurrent.futures.Executor, e.g. a Dask ``client.get_executor()``) or a local
        process pool of ``workers``; the best is refined and returned, with every start
        ranked in ``result.starts``. The local pool spawns fresh processes, which
        re-import the calling script: guard a script's top level with
        ``if __name__ == "__main__":``.
    batch : with starts, fit this many starts together in each task, in lock-step,
        their evaluations vectorised into one jax.vmap call (see fit_batch; methods
        "newton" and "gauss-newton"). On a CPU this raises the throughput of each
        worker (benchmarks/bench_multistart.py: 1.5x on Silverbox). Default: the
        starts shared evenly over the local workers (at most 16 per task) for those
        methods, one start per task for the others or with an ``executor``.
    """
    if not isinstance(problem, Problem):
        raise TypeError(f"fit needs a tensorid.Problem, got {type(problem).__name__}")
    if method not in METHODS:
        raise ValueError(f"unknown method {method!r}; choose one of {list(METHODS)}")
    if batch is None:
        batch = 1
        if starts and starts > 1 and method in ("newton", "gauss-newton") and executor is None:
            batch = min(16, -(-starts // (workers or os.cpu_count() or 1)))
    if not isinstance(batch, int | np.integer) or batch < 1:
        raise ValueError(f"batch must be a positive integer, got {batch!r}")
    if batch > 1 and method not in ("newton", "gauss-newton"):
        raise ValueError(
            f"batch > 1 works with 'newton' and 'gauss-newton', not {method!r}; use batch=1"
        )
    start = time.perf_counter()
    theta0 = problem.theta0 if theta0 is None else problem._check_theta(theta0)
    lo, hi = problem.lower, problem.upper
    if ((theta0 < lo) | (theta0 > hi)).any():
        raise ValueError("theta0 lies outside the bounds")
    options = dict(x_scale=x_scale, maxiter=maxiter, gtol=gtol, ftol=ftol, xtol=xtol)
    if starts is not None and starts > 1:
        return _multistart(
            problem,
            method,
            theta0,
            starts,
            spread,
            sampling,
            seed,
            executor,
            workers,
            batch,
            options,
            callback,
            start,
        )

    J0, g0, H0 = problem.cost_grad_gn(theta0)
    if not np.isfinite(J0):
        return _failed_start(problem, method, theta0, start)
    tr = _Tracker(problem, _scale(problem, theta0, J0, H0, x_scale), J0 if J0 > 0 else 1.0)
    phi0, plo, phi_hi = theta0 / tr.scale, lo / tr.scale, hi / tr.scale
    history: list[dict] = []
    natural = _recorder(tr, history, callback)
    nhev = 0

    try:
        if method in ("newton", "newton-cg", "gauss-newton"):
            if method == "newton-cg":
                fn = tr.derivs_hessp
            else:
                fn = tr.derivs(
                    problem.cost_grad_hess if method == "newton" else problem.cost_grad_gn
                )
            r = minimize_trust_region(
                fn,
                phi0,
                plo,
                phi_hi,
                maxiter=maxiter,
                gtol=gtol,
                ftol=ftol,
                xtol=xtol,
                fatol=problem.rounding_floor / tr.J_ref,
                callback=natural,
            )
            phi, nit, success, message, nhev = r.x, r.nit, r.success, r.message, r.nhev
        else:
            phi, nit, success, message = _baseline(
                method, tr, phi0, plo, phi_hi, maxiter, gtol, ftol, xtol, natural
            )
    except Exception as e:  # a baseline inside SciPy may give up in its own way
        message = f"{method} stopped with {type(e).__name__}: {e}"
        if tr.best_phi is None:
            return _failed(problem, method, theta0, start, message)
        phi, nit, success = tr.best_phi, len(history), False

    res = _finish(tr, method, phi, nit, success, message, start, history)
    res.nhev = nhev
    return res


def _scale(problem, theta0, J0, H0, x_scale) -> np.ndarray:
    if isinstance(x_scale, str):
        if x_scale != "auto":
            raise ValueError("x_scale must be 'auto' or an array of typical magnitudes")
        return _auto_scale(problem, theta0, J0, H0)
    scale = np.asarray(x_scale, dtype=float).reshape(-1)
    if scale.shape != (problem.K,) or not (scale > 0).all():
        raise ValueError(f"x_scale must hold {problem.K} positive values")
    return scale


def _recorder(tr: _Tracker, history: list, callback):
    def natural(entry):  # back to the user's cost units
        entry = dict(entry, cost=entry["cost"] * tr.J_ref, grad_norm=entry["grad_norm"] * tr.J_ref)
        history.append(entry)
        if callback is not None:
            callback(entry)

    return natural


def _finish(tr: _Tracker, method, phi, nit, success, message, start, history) -> FitResult:
    """The result at the end point, or at the best point seen if that is better."""
    problem = tr.problem
    if tr.best_phi is not None and tr.best_J < problem.cost(tr.theta(phi)):
        phi = tr.best_phi
    res = _result(
        problem, method, tr.theta(phi), tr.scale, nit, tr.nfev, success, message, start, history
    )
    res.notes = tr.notes()
    if not success and tr.nonfinite:
        res.message += f" ({tr.nonfinite} trial points blew up; see warnings)"
    return res


def fit_batch(problem: Problem, method: str, thetas, **options) -> list[FitResult]:
    """Fits from every row of ``thetas`` (B, K) in lock-step: at each iteration the
    points of all unfinished starts are evaluated in one vectorised (jax.vmap) call,
    which costs far less than B separate calls on a CPU. Methods "newton" and
    "gauss-newton"; options as for :func:`fit` (x_scale, maxiter, gtol, ftol,
    xtol). Each result is what ``fit(problem, method, theta0=row)`` returns; its
    ``seconds`` is the wall time of the whole batch."""
    if method not in ("newton", "gauss-newton"):
        raise ValueError(
            f"batched starts work with 'newton' and 'gauss-newton', not {method!r}; use batch=1"
        )
    start = time.perf_counter()
    thetas = np.atleast_2d(np.asarray(thetas, dtype=float))
    x_scale = options.pop("x_scale", "auto")
    tr_options = {k: options.pop(k) for k in ("maxiter", "gtol", "ftol", "xtol") if k in options}
    if options:
        raise TypeError(f"fit_batch got unexpected options {sorted(options)}")
    for th in thetas:
        th = problem._check_theta(th)
        if ((th < problem.lower) | (th > problem.upper)).any():
            raise ValueError("a start lies outside the bounds")
    gn = method == "gauss-newton"
    B = len(thetas)
    J0, _, H0 = problem.cost_grad_hess_batch(thetas, gauss_newton=True)
    results: list[FitResult | None] = [None] * B
    runs, pending = {}, {}
    for i, th in enumerate(thetas):
        if not np.isfinite(J0[i]):
            results[i] = _failed_start(problem, method, th, start)
            continue
        J_ref = J0[i] if J0[i] > 0 else 1.0
        tr = _Tracker(problem, _scale(problem, th, J0[i], H0[i], x_scale), J_ref)
        history: list[dict] = []
        steps = trust_region_steps(
            th / tr.scale,
            problem.lower / tr.scale,
            problem.upper / tr.scale,
            fatol=problem.rounding_floor / J_ref,
            callback=_recorder(tr, history, None),
            **tr_options,
        )
        runs[i] = (tr, steps, history)
        pending[i] = next(steps)
    while pending:
        ids = list(pending)
        points = [runs[i][0].theta(pending[i]) for i in ids]
        points += [points[0]] * (B - len(ids))  # one shape: one compilation
        J, g, H = problem.cost_grad_hess_batch(np.array(points), gauss_newton=gn)
        for k, i in enumerate(ids):
            tr, steps, history = runs[i]
            try:
                pending[i] = steps.send(tr.scaled(pending[i], J[k], g[k], H[k]))
            except StopIteration as done:
                r = done.value
                del pending[i]
                results[i] = _finish(tr, method, r.x, r.nit, r.success, r.message, start, history)
    for r in results:
        assert r is not None
        r.seconds = time.perf_counter() - start
    return results  # type: ignore[return-value]


def _multistart(
    problem,
    method,
    theta0,
    n,
    spread,
    sampling,
    seed,
    executor,
    workers,
    batch,
    options,
    callback,
    start,
):
    from .multistart import draw_starts, run_starts

    thetas = draw_starts(
        theta0, problem.lower, problem.upper, n, spread=spread, sampling=sampling, seed=seed
    )
    runs = run_starts(problem, method, thetas, options, executor, workers, batch)
    for i, r in enumerate(runs):
        r["start"] = i
    ranked = sorted(runs, key=lambda r: (not np.isfinite(r["cost"]), r["cost"]))
    best = ranked[0]
    if not np.isfinite(best["cost"]):
        res = _failed(problem, method, theta0, start, f"none of the {n} starts gave a finite cost")
    else:  # refine the winner here, where the caller's callback can watch it
        res = fit(problem, method, theta0=np.asarray(best["theta"]), callback=callback, **options)
    res.starts = ranked
    res.nfev += sum(r["nfev"] for r in runs)
    res.seconds = time.perf_counter() - start
    return res


def _baseline(method, tr: _Tracker, phi0, lo, hi, maxiter, gtol, ftol, xtol, natural):
    bounded = bool(np.isfinite(lo).any() or np.isfinite(hi).any())
    it = [0]

    # SciPy passes its OptimizeResult only to a parameter named intermediate_result
    def cb(intermediate_result):
        it[0] += 1
        r = intermediate_result
        J = r.fun if method == "fd-bfgs" else 2.0 * r.cost  # least_squares: ½ Σ r²
        natural(
            {
                "iteration": it[0],
                "cost": float(J),
                "grad_norm": np.nan,
                "radius": np.nan,
                "step_norm": np.nan,
                "rho": np.nan,
                "accepted": True,
                "nfev": tr.nfev,
            }
        )

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        if method == "fd-bfgs":
            res = scipy.optimize.minimize(
                tr.cost,
                phi0,
                method="L-BFGS-B" if bounded else "BFGS",
                jac="2-point",
                bounds=list(zip(lo, hi, strict=True)) if bounded else None,
                options={"maxiter": maxiter, "gtol": gtol},
                callback=cb,
            )
            return res.x, int(res.nit), bool(res.success), str(res.message)
        res = scipy.optimize.least_squares(
            tr.residuals,
            phi0,
            jac="2-point",
            bounds=(lo, hi),
            method="trf",
            ftol=max(ftol, 1e-15),
            xtol=max(xtol, 1e-15),
            gtol=max(gtol, 1e-15),
            max_nfev=maxiter * (len(phi0) + 1),
            callback=cb,
        )
        return res.x, int(res.njev or res.nfev), bool(res.success), str(res.message)


def _result(
    problem,
    method,
    theta,
    scale,
    nit,
    nfev,
    success,
    message,
    start,
    history,
    evaluate: bool = True,
):
    """The FitResult at theta, with the exact gradient and Hessian there. A point whose
    simulation is not finite gets cost inf and zero derivatives, never NaN."""
    K = theta.size
    J, g, H = problem.cost_grad_hess(theta) if evaluate else (np.inf, None, None)
    if np.isfinite(J) and g is not None and H is not None:
        phi = theta / scale
        pg = np.clip(phi - g * scale, problem.lower / scale, problem.upper / scale) - phi
        grad_norm = float(np.linalg.norm(pg, np.inf))
    else:
        J, g, H, grad_norm = np.inf, np.zeros(K), np.zeros((K, K)), np.inf
    p, x0 = problem.unpack(theta)
    return FitResult(
        problem=problem,
        method=method,
        theta=theta,
        params=dict(zip(problem.model.params, map(float, p), strict=True)),
        x0=x0[0] if len(problem.experiments) == 1 else x0,
        cost=float(J),
        jac=g,
        hess=H,
        grad_norm=grad_norm,
        nit=int(nit),
        nfev=int(nfev),
        success=bool(success),
        message=message,
        seconds=time.perf_counter() - start,
        scale=scale,
        history=history,
    )


def _failed_start(problem, method, theta0, start):
    """The result for a start where the simulation already blows up, saying where."""
    why = problem.diagnose(theta0) or "the simulation is not finite at the start"
    return _failed(problem, method, theta0, start, why + " Choose another initial guess.")


def _failed(problem, method, theta0, start, message):
    return _result(
        problem, method, theta0, np.ones(problem.K), 0, 1, False, message, start, [], evaluate=False
    )
