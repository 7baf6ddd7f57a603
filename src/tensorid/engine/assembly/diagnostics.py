"""Plain-language accounts of a simulation that failed: where, what, and what to try.

The cause comes from the integrator's own status (``Simulation.status``), not from
a guess at what the scheme might have done.
"""

from __future__ import annotations

import numpy as np

from ..schemes.integrators import AdaptiveRungeKutta
from ..schemes.status import Status
from .simulate import Simulation

_DOMAIN = (
    "a state or parameter outside the model's domain (square root or log of a "
    "negative value, division by a parameter near 0): add bounds, or write the "
    "model with tensorid.functions.safe_sqrt"
)
_DIVERGE = "dynamics that really diverge at these values: start closer"
# remedies in both spellings: the same words reach a script and the command line
_IMPLICIT = "use the implicit scheme sdirk3 (scheme='sdirk3'; on the command line --scheme sdirk3)"
_SUBSTEPS = "raise substeps (on the command line --substeps)"


def _hints(sim: Simulation, scheme) -> list[str]:
    """Likely causes and remedies, by how the integrator failed."""
    if sim.status is Status.STEP_LIMIT:
        limit = getattr(scheme, "max_steps", "its limit of")
        return [
            f"a stiff model: the adaptive scheme {scheme.name!r} gave up after "
            f"{limit} steps within one sample; {_IMPLICIT}",
            _DOMAIN,
        ]
    if sim.status is Status.STEP_UNDERFLOW:
        return [
            "the error-controlled step size shrank to nothing: a singularity, a state "
            f"leaving the model's domain, or a stiff model: {_IMPLICIT}",
            _DOMAIN,
        ]
    if sim.status is Status.NEWTON_FAILED:
        return [
            f"an implicit stage's Newton iteration did not converge: {_SUBSTEPS}",
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
            f"a stiff model, or a step too large for an explicit scheme: {_SUBSTEPS}, or "
            f"{_IMPLICIT}"
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
    """None when every experiment of ``problem`` simulates finitely at θ (and, with
    the extended Kalman filter, its innovation covariances stay positive definite);
    otherwise where it first fails and what to try."""
    values = ", ".join(f"{n}={v:.4g}" for n, v in zip(problem.theta_names, theta, strict=True))
    for e, sim in enumerate(problem.simulate(theta)):
        if sim.status is Status.OK:
            continue
        return f"the simulation is not finite at {values}: " + describe_failure(
            sim, problem.scheme, _where(problem, e)
        )
    if problem.sweeps.predictor.update is not None:
        why = _filter_failure(problem, theta)
        return None if why is None else f"the filter fails at {values}: {why}"
    return None


def _where(problem, e: int) -> str:
    name = problem.experiments[e].name
    return f"experiment {e}" + (f" ({name})" if name else "")


def _noise_lost(problem, theta: np.ndarray, S: np.ndarray) -> str | None:
    """Why S has no measurement part, where that is why: an output's σ_e² underflows
    in double precision, or is lost in rounding beside S (the filter then follows the
    output exactly, and S is the state covariance's alone, singular where the states
    are known); None otherwise (the states' region is then the likely cause)."""
    index = getattr(problem.sweeps.predictor, "measurement", ())
    if not index:
        return None
    p = np.asarray(problem.unpack(theta)[0])
    with np.errstate(over="ignore", under="ignore", invalid="ignore"):
        scale = np.abs(np.diag(S)) if np.isfinite(S).all() else np.zeros(len(index))
        for j, i in enumerate(index):
            o, var = problem.model.outputs[j], float(np.exp(2.0 * p[i]))
            if var >= np.finfo(float).tiny and not var < 1e-16 * scale[j]:
                continue
            how = "underflows to 0" if var == 0 else f"is {var:.2g}, lost in rounding"
            return (
                f"σ_e({o}) = e^{p[i]:.4g}: its variance {how} in double precision, so the "
                f"innovation covariance has no measurement part and the filter follows {o} "
                f"exactly. Keep it off that floor: fix it at the sensor's noise (--fix "
                f"log_sigma_e_{o}=log σ), or bound it (--bounds log_sigma_e_{o}=-30,5)"
            )
    return None


def _filter_failure(problem, theta: np.ndarray) -> str | None:
    """Where the extended Kalman filter's innovation covariance S first stops being
    positive definite (the likelihood's log det S and S⁻¹ then mean nothing), with
    the state estimates there; None where it never does."""
    import jax.numpy as jnp

    m, sw = problem.model, problem.sweeps
    for e, (t, u, y) in enumerate(problem.arrays):
        local = jnp.asarray(theta[problem._slices(e)])
        x0, p = jnp.asarray(problem.x0[e]), jnp.asarray(problem.p0)
        z, pis = (np.asarray(a) for a in sw.predictions(local, x0, p, t, u, y))
        S = pis[:, m.S :].reshape(-1, m.S, m.S)
        with np.errstate(invalid="ignore"):
            ok = np.isfinite(S).all(axis=(1, 2))
            try:
                ok[ok] = np.linalg.eigvalsh(S[ok]).min(axis=1) > 0
            except np.linalg.LinAlgError:  # a diagnosis never fails: then name the first
                ok[:] = False
        if ok.all():
            continue
        h = int(np.argmin(ok))
        lost = _noise_lost(problem, theta, S[h])
        if lost:
            return (
                f"in {_where(problem, e)}, its innovation covariance is not positive "
                f"definite at t = {float(t[h]):.6g} (sample {h} of {len(t)}), where {lost}"
            )
        states = ", ".join(f"{n}={v:.4g}" for n, v in zip(m.states, z[h, : m.N], strict=True))
        return (
            f"in {_where(problem, e)}, its innovation covariance is not positive definite "
            f"at t = {float(t[h]):.6g} (sample {h} of {len(t)}), with the state estimates "
            f"at {states}. The filter's covariance lost positive-definiteness, most often "
            "where its state estimates left the region the model was written for (a level "
            "below zero). Likely causes: process noise only on states the outputs barely "
            "observe (give the measured states process noise too, or start it smaller); "
            "a step too large for the linearised covariance (raise substeps)."
        )
    return None
