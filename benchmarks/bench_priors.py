"""The noise level that weighs the priors: MAP estimates under each rule against the
answer with the true noise given (``noise=``), on seeded records sampled coarsely and
finely against their dynamics.

    python benchmarks/bench_priors.py [--records osc-1kHz ...] [--seeds 4]

For every record (four seeds) and two priors (one in conflict with the data, one
consistent and about as tight as the data), the fit without ``noise=`` under each rule:
"none" keeps the second-difference estimate (the behaviour before the check), "x2",
"x1.5" (the rule chosen) and "x1.1" re-estimate it from the residuals and refit while
it and the residual variance differ by more than that factor. Printed per record: the
second-difference estimate over the true noise variance (range over seeds), and per
rule the largest |θ − θ(noise given)| over the result's own standard error (every
unknown, seed and prior) and the refits made (range).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

import tensorid as ti
import tensorid.fitting.priors as rule

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from conftest import SILVERBOX_P, silverbox_data, silverbox_model  # noqa: E402

OSCILLATOR = silverbox_model(name="oscillator")  # the README's: the Silverbox's structure
LINEAR = ti.Model(
    rhs=lambda x, p, u: p[0] * u[0] + p[1] * u[1] + 0 * x, states=["x"], params=["a", "b"],
    inputs=["u", "v"], output=lambda x, p: x, outputs=["y"], name="linear",
)  # fmt: skip
SILVERBOX = silverbox_model()


def oscillator(dt: float, P: int, seed: int):
    """The README's example: noise sd 1e-4, inputs at 12 and 23 Hz."""
    t = np.arange(P) * dt
    u = 0.5 * np.sin(2 * np.pi * 12 * t) + 0.3 * np.sin(2 * np.pi * 23 * t)
    y = ti.simulate(OSCILLATOR, {"m": 1e-4, "d": 2e-3, "a": 1.0, "b": 4.0}, [0.0, 0.0],
                    ti.Experiment(t, u)).y  # fmt: skip
    y = y + 1e-4 * np.random.default_rng(seed).standard_normal(y.shape)
    kw = dict(p0={"m": 1.2e-4, "d": 1.8e-3, "a": 0.9, "b": 3.0}, x0=[0.0, 0.0],
              free_x0=["v"], bounds={"m": (1e-6, 1e-2)})  # fmt: skip
    return OSCILLATOR, ti.Experiment(t, u, y), kw


def linear(n: int, noise: float, seed: int):
    """tests/test_priors.py's linear model, n samples on [0, 2]."""
    t = np.linspace(0, 2, n)
    u = np.stack([np.cos(3 * t), np.sin(5 * t)], 1)
    y = ti.simulate(LINEAR, {"a": 2.0, "b": -1.0}, [0.0], ti.Experiment(t, u)).y[:, 0]
    y = y + noise * np.random.default_rng(seed).standard_normal(t.size)
    return LINEAR, ti.Experiment(t, u, y), dict(p0={"a": 1.0, "b": 0.0})


def silverbox(seed: int):
    """The Silverbox at its 610 Hz sampling, 512 samples, noise sd 1e-4."""
    e = silverbox_data(P=512, seed=seed, noise=1e-4)
    return SILVERBOX, e, dict(p0=SILVERBOX_P, free_x0=["y"])


# record -> (maker(seed), true noise sd, [conflicting prior, consistent prior])
RECORDS = {
    "osc-1kHz": (lambda s: oscillator(1e-3, 1000, s), 1e-4,
                 [{"b": (3.5, 0.01)}, {"b": (4.0, 2e-4)}]),
    "osc-10kHz": (lambda s: oscillator(1e-4, 2000, s), 1e-4,
                  [{"b": (3.5, 0.01)}, {"b": (4.0, 2e-3)}]),
    "linear-40": (lambda s: linear(40, 0.005, s), 0.005, [{"a": (1.5, 0.1)}, {"a": (2.0, 0.005)}]),
    "linear-400": (lambda s: linear(400, 0.05, s), 0.05, [{"a": (1.5, 0.1)}, {"a": (2.0, 0.01)}]),
    "silverbox-512": (silverbox, 1e-4, [{"a": (0.9, 0.01)}, {"d": (2.15e-4, 2e-6)}]),
}  # fmt: skip
RULES = {"none": (rule.TOLERANCE, 0), "x2": (2.0, 10), "x1.5": (1.5, 10), "x1.1": (1.1, 10)}


def measure(name: str, seeds: int) -> dict:
    make, sigma, priors = RECORDS[name]
    worst = dict.fromkeys(RULES, 0.0)
    refits: dict[str, list[int]] = {r: [] for r in RULES}
    estimate = []
    for seed in range(seeds):
        model, e, kw = make(seed)
        for prior in priors:
            given = ti.fit(ti.Problem(model, e, priors=prior, noise=sigma, **kw))
            for r, (tolerance, most) in RULES.items():
                rule.TOLERANCE, rule.MAX_REFITS = tolerance, most
                prob = ti.Problem(model, e, priors=prior, **kw)
                res = ti.fit(prob)
                off = np.abs(res.theta - given.theta) / res.uncertainty().stderr
                worst[r] = max(worst[r], float(off.max()))
                refits[r].append(res.noise_check.refits)
            estimate.append(prob.noise_variance / sigma**2)
    return {"estimate": (min(estimate), max(estimate)), "worst": worst, "refits": refits}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--records", nargs="+", default=list(RECORDS), choices=list(RECORDS))
    ap.add_argument("--seeds", type=int, default=4)
    args = ap.parse_args()
    print("| record | estimate / true variance | " + " | ".join(
        f"{r}: largest offset (se)" for r in RULES) + " | refits, x1.5 |")  # fmt: skip
    print("|---" * (len(RULES) + 3) + "|")
    for name in args.records:
        start = time.perf_counter()
        m = measure(name, args.seeds)
        lo, hi = m["estimate"]
        cells = [f"{m['worst'][r]:.2g}" for r in RULES]
        k = m["refits"]["x1.5"]
        print(f"| {name} | {lo:.3g} to {hi:.3g} | " + " | ".join(cells)
              + f" | {min(k)} to {max(k)} |  ({time.perf_counter() - start:.0f} s)")  # fmt: skip


if __name__ == "__main__":
    main()
