"""Multiple shooting against single shooting: how often each reaches the best cost,
what a fit costs, and how that scales with the number of segments.

    python benchmarks/bench_shooting.py [--quick] [--figure docs/figures/shooting_waterfall_lv.png]

Part 1, robustness (tensorid.benchmarks.lotka_volterra_problem: about nine periods,
601 samples, both populations measured with 5 % noise): starts drawn uniformly
within ±50 % of the truth (three seeds of 20, the first start of each draw, the
truth, left out), fitted by single-shooting newton and gauss-newton and by multiple
shooting (10 segments, polished) with each; a start "reaches the best" when its cost
is within 1e-6 (relative) of the lowest cost found by any. The waterfall figure
sorts every start's final cost for single and multiple shooting.

Part 2, cost where single shooting needs no help: the paper's Silverbox problem from
its guess, single against multiple shooting with 5 and 20 segments (median of 3
fits after a first, compiling one).

Part 3, scaling with S on the Lotka–Volterra record, one ±50 % start: time per fit,
iterations and time per evaluation of the lifted problem's exact derivatives, and
the time per fit with the dense subproblem solver in place of the block-arrow one
(used from 100 unknowns on).

Part 4, one trust-region subproblem on a random block-arrow Hessian (N = 2 states
per segment, 4 parameters, indefinite): the block-arrow solver against the dense
eigen-solver, for S = 100, 400 and 1600 segments.
"""

from __future__ import annotations

import argparse
import statistics
import time

import numpy as np

import tensorid as ti
from tensorid.benchmarks import lotka_volterra_problem, silverbox_problem
from tensorid.solve import shooting
from tensorid.solve.multistart import draw_starts


def starts(problem, seeds, n=20) -> np.ndarray:
    rows = [
        draw_starts(
            problem.theta0, problem.lower, problem.upper, n + 1, spread=0.5,
            sampling="uniform", seed=s,
        )[1:]
        for s in seeds
    ]  # fmt: skip
    return np.concatenate(rows)


def robustness(seeds, segments: int) -> dict:
    single = lotka_volterra_problem()
    multiple = lotka_volterra_problem(segments=segments)
    thetas = starts(single, seeds)
    out = {}
    for label, prob in (("single", single), (f"multiple (S = {segments})", multiple)):
        for method in ("newton", "gauss-newton"):
            ti.fit(prob, method)  # compile
            costs, its, secs = [], [], []
            for th in thetas:
                t0 = time.perf_counter()
                r = ti.fit(prob, method, theta0=th)
                secs.append(time.perf_counter() - t0)
                costs.append(r.cost)
                its.append(r.nit)
            out[(label, method)] = (np.array(costs), its, secs)
    best = min(c.min() for c, _, _ in out.values())
    print(f"\nPart 1: Lotka-Volterra, {len(thetas)} starts within ±50 % (best cost {best:.6g})\n")
    print("| shooting | method | reach the best | median iterations | median s/fit |")
    print("|---|---|---|---|---|")
    for (label, method), (c, its, secs) in out.items():
        hits = int((c <= best * (1 + 1e-6)).sum())
        print(
            f"| {label} | {method} | {hits}/{c.size} ({100 * hits / c.size:.0f} %) | "
            f"{statistics.median(its):.0f} | {statistics.median(secs):.3f} |"
        )
    return {k: v[0] for k, v in out.items()} | {"best": best}


