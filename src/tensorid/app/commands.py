"""`tensorid fit` and `tensorid simulate`: from a model file and data files to fit.json,
report.md and figures, with live progress."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
from rich.console import Console
from rich.live import Live
from rich.table import Table

from .data import Experiment
from .loaders import load_data, load_model
from .metrics import gof
from .optimize import FitResult, fit
from .problem import Problem
from .report import fit_figures, md_table, summary_table, write_json
from .simulate import Simulation, simulate


def _progress_table(rows: list[dict]) -> Table:
    t = Table(title="tensorid fit", show_edge=False)
    for c in ("iter", "cost", "grad norm", "trust radius", "step"):
        t.add_column(c, justify="right")
    for h in rows[-12:]:
        t.add_row(
            str(h["iteration"]),
            f"{h['cost']:.8g}",
            f"{h['grad_norm']:.2e}",
            f"{h['radius']:.2e}",
            "accepted" if h["accepted"] else "rejected",
        )
    return t


def validation_simulations(
    res: FitResult, exps: list[Experiment]
) -> list[tuple[Experiment, Simulation]]:
    """Simulate the fitted model on validation data. Initial states that were free in
    the fit are unknown there too: they are estimated on each validation record with
    the parameters held at their estimates (as MATLAB's compare does)."""
    prob = res.problem
    m = prob.model
    out = []
    x0_fit = np.atleast_2d(res.x0)[0]
    for e in exps:
        if prob.free_x0:
            vp = Problem(
                m,
                e,
                p0=res.params,
                x0=x0_fit,
                free_x0=prob.free_x0,
                fixed=list(m.params),
                substeps=prob.substeps,
                interpolation=prob.interpolation,
                scheme=prob.scheme,
            )
            x0 = fit(vp, "newton").x0
        else:
            x0 = x0_fit
        out.append(
            (
                e,
                simulate(
                    m,
                    res.params,
                    x0,
                    e,
                    substeps=prob.substeps,
                    interpolation=prob.interpolation,
                    scheme=prob.scheme,
                ),
            )
        )
    return out


def _integration(prob: Problem) -> dict:
    """How the model was integrated: what a reader needs to reproduce the cost."""
    d = {
        "scheme": prob.scheme.name,
        "substeps": prob.substeps,
        "interpolation": prob.interpolation,
    }
    for k in ("rtol", "atol"):
        if hasattr(prob.scheme, k):
            d[k] = getattr(prob.scheme, k)
    return d


def fit_json(res: FitResult, validation) -> dict:
    u = res.uncertainty() if np.isfinite(res.cost) else None
    m = res.problem.model

    def gofs(pairs):
        return {
            e.name or str(i): {o: float(gof(e.y[:, j], s.y[:, j])) for j, o in enumerate(m.outputs)}
            for i, (e, s) in enumerate(pairs)
        }

    train = list(zip(res.problem.experiments, res.simulate(), strict=True))
    d = {
        "params": res.params,
        "free": res.problem.theta_names,
        "estimates": dict(zip(res.problem.theta_names, res.theta.tolist(), strict=True)),
        "x0": np.asarray(res.x0).tolist(),
        "cost": res.cost,
        "gof": {"train": gofs(train), "validation": gofs(validation)},
        "success": res.success,
        "message": res.message,
        "iterations": res.nit,
        "function_evaluations": res.nfev,
        "hessian_vector_products": res.nhev,
        "method": res.method,
        "integration": _integration(res.problem),
        "seconds": res.seconds,
        "warnings": res.warnings,
        "residual_variance": u.sigma2 if u else None,
        "correlation_names": res.problem.theta_names,
        "history": res.history,
        "starts": res.starts,
    }
    if u:
        d.update(u.as_dicts())
        d["stderr_gauss_newton"] = dict(
            zip(
                res.problem.theta_names,
                res.uncertainty("gauss-newton").stderr.tolist(),
                strict=True,
            )
        )
    return d


def fit_report(res: FitResult, data: dict, figures: list[Path]) -> str:
    names = res.problem.theta_names
    rows = [
        [
            n,
            f"{data['estimates'][n]:.6g}",
            f"{data.get('stderr', {}).get(n, np.nan):.3g}",
            str([round(v, 6) for v in data.get("ci95", {}).get(n, [])]),
        ]
        for n in names
    ]
    lines = [
        f"# Fit of {res.problem.model.name}",
        "",
        f"{res.method}: {'converged' if res.success else 'did not converge'} "
        f"({res.message}) in {res.nit} iterations, {res.nfev} cost evaluations, "
        f"{res.seconds:.2f} s; cost J = {res.cost:.6g}.",
        "",
        md_table(["unknown", "estimate", "std. error", "95 % interval"], rows),
        "",
    ]
    if data["warnings"]:
        lines += ["## Warnings", ""] + [f"- {w}" for w in data["warnings"]] + [""]
    lines += ["## Goodness of fit", ""]
    for kind in ("train", "validation"):
        for exp, per in data["gof"][kind].items():
            lines.append(f"- {kind} {exp}: " + ", ".join(f"{o} {v:.4f}" for o, v in per.items()))
    if res.starts:
        lines += [
            "",
            f"## {len(res.starts)} starts, best first",
            "",
            md_table(
                ["start", "cost", "success", "iterations"],
                [[s["start"], s["cost"], s["success"], s["nit"]] for s in res.starts[:20]],
            ),
        ]
    lines += ["", "## Figures", ""] + [f"![{f.stem}]({f.name})" for f in figures]
    return "\n".join(lines) + "\n"


def run_fit(args) -> int:
    console = Console(stderr=True)
    spec = load_model(args.model)
    m = spec.model
    train = load_data(args.data, m, ts=args.ts, samples=args.samples)
    val = (
        load_data(args.validate, m, ts=args.ts, samples=args.validate_samples)
        if args.validate
        else []
    )
    if spec.p0 is None:
        raise SystemExit(
            f"{args.model} defines no p0: add p0 = {{name: start value}} for {list(m.params)}"
        )
    problem = Problem(
        m,
        train,
        p0=spec.p0,
        x0=spec.x0_array(),
        free_x0=spec.free_x0,
        fixed=spec.fixed,
        bounds=spec.bounds,
        substeps=args.substeps,
        interpolation=args.interpolation,
        scheme=args.scheme,
        rtol=args.rtol,
        atol=args.atol,
    )
    executor = client = None
    if args.scheduler:
        from distributed import Client

        client = Client(args.scheduler)
        executor = client.get_executor()
    rows: list[dict] = []
    options = dict(
        starts=args.starts,
        spread=args.spread,
        seed=args.seed,
        executor=executor,
        workers=args.workers,
        batch=args.batch,
    )
    try:
        if args.no_progress:
            res = fit(problem, args.method, **options)
        else:
            if args.starts > 1:
                where = "on " + args.scheduler if args.scheduler else "locally"
                console.log(f"running {args.starts} starts {where}...")
            with Live(_progress_table(rows), console=console, refresh_per_second=8) as live:

                def show(entry):
                    rows.append(entry)
                    live.update(_progress_table(rows))

                res = fit(problem, args.method, callback=show, **options)
    finally:
        if client is not None:
            client.close()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    vsims = validation_simulations(res, val)
    data = fit_json(res, vsims)
    figures = fit_figures(res, out, vsims)
    write_json(out / "fit.json", data)
    (out / "report.md").write_text(fit_report(res, data, figures))
    print(summary_table(res))
    for kind in ("train", "validation"):
        for exp, per in data["gof"][kind].items():
            print(f"GOF {kind} {exp}: " + ", ".join(f"{o} {v:.4f}" for o, v in per.items()))
    print(f"wrote {out}/fit.json, report.md and {len(figures)} figures")
    return 0 if res.success else 1


def _assignments(items: list[str], what: str) -> dict[str, float]:
    out = {}
    for it in items:
        if "=" not in it:
            raise SystemExit(f"{what} must be NAME=VALUE, got {it!r}")
        k, v = it.split("=", 1)
        out[k.strip()] = float(v)
    return out


def run_simulate(args) -> int:
    spec = load_model(args.model)
    m = spec.model
    params = dict(spec.p0 or {})
    x0 = dict(zip(m.states, spec.x0_array(), strict=True))
    if len(args.params) == 1 and args.params[0].endswith(".json"):
        fitted = json.loads(Path(args.params[0]).read_text())
        params.update(fitted["params"])
        x0 = dict(zip(m.states, np.atleast_2d(fitted["x0"])[0], strict=True))
    else:
        params.update(_assignments(args.params, "--params"))
    x0.update(_assignments(args.x0, "--x0"))
    e = load_data([args.data], m, ts=args.ts, require_outputs=False)[0]
    sim = simulate(
        m,
        params,
        x0,
        e,
        substeps=args.substeps,
        interpolation=args.interpolation,
        scheme=args.scheme,
        rtol=args.rtol,
        atol=args.atol,
    )
    header = ["t"] + list(m.states) + [f"{o}_sim" for o in m.outputs]
    table = np.column_stack([e.t, sim.x, sim.y])
    np.savetxt(args.out, table, delimiter=",", header=",".join(header), comments="")
    if e.y is not None:
        for j, o in enumerate(m.outputs):
            print(f"GOF {o}: {gof(e.y[:, j], sim.y[:, j]):.4f}")
    print(f"wrote {args.out}")
    return 0
