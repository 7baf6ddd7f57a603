"""Where a population's estimates reach the edge of what the data say: a direction of
ψ in which the objective does not change at all (a parameter with no effect on the
outputs), and a random effect whose ω collapses to 0 (the data show no unit-to-unit
variation in that parameter beyond the residual error). The first is held where it
started, without error bars; the second is dropped (the parameter shared by every
unit) and the fit repeated from where it had got, rather than creeping along
log ω → −∞ for tens of slow iterations with an SE printed beside ω = 0."""

from __future__ import annotations

import copy

import numpy as np

# ω below this (0.1 % variation on the log scale) with the objective still falling as
# it shrinks: collapsing to 0, not a spread the data could measure
OMEGA_FLOOR = 1e-3


def bounds(obj) -> tuple[np.ndarray, np.ndarray]:
    """ψ's bounds: a shared parameter's own, a typical value's on the log scale (its
    parameter's where positive), none on ω and the residual error."""
    pr = obj.problem
    lo, hi = np.full(obj.size, -np.inf), np.full(obj.size, np.inf)
    first = obj.first_shared
    for j, n in enumerate(obj.shared):
        i = pr.theta_names.index(n)
        lo[first + j], hi[first + j] = pr.lower[i], pr.upper[i]
    for k, n in enumerate(obj.pop[: obj.qp]):
        i = pr.theta_names.index(n)
        lo[k] = np.log(pr.lower[i]) if pr.lower[i] > 0 else -np.inf
        hi[k] = np.log(pr.upper[i]) if np.isfinite(pr.upper[i]) and pr.upper[i] > 0 else np.inf
    return lo, hi


class Collapsed(Exception):  # noqa: N818 (an outcome of the fit, not an error)
    """Raised by the outer loop's evaluation: the random effects ``names`` collapse to
    0 at ψ ``psi`` (η̂ ``etas``), the objective ``value`` there."""

    def __init__(self, names: list[str], psi: np.ndarray, etas: np.ndarray, value: float):
        super().__init__(names)
        self.names, self.psi, self.etas, self.value = names, psi, etas, value


def collapsing(obj, psi, grad) -> list[str]:
    """The random effects (diagonal Ω) whose ω is below OMEGA_FLOOR with the gradient
    still pushing it down, where dropping them leaves a fleet to fit."""
    if obj.full or obj.joint or not obj.qp:
        return []
    k = np.arange(obj.qp)
    low = (psi[obj.qp + k] < np.log(OMEGA_FLOOR)) & (grad[obj.qp + k] > 0)
    names = [obj.pop[i] for i in np.flatnonzero(low)]
    others = obj.qp - len(names) + len(obj.problem.individual or [])
    return names if names and others > 0 else []


def without(obj, names: list[str], psi: np.ndarray):
    """``obj``'s problem with the random effects ``names`` dropped (those parameters
    shared), every start at ψ's values: the typical values and ω of the others, the
    shared values, and the dropped ones at their typical values."""
    problem = obj.problem
    new = copy.copy(problem)
    m = problem.model
    p0 = np.array(problem.p0, dtype=float)
    for k, n in enumerate(obj.pop[: obj.qp]):
        p0[m.params.index(n)] = float(np.exp(psi[k]))
    for j, n in enumerate(obj.shared):
        p0[m.params.index(n)] = float(psi[obj.first_shared + j])
    new.p0 = p0
    new.population = {
        n: float(np.exp(psi[obj.qp + k])) for k, n in enumerate(obj.pop[: obj.qp]) if n not in names
    }
    return new


def collapse_note(names: list[str], before: float, after: float) -> str:
    which = ", ".join(names)
    return (
        f"the random effect of {which} collapsed to 0 (ω below {OMEGA_FLOOR:g} and still "
        f"falling): the data show no unit-to-unit variation in {which} beyond the "
        f"residual error, so {which} was made shared and the fit repeated from where it "
        f"had got (−2 log L {before:.4f} → {after:.4f}); drop {which} from population"
    )


def flat_directions(grad, H) -> np.ndarray:
    """The directions of ψ in which the objective does not change at all, its gradient
    and its row of H zero to rounding (a parameter that has no effect on the outputs:
    it cancels in them, or its state stays 0): (size,) bool."""
    scale = float(np.max(np.abs(np.diag(H)), initial=0.0))
    tiny = 1e-10 * (scale + float(np.max(np.abs(grad), initial=0.0)))
    return (np.max(np.abs(H), axis=1, initial=0.0) <= tiny) & (np.abs(grad) <= tiny) & (scale > 0)


def no_effect_note(obj, flat: np.ndarray) -> str | None:
    """One line naming the parameters whose every direction of ψ is flat."""
    names = []
    for k in np.flatnonzero(flat):
        if k < 2 * obj.qp:  # a typical value or its ω
            n = obj.pop[k % obj.qp]
        elif obj.first_shared <= k < obj.first_shared + obj.ns:
            n = obj.shared[k - obj.first_shared]
        else:
            n = obj.names[k]
        names += [n] if n not in names else []
    if not names:
        return None
    return (
        f"{', '.join(names)} {'has' if len(names) == 1 else 'have'} no effect on the outputs "
        "at the estimates (the objective does not change with it at all: it cancels in the "
        "outputs, or what it acts on stays 0); it was held where it started and has no "
        "error bars: fix it, or drop it from the model"
    )
