"""Multi-start throughput on this machine: fits per second on the paper's Silverbox
problem (P = 1024, K = 5) from ±20 % starts, by each way tensorid can run them.

    python benchmarks/bench_multistart.py [--starts 16] [--workers 2]

Ways: one process, one start at a time; one process, all starts in lock-step with
their evaluations vectorised by jax.vmap (``fit(..., batch=B)``); a pool of worker
processes, one start per task; and a pool with lock-step batches per worker. Pools
are timed warm (the same executor reused, so worker start-up and compilation are
excluded) and the cold figure, a fresh ``fit(starts=...)`` call with its own pool,
is listed beside it. Every way must reach the same best cost.
"""

from __future__ import annotations

import argparse
import os
import time

import jax
import numpy as np

import tensorid as ti
from tensorid.benchmarks import silverbox_problem
from tensorid.fitting.methods import fit_task
from tensorid.solve.multistart import draw_starts, process_pool, run_starts

TASK = fit_task("newton", ti.FitOptions())


def _run(prob, thetas, **kw) -> tuple[float, list[dict]]:
    t0 = time.perf_counter()
    runs = run_starts(prob, TASK, thetas, **kw)
    return time.perf_counter() - t0, runs


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--starts", type=int, default=16)
    ap.add_argument("--workers", type=int, default=os.cpu_count() or 1)
    args = ap.parse_args()
    ti.enable_compilation_cache()
    prob = silverbox_problem()
    n, W = args.starts, args.workers
    thetas = draw_starts(prob.theta0, prob.lower, prob.upper, n, seed=0)
    print(
        f"Silverbox P = 1024, K = 5, {n} starts within ±20 %, {W} worker(s), "
        f"{os.cpu_count()} cores, jax {jax.__version__}\n"
    )
    rows = []
    # one process: warm up each compiled shape first
    _run(prob, thetas[:1], workers=1)
    rows.append(("1 process, one start at a time", *_run(prob, thetas, workers=1)))
    for B in sorted({4, 8, n}):
        if B <= n:
            _run(prob, thetas[:B], workers=1, batch=B)
            rows.append(
                (f"1 process, lock-step batches of {B}", *_run(prob, thetas, workers=1, batch=B))
            )
    if W > 1:
        with process_pool(W) as pool:
            for B in (1, max(1, n // W)):
                run_starts(prob, TASK, thetas, executor=pool, batch=B)  # warm
                label = f"{W} workers (warm pool), " + (
                    "one start per task" if B == 1 else f"lock-step batches of {B}"
                )
                rows.append((label, *_run(prob, thetas, executor=pool, batch=B)))
        for B in (1, max(1, n // W)):
            t0 = time.perf_counter()
            res = ti.fit(prob, "newton", starts=n, workers=W, batch=B)
            cold = time.perf_counter() - t0
            rows.append(
                (
                    f"fit(starts={n}, workers={W}, batch={B}), fresh pool, refine included",
                    cold,
                    res.starts,
                )
            )
    base = rows[0][1]
    print("| way | wall s | fits / s | speed-up | best cost | starts at best |")
    print("|---|---:|---:|---:|---:|---:|")
    for label, sec, runs in rows:
        # run_starts gives FitResults, fit's .starts dicts
        costs = np.array([r["cost"] if isinstance(r, dict) else r.cost for r in runs])
        best = costs.min()
        hits = int(np.sum(costs <= best * (1 + 1e-6)))
        print(
            f"| {label} | {sec:.2f} | {n / sec:.1f} | {base / sec:.2f} | {best:.6g} | {hits}/{n} |"
        )


if __name__ == "__main__":
    main()
