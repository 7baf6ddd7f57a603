"""A check for model error: do separate parts of the record give the same estimates?

Robust (sandwich) error bars cover coloured noise, not a wrong model: a model that
cannot follow the system leaves an error that no noise model explains, and the
estimates absorb it (a Bouc–Wen fit's mass sat 34 robust standard errors from the
truth). Whiteness cannot tell the two apart: both colour the residuals.

The check. The record is cut into parts: the given records when there are several,
else the record's two halves (of one length: an odd record's middle sample is left
out). The model is fitted to each part alone, from the full fit's estimate. Where the
problem's record carries a mask (``Problem.masked``: one record, output error, single
shooting, no events, linear or held inputs), a half is the whole record with the other
samples masked, so that the fit's own compiled programs fit it (programs of the
half's length had compiled for about a second); a masked sample adds nothing, even
where the model is not finite there, so this is the fit of the half alone. Where the
model is right, every part estimates the same θ and the parts' estimates differ by
noise only, θ̂_i ≈ N(θ, Σ_i) with Σ_i each part's robust covariance (Newey-West:
coloured noise included), nearly independent between parts (the scores' correlation
dies out within the bandwidth, far shorter than a part).
The homogeneity statistic

    Q = Σ_i (θ̂_i − θ̄)ᵀ Σ_i⁻¹ (θ̂_i − θ̄),      θ̄ = (Σ_i Σ_i⁻¹)⁻¹ Σ_i Σ_i⁻¹ θ̂_i

is then χ² with (m − 1)·p degrees of freedom (m parts, p parameters compared); for
two parts Q = dᵀ (Σ_1 + Σ_2)⁻¹ d, d = θ̂_1 − θ̂_2. Where the model is wrong, each
part's estimate is its best approximation to that part's excitation and response,
and these differ by more than noise: Q exceeds its quantile and the check fails.

Why this check: it puts the robust error bars' own claim — that they cover the
estimates' error — to the test, on the data, with nothing but the fit's own
machinery (Chow's and Hausman's tests are of this kind). A validation record would
say how well the model predicts, not whether its error bars are honest; a
whiteness test cannot separate noise from model error.

What it cannot see: a wrong model whose best approximation is the same on every
part. Parts with the same excitation (periods of one periodic input, a stationary
random input) can agree although the model is wrong: the check then passes, and
says only that the estimates do not drift along the record. Records with different
excitations give it power; give them as separate records where you have them.

Details. Only parameters are compared (each part estimates its own initial states);
a parameter that some part cannot determine (an unbounded robust standard error) is
left out and named. The second half's initial state: the states the fit estimates
(free_x0) are estimated again; the others start where the full fit's trajectory
(a filter's: its state estimate) is at the cut. Each part is fitted by the trust
region on the exact Hessian from the full estimate, by single shooting, with the
full problem's loss, weights, noise level and priors; a part whose trust region
collapsed in a flat valley (nothing decreases further) is compared on the
parameters it determines, and a part that ends otherwise unconverged stops the
check ("not made", with the reason).
"""

from __future__ import annotations

import copy
import time
from dataclasses import dataclass, field

import numpy as np

from ..engine.compiling.compiled import on_device
from ..engine.modelling.data import Experiment
from ..engine.schemes.status import Status
from ..solve.minimize import interrupted, minimize_trust_region
from ..solve.scaling import Tracker
from . import quantiles
from .sandwich import score_covariance
from .summary import Table, Tabular, collapsed_outputs, significant, stderr_text
from .uncertainty import uncertainty

MIN_PART = 20  # samples a part needs (and more than twice its unknowns)
SAME_INPUT = 0.05  # parts whose inputs differ by less (relative RMS) repeat one excitation
REPEATED = (
    "its parts repeat one excitation (the same input in each), so they carry the same "
    "model error and agreeing shows only that the estimates do not drift, not that the "
    "model is right"
)


