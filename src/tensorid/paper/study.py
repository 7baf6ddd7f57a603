"""Reproduce the paper: Silverbox and two-tank identification, its figures, and the
robustness comparison of its Table 1, on the bundled measurements.

    tensorid paper --out DIR [--starts N] [--quick]

writes DIR/results.json, DIR/report.md and PNG figures.
"""

from __future__ import annotations

import os
import platform
import time
from collections.abc import Callable
from datetime import UTC, datetime
from functools import cache
from pathlib import Path

import numpy as np

from .. import datasets
from .._config import __version__
from ..app.output import write_text
from ..app.progress import study_progress
from ..app.reports import bar_plot, write_json
from ..engine.data import Experiment
from ..engine.integrators import RTOL_FLOOR
from ..engine.metrics import gof
from ..engine.problem import Problem
from ..engine.simulate import simulate
from ..fitting.figures import compare_plot
from ..fitting.methods import fit
from ..fitting.multistart import process_pool
from . import problems as benchmarks
from .report import render

# the paper's comparison: exact Newton and Gauss-Newton against the finite-difference
# baselines (newton-cg, for large K, is benchmarked in benchmarks/bench_scaling.py),
# and a fifth column of our own: exact Newton by multiple shooting with SEGMENTS segments
COMPARED = ("newton", "gauss-newton", "fd-bfgs", "fd-lsq", "multiple-shooting", "auto")
SEGMENTS = 5

# the accuracy levels of the robustness study: RK4 with 4, 16 and 64 substeps per
# sample (a smooth simulator, "rk4x4" ...), and the paper's own levels, the adaptive
# dopri5 at rtol = atol = 1e-10, 1e-12, 1e-14 ("dopri5-1e-10" ...), where step-size
# control reacts to every change of θ, finite differences included, as in MATLAB
ACCURACY_LEVELS = (4, 16, 64)
ADAPTIVE_TOLERANCES = (1e-10, 1e-12, 1e-14)
QUICK_LEVELS = (4,)


def level_name(level) -> str:
    """ "rk4x16" for 16 substeps; a name passes through."""
    return level if isinstance(level, str) else f"rk4x{int(level)}"


def level_options(level) -> dict:
    """The Problem/simulate options of a level: {"substeps": n} or the adaptive
    scheme with its tolerances."""
    name = level_name(level)
    if name.startswith("rk4x") and name[4:].isdigit():
        return {"substeps": int(name[4:])}
    if name.startswith("dopri5-"):
        tol = float(name[7:])
        # rtol below 100 eps is raised to it, as MATLAB's ode45 does with RelTol 1e-14
        return {"scheme": "dopri5", "rtol": max(tol, RTOL_FLOOR), "atol": tol}
    raise ValueError(f"unknown accuracy level {name!r}: use rk4xN (N substeps) or dopri5-TOL")


def all_levels() -> tuple[str, ...]:
    """Every level of the full study, fixed-step first."""
    return tuple(map(level_name, ACCURACY_LEVELS)) + tuple(
        f"dopri5-{t:g}" for t in ADAPTIVE_TOLERANCES
    )


SPREAD = 0.2
CONVERGED_RTOL = 1e-6


# -- headline fits --------------------------------------------------------------------
def _y(e: Experiment) -> np.ndarray:
    return e.measured[:, 0]


def _silverbox_validate(model, params, level, val: Experiment) -> float:
    """Validation as in the paper: y(t0) measured, ẏ(t0) = 0."""
    x0 = [float(val.measured[0, 0]), 0.0]
    sim = simulate(model, params, x0, val, **level_options(level))
    return float(gof(_y(val), sim.y[:, 0]))


def silverbox_study(out: Path) -> tuple[dict, list[Path]]:
    train, val = datasets.silverbox_train(), datasets.silverbox_validation()
    paper_model, model, figures = _silverbox_paper_model(out, train, val)
    offset_model, figure = _silverbox_offset_model(out, val)
    return {
        "paper_model": paper_model,
        "paper_estimates": _silverbox_paper_estimates(model, train, val),
        "offset_model": offset_model,
        "mean_removed": _silverbox_mean_removed(model, train, val),
    }, [*figures, figure]


