"""Profile likelihood: integration-based (exact-Hessian predictor-corrector) against
optimisation-based profiles (a full re-fit at every trial value), and the coverage
of profile and Wald intervals.

    python benchmarks/bench_profiles.py [--draws 200]

Part 1, for every unknown of three problems (the decay below, the paper's Silverbox
and two-tank problems): the time of each method (after a first, compiling run), and
the largest relative difference between their interval ends.

Part 2, coverage: y = x0·exp(−t/τ) + noise, τ = x0 = 1, ten samples on t ∈ [0, T]
with noise sd σ: (T, σ) = (0.5, 0.3), a record much shorter than the time constant,
where τ's Wald interval is poor, and (0.7, 0.15); the fraction of seeded noise draws
whose 95 % interval holds the true τ, and how many profile intervals are unbounded.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

import tensorid as ti
from tensorid.benchmarks import silverbox_problem, two_tank_problem

DECAY = ti.Model(
    rhs=lambda x, p, u: -x / p[0], states=["x"], params=["tau"],
    output=lambda x, p: x, outputs=["y"], name="decay",
)  # fmt: skip


def decay_problem(seed: int, T: float = 0.5, noise: float = 0.3) -> ti.Problem:
    t = np.linspace(0, T, 10)
    y = np.exp(-t) + noise * np.random.default_rng(seed).standard_normal(t.size)
    return ti.Problem(DECAY, ti.Experiment(t, None, y), p0={"tau": 1.0}, x0=[1.0],
                      free_x0=["x"])  # fmt: skip


def timed_profiles(res, method: str) -> tuple[float, dict]:
    res.profile(method=method)  # compile and warm
    t0 = time.perf_counter()
    profiles = res.profile(method=method)
    return time.perf_counter() - t0, profiles


def compare(name: str, res) -> None:
    t_int, fast = timed_profiles(res, "integrate")
    t_ref, slow = timed_profiles(res, "refit")
    worst = 0.0
    for n in fast:
        for a, b in zip(fast[n].interval, slow[n].interval, strict=True):
            if np.isfinite(a) or np.isfinite(b):
                worst = max(worst, abs(a - b) / max(abs(b), 1e-300))
    ends = sum(p.ends != {"lower": "crossed", "upper": "crossed"} for p in fast.values())
    print(
        f"| {name} | {len(fast)} | {t_int:.3f} | {t_ref:.3f} | {t_ref / t_int:.2f} | "
        f"{worst:.1e} | {ends} |"
    )


def coverage(draws: int, T: float, noise: float) -> None:
    wald = profile = unbounded = 0
    for seed in range(draws):
        res = ti.fit(decay_problem(seed, T, noise))
        lo, hi = res.uncertainty().ci95[1]
        wald += lo <= 1.0 <= hi
        p = res.profile(["tau"])["tau"]
        profile += p.interval[0] <= 1.0 <= p.interval[1]
        unbounded += not p.identifiable
    print(f"| T = {T}, σ = {noise} | {draws} | {wald / draws:.3f} | {profile / draws:.3f} | "
          f"{unbounded} |")  # fmt: skip


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--draws", type=int, default=200)
    args = ap.parse_args()
    print("| problem | unknowns profiled | integrate s | refit s | refit / integrate | "
          "largest relative difference of the ends | sides not crossed |")  # fmt: skip
    print("|---|---|---|---|---|---|---|")
    compare("decay (seed 1)", ti.fit(decay_problem(1)))
    compare("Silverbox, paper", ti.fit(silverbox_problem()))
    compare("two-tank, paper", ti.fit(two_tank_problem()))
    print("\ncoverage of the true τ by 95 % intervals:\n")
    print("| record | noise draws | Wald (exact Hessian, t quantile) | profile likelihood | "
          "profile intervals unbounded above |")  # fmt: skip
    print("|---|---|---|---|---|")
    for T, noise in ((0.5, 0.3), (0.7, 0.15)):
        coverage(args.draws, T, noise)


if __name__ == "__main__":
    main()
