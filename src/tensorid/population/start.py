"""Where a population's outer fit starts: ψ0 from the Problem's p0 and ω starts, the
residual error from the typical unit's residuals there; and, for ``starts`` > 1,
other starts drawn around it (the typical values and shared parameters as a single
fit's starts are, solve/multistart.draw_starts, inside their bounds; each ω within a
factor 2 of its start, log-uniformly)."""

from __future__ import annotations

import numpy as np

from ..solve.multistart import draw_starts


def start_point(obj, typical=None, omega=None) -> np.ndarray:
    """ψ0: the typical values from p0 (or ``typical``, {name: value}), ω as given (or
    ``omega``), the shared parameters from p0 (or ``typical``), and each output's
    residual error from the residuals of the typical unit there (each error model's
    own start: errors.py)."""
    pr, m = obj.problem, obj.problem.model
    given = {n: pr.p0[m.params.index(n)] for n in m.params} | (typical or {})
    if obj.joint:  # the shared parameters alone
        return np.array([given[n] for n in obj.shared], dtype=float)
    random = obj.pop[: obj.qp]
    omegas = dict(pr.population) | (omega or {})
    mu = [np.log(given[n]) for n in random]
    logw = [np.log(omegas[n]) for n in random] + [0.0] * (obj.n_omega - obj.qp)
    s = [given[n] for n in obj.shared]
    noise = len(obj.error.terms)
    psi = np.array(mu + logw + s + [0.0] * noise, dtype=float)
    u = obj.units
    yhat = np.asarray(obj.predict_all(psi, obj.start_etas()))
    _zero_predictions(obj, yhat)
    psi[obj.first_shared + obj.ns :] = obj.error.log_start(u.y, yhat, u.mask)
    return psi


def _zero_predictions(obj, yhat: np.ndarray) -> None:
    """A proportional error alone has no variance where the prediction is 0 (a
    concentration before the dose arrives), an exponential one no logarithm: one line
    naming the first such sample."""
    u, outs = obj.units, obj.problem.model.outputs
    for g, e in enumerate(obj.error.models):
        if not e.positive:
            continue
        low = yhat[..., g] <= 0 if e.log_scale else yhat[..., g] == 0
        zero = (u.mask[..., g] > 0) & low
        if zero.any():
            i, h = np.argwhere(zero)[0]
            what = "no logarithm" if e.log_scale else "no variance"
            raise ValueError(
                f"residual_error {e.name!r} for {outs[g]}: unit {u.names[i]}'s "
                f"prediction at t = {u.t[i, h]:g} is {yhat[i, h, g]:g}, where "
                f"{'an' if e.name[0] in 'aeiou' else 'a'} {e.name} error has {what}; "
                f"use 'combined' (σ² = a² + b²ŷ²) for {outs[g]}"
            )


def drawn_starts(obj, n: int, spread=None, sampling: str = "lhs", seed: int = 0) -> list:
    """``n`` starts of ψ, the first :func:`start_point` itself."""
    pr, m = obj.problem, obj.problem.model
    names = [*obj.pop[: obj.qp], *obj.shared]
    theta0 = np.array([pr.p0[m.params.index(k)] for k in names], dtype=float)
    at = [pr.theta_names.index(k) for k in names]
    lower = pr.lower[at].copy()
    typical = np.arange(len(names)) < obj.qp  # > 0 (ψ holds their logarithm): drawn
    lower[typical] = np.maximum(lower[typical], 1e-6 * theta0[typical])  # log-uniformly
    drawn = draw_starts(theta0, lower, pr.upper[at], n, spread=spread, sampling=sampling,
                        seed=seed)  # fmt: skip
    factor = np.exp(np.random.default_rng(seed + 1).uniform(-np.log(2), np.log(2),
                                                            (n, obj.qp)))  # fmt: skip
    out = [start_point(obj)]
    for k in range(1, n):
        omega = {q: pr.population[q] * factor[k, j] for j, q in enumerate(obj.pop[: obj.qp])}
        out.append(start_point(obj, dict(zip(names, drawn[k], strict=True)), omega))
    return out