def _silverbox_paper_model(out: Path, train: Experiment, val: Experiment):
    """The paper's model fitted from the paper's guess, with its two figures."""
    figures = []
    res = fit(benchmarks.silverbox_problem(), method="newton")
    sim_tr = res.simulate()[0]
    model = res.problem.model
    sim_va = simulate(model, res.params, [float(val.measured[0, 0]), 0.0], val)
    paper_model = {
        "params": res.params,
        "x0": res.x0.tolist(),
        "train_cost": res.cost,
        "train_gof": float(gof(_y(train), sim_tr.y[:, 0])),
        "val_gof": float(gof(_y(val), sim_va.y[:, 0])),
        "iterations": res.nit,
        "success": res.success,
        "message": res.message,
        "seconds": res.seconds,
    }
    figures.append(
        compare_plot(
            out / "silverbox_train.png",
            train.t,
            _y(train),
            sim_tr.y[:, 0],
            ylabel="V2 [V]",
            title=f"Silverbox, training [10584:11608]: GOF "
            f"{paper_model['train_gof']:.4f} (paper's figure 1)",
        )
    )
    figures.append(
        compare_plot(
            out / "silverbox_validation.png",
            val.t,
            _y(val),
            sim_va.y[:, 0],
            ylabel="V2 [V]",
            title=f"Silverbox, validation [11608:13655], ẏ(t0) = 0: GOF "
            f"{paper_model['val_gof']:.4f} (paper's figure 2)",
        )
    )
    return paper_model, model, figures


def _silverbox_paper_estimates(model, train: Experiment, val: Experiment) -> dict:
    """The paper's own estimates, on our simulator."""
    pp = benchmarks.silverbox_problem(p0=benchmarks.SILVERBOX_PAPER)
    theta_p = pp.theta0.copy()
    theta_p[0] = benchmarks.SILVERBOX_PAPER_VDOT0
    return {
        "params": benchmarks.SILVERBOX_PAPER,
        "x0": [float(train.measured[0, 0]), benchmarks.SILVERBOX_PAPER_VDOT0],
        "train_cost": pp.cost(theta_p),
        "train_gof": float(gof(_y(train), pp.simulate(theta_p)[0].y[:, 0])),
        "val_gof": _silverbox_validate(model, benchmarks.SILVERBOX_PAPER, 4, val),
        "reported_val_gof": benchmarks.SILVERBOX_PAPER_VAL_GOF,
    }


def _silverbox_offset_model(out: Path, val: Experiment) -> tuple[dict, Path]:
    """Beyond the paper: the input offset and y(t0) estimated too."""
    ro = fit(benchmarks.silverbox_problem(offset=True), method="newton")
    om = ro.problem.model
    sim_vo = simulate(om, ro.params, [float(val.measured[0, 0]), 0.0], val)
    offset_model = {
        "params": ro.params,
        "x0": ro.x0.tolist(),
        "train_cost": ro.cost,
        "train_gof": float(ro.gof()[0]),
        "val_gof": float(gof(_y(val), sim_vo.y[:, 0])),
        "iterations": ro.nit,
        "success": ro.success,
    }
    figure = compare_plot(
        out / "silverbox_offset_validation.png",
        val.t,
        _y(val),
        sim_vo.y[:, 0],
        ylabel="V2 [V]",
        title=f"Silverbox with input offset u0 = "
        f"{ro.params['u0'] * 1e3:.2f} mV, validation: GOF "
        f"{offset_model['val_gof']:.4f}",
    )
    return offset_model, figure


def _silverbox_mean_removed(model, train: Experiment, val: Experiment) -> dict:
    """Diagnostic: the archive's README removes the record means of V1 and V2."""
    means = datasets._load("silverbox_schroeder80mV.npz")
    mu, my = float(means["record_mean_V1"]), float(means["record_mean_V2"])
    tr_c = Experiment(train.t, train.u - mu, train.measured - my)
    va_c = Experiment(val.t, val.u - mu, val.measured - my)
    rc = fit(
        Problem(
            model,
            tr_c,
            p0=benchmarks.SILVERBOX_GUESS,
            x0=[float(tr_c.measured[0, 0]), 0.0],
            free_x0=["ydot"],
        ),
        method="newton",
    )
    return {
        "params": rc.params,
        "train_cost": rc.cost,
        "train_gof": float(rc.gof()[0]),
        "val_gof": _silverbox_validate(model, rc.params, 4, va_c),
        "paper_estimates_val_gof": _silverbox_validate(model, benchmarks.SILVERBOX_PAPER, 4, va_c),
    }


