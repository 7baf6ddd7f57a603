"""newton, gauss-newton and auto side by side: how many starts reach the best cost,
median iterations and median seconds per fit (compilation excluded: each method
fits once before the clock runs).

    python benchmarks/bench_methods.py [--quick] [--rows NAME ...]

Rows: the paper's Silverbox and two-tank problems from the paper's guesses (one
start, the median of 5 fits), a chain of 5 masses (N = 10, K = 11, 2,000 samples,
5 seeded starts within ±20 %), chains of 16 and 32 masses (K = 33 and 65, 400
samples; 3 starts and 1 start), and the Lotka-Volterra record of the multiple-shooting
benchmark (60 starts within ±50 %). A start reaches the best when its cost is within
1e-6 (relative) of the lowest any method found on that row. The verdict column checks
what method "auto" promises: on every row it reaches the best at least as often as
the better of the two, with a median time at most 1.2x the faster one's. A last
table fits the first 20 Lotka-Volterra starts in lock-step (fit_batch: every
iteration's points in one vectorised call), where auto runs one second-order sweep
for all starts as soon as one of them needs it.
"""

from __future__ import annotations

import argparse
import statistics
import time

import jax
import numpy as np

import tensorid as ti
from tensorid.benchmarks import (
    lotka_volterra_problem,
    mass_chain_problem,
    silverbox_problem,
    two_tank_problem,
)
from tensorid.solve.multistart import draw_starts

METHODS = ("newton", "gauss-newton", "auto")


def _starts(problem, n: int, spread: float, seeds=(0,)) -> np.ndarray:
    rows = [
        draw_starts(problem.theta0, problem.lower, problem.upper, n + 1, spread=spread,
                    sampling="uniform", seed=s)[1:]
        for s in seeds
    ]  # fmt: skip
    return np.concatenate(rows)


def rows(quick: bool) -> dict:
    """name: (problem maker, starts maker, repeats per start)."""
    lv_seeds = (0,) if quick else (0, 1, 2)
    return {
        "Silverbox": (silverbox_problem, lambda p: p.theta0[None], 5),
        "two-tank": (two_tank_problem, lambda p: p.theta0[None], 5),
        "chain N = 10, K = 11": (lambda: mass_chain_problem(5), lambda p: _starts(p, 5, 0.2), 1),
        "chain N = 32, K = 33": (
            lambda: mass_chain_problem(16, samples=400),
            lambda p: _starts(p, 1 if quick else 3, 0.2),
            1,
        ),
        "chain N = 64, K = 65": (
            lambda: mass_chain_problem(32, samples=400),
            lambda p: _starts(p, 1, 0.2),
            1,
        ),
        "Lotka-Volterra": (
            lotka_volterra_problem,
            lambda p: _starts(p, 20, 0.5, lv_seeds),
            1,
        ),
    }


def run_row(make_problem, make_starts, repeats: int) -> dict:
    problem = make_problem()
    thetas = make_starts(problem)
    out = {}
    for method in METHODS:
        ti.fit(problem, method, theta0=thetas[0], maxiter=2)  # compile
        problem.cost_grad_hess_gn(thetas[0])  # auto's exact mode
        costs, its, secs, exact = [], [], [], []
        for th in thetas:
            times = []
            for _ in range(repeats):
                t0 = time.perf_counter()
                res = ti.fit(problem, method, theta0=th)
                times.append(time.perf_counter() - t0)
            costs.append(res.cost)
            its.append(res.nit)
            secs.append(statistics.median(times))
            exact.append(res.hybrid["exact_evaluations"] if res.hybrid else None)
        out[method] = {"costs": np.array(costs), "its": its, "secs": secs, "exact": exact}
    return out


def report(name: str, out: dict) -> list[str]:
    best = min(r["costs"].min() for r in out.values())
    lines, hits, medians = [], {}, {}
    for method, r in out.items():
        hits[method] = int((r["costs"] <= best * (1 + 1e-6)).sum())
        medians[method] = statistics.median(r["secs"])
        n = r["costs"].size
        extra = ""
        if method == "auto":
            exact = sum(r["exact"])
            extra = f" ({exact} exact-Hessian evaluations in all)"
        lines.append(
            f"| {name} | {method} | {hits[method]}/{n} | {statistics.median(r['its']):.0f} "
            f"| {medians[method]:.3f}{extra} |"
        )
    better = max(hits["newton"], hits["gauss-newton"])
    faster = min(medians["newton"], medians["gauss-newton"])
    ok_hits, ratio = hits["auto"] >= better, medians["auto"] / faster
    verdict = f"auto: {'as robust' if ok_hits else 'LESS robust'}, {ratio:.2f}x the faster"
    verdict += "" if ok_hits and ratio <= 1.2 else " (MISSES the promise)"
    lines.append(f"| {name} | verdict | best cost {best:.6g} | | {verdict} |")
    return lines


def lockstep(n: int = 20) -> None:
    """The Lotka-Volterra starts fitted together, per method: the whole batch's time."""
    problem = lotka_volterra_problem()
    thetas = _starts(problem, n, 0.5)
    print(f"\n| Lotka-Volterra, {n} starts in lock-step | reach the best | batch s |")
    print("|---|---|---|")
    out = {}
    for method in METHODS:
        ti.fit_batch(problem, method, thetas, maxiter=2)  # compile
        problem.cost_grad_hess_batch(thetas, both=True)
        t0 = time.perf_counter()
        res = ti.fit_batch(problem, method, thetas)
        out[method] = (np.array([r.cost for r in res]), time.perf_counter() - t0)
    best = min(c.min() for c, _ in out.values())
    for method, (costs, seconds) in out.items():
        print(f"| {method} | {int((costs <= best * (1 + 1e-6)).sum())}/{n} | {seconds:.2f} |")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="fewer starts")
    ap.add_argument("--rows", nargs="+", help="row names (substrings) to run")
    args = ap.parse_args()
    ti.enable_compilation_cache()
    print(
        f"tensorid {ti.__version__}, jax {jax.__version__}, {jax.default_backend()}; "
        "seconds per fit after compilation\n"
    )
    print("| problem | method | reach the best | median iterations | median s/fit |")
    print("|---|---|---|---|---|")
    for name, (make_problem, make_starts, repeats) in rows(args.quick).items():
        if args.rows and not any(r.lower() in name.lower() for r in args.rows):
            continue
        for line in report(name, run_row(make_problem, make_starts, repeats)):
            print(line, flush=True)
    if not args.rows or any("lock" in r.lower() for r in args.rows):
        lockstep()


if __name__ == "__main__":
    main()
