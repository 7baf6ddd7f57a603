"""Plain-language accounts of a simulation that failed: where, what, and what to try.

The cause comes from the integrator's own status (``Simulation.status``), not from
a guess at what the scheme might have done.
"""

from __future__ import annotations

import numpy as np

from .integrators import AdaptiveRungeKutta
from .simulate import Simulation
from .status import Status

_DOMAIN = (
    "a state or parameter outside the model's domain (square root or log of a "
    "negative value, division by a parameter near 0): add bounds, or write the "
    "model with tensorid.functions.safe_sqrt"
)
_DIVERGE = "dynamics that really diverge at these values: start closer"


def _hints(sim: Simulation, scheme) -> list[str]:
    """Likely causes and remedies, by how the integrator failed."""
    if sim.status is Status.STEP_LIMIT:
        limit = getattr(scheme, "max_steps", "its limit of")
        return [
            f"a stiff model: the adaptive scheme {scheme.name!r} gave up after "
            f"{limit} steps within one sample; use scheme='sdirk3'",
            _DOMAIN,
        ]
    if sim.status is Status.STEP_UNDERFLOW:
        return [
            "the error-controlled step size shrank to nothing: a singularity, a state "
            "leaving the model's domain, or a stiff model (use scheme='sdirk3')",
            _DOMAIN,
        ]
    if sim.status is Status.NEWTON_FAILED:
        return [
            "an implicit stage's Newton iteration did not converge: raise substeps",
            _DOMAIN,
            _DIVERGE,
        ]
    if sim.status is Status.NONFINITE_OUTPUT:
        return [
            "the output function is not finite at these states (a division or "
            "square root in the output map)",
            _DOMAIN,
        ]
    hints = [_DOMAIN]
    if isinstance(scheme, AdaptiveRungeKutta):
        hints.append("a singularity that the adaptive steps ran into")
    else:
        hints.append(
            "a stiff model, or a step too large for an explicit scheme: raise "
            "substeps, or use scheme='sdirk3'"
        )
    return hints + [_DIVERGE]


def describe_failure(sim: Simulation, scheme, where: str) -> str:
    """Where and why ``sim`` (which is not finite) failed, with remedies."""
    m = sim.model
    h = sim.failed_at if sim.failed_at is not None else 0
    if sim.status is Status.NONFINITE_OUTPUT:
        outs = [n for n, ok in zip(m.outputs, np.isfinite(sim.y[h]), strict=True) if not ok]
        what = f"output(s) {outs} are not finite although the states are"
    else:
        states = [n for n, ok in zip(m.states, np.isfinite(sim.x[h]), strict=True) if not ok]
        what = f"state(s) {states} are not finite"
        if sim.status is not Status.NONFINITE_STATE:
            what += f" ({sim.status.message})"
    last = (
        "from the initial state"
        if h == 0
        else "after "
        + ", ".join(f"{n}={v:.4g}" for n, v in zip(m.states, sim.x[h - 1], strict=True))
    )
    return (
        f"in {where}, {what} at t = {sim.t[h]:.6g} (sample {h} of {sim.t.size}), {last}. "
        "Likely causes: " + "; ".join(_hints(sim, scheme)) + "."
    )


def diagnose(problem, theta: np.ndarray) -> str | None:
    """None when every experiment of ``problem`` simulates finitely at θ; otherwise
    where the simulation first fails and what to try."""
    values = ", ".join(f"{n}={v:.4g}" for n, v in zip(problem.theta_names, theta, strict=True))
    for e, sim in enumerate(problem.simulate(theta)):
        if sim.status is Status.OK:
            continue
        name = sim.experiment.name
        where = f"experiment {e}" + (f" ({name})" if name else "")
        return f"the simulation is not finite at {values}: " + describe_failure(
            sim, problem.scheme, where
        )
    return None
