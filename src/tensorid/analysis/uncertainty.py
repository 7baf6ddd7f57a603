"""Parameter uncertainty at the optimum, and identifiability.

For J = Σ w r² with n weighted residuals and K unknowns, the residual variance is
σ² = J / (n - K) and, to first order, cov(θ) = 2 σ² H⁻¹, with H the Hessian of J
(H ≈ 2 JᵀJ in the Gauss-Newton form, which gives the textbook σ² (JᵀJ)⁻¹). The exact
Hessian from transition tensors is the default; the Gauss-Newton form is available
for comparison. When H is (nearly) singular, the data cannot pin down some
combination of unknowns: the warning names the unknowns in that flat direction.

Two cases where the textbook formula would lie, and what is done instead:

* H indefinite (a saddle, or a fit stopped short): its pseudo-inverse has negative
  variances. The directions with negative curvature are named, and the intervals
  come from the Gauss-Newton form, which is positive semi-definite; each interval
  records the form it came from.
* An estimate on a bound: a symmetric Wald interval across the bound is not
  meaningful. It is flagged, and intervals are cut at the bounds.
* n <= K: σ² cannot be estimated. No error bars (NaN, null in fit.json); ``not_available`` says why.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..solve.curvature import jacobi_scale
from . import quantiles
from .residuals import residual_count, too_few
from .summary import Table, Tabular, estimates_table, stderr_text

# relative eigenvalue below which a direction counts as not identifiable; the
# Hessian is exact to ~1e-12 relative, so this is far above its rounding
FLAT = 1e-8


@dataclass(repr=False)
class Uncertainty(Tabular):
    """Standard errors, 95 % intervals and correlations of θ (natural units).

    ``forms`` names, per unknown, the Hessian its interval comes from ("hessian" or
    "gauss-newton"); ``at_bound`` maps an unknown that sits on a bound to "lower" or
    "upper"; ``cut`` maps an unknown whose interval was cut at a bound to the side.
    ``not_available``: why there are no error bars ("not available: 3 samples ..."), or None.
    """

    names: list[str]
    theta: np.ndarray
    covariance: np.ndarray
    stderr: np.ndarray
    ci95: np.ndarray  # (K, 2)
    correlation: np.ndarray
    sigma2: float
    dof: int
    kind: str
    warnings: list[str] = field(default_factory=list)
    forms: list[str] = field(default_factory=list)
    at_bound: dict[str, str] = field(default_factory=dict)
    cut: dict[str, str] = field(default_factory=dict)
    not_available: str | None = None
    lags: int | None = None  # a sandwich's Newey-West lags (0: independent samples)

    def as_dicts(self) -> dict:
        """stderr, ci95, correlation, the form of each interval and the unknowns at a
        bound, as JSON-ready dicts keyed by unknown."""
        return {
            "stderr": dict(zip(self.names, map(float, self.stderr), strict=True)),
            "ci95": {
                n: [float(a), float(b)] for n, (a, b) in zip(self.names, self.ci95, strict=True)
            },
            "correlation": self.correlation.tolist(),
            "interval_form": dict(zip(self.names, self.forms, strict=True)),
            "at_bound": dict(self.at_bound),
            "interval_cut_at_bound": dict(self.cut),
            "stderr_not_available": self.not_available,
        }

    def blocks(self) -> list:
        """What the numbers rest on, the estimates table, the strong correlations and
        the warnings (``print(u)``; a notebook shows the same as HTML)."""
        if self.lags is None:
            how = {"hessian": "exact Hessian", "gauss-newton": "Gauss-Newton form"}[self.kind]
        else:
            how = "sandwich, " + (
                f"Newey-West after prewhitening, {self.lags} lags"
                if self.kind == "robust"
                else "independent samples"
            )
        head = self.not_available or (
            f"standard errors ({how}): residual variance {self.sigma2:.4g} on {self.dof} "
            "degrees of freedom"
        )
        out: list = [head, estimates_table(self.names, self.theta, self)]
        i, j = np.triu_indices(len(self.names), 1)
        strong = [(a, b) for a, b in zip(i, j, strict=True) if abs(self.correlation[a, b]) >= 0.9]
        if strong:
            pairs = [
                f"{self.names[a]}-{self.names[b]} {self.correlation[a, b]:+.3f}" for a, b in strong
            ]
            out.append("correlations of 0.9 or more: " + ", ".join(pairs))
        return out + [f"warning: {w}" for w in self.warnings]

    def __repr__(self) -> str:
        se = ", ".join(
            f"{n}={stderr_text(float(s))}" for n, s in zip(self.names, self.stderr, strict=True)
        )
        return f"Uncertainty(kind={self.kind!r}, stderr={{{se}}}, dof={self.dof})"


def _directions(H: np.ndarray, names: list[str], keep) -> list[tuple[float, list[str]]]:
    """Eigen-directions of H in Jacobi-scaled units whose relative eigenvalue passes
    ``keep``: (relative eigenvalue, names of the unknowns that move together)."""
    s = jacobi_scale(H)
    Hs = H * np.outer(s, s)
    lam, V = np.linalg.eigh(0.5 * (Hs + Hs.T))
    top = max(np.abs(lam).max(), np.finfo(float).tiny)
    out = []
    for k in range(lam.size):
        if keep(lam[k] / top):
            v = V[:, k] / np.abs(V[:, k]).max()
            involved = [n for n, c in zip(names, v, strict=True) if abs(c) > 0.1]
            out.append((float(lam[k] / top), involved))
    return out


def flat_directions(
    H: np.ndarray, names: list[str], threshold: float = FLAT
) -> list[tuple[float, list[str]]]:
    """Directions along which the cost is (nearly) flat, in Jacobi-scaled units:
    (relative eigenvalue, names of the unknowns that move together)."""
    return _directions(H, names, lambda r: abs(r) <= threshold)


def negative_directions(
    H: np.ndarray, names: list[str], threshold: float = FLAT
) -> list[tuple[float, list[str]]]:
    """Directions of clearly negative curvature (relative eigenvalue below
    -threshold): the point is not a minimum along them."""
    return _directions(H, names, lambda r: r < -threshold)


SHOWN = 6  # flat directions named one by one in the identifiability line


def flat_line(flat: list[tuple[float, list[str]]]) -> str:
    """One line for every flat direction (``flat_directions``), the flattest first,
    each naming the unknowns it moves: a fit of many unknowns that the data do not
    pin down gave one warning per direction (11 for a two-tank filter)."""
    if len(flat) == 1:
        rel, involved = flat[0]
        return (
            f"not identifiable from these data: the cost is flat (relative curvature "
            f"{rel:.1e}) along a direction that moves {', '.join(involved)} together; "
            "fix one of them, add data that excites them differently, or reparametrise"
        )
    ranked = sorted(flat, key=lambda d: abs(d[0]))
    items = [
        f"({i}) {', '.join(inv)} (relative curvature {rel:.1e})"
        for i, (rel, inv) in enumerate(ranked[:SHOWN], 1)
    ]
    rest = ranked[SHOWN:]
    if rest:
        more = sorted({n for _, inv in rest for n in inv})
        items.append(f"and {len(rest)} more moving {', '.join(more)}")
    return (
        f"not identifiable from these data: the cost is flat along {len(flat)} directions, "
        f"the flattest first: {'; '.join(items)}. Their unknowns get unbounded error bars; "
        "fix one unknown of each direction, add data that excites them differently, or "
        "reparametrise"
    )


def _variances(H: np.ndarray, sigma2: float, names: list[str], unbounded, meat=None) -> tuple:
    """(covariance, variances) from the positive part of H in Jacobi-scaled units (relative
    eigenvalue above FLAT); the unknowns in ``unbounded`` directions get infinite variance.
    Scaled units, because on the raw Hessian rounding makes the smallest eigenvalue's sign
    meaningless and a relative cutoff would discard the poorly determined directions.
    With ``meat`` B (the scores' covariance, sandwich.py) the covariance is H⁻¹ B H⁻¹."""
    sc = jacobi_scale(H)
    lam, V = np.linalg.eigh(0.5 * (H + H.T) * np.outer(sc, sc))
    keep = lam > FLAT * max(np.abs(lam).max(), np.finfo(float).tiny)
    inv = (V[:, keep] / lam[keep]) @ V[:, keep].T * np.outer(sc, sc)
    cov = 2.0 * sigma2 * inv if meat is None else inv @ meat @ inv
    var = np.diag(cov).copy()
    for _, involved in unbounded:  # the positive part leaves these out: not zero, unbounded
        for name in involved:
            var[names.index(name)] = np.inf
    var[~(var > 0) & (sigma2 > 0)] = np.inf  # never print a 0 that is not one
    return cov, var


def on_bounds(problem, theta, grad=None, scale=None) -> tuple[dict[str, str], np.ndarray]:
    """({name: "lower" | "upper"} for the unknowns on a bound, and the mask of those
    the bound holds: the gradient pushes them outward, so the data alone would move
    them past it). "On" means within rounding: 1e-12 (scale + |θ|), the trust
    region's own test in scaled units (scale: the fit's typical magnitudes)."""
    lo, hi = np.asarray(problem.lower), np.asarray(problem.upper)
    typical = np.ones_like(theta) if scale is None else np.asarray(scale)
    near = 1e-12 * (typical + np.abs(theta))
    g = np.zeros_like(theta) if grad is None else np.asarray(grad)
    on, held = {}, np.zeros(theta.size, dtype=bool)
    for k, name in enumerate(problem.theta_names):
        if theta[k] - lo[k] <= near[k]:
            on[name], held[k] = "lower", g[k] > 0
        elif hi[k] - theta[k] <= near[k]:
            on[name], held[k] = "upper", g[k] < 0
    return on, held


def _bound_warning(problem, on: dict[str, str], held: np.ndarray) -> list[str]:
    if not on:
        return []
    names = problem.theta_names
    items = []
    for name, side in on.items():
        k = names.index(name)
        bound = problem.lower[k] if side == "lower" else problem.upper[k]
        pushed = " (the data pull it further)" if held[k] else ""
        items.append(f"{name} on its {side} bound {bound:g}{pushed}")
    return [
        "estimates on a bound: " + "; ".join(items) + ". Their intervals are one-sided and "
        "only indicative (the Wald approximation does not hold at a bound); check whether "
        "each bound is physical or the model is missing something"
    ]


def _cut(problem, ci: np.ndarray) -> dict[str, str]:
    """Cut the intervals at the bounds, in place; returns {name: side(s) cut}."""
    lo, hi = np.asarray(problem.lower), np.asarray(problem.upper)
    cut = {}
    for k, name in enumerate(problem.theta_names):
        sides = [s for s, out in (("lower", ci[k, 0] < lo[k]), ("upper", ci[k, 1] > hi[k])) if out]
        if sides:
            cut[name] = "both" if len(sides) == 2 else sides[0]
            ci[k] = np.clip(ci[k], lo[k], hi[k])
    return cut


def _indefinite(H, names, held, kind, gauss_newton) -> tuple:
    """Directions of negative curvature among the unknowns that no bound holds (at a
    bound the cost may curve down along the held unknown: that is still a minimum).
    Returns (H to use, form, unbounded directions, warnings)."""
    free = ~held
    free_names = [n for n, f in zip(names, free, strict=True) if f]
    negative = negative_directions(H[np.ix_(free, free)], free_names) if free.any() else []
    if not negative:
        return H, kind, [], []
    where = "; ".join(
        f"a direction that moves {', '.join(inv)} (relative curvature {rel:.1e})"
        for rel, inv in negative
    )
    if kind == "hessian" and gauss_newton is not None:
        H = gauss_newton() if callable(gauss_newton) else gauss_newton
        kind, unbounded = "gauss-newton", []
        then = (
            "the standard errors and intervals below come from the Gauss-Newton form "
            "(the expected information) instead"
        )
    else:
        unbounded = negative
        then = "the unknowns in those directions get unbounded intervals"
    msg = (
        f"the Hessian is indefinite here: the cost curves downward along {where}, so "
        f"this is not a strict local minimum; {then}"
    )
    return H, kind, unbounded, [msg]


def _prior_warning(problem, H: np.ndarray, names: list[str]) -> list[str]:
    """Name the unknowns whose curvature comes mostly from their prior, not the data."""
    prior = problem.prior_curvature
    out = []
    for i in np.nonzero(prior)[0]:
        share = prior[i] / H[i, i] if H[i, i] > 0 else 1.0
        if share > 0.5:
            out.append(
                f"{names[i]} is determined more by its prior than by the data (the prior "
                f"gives {min(share, 1.0):.0%} of its curvature): the data say little about it"
            )
    return out


def uncertainty(
    problem,
    theta: np.ndarray,
    J: float,
    H: np.ndarray,
    kind: str = "hessian",
    gauss_newton=None,
    grad=None,
    scale=None,
    meat=None,
    refused: str | None = None,
) -> Uncertainty:
    """Uncertainty of θ at an optimum with cost J, gradient ``grad`` and Hessian H
    (exact or Gauss-Newton, as ``kind`` says). ``gauss_newton``: the Gauss-Newton
    Hessian (or a function returning it) to fall back on where H is indefinite, and
    for the unknowns that a bound holds. ``meat``: the scores' covariance for the
    sandwich form H⁻¹ B H⁻¹ (sandwich.py) in place of 2σ² H⁻¹. ``refused``: why there
    are no error bars although there are samples enough ("not available: ...")."""
    names = problem.theta_names
    K = theta.size
    n = residual_count(problem)
    dof = max(n - K, 1)
    missing = too_few(n, K) or refused  # then no σ², and no number derived from it
    sigma2 = np.nan if missing else (J - problem.prior_cost(theta)) / dof  # data's share
    if problem.loss.likelihood and not missing:  # J = −2 log L: cov = 2 H⁻¹
        sigma2 = 1.0
    on, held = on_bounds(problem, theta, grad, scale)
    H_used, form, unbounded, warnings = _indefinite(H, names, held, kind, gauss_newton)
    flat = flat_directions(H_used, names)
    warnings += [flat_line(flat)] if flat else []
    cov, var = _variances(H_used, sigma2, names, flat + unbounded, meat)
    forms = [form] * K
    if held.any() and form == "hessian" and gauss_newton is not None:
        # the exact Hessian along a held unknown describes the cost beyond the bound
        H_gn = gauss_newton() if callable(gauss_newton) else gauss_newton
        var[held] = _variances(H_gn, sigma2, names, flat_directions(H_gn, names), meat)[1][held]
        forms = ["gauss-newton" if h else form for h in held]
    se = np.full(K, np.nan) if missing else np.sqrt(var)
    q = quantiles.student_t(dof, 0.975)
    ci = np.stack([theta - q * se, theta + q * se], axis=1)
    cut = _cut(problem, ci)
    with np.errstate(divide="ignore", invalid="ignore"):
        corr = cov / np.outer(se, se)
    corr = np.where(np.isfinite(corr), corr, np.nan)
    np.fill_diagonal(corr, 1.0)
    warnings += _bound_warning(problem, on, held) + _prior_warning(problem, H_used, names)
    warnings += [f"error bars {missing}"] if missing else []
    return Uncertainty(
        names, theta, cov, se, ci, corr, float(sigma2), dof, kind, warnings, forms, on, cut, missing
    )


@dataclass(repr=False)
class Information(Tabular):
    """Observed against expected information at an estimate.

    The observed information is the exact Hessian of J (transition tensors included);
    the expected information is its Gauss-Newton form 2 JᵀWJ (what the Fisher
    information would be at the truth, and all a first-order method has). Where the
    residuals are large or the model strongly nonlinear they differ, and the standard
    errors with them.

    stderr_observed, stderr_expected : (K,) standard errors from each.
    condition_observed, condition_expected : condition numbers of each in
        Jacobi-scaled (unit-free) form; inf where not positive definite.
    weakest : the least determined combination of unknowns (the eigenvector of the
        smallest eigenvalue of the scaled observed information), {name: component},
        largest component 1; ``describe()`` says it in words.
    """

    names: list[str]
    stderr_observed: np.ndarray
    stderr_expected: np.ndarray
    condition_observed: float
    condition_expected: float
    weakest: dict[str, float]

    def describe(self) -> str:
        """The comparison in one or two sentences."""
        parts = [f"{n} {c:+.2f}" for n, c in self.weakest.items()]
        moves = "alone" if len(parts) == 1 else "together"
        with np.errstate(divide="ignore", invalid="ignore"):  # inf/inf: a flat direction
            ratio = self.stderr_observed / self.stderr_expected
        finite = ratio[np.isfinite(ratio)]
        spread = (
            f"observed/expected standard errors {finite.min():.2f} to {finite.max():.2f}"
            if finite.size
            else "no finite standard error"
        )
        return (
            f"condition number {self.condition_observed:.2e} (observed information, exact "
            f"Hessian) against {self.condition_expected:.2e} (expected, Gauss-Newton); "
            f"{spread}; the least determined direction moves {', '.join(parts)} {moves}"
        )

    def as_dict(self) -> dict:
        return {
            "stderr_observed": dict(zip(self.names, self.stderr_observed.tolist(), strict=True)),
            "stderr_expected": dict(zip(self.names, self.stderr_expected.tolist(), strict=True)),
            "condition_observed": self.condition_observed,
            "condition_expected": self.condition_expected,
            "weakest_direction": dict(self.weakest),
            "text": self.describe(),
        }

    def blocks(self) -> list:
        """The standard errors from each side per unknown, then ``describe()``."""
        rows = []
        for n, a, b in zip(self.names, self.stderr_observed, self.stderr_expected, strict=True):
            with np.errstate(divide="ignore", invalid="ignore"):  # inf/inf: a flat direction
                ratio = float(a / b)
            rows.append(
                [
                    n,
                    stderr_text(float(a)),
                    stderr_text(float(b)),
                    f"{ratio:.3f}" if np.isfinite(ratio) else "–",
                ]
            )
        header = ["unknown", "std. error (observed)", "std. error (expected)", "observed/expected"]
        return [Table("observed and expected information", header, rows), self.describe()]

    def __repr__(self) -> str:
        return (
            f"Information(condition_observed={self.condition_observed:.3g}, "
            f"condition_expected={self.condition_expected:.3g}, "
            f"weakest={ {n: round(c, 3) for n, c in self.weakest.items()} })"
        )


def _condition(H: np.ndarray) -> float:
    s = jacobi_scale(H)
    lam = np.linalg.eigvalsh(0.5 * (H + H.T) * np.outer(s, s))
    return float(lam[-1] / lam[0]) if lam[0] > 0 else np.inf


def information(
    observed: Uncertainty, expected: Uncertainty, H: np.ndarray, H_gn: np.ndarray
) -> Information:
    """Compare the uncertainty from the exact Hessian H with its Gauss-Newton form H_gn's."""
    s = jacobi_scale(H)
    _, V = np.linalg.eigh(0.5 * (H + H.T) * np.outer(s, s))
    v = V[:, 0] / V[np.abs(V[:, 0]).argmax(), 0]
    weakest = {n: float(c) for n, c in zip(observed.names, v, strict=True) if abs(c) > 0.1}
    return Information(
        observed.names,
        observed.stderr,
        expected.stderr,
        _condition(H),
        _condition(H_gn),
        weakest,
    )
