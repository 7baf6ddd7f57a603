"""A fleet of 200 mass-spring-damper units of one design: each unit its own stiffness,
the damping shared (docs: Fleets and populations).

    python examples/fleet_oscillators.py

Each unit is shaken by its own random force and its position measured 100 times; the
fleet is fitted twice: with the stiffness individual (each unit its own value, no
distribution: joint least squares) and as a population parameter (log-normal over the
units, ω estimated), and the estimates are set beside the truth.
"""

from __future__ import annotations

import time

import jax.numpy as jnp
import numpy as np

import tensorid as ti


def rhs(x, p, u):
    k, c = p
    return jnp.stack([x[1], u[0] - c * x[1] - k * x[0]])


MODEL = ti.Model(rhs=rhs, output=lambda x, p: x[:1], states=["x", "v"], params=["k", "c"],
                 inputs=["F"], outputs=["x"], name="oscillator")  # fmt: skip


def fleet(n=200, samples=100, seed=0):
    rng = np.random.default_rng(seed)
    k = 4.0 * np.exp(0.25 * rng.standard_normal(n))  # stiffness per unit: CV about 25 %
    t = np.arange(samples) * 0.1
    units = []
    for i in range(n):
        u = rng.standard_normal((samples, 1))
        y = ti.simulate(MODEL, {"k": k[i], "c": 0.4}, [0.0, 0.0], ti.Experiment(t, u)).y
        units.append(ti.Experiment(t, u, y + 0.01 * rng.standard_normal(y.shape), name=f"unit{i}"))
    return units, k


if __name__ == "__main__":
    units, k_true = fleet()
    start = {"k": 4.0, "c": 0.3}
    t0 = time.perf_counter()
    own = ti.fit(ti.Problem(MODEL, units, p0=start, individual=["k"]))
    print(own, f"\n({time.perf_counter() - t0:.1f} s with compilation)")
    k = np.array([u["params"]["k"] for u in own.units])
    se = np.array([u["stderr"]["k"] for u in own.units])
    inside = np.mean(np.abs(k - k_true) < 1.96 * se)
    print(f"stiffness: largest error {np.max(np.abs(k / k_true - 1)):.2%}; "
          f"95 % intervals hold the truth for {inside:.0%} of the units")  # fmt: skip
    t0 = time.perf_counter()
    pop = ti.fit(ti.Problem(MODEL, units, p0=start, population={"k": 0.5}))
    print(pop, f"\n({time.perf_counter() - t0:.1f} s with compilation)")
    print(f"the truth's sample: typical k {np.exp(np.log(k_true).mean()):.4f}, "
          f"omega {np.log(k_true).std(ddof=1):.4f}")  # fmt: skip
