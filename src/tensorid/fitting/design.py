"""Optimal experiment design from the Fisher information.

For Gaussian output noise of standard deviation σ_s on output s, the Fisher information
of θ at nominal values is

    F(u) = Σ_k Σ_s (∂ŷ_ks/∂θ)ᵀ (∂ŷ_ks/∂θ) / σ_s²,

with the output sensitivities exact for the discretised model (the first-order
transition matrices); F⁻¹ predicts the covariance of the estimates from an experiment
with input u. ``design_input`` chooses the input, within a family u = family(a) and
box limits on the design variables a (amplitude limits), to

* "D": maximise log det F (the volume of the confidence region, in relative units), or
* "max-variance": minimise the largest relative variance var(θ_i)/θ_i² of the
  unknowns named,

and reports the predicted standard errors before (at a0) and after. ``verify`` fits
simulated noisy experiments to check the prediction: what a user should do before
spending a day on the rig.
"""

from __future__ import annotations

import warnings
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np

from ..analysis.summary import Table, Tabular
from ..engine.assembly.problem import Problem
from ..engine.assembly.simulate import simulate
from ..engine.modelling.data import Experiment
from ..engine.schemes.status import Status
from ..solve.endings import Outcome, OwnRun, Run, iterate

CRITERIA = ("D", "max-variance")


@dataclass(repr=False)
class InputDesign(Tabular):
    """The designed input and what it predicts.

    a, u : the design variables and the input they give, (P, U); a0, u0 the start.
    stderr_before, stderr_after : predicted standard errors {unknown: value} at a0 and a.
    criterion : its value before and after (lower is better).
    """

    names: list[str]
    theta: np.ndarray
    a0: np.ndarray
    a: np.ndarray
    u0: np.ndarray
    u: np.ndarray
    stderr_before: dict[str, float]
    stderr_after: dict[str, float]
    criterion: str
    value_before: float
    value_after: float
    problem: Callable[..., Problem] = field(repr=False)
    noise: np.ndarray = field(repr=False, default_factory=lambda: np.ones(1))

    def describe(self) -> str:
        def rel(se, v):
            return f"{se / abs(v):.2%}" if v != 0 else f"{se:.3g} (absolute)"

        rows = [
            f"  {n}: {rel(self.stderr_before[n], v)} -> {rel(self.stderr_after[n], v)}"
            for n, v in zip(self.names, self.theta, strict=True)
        ]
        return "predicted relative standard errors, before -> after:\n" + "\n".join(rows)

    def blocks(self) -> list:
        """The criterion before and after, and each unknown's predicted standard error
        (absolute and relative to its value) at the start and with the design."""
        head = (
            f"input design ({self.criterion}, lower is better): {self.value_before:.4g} -> "
            f"{self.value_after:.4g} over {self.u.shape[0]} samples"
        )
        header = ["unknown", "value", "std. error at start", "std. error designed"]
        header += ["relative at start", "relative designed"]
        rows = []
        for n, v in zip(self.names, self.theta, strict=True):
            b, a = self.stderr_before[n], self.stderr_after[n]
            rel = [f"{se / abs(v):.2%}" if v != 0 else "–" for se in (b, a)]
            rows.append([n, f"{v:.6g}", f"{b:.3g}", f"{a:.3g}", *rel])
        return [head, Table(None, header, rows)]

    def __repr__(self) -> str:
        return (
            f"InputDesign(criterion={self.criterion!r}, value {self.value_before:.4g} -> "
            f"{self.value_after:.4g}, u {self.u.shape}, unknowns {self.names})"
        )

    def predict(self, u) -> dict[str, float]:
        """Predicted standard errors for any input u (P,) or (P, U), e.g. a recorded one."""
        return _stderr(self.problem(u))

    def verify(self, draws: int = 50, seed: int = 0, designed: bool = True) -> dict[str, float]:
        """Fit ``draws`` simulated experiments (the designed input, or the start's, with
        Gaussian noise of the given σ) from the nominal values; return the realised
        standard deviation of each estimate, to set beside the prediction."""
        return self.verify_input(self.u if designed else self.u0, draws, seed)

    def verify_input(self, u, draws: int = 50, seed: int = 0) -> dict[str, float]:
        """As :meth:`verify`, for any input u (e.g. a recorded one)."""
        from .methods import fit

        clean = self.problem(u).experiments[0].measured
        rng = np.random.default_rng(seed)
        estimates = []
        for _ in range(draws):
            y = clean + self.noise * rng.standard_normal(clean.shape)
            res = fit(self.problem(u, y), "gauss-newton")
            if res.success:
                estimates.append(res.theta)
        spread = np.std(np.array(estimates), axis=0, ddof=1)
        return dict(zip(self.names, spread.tolist(), strict=True))


def _fisher(problem: Problem) -> np.ndarray:
    """F = JᵀWJ with W = 1/σ² (the problem's weights): half the Gauss-Newton Hessian."""
    _, _, H = problem.cost_grad_gn(problem.theta0)
    return 0.5 * H


