"""auto against newton and gauss-newton on a seeded panel of perturbed starts: how
often each reaches the best cost, and its median time per fit (compilation excluded).

    python benchmarks/bench_start_panel.py [--rows NAME ...] [--repeats R] [--starts N] [--seed S]

Each start scales every parameter by 1 + U(-s, s) and moves every free initial
state by U(-s, s) times its value, or, where that value is 0, by U(-a, a) absolute
(Silverbox's initial velocity: a = 1e-3), seeded, inside the bounds. Rows: Silverbox
(5 starts, s = 0.2), two-tank with measured levels and with the upper tank's level
free (5 each), the chains of 5 and 16 masses (K = 11 and 33; 5 and 2 starts), and
Lotka-Volterra (20 starts, s = 0.5, both initial populations free). Per start the
three methods run one after another in a rotating order, so that a change in the
machine's load falls on all of them; a start reaches the best when its cost is
within 1e-6 (relative) of the lowest any method found on that row. The verdict checks
what method "auto" promises: on every row it reaches the best at least as often as
the better of the two, with a median time at most 1.2x the faster one's.
"""

from __future__ import annotations

import argparse
import os
import statistics
import time

import jax
import numpy as np
from bench_methods import report

import tensorid as ti
from tensorid.benchmarks import (
    lotka_volterra_problem,
    mass_chain_problem,
    silverbox_problem,
    two_tank_problem,
)

METHODS = ("newton", "gauss-newton", "auto")


def perturbed_starts(problem, n: int, spread: float, absolute: float = 1e-3, seed: int = 0):
    """n starts: parameters times 1 + U(-spread, spread); free initial states plus
    U(-spread, spread) times their value, or U(-absolute, absolute) where it is 0."""
    rng = np.random.default_rng(seed)
    th0 = problem.theta0
    n_init = len(problem.experiments) * len(problem.free_x0)
    width = spread * np.abs(th0)
    width[:n_init] = np.where(th0[:n_init] == 0.0, absolute, width[:n_init])
    out = []
    for _ in range(n):
        u = rng.uniform(-1.0, 1.0, th0.size)
        th = np.where(np.arange(th0.size) < n_init, th0 + width * u, th0 * (1.0 + spread * u))
        out.append(np.clip(th, problem.lower, problem.upper))
    return np.array(out)


def rows() -> dict:
    """name: (problem maker, number of starts, spread, repeats per start)."""
    return {
        "Silverbox, ydot(t0) +-1e-3": (silverbox_problem, 5, 0.2, 3),
        "two-tank": (two_tank_problem, 5, 0.2, 3),
        "two-tank, x1(t0) free": (lambda: two_tank_problem(free_x0=["x1"]), 5, 0.2, 3),
        "chain N = 10, K = 11": (lambda: mass_chain_problem(5), 5, 0.2, 1),
        "chain N = 32, K = 33": (lambda: mass_chain_problem(16, samples=400), 2, 0.2, 1),
        "Lotka-Volterra, x0 free": (lotka_volterra_problem, 20, 0.5, 1),
    }


def run_row(make_problem, n: int, spread: float, repeats: int, seed: int = 0) -> dict:
    problem = make_problem()
    thetas = perturbed_starts(problem, n, spread, seed=seed)
    for method in METHODS:  # compile every sweep a method uses
        ti.fit(problem, method, theta0=thetas[0], maxiter=2)
    problem.cost_grad_hess_gn(thetas[0])  # auto's exact mode
    out = {m: {"costs": [], "its": [], "secs": [], "exact": []} for m in METHODS}
    for k, th in enumerate(thetas):
        times: dict = {m: [] for m in METHODS}
        for rep in range(repeats):
            turn = (k + rep) % len(METHODS)
            for method in METHODS[turn:] + METHODS[:turn]:
                t0 = time.perf_counter()
                res = ti.fit(problem, method, theta0=th)
                times[method].append(time.perf_counter() - t0)
                last = res
                if rep == 0:
                    r = out[method]
                    r["costs"].append(last.cost)
                    r["its"].append(last.nit)
                    r["exact"].append(last.hybrid["exact_evaluations"] if last.hybrid else 0)
        for method in METHODS:
            out[method]["secs"].append(statistics.median(times[method]))
    for r in out.values():
        r["costs"] = np.array(r["costs"])
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rows", nargs="+", help="row names (substrings) to run")
    ap.add_argument("--repeats", type=int, help="fits per start and method (default per row)")
    ap.add_argument("--starts", type=int, help="starts per row (default per row)")
    ap.add_argument("--seed", type=int, default=0, help="the starts' seed (default 0)")
    args = ap.parse_args()
    ti.enable_compilation_cache()
    load = os.getloadavg()[0]
    print(
        f"tensorid {ti.__version__}, jax {jax.__version__}, {jax.default_backend()}, "
        f"{os.cpu_count()} cores, load {load:.1f}; seconds per fit after compilation\n"
    )
    print("| problem | method | reach the best | median iterations | median s/fit |")
    print("|---|---|---|---|---|")
    for name, (make_problem, n, spread, repeats) in rows().items():
        if args.rows and not any(r.lower() in name.lower() for r in args.rows):
            continue
        out = run_row(make_problem, args.starts or n, spread, args.repeats or repeats, args.seed)
        for line in report(name, out):
            print(line, flush=True)
    print(f"\nload {load:.1f} at the start, {os.getloadavg()[0]:.1f} at the end")


if __name__ == "__main__":
    main()