@dataclass(repr=False)
class ModelCheck(Tabular):
    """The estimates of separate parts of the record compared with their robust error
    bars (see the module's docstring).

    parts : the parts' labels; names : the parameters compared; estimates, stderr :
    (parts, parameters), the robust standard errors; statistic Q, dof, threshold
    (the χ² quantile at ``level``); passed : True, False, or None where the check
    could not be made (``not_available`` says why); left_out : parameters some part
    cannot determine, not compared.
    """

    level: float
    how: str  # "halves" or "records"
    parts: list[str] = field(default_factory=list)
    names: list[str] = field(default_factory=list)
    estimates: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)))
    stderr: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)))
    statistic: float = np.nan
    dof: int = 0
    threshold: float = np.nan
    passed: bool | None = None
    left_out: list[str] = field(default_factory=list)
    not_available: str | None = None
    # the parts repeat one excitation (periods of one periodic input): they then carry
    # the same model error, and agreeing says only that the estimates do not drift
    repeated: bool = False
    # the check's wall time (its parts' fits and error bars): beside the fit's own
    # seconds in fit.json (it can double a command's time and had been counted nowhere)
    seconds: float = 0.0

    def spread(self) -> list[tuple[str, float]]:
        """(parameter, largest distance between two parts in robust standard errors of
        their difference), the most discordant first."""
        out = []
        for k, name in enumerate(self.names):
            th, se = self.estimates[:, k], self.stderr[:, k]
            i, j = np.triu_indices(len(th), 1)
            z = np.abs(th[i] - th[j]) / np.sqrt(se[i] ** 2 + se[j] ** 2)
            out.append((name, float(z.max())))
        return sorted(out, key=lambda a: -a[1])

    def line(self) -> str:
        """The verdict in one line."""
        if self.passed is None:
            return f"not made: {self.not_available}"
        verdict = "passes" if self.passed else "FAILS"
        side = "below" if self.passed else "above"
        worst = ", ".join(f"{n} {z:.1f}" for n, z in self.spread()[:3])
        out = (
            f"{verdict}: the estimates of {' and '.join(self.parts)} differ by Q = "
            f"{self.statistic:.1f}, {side} {self.threshold:.1f} (χ², {self.dof} degrees of "
            f"freedom, {self.level:.0%}); the widest apart, in robust standard errors of "
            f"their difference: {worst}"
        )
        if self.left_out:
            out += f"; not compared (a part cannot determine them): {', '.join(self.left_out)}"
        if not self.passed and self.spread() and self.spread()[0][1] <= 2.0:
            out += (
                "; no unknown alone is more than 2 apart: it is their joint difference "
                "that fails (the parts' estimates move together in a direction their "
                "correlated error bars do not allow)"
            )
        if self.passed and self.repeated:
            out += f"; but {REPEATED}"
        return out

    def advice(self) -> str:
        """What a failed check means and what to try."""
        return (
            "But the model-error check FAILS (separate parts of the record give estimates "
            "further apart than their robust error bars allow): the error bars, robust ones "
            "included, do not cover the model's error. Try a richer model (a missing "
            "dynamic or nonlinearity), the input's intersample setting (interpolation), or "
            "process noise (predictor='ekf', --predictor ekf --process-noise)"
        )

    def blocks(self) -> list:
        head = f"model-error check ({self.how}, {self.level:.0%}): {self.line()}"
        if self.passed is None:
            return [head]
        header = ["unknown"] + [f"{p}" for p in self.parts]
        rows = [
            [n]
            + [
                f"{significant(float(self.estimates[i, k]), float(self.stderr[i, k]))} "
                f"± {stderr_text(float(self.stderr[i, k]))}"
                for i in range(len(self.parts))
            ]
            for k, n in enumerate(self.names)
        ]
        return [head, Table("estimates ± robust standard errors, per part", header, rows)]

    def as_dict(self) -> dict:
        return {
            "passed": self.passed,
            "how": self.how,
            "level": self.level,
            "parts": self.parts,
            "names": self.names,
            "estimates": self.estimates.tolist(),
            "stderr_robust": self.stderr.tolist(),
            "statistic": self.statistic,
            "dof": self.dof,
            "threshold": self.threshold,
            "left_out": self.left_out,
            "not_available": self.not_available,
            "text": self.line(),
            "seconds": self.seconds,
        }

    def __repr__(self) -> str:
        return f"ModelCheck(passed={self.passed}, statistic={self.statistic:.4g}, dof={self.dof})"


def model_check(res, level: float = 0.99, maxiter: int = 100) -> ModelCheck:
    """The model-error check of a fit (see the module's docstring): each part fitted
    from ``res``'s estimate (at most ``maxiter`` iterations), its robust covariance,
    and the homogeneity statistic Q against its χ² quantile at ``level``; ``seconds``
    it took."""
    started = time.perf_counter()
    check = _model_check(res, level, maxiter)
    check.seconds = time.perf_counter() - started
    return check


def _model_check(res, level: float, maxiter: int) -> ModelCheck:
    if not 0 < level < 1:
        raise ValueError(f"level must be between 0 and 1, got {level!r}")
    problem = res.problem
    how = "records" if len(problem.experiments) > 1 else "halves"
    short = _too_short(problem) or _floor(res)
    if short or not res.has_uncertainty:
        why = short or f"the fit ended as {res.status}, without derivatives at its end"
        return ModelCheck(level, how, not_available=why)
    p = len(problem.free_params)
    if p == 0:
        return ModelCheck(level, how, not_available="no parameter is estimated")
    labels, est, covs, ses, inputs = [], [], [], [], []
    for label, part, theta0, own in _parts(res):
        inputs.append(np.asarray(part.experiments[0].u[own], dtype=float))
        fitted = _fit_part(part, theta0, maxiter)
        if isinstance(fitted, str):
            return ModelCheck(level, how, not_available=f"the fit of {label} {fitted}")
        labels.append(label)
        est.append(fitted.theta[-p:])
        covs.append(fitted.covariance[-p:, -p:])
        ses.append(fitted.stderr[-p:])
    check = _compare(level, how, labels, list(problem.free_params), est, covs, np.array(ses))
    check.repeated = _same_excitation(inputs)
    return check


