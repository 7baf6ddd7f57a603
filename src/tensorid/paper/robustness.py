"""The robustness comparison of the paper's Table 1: every method from the same
seeded ±20 % starts at every accuracy level, on worker processes; the summary rows
of results.json, the integration error of each level, and the figure."""

from __future__ import annotations

from collections.abc import Callable
from functools import cache
from pathlib import Path

import numpy as np

from .. import datasets
from ..app.reports import bar_plot
from ..engine.assembly.simulate import simulate
from ..fitting.methods import fit
from ..solve.multistart import process_pool
from . import problems as benchmarks
from .headline import _silverbox_validate
from .levels import level_name, level_options

# the paper's comparison: exact Newton and Gauss-Newton against the finite-difference
# baselines (newton-cg, for large K, is benchmarked in benchmarks/bench_scaling.py),
# and a fifth column of our own: exact Newton by multiple shooting with SEGMENTS segments
COMPARED = ("newton", "gauss-newton", "fd-bfgs", "fd-lsq", "multiple-shooting", "auto")
SEGMENTS = 5
SPREAD = 0.2
CONVERGED_RTOL = 1e-6


def draw_starts(guess: np.ndarray, n: int, seed: int) -> np.ndarray:
    """n starts uniform within ±20 % of each entry of the guess (zeros stay zero)."""
    rng = np.random.default_rng(seed)
    return guess * (1 + rng.uniform(-SPREAD, SPREAD, size=(n, guess.size)))


@cache
def _worker_problem(dataset: str, level, segments: int | None = None):
    options = level_options(level) | {"segments": segments}
    prob = (
        benchmarks.silverbox_problem(**options)
        if dataset == "silverbox"
        else benchmarks.two_tank_problem(**options)
    )
    th = prob.theta0
    # compile every path once, so that the timed fits below exclude compilation
    prob.cost_grad_hess(th)
    prob.cost_grad_hess_gn(th)  # auto's exact mode
    prob.cost_grad_gn(th)
    prob.cost(th)
    prob.residuals(th)
    prob.simulate(th)
    if prob.shooting is not None:  # the segments' sweeps, so that its timings exclude them too
        z = prob.shooting.start(th)
        prob.shooting.evaluate(z)
        prob.shooting.evaluate(z, exact=False)
    if dataset == "silverbox":
        val = datasets.silverbox_validation()
        simulate(prob.model, prob.p0, [0.0, 0.0], val, **level_options(level))
    return prob


def robustness_task(task: tuple) -> dict:
    """One start of one method at one accuracy level (runs in a worker process)."""
    dataset, method, level, index, theta0 = task
    shooting = method == "multiple-shooting"
    prob = _worker_problem(dataset, level, SEGMENTS if shooting else None)
    res = fit(prob, method="newton" if shooting else method, theta0=np.asarray(theta0))
    if not np.isfinite(res.cost):
        val_gof = -np.inf
    elif dataset == "silverbox":
        val_gof = _silverbox_validate(
            prob.model, res.params, level, datasets.silverbox_validation()
        )
    else:
        val_gof = float(res.gof()[0])
    return {
        "dataset": dataset,
        "method": method,
        "accuracy": level_name(level),
        "substeps": level_options(level).get("substeps"),
        "start": index,
        "cost": res.cost,
        "success": res.success,
        "iterations": res.nit,
        "nfev": res.nfev,
        "seconds": res.seconds,
        "val_gof": val_gof,
        "message": res.message,
    }


def _guess(dataset: str) -> np.ndarray:
    prob = (
        benchmarks.silverbox_problem() if dataset == "silverbox" else benchmarks.two_tank_problem()
    )
    return prob.theta0


