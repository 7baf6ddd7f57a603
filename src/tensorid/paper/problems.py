"""The paper's two identification problems on the bundled measurements.

Silverbox: m ÿ + d ẏ + (a + b y²) y = u, states (y, ẏ), θ = (ẏ(t0), m, d, a, b),
y(t0) the first measured sample. Two-tank: x1' = -p1 √x1 + p2 u,
x2' = -p3 √x2 + p4 √x1, y = x2, initial levels from the first sample.
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np

from .. import datasets
from ..engine.assembly.problem import Problem
from ..engine.modelling.model import Model
from ..functions import safe_sqrt

# the paper's initial guesses and reported estimates
SILVERBOX_GUESS = {"m": 5.1025e-6, "d": 2.15e-4, "a": 0.968, "b": 3.976}
SILVERBOX_PAPER = {"m": 5.271e-6, "d": 2.1491e-4, "a": 0.9675, "b": 3.975}
SILVERBOX_PAPER_VDOT0 = 5.1112e-9
SILVERBOX_PAPER_VAL_GOF = 0.96258343
TWO_TANK_GUESS = {"p1": 0.04, "p2": 0.02, "p3": 0.02, "p4": 0.04}
TWO_TANK_PAPER = {"p1": 0.0418, "p2": 0.0235, "p3": 0.0221, "p4": 0.0590}
TWO_TANK_PAPER_GOF = 0.79088


def _silverbox_rhs(x, p, u):
    m, d, a, b = p[0], p[1], p[2], p[3]
    return jnp.stack([x[1], (u[0] - d * x[1] - a * x[0] - b * x[0] ** 3) / m])


def _silverbox_offset_rhs(x, p, u):
    m, d, a, b, u0 = p[0], p[1], p[2], p[3], p[4]
    return jnp.stack([x[1], (u[0] - u0 - d * x[1] - a * x[0] - b * x[0] ** 3) / m])


def _first_state(x, p):
    return x[:1]


def silverbox_model() -> Model:
    """The paper's Silverbox model (a Duffing oscillator)."""
    return Model(
        rhs=_silverbox_rhs,
        output=_first_state,
        states=["y", "ydot"],
        params=["m", "d", "a", "b"],
        inputs=["u"],
        outputs=["y"],
        name="silverbox",
    )


def silverbox_offset_model() -> Model:
    """Beyond the paper: the input V1 carries a DC offset (~6.2 mV); estimate it as u0."""
    return Model(
        rhs=_silverbox_offset_rhs,
        output=_first_state,
        states=["y", "ydot"],
        params=["m", "d", "a", "b", "u0"],
        inputs=["u"],
        outputs=["y"],
        name="silverbox-offset",
    )


def silverbox_problem(p0=None, substeps: int = 4, offset: bool = False, data=None, **kw) -> Problem:
    """The paper's training problem (samples [10584:11608], or the Experiment
    ``data``, with y(t0) its first sample); with ``offset`` the variant with an input
    offset and y(t0) free as well."""
    data = datasets.silverbox_train() if data is None else data
    x0 = [float(data.measured[0, 0]), 0.0]
    if offset:
        p0 = dict(SILVERBOX_GUESS, u0=0.0) if p0 is None else p0
        return Problem(
            silverbox_offset_model(),
            data,
            p0=p0,
            x0=x0,
            free_x0=["y", "ydot"],
            substeps=substeps,
            **kw,
        )
    return Problem(
        silverbox_model(),
        data,
        p0=SILVERBOX_GUESS if p0 is None else p0,
        x0=x0,
        free_x0=["ydot"],
        substeps=substeps,
        **kw,
    )


def _two_tank_rhs(x, p, u):
    s1, s2 = safe_sqrt(x[0]), safe_sqrt(x[1])
    return jnp.stack([-p[0] * s1 + p[1] * u[0], -p[2] * s2 + p[3] * s1])


def _second_state(x, p):
    return x[1:]


def two_tank_model() -> Model:
    """The paper's two-tank model; √ is safe_sqrt, equal to √ above 1e-6."""
    return Model(
        rhs=_two_tank_rhs,
        output=_second_state,
        states=["x1", "x2"],
        params=["p1", "p2", "p3", "p4"],
        inputs=["u"],
        outputs=["y"],
        name="two-tank",
    )


def two_tank_problem(p0=None, substeps: int = 4, samples: int = 501, **kw) -> Problem:
    """The paper's two-tank problem: the first 501 samples, initial levels measured."""
    return Problem(
        two_tank_model(),
        datasets.two_tank(samples),
        p0=TWO_TANK_GUESS if p0 is None else p0,
        x0=datasets.two_tank_levels(samples)[0],
        substeps=substeps,
        **kw,
    )


# -- a problem of our own: where single shooting falls into local minima ---------------
LOTKA_VOLTERRA_TRUE = {"a": 1.0, "b": 0.5, "c": 1.0, "d": 0.3}
LOTKA_VOLTERRA_X0 = {"prey": 2.0, "pred": 1.0}