def _criterion(F: np.ndarray, theta: np.ndarray, kind: str, pick: np.ndarray) -> float:
    S = np.abs(theta) + (theta == 0)  # relative units; an unknown at 0 stays absolute
    Fs = F * np.outer(S, S)
    if not np.isfinite(Fs).all():
        return np.inf
    lam = np.linalg.eigvalsh(0.5 * (Fs + Fs.T))
    if lam[0] <= 1e-14 * max(lam[-1], 1e-300):
        return np.inf  # an unknown this input cannot identify
    if kind == "D":
        return -float(np.sum(np.log(lam)))
    cov = np.linalg.inv(Fs)
    return float(np.max(np.diag(cov)[pick]))


def design_input(
    model,
    params: dict,
    t: np.ndarray,
    family: Callable[[np.ndarray], np.ndarray],
    a0: Sequence[float] | np.ndarray,
    *,
    bounds: Sequence[tuple[float, float]] | None = None,
    x0: Sequence[float] | np.ndarray | None = None,
    free_x0: Sequence[str] = (),
    fixed: Sequence[str] = (),
    noise: float | Sequence[float] = 1.0,
    criterion: str = "D",
    names: Sequence[str] | None = None,
    starts: int = 4,
    seed: int = 0,
    **problem_options,
) -> InputDesign:
    """The input within ``family`` that best identifies the unknowns at ``params``.

    Arguments:
        model (Model): the model, ``params`` its nominal parameter values {name: value}.
        t: (P,) sample times of the planned experiment.
        family: a ↦ u (P,) or (P, U) for design variables a (step levels, amplitudes).
        a0: the starting design.
        bounds: box limits [(lo, hi), ...] per design variable (amplitude limits).
        x0: the initial state; ``free_x0`` (unknown initial states) and ``fixed``
            (known parameters) as for :class:`tensorid.Problem`.
        noise: output noise standard deviation (scalar, or one per output).
        criterion: "D" (maximise log det F) or "max-variance" (the largest relative
            variance among ``names``).
        names: the unknowns "max-variance" looks at (default all).
        starts: optimisation starts (a0 and random points within the bounds, drawn
            with ``seed``).
        **problem_options (Any): integration settings passed to the Problem (scheme, ...).

    Returns:
      :class:`InputDesign`, with predicted standard errors before and after.
    """
    if criterion not in CRITERIA:
        raise ValueError(f"criterion must be one of {CRITERIA}, got {criterion!r}")
    a0 = np.atleast_1d(np.asarray(a0, dtype=float))
    lo, hi = _box(a0, bounds)
    if names is not None and criterion == "D":
        raise ValueError("names picks the unknowns of criterion='max-variance'; 'D' weighs all")
    sigma = np.broadcast_to(np.asarray(noise, dtype=float), (model.S,)).copy()
    if not (np.isfinite(sigma).all() and (sigma > 0).all()):
        raise ValueError(f"noise must be standard deviations > 0, got {noise!r}")
    x0 = np.zeros(model.N) if x0 is None else model.states_array(x0)
    setting = dict(x0=x0, free_x0=free_x0, fixed=fixed, **problem_options)
    problem = _planned(model, params, np.asarray(t, dtype=float), sigma, setting)
    base = problem(family(a0))
    theta = base.theta0
    pick = _pick(names, base.theta_names)

    def objective(a):
        try:
            return _criterion(_fisher(problem(family(a))), theta, criterion, pick)
        except ValueError:  # the simulation failed for this input
            return np.inf

    best = _optimise(objective, a0, lo, hi, starts, seed)
    if not np.isfinite(objective(best)):
        _warn_unidentifiable()
    before, after = problem(family(a0)), problem(family(best))
    return InputDesign(
        names=base.theta_names,
        theta=theta,
        a0=a0,
        a=best,
        u0=before.experiments[0].u,
        u=after.experiments[0].u,
        stderr_before=_stderr(before),
        stderr_after=_stderr(after),
        criterion=criterion,
        value_before=objective(a0),
        value_after=objective(best),
        problem=problem,
        noise=sigma,
    )


def _pick(names, theta_names: list[str]) -> np.ndarray:
    """The indices of ``names`` (default: every unknown) among the unknowns."""
    unknown = [n for n in names or [] if n not in theta_names]
    if unknown:
        raise ValueError(f"names: unknown {unknown}; the unknowns are {theta_names}")
    return np.array([theta_names.index(n) for n in (names or theta_names)])


def _warn_unidentifiable() -> None:
    warnings.warn(
        "design_input: no input tried identifies every unknown at these parameters (the "
        "Fisher information stays singular), so the input is returned unchanged and its "
        "predicted standard errors are not meaningful; fix or reparametrise the unknowns "
        "that cannot be told apart, or widen the family",
        RuntimeWarning,
        stacklevel=3,
    )