def robustness_study(
    starts: int, levels, workers: int, seed: int = 0, on_done: Callable[[dict], None] | None = None
) -> list[dict]:
    tasks = []
    for dataset in ("silverbox", "two_tank"):
        thetas = draw_starts(_guess(dataset), starts, seed)
        for level in map(level_name, levels):
            for method in COMPARED:
                tasks += [(dataset, method, level, i, th.tolist()) for i, th in enumerate(thetas)]
    if workers <= 1:
        out = []
        for t in tasks:
            out.append(robustness_task(t))
            if on_done:
                on_done(out[-1])
        return out
    out = []
    with process_pool(workers) as pool:
        for r in pool.map(robustness_task, tasks, chunksize=1):
            out.append(r)
            if on_done:
                on_done(r)
    return out


def summarise(runs: list[dict], levels) -> list[dict]:
    """One row per (dataset, method, accuracy level), as in results.json."""
    rows = []
    for dataset in ("silverbox", "two_tank"):
        for name in map(level_name, levels):
            level = [r for r in runs if r["dataset"] == dataset and r["accuracy"] == name]
            costs = [r["cost"] for r in level if np.isfinite(r["cost"])]
            best = min(costs) if costs else np.inf
            for method in COMPARED:
                rs = [r for r in level if r["method"] == method]
                if not rs:
                    continue
                conv = sum(
                    np.isfinite(r["cost"]) and r["cost"] <= best * (1 + CONVERGED_RTOL) for r in rs
                )
                failed = sum((not r["success"]) or not np.isfinite(r["cost"]) for r in rs)
                gofs = [r["val_gof"] for r in rs]
                rows.append(
                    {
                        "dataset": dataset,
                        "method": method,
                        "accuracy": name,
                        "substeps": level_options(name).get("substeps"),
                        "tolerance": level_options(name).get("atol"),
                        "starts": len(rs),
                        "converged": int(conv),
                        "failed": int(failed),
                        "best_cost": best,
                        "best_val_gof": float(np.max(gofs)),
                        "median_val_gof": float(np.median(gofs)),
                        "median_iterations": float(np.median([r["iterations"] for r in rs])),
                        "median_nfev": float(np.median([r["nfev"] for r in rs])),
                        "median_seconds": float(np.median([r["seconds"] for r in rs])),
                    }
                )
    return rows


def integration_errors(levels) -> dict:
    """Max output error of each level relative to the output's range, at the paper's
    estimates, against RK4 with 2048 substeps."""
    out = {}
    for dataset in ("silverbox", "two_tank"):
        if dataset == "silverbox":
            m, p, e = (
                benchmarks.silverbox_model(),
                benchmarks.SILVERBOX_PAPER,
                datasets.silverbox_train(),
            )
            x0 = [float(e.measured[0, 0]), 0.0]
        else:
            m, p, e = (benchmarks.two_tank_model(), benchmarks.TWO_TANK_PAPER, datasets.two_tank())
            x0 = datasets.two_tank_levels()[0]
        ref = simulate(m, p, x0, e, substeps=2048).y[:, 0]
        out[dataset] = {
            level_name(lv): float(
                np.abs(simulate(m, p, x0, e, **level_options(lv)).y[:, 0] - ref).max()
                / np.abs(ref).max()
            )
            for lv in levels
        }
    return out


def _level_order(group: tuple[str, str]) -> tuple:
    """(data set, fixed-step levels by substeps, then adaptive by tolerance)."""
    options = level_options(group[1])
    return (group[0], "substeps" not in options, options.get("substeps", -options.get("atol", 0)))


def _robustness_figure(out: Path, rows: list[dict]) -> Path:
    groups = sorted({(r["dataset"], r["accuracy"]) for r in rows}, key=_level_order)
    series = {
        m: [
            next(
                (
                    r["converged"] / r["starts"]
                    for r in rows
                    if (r["dataset"], r["accuracy"]) == g and r["method"] == m
                ),
                np.nan,
            )
            for g in groups
        ]
        for m in COMPARED
    }
    return bar_plot(
        out / "robustness.png",
        [f"{d}\n{a}" for d, a in groups],
        series,
        title="Share of ±20 % starts that reach the best cost found",
        ylabel="converged / starts",
    )