def two_tank_study(out: Path) -> tuple[dict, list[Path]]:
    data = datasets.two_tank()
    res = fit(benchmarks.two_tank_problem(), method="newton")
    sim = res.simulate()[0]
    warnings = _level_warnings(sim.x, res.problem.model.states, "the fitted model")
    paper_model = {
        "params": res.params,
        "x0": res.x0.tolist(),
        "cost": res.cost,
        "gof": float(gof(_y(data), sim.y[:, 0])),
        "iterations": res.nit,
        "success": res.success,
        "message": res.message,
        "min_levels": sim.x.min(axis=0).tolist(),
        "warnings": warnings,
    }
    pp = benchmarks.two_tank_problem(p0=benchmarks.TWO_TANK_PAPER)
    psim = pp.simulate(pp.theta0)[0]
    paper_estimates = {
        "params": benchmarks.TWO_TANK_PAPER,
        "cost": pp.cost(pp.theta0),
        "gof": float(gof(_y(data), psim.y[:, 0])),
        "reported_gof": benchmarks.TWO_TANK_PAPER_GOF,
        "warnings": _level_warnings(psim.x, pp.model.states, "the paper's estimates"),
    }
    rz = fit(benchmarks.two_tank_problem(interpolation="zoh"), method="newton")
    zoh = {"params": rz.params, "cost": rz.cost, "gof": float(rz.gof()[0])}
    fig = compare_plot(
        out / "two_tank.png",
        data.t,
        _y(data),
        sim.y[:, 0],
        ylabel="lower tank level x2 [V]",
        title=f"Two-tank, 501 samples, Ts = 5 s: GOF {paper_model['gof']:.4f} (paper's figure 3)",
    )
    return {"paper_model": paper_model, "paper_estimates": paper_estimates, "zoh_input": zoh}, [fig]


def _level_warnings(x: np.ndarray, states, who: str) -> list[str]:
    out = []
    for i, name in enumerate(states):
        if x[:, i].min() < 0:
            k = int(np.argmin(x[:, i]))
            out.append(
                f"{who}: level {name} goes negative (min {x[k, i]:.4g} at sample {k}); "
                "√ of a negative level is not physical, the simulation continues "
                "with safe_sqrt's smooth extension"
            )
    return out


# -- robustness (Table 1) ---------------------------------------------------------------
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


# -- the whole study ----------------------------------------------------------------------
def run(
    out: Path,
    *,
    starts: int = 100,
    quick: bool = False,
    workers: int | None = None,
    seed: int = 0,
    progress: bool = True,
    levels=None,
) -> dict:
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    if levels is None:
        levels = QUICK_LEVELS if quick else all_levels()
    levels = tuple(map(level_name, levels))
    for lv in levels:
        level_options(lv)  # an unknown level fails here, before any work
    workers = workers or os.cpu_count() or 1
    t_start = time.perf_counter()
    with study_progress(enabled=progress) as prog:
        prog.step("Silverbox: paper's model, paper's estimates, offset variant")
        silverbox, figs = silverbox_study(out)
        prog.step("Two-tank: paper's model and estimates")
        two_tank, figs2 = two_tank_study(out)
        figs += figs2
        n_tasks = 2 * len(levels) * len(COMPARED) * starts
        prog.start_robustness(n_tasks, workers)
        runs = robustness_study(starts, levels, workers, seed, on_done=prog.advance)
        prog.step("Integration accuracy of each level")
        errors = integration_errors(levels)
    rows = summarise(runs, levels)
    figs.append(_robustness_figure(out, rows))
    results = {
        "silverbox": silverbox,
        "two_tank": two_tank,
        "robustness": rows,
        "robustness_runs": runs,
        "meta": {
            "tensorid": __version__,
            "date": datetime.now(UTC).isoformat(),
            "machine": f"{platform.machine()}, {os.cpu_count()} cores, "
            f"{platform.python_implementation()} {platform.python_version()}",
            "starts": starts,
            "quick": quick,
            "seed": seed,
            "spread": SPREAD,
            "workers": workers,
            "accuracy_levels": {
                lv: level_options(lv).get("substeps", level_options(lv).get("atol"))
                for lv in levels
            },
            "integration_error": errors,
            "converged_rtol": CONVERGED_RTOL,
            "segments": SEGMENTS,
            "seconds": time.perf_counter() - t_start,
        },
    }
    write_json(out / "results.json", results)
    write_text(out / "report.md", render(results, [Path(f).name for f in figs]))
    return results


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