def _same_excitation(inputs: list[np.ndarray]) -> bool:
    """Whether every part has (nearly) the input of the first: periods of one
    periodic excitation, within SAME_INPUT of its spread (relative RMS)."""
    first = inputs[0]
    if first.size == 0 or any(u.shape != first.shape for u in inputs):
        return False
    spread = np.linalg.norm(first - first.mean(axis=0))
    return bool(spread > 0 and all(
        np.linalg.norm(u - first) <= SAME_INPUT * spread for u in inputs[1:]))  # fmt: skip


def _compare(level, how, labels, names, est, covs, ses) -> ModelCheck:
    """Q = Σ_i (θ̂_i − θ̄)ᵀ Σ_i⁻¹ (θ̂_i − θ̄) over the parameters every part determines,
    in units of their typical standard error (Q does not depend on units; the
    pseudo-inverses' cutoff would)."""
    keep = (np.isfinite(ses) & (ses > 0)).all(axis=0)
    left = [n for n, k in zip(names, keep, strict=True) if not k]
    if not keep.any():
        why = "no parameter is determined by every part"
        return ModelCheck(level, how, labels, not_available=why)
    idx = np.nonzero(keep)[0]
    ref = ses[:, idx].mean(axis=0)
    z = [e[idx] / ref for e in est]
    W = [np.linalg.pinv(c[np.ix_(idx, idx)] / np.outer(ref, ref), hermitian=True) for c in covs]
    mean = np.linalg.pinv(sum(W), hermitian=True) @ sum(w @ t for w, t in zip(W, z, strict=True))
    Q = float(sum((t - mean) @ w @ (t - mean) for w, t in zip(W, z, strict=True)))
    dof = (len(labels) - 1) * idx.size
    threshold = float(quantiles.chi2(dof, level))
    estimates = np.array(est)[:, idx]
    return ModelCheck(
        level, how, labels, [names[i] for i in idx], estimates, ses[:, idx], Q, dof,
        threshold, bool(Q <= threshold), left,
    )  # fmt: skip


def _too_short(problem) -> str | None:
    """Why the record cannot be cut into parts that each determine the unknowns."""
    need = max(MIN_PART, 2 * problem.K + 2)
    if len(problem.experiments) > 1:
        exps = enumerate(problem.experiments)
        short = [e.name or str(i) for i, e in exps if e.seen_rows.sum() < need]
        if short:
            return f"records {short} are shorter than {need} samples, too short to fit alone"
        return None
    e = problem.experiments[0]
    half = e.P // 2
    n = (int(e.seen_rows[:half].sum()), int(e.seen_rows[e.P - half :].sum()))
    if min(n) < need:
        held = f"{n[0]} samples" if n[0] == n[1] else f"{n[0]} and {n[1]} measured samples"
        return f"the record's halves ({held}) are shorter than {need} samples"
    return None


def _floor(res) -> str | None:
    """Why a filter fit whose measurement noise sits at its floor cannot be checked:
    its likelihood is in a corner, and its parts' σ_e would be compared at theirs."""
    collapsed = collapsed_outputs(res)
    if not collapsed:
        return None
    o, sigma = next(iter(collapsed.items()))
    return (
        f"the measurement noise σ_e({o}) = {sigma:.2g} sits at its floor; fix it at the "
        f"sensor's noise (--fix log_sigma_e_{o}=log σ) and fit again first"
    )


def _parts(res):
    """(label, the part as a Problem, its θ to start from, the part's own samples: a
    slice of its record) for each part."""
    problem = res.problem
    exps = problem.experiments
    _, x0 = problem.unpack(res.theta)
    if len(exps) > 1:  # each record alone: the programs the fit compiled for its length
        for e, rec in enumerate(exps):
            keep = problem._slices(e)
            label = f"record '{rec.name}'" if rec.name else f"record {e}"
            yield label, _part(problem, [rec], x0[e], keep), res.theta[keep], slice(None)
        return
    # halves of one length (an odd record's middle sample is in neither); where the
    # problem's record carries a mask (Problem.masked), each half is a record of the
    # full length with the rest masked, so the fit's own compiled programs fit it
    rec = exps[0]
    half = rec.P // 2
    cut = rec.P - half
    own = slice(0, half)
    yield f"samples 0-{half - 1}", _half(problem, rec, 0, half, x0[0]), res.theta, own
    at_cut = _state_at(problem, res.theta, cut)
    theta = res.theta.copy()
    free = [problem.model.states.index(n) for n in problem.free_x0]
    theta[: len(free)] = at_cut[free]
    yield f"samples {cut}-{rec.P - 1}", _half(problem, rec, cut, rec.P, at_cut), theta, own