def _box(a0: np.ndarray, bounds) -> tuple:
    """(lo, hi) of the design variables, or (None, None); a0 within them."""
    if not np.isfinite(a0).all():
        raise ValueError(f"a0 must be finite, got {a0.tolist()}")
    if bounds is None:
        return None, None
    try:
        box = np.asarray(bounds, dtype=float)
    except (TypeError, ValueError):
        box = np.zeros(0)
    if box.shape != (a0.size, 2):
        raise ValueError(
            f"bounds must be one (lo, hi) per design variable ({a0.size}), got {bounds!r}"
        )
    lo, hi = box[:, 0], box[:, 1]
    for i in range(a0.size):
        if np.isnan(box[i]).any() or lo[i] > hi[i]:
            raise ValueError(f"bounds[{i}] = {box[i].tolist()} must be (lo, hi) with lo <= hi")
        if not lo[i] <= a0[i] <= hi[i]:
            raise ValueError(f"a0[{i}] = {a0[i]:g} is outside bounds[{i}] = {box[i].tolist()}")
    return lo, hi


def _planned(model, params, t, sigma, setting: dict):
    """The planned experiment as a function of its input u (and, for simulated
    experiments, of measured y; else the noise-free outputs), weighted by 1/σ²."""

    def problem(u, y=None) -> Problem:
        e = Experiment(t, np.asarray(u, dtype=float).reshape(t.size, -1))
        y = simulate(model, params, setting["x0"], e).y if y is None else y
        return Problem(model, Experiment(t, e.u, y), p0=params, weights=1.0 / sigma**2, **setting)

    return problem


def _stderr(problem: Problem) -> dict[str, float]:
    F = _fisher(problem)
    try:
        with np.errstate(invalid="ignore"):
            se = np.sqrt(np.diag(np.linalg.inv(F)))
        se = np.where(np.isfinite(se) & (se >= 0), se, np.inf)
    except np.linalg.LinAlgError:
        se = np.full(problem.K, np.inf)
    return dict(zip(problem.theta_names, se.tolist(), strict=True))


def _optimise(objective, a0, lo, hi, starts: int, seed: int) -> np.ndarray:
    """The best of L-BFGS-B runs from a0 and random points in the box, each a run of
    the one loop (solve/endings.iterate): Ctrl-C stops them all at once."""
    rng = np.random.default_rng(seed)
    points = [a0]
    if lo is not None and hi is not None and np.isfinite(lo).all() and np.isfinite(hi).all():
        points += [lo + rng.uniform(size=a0.size) * (hi - lo) for _ in range(starts - 1)]
    box = list(zip(lo, hi, strict=True)) if lo is not None else None
    values = [objective(p) for p in points]  # each start's value, once
    finite = [p for p, v in zip(points, values, strict=True) if np.isfinite(v)]
    runs = [_Search(objective, p, box) for p in finite]
    ran = [Run(r, r) for r in runs]
    iterate(ran, lambda asking: [])  # (each evaluates for itself, as SciPy's baselines)
    if any(r.ending is not None and r.ending.status is Status.INTERRUPTED for r in ran):
        raise KeyboardInterrupt
    best, best_value = a0, values[0]
    for r in runs:
        if r.value < best_value:
            best, best_value = r.x, r.value
    return best


class _Search(OwnRun):
    """One L-BFGS-B run on the design criterion: the method and the state of a run of
    the one loop, which evaluates for itself (``point`` None) in one step."""

    name = "L-BFGS-B"
    point = None

    def __init__(self, objective, a0: np.ndarray, box):
        self.objective, self.x, self.box = objective, np.asarray(a0, dtype=float), box
        self.value = np.inf

    def step(self, state, value) -> None:
        from scipy import optimize  # here, not at the top: keeps `import tensorid` cheap

        r = optimize.minimize(self.objective, self.x, method="L-BFGS-B", bounds=self.box)
        self.x, self.value = np.asarray(r.x), float(r.fun)
        status = Status.BASELINE_CONVERGED if r.success else Status.BASELINE_STOPPED
        self.outcome = Outcome(self.x, int(r.nit), status, "" if r.success else str(r.message))

    def best(self, state) -> tuple:
        return self.x, 0


def step_levels(samples: int, levels: int) -> Callable[[np.ndarray], np.ndarray]:
    """A family of piecewise-constant inputs: ``levels`` equal-length steps over
    ``samples`` samples, the design variables being the levels."""
    edges = np.linspace(0, samples, levels + 1).round().astype(int)
    which = np.searchsorted(edges, np.arange(samples), side="right") - 1

    def family(a):
        return np.asarray(a, dtype=float)[which]

    return family


def multisine(
    t, frequencies, offset: float = 0.0, limits: tuple[float, float] | None = None
) -> Callable[[np.ndarray], np.ndarray]:
    """A family of multisines u = offset + Σ a_j sin(2π f_j t + φ_j), Schroeder phases,
    the design variables being the amplitudes a_j; clipped to ``limits`` (the
    actuator's range) when given."""
    t = np.asarray(t, dtype=float)
    f = np.asarray(frequencies, dtype=float)
    phase = -np.pi * np.arange(f.size) * (np.arange(f.size) + 1) / f.size
    basis = np.sin(2 * np.pi * f[None, :] * t[:, None] + phase[None, :])

    def family(a):
        u = offset + basis @ np.asarray(a, dtype=float)
        return np.clip(u, *limits) if limits is not None else u

    return family