def _lotka_volterra_rhs(x, p, u):
    return jnp.stack([p[0] * x[0] - p[1] * x[0] * x[1], -p[2] * x[1] + p[3] * x[0] * x[1]])


def lotka_volterra_model() -> Model:
    """prey' = a·prey − b·prey·pred, pred' = −c·pred + d·prey·pred; both measured."""
    return Model(
        rhs=_lotka_volterra_rhs,
        states=["prey", "pred"],
        params=["a", "b", "c", "d"],
        name="lotka-volterra",
    )


def lotka_volterra_problem(
    p0=None, samples: int = 601, noise: float = 0.05, seed: int = 1, **kw
) -> Problem:
    """A synthetic Lotka–Volterra record: t ∈ [0, 60] (about nine periods), both
    populations measured with ``noise`` relative Gaussian noise (seeded), the initial
    populations free; positive parameters (bounded below by 1e-3)."""
    from ..engine.assembly.simulate import simulate
    from ..engine.modelling.data import Experiment

    t = np.linspace(0.0, 60.0, samples)
    u = np.zeros((samples, 0))
    model = lotka_volterra_model()
    clean = simulate(model, LOTKA_VOLTERRA_TRUE, LOTKA_VOLTERRA_X0, Experiment(t, u)).y
    rng = np.random.default_rng(seed)
    y = clean * (1.0 + noise * rng.standard_normal(clean.shape))
    kw.setdefault("bounds", {n: (1e-3, None) for n in LOTKA_VOLTERRA_TRUE})
    return Problem(
        model,
        Experiment(t, u, y, name="lotka-volterra"),
        p0=LOTKA_VOLTERRA_TRUE if p0 is None else p0,
        x0=LOTKA_VOLTERRA_X0,
        free_x0=["prey", "pred"],
        **kw,
    )


def mass_chain_model(n: int) -> Model:
    """n masses in a line (N = 2n states), the first forced by u, joined to each
    other and to a wall by hardening springs k_i (δ + δ³) and dampers d_i; a shared
    mass m. K = 2n + 1 parameters; outputs: every position."""
    if not (isinstance(n, int) and n >= 1):
        raise ValueError(f"n must be a whole number of masses >= 1, got {n!r}")

    def rhs(x, p, u):
        m, k, d = p[0], p[1 : n + 1], p[n + 1 :]
        q, v = x[:n], x[n:]
        dq = jnp.diff(q, prepend=0.0)  # each link's stretch (wall at 0 on the left)
        link = k * (dq + dq**3) + d * jnp.diff(v, prepend=0.0)
        force = jnp.append(link[1:], 0.0) - link
        return jnp.concatenate([v, force.at[0].add(u[0]) / m])

    return Model(
        rhs=rhs,
        output=lambda x, p: x[:n],
        states=[f"q{i + 1}" for i in range(n)] + [f"v{i + 1}" for i in range(n)],
        params=["m"] + [f"k{i + 1}" for i in range(n)] + [f"d{i + 1}" for i in range(n)],
        inputs=["u"],
        outputs=[f"q{i + 1}" for i in range(n)],
        name=f"mass-chain-{n}",
    )


def mass_chain_truth(n: int) -> np.ndarray:
    """The parameters the chain's records are simulated with: m = 1, stiffness 2 to
    3 and damping 0.1 to 0.2 along the chain."""
    ramp = np.linspace(0.0, 1.0, n)
    return np.concatenate([[1.0], 2.0 + ramp, 0.1 + 0.1 * ramp])


def mass_chain_problem(
    n: int = 5, samples: int = 2000, noise: float = 0.01, seed: int = 0, p0=None, **kw
) -> Problem:
    """A synthetic record of the chain of ``n`` masses: a multisine force on the first
    (Ts = 0.05 s), every position measured with Gaussian noise of ``noise`` times its
    RMS (seeded), starting at rest (x0 known); positive parameters (bounded below by
    1e-3)."""
    from ..engine.assembly.simulate import simulate
    from ..engine.modelling.data import Experiment

    model = mass_chain_model(n)
    t = np.arange(samples) * 0.05
    u = (np.sin(0.31 * t) + 0.7 * np.sin(0.83 * t + 1.0) + 0.5 * np.sin(1.9 * t + 2.0))[:, None]
    truth = mass_chain_truth(n)
    clean = simulate(model, truth, np.zeros(2 * n), Experiment(t, u)).y
    rng = np.random.default_rng(seed)
    y = clean + noise * np.sqrt(np.mean(clean**2, axis=0)) * rng.standard_normal(clean.shape)
    kw.setdefault("bounds", {name: (1e-3, None) for name in model.params})
    data = Experiment(t, u, y, name=f"mass-chain-{n}")
    return Problem(model, data, p0=truth if p0 is None else p0, **kw)