def _half(problem, rec, start: int, stop: int, x0):
    """The part on samples [start, stop) of ``rec``: the record with its other samples
    masked where the problem's record carries a mask (the fit's compiled programs fit
    it; an unobserved sample adds nothing, even where the model is not finite there),
    else a record of its own length (its programs compiled for it)."""
    keep = np.arange(problem.K)
    part = _padded(rec, start, stop) if problem.masked else rec.window(start, stop)
    return _part(problem, [part], x0, keep)


def _padded(rec, start: int, stop: int) -> Experiment:
    """Samples [start, stop) of ``rec`` as a record of its length whose other samples
    are not observed: the record from ``start`` on, then its beginning played again
    after its end (its times shifted by its span and one interval)."""
    P = rec.P
    rows = (start + np.arange(P)) % P
    shift = np.where(rows < start, rec.t[-1] - rec.t[0] + (rec.t[1] - rec.t[0]), 0.0)
    own = np.arange(P) < stop - start
    return Experiment(
        rec.t[rows] + shift, rec.u[rows], rec.y[rows], name=rec.name,
        observed=rec.seen[rows] & own[:, None],
    )  # fmt: skip


def _state_at(problem, theta, h: int) -> np.ndarray:
    """The state at sample h: the simulation's (output error without events: the
    fit's own program), or the predictor's (a filter's estimate before its update)."""
    _, x0 = problem.unpack(theta)
    if not problem.predictor.filters and problem.dosing is None:
        x = problem.simulate(theta)[0].x[h]
        return x if np.isfinite(x).all() else x0[0]
    sw = problem.sweeps
    t, u, y = problem.arrays[0]
    local = on_device(theta[problem._slices(0)])
    zs, _ = sw.predictions(local, on_device(problem.x0[0]), on_device(problem.p0), t, u, y)
    x = np.asarray(sw.predictor.states(np.asarray(zs)))[h]
    return x if np.isfinite(x).all() else x0[0]


def _part(problem, records, x0, keep):
    """``problem`` on ``records`` alone (a shallow copy sharing its compiled sweeps):
    initial states ``x0``, θ's entries ``keep`` of the full θ (bounds and priors
    with them), single shooting."""
    out = copy.copy(problem)
    out.experiments = list(records)
    out.x0 = np.atleast_2d(np.asarray(x0, dtype=float)).copy()
    out._arrays = [out.arrays_of(e) for e in records]
    out.shooting = None
    out.lower, out.upper = problem.lower[keep], problem.upper[keep]
    where = {int(old): new for new, old in enumerate(keep)}
    out.priors = {where[i]: v for i, v in problem.priors.items() if i in where}
    out.constraints = None  # the data's parts alone (and θ's layout is not the problem's)
    return out


def _fit_part(part, theta0, maxiter: int):
    """The part's Uncertainty (robust) at its optimum from ``theta0``, or why not (text)
    (its scores on its measured samples: a padded record's masked rest has none)."""
    theta0 = np.clip(theta0, part.lower, part.upper)
    J0, _, H_gn = part.cost_grad_gn(theta0)
    if not np.isfinite(J0):
        return "could not start: the model is not finite there from the full fit's estimate"
    tr = Tracker.start(part, theta0, J0, H_gn, "auto")
    lo, hi = tr.box()
    fun = tr.derivs(part.cost_grad_hess)
    r = interrupted(
        minimize_trust_region(fun, tr.phi(theta0), lo, hi, fatol=tr.fatol, maxiter=maxiter)
    )
    theta = tr.theta(r.x if tr.best_phi is None else tr.best_phi)
    J, g, H = part.cost_grad_hess(theta)
    # a trust region that collapsed where nothing decreases further ended in a flat
    # valley: its flat directions' unknowns get unbounded error bars and are left out
    flat_end = r.status in (Status.RADIUS_COLLAPSED, Status.NO_PREDICTED_DECREASE)
    if not ((r.success or flat_end) and np.isfinite(J)):
        return f"did not converge ({r.message})"
    meat = score_covariance(part, theta, "auto")[0]
    u = uncertainty(
        part, theta, J, H, "hessian", gauss_newton=lambda: part.cost_grad_gn(theta)[2],
        grad=g, scale=tr.scale, meat=meat,
    )  # fmt: skip
    u.kind = "robust"
    return u