def waterfall(costs: dict, path: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    best = costs.pop("best")
    fig, ax = plt.subplots(figsize=(7, 4))
    for (label, method), c in costs.items():
        if method != "newton":
            continue
        ax.semilogy(np.arange(1, c.size + 1), np.sort(c) / best, "o-", ms=3, label=label)
    ax.set_xlabel("start (sorted by final cost)")
    ax.set_ylabel("final cost / best cost")
    ax.set_title("Lotka-Volterra, starts within ±50 %: final costs, newton")
    ax.legend()
    ax.grid(True, which="both", alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    print(f"\nwrote {path}")


def timed_fit(prob, method, theta0=None, repeats=3):
    ti.fit(prob, method, theta0=theta0)  # compile
    runs = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        r = ti.fit(prob, method, theta0=theta0)
        runs.append(time.perf_counter() - t0)
    return statistics.median(runs), r


def silverbox(segment_counts) -> None:
    print("\nPart 2: Silverbox (the paper's problem, from its guess)\n")
    print("| shooting | method | s/fit | iterations (shooting + polish) | cost | largest defect |")
    print("|---|---|---|---|---|---|")
    for method in ("newton", "gauss-newton"):
        for S in (1, *segment_counts):
            prob = silverbox_problem(segments=S)
            sec, r = timed_fit(prob, method)
            sh = r.shooting
            its = f"{sh['nit']} + {sh['polish_nit']}" if sh else str(r.nit)
            defect = f"{sh['max_defect']:.1e}" if sh else "–"
            label = "single" if S == 1 else f"S = {S}"
            print(f"| {label} | {method} | {sec:.3f} | {its} | {r.cost:.8g} | {defect} |")


def scaling(segment_counts) -> None:
    single = lotka_volterra_problem()
    theta0 = starts(single, [3], 1)[0]
    print("\nPart 3: scaling with S (Lotka-Volterra, one ±50 % start, newton)\n")
    print("| S | unknowns | s/fit | iterations | ms per exact evaluation | cost | s/fit, dense |")
    print("|---|---|---|---|---|---|---|")
    for S in segment_counts:
        prob = lotka_volterra_problem(segments=S)
        sec, r = timed_fit(prob, "newton", theta0)
        sh = prob.shooting
        z = sh.start(theta0)
        sh.evaluate(z)
        t0 = time.perf_counter()
        for _ in range(10):
            sh.evaluate(z)
        ms = 100 * (time.perf_counter() - t0)
        dense = "–"
        if sh.nz >= shooting.ARROW_FROM:
            saved, shooting.ARROW_FROM = shooting.ARROW_FROM, 10**9
            dense = f"{timed_fit(prob, 'newton', theta0, repeats=1)[0]:.3f}"
            shooting.ARROW_FROM = saved
        print(f"| {S} | {sh.nz} | {sec:.3f} | {r.nit} | {ms:.2f} | {r.cost:.8g} | {dense} |")


def subproblems(segment_counts) -> None:
    from tensorid.solve.arrow import ArrowSolver
    from tensorid.solve.trust_region import solve_subproblem

    rng = np.random.default_rng(0)
    print("\nPart 4: one trust-region subproblem, block arrow (N = 2, 4 parameters)\n")
    print("| S | unknowns | block-arrow ms | dense ms | model values agree to |")
    print("|---|---|---|---|---|")
    for S in segment_counts:
        nb = 2 * S
        H = np.zeros((nb + 4, nb + 4))
        for i in range(S):
            blk = rng.normal(size=(4, 4))
            j = slice(2 * i, min(2 * i + 4, nb))
            m = j.stop - j.start
            H[j, j] += (blk @ blk.T)[:m, :m]
        C = rng.normal(size=(nb, 4))
        H[:nb, nb:], H[nb:, :nb] = C, C.T
        H[nb:, nb:] = 10.0 * np.eye(4)
        H -= 0.5 * np.eye(nb + 4)  # indefinite
        g, free = rng.normal(size=nb + 4), np.ones(nb + 4, bool)
        t0 = time.perf_counter()
        s1, _ = ArrowSolver(nb)(g, H, 1.0, free)
        t1 = time.perf_counter()
        s2, _ = solve_subproblem(g, H, 1.0)
        t2 = time.perf_counter()
        m1, m2 = (float(g @ s + 0.5 * s @ H @ s) for s in (s1, s2))
        print(f"| {S} | {nb + 4} | {1e3 * (t1 - t0):.1f} | {1e3 * (t2 - t1):.1f} | "
              f"{abs(m1 - m2) / abs(m2):.0e} |")  # fmt: skip


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="one seed of starts, fewer S")
    ap.add_argument("--figure", default=None, help="write the waterfall figure here")
    args = ap.parse_args()
    costs = robustness([3] if args.quick else [3, 4, 5], segments=10)
    if args.figure:
        waterfall(costs, args.figure)
    silverbox([5] if args.quick else [5, 20])
    scaling([2, 10, 80] if args.quick else [2, 5, 10, 20, 40, 80, 150, 300])
    subproblems([100, 400] if args.quick else [100, 400, 1600])


if __name__ == "__main__":
    main()
