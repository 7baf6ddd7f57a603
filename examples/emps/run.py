"""The EMPS study: the rigid-body friction model of a real closed-loop positioning
system, identified in closed loop (from the reference position, the controller in the
model) and in open loop (from the controller's output, single and multiple shooting),
scored as the benchmark asks (test record DATA_EMPS_PULSES, initial states estimated on
its first 20 samples) and set beside the benchmark document's IDIM-LS reference model.

    python examples/emps/run.py [--out emps-study] [--figures DIR]

Writes results.json and the figures to --out (the docs' figures come from
``--figures docs/figures``) and prints the tables of docs/emps.md. About 1 minute on
a 2-core machine (2½ with --starts 8).
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import closed_loop
import numpy as np
import open_loop

import tensorid as ti
from tensorid.datasets import EMPS_IDIM_LS, EMPS_INIT_WINDOW, emps

SEGMENTS = 100  # multiple shooting: segments of about 250 samples (0.25 s)
LOOPS = {
    # loop: (model module, its Problem options)
    "open": (open_loop, {"substeps": 1}),
    "closed": (closed_loop, {}),
}


def problem(loop: str, p0: dict, model=None, fixed=None, **options) -> ti.Problem:
    """The estimation record's Problem for the open or the closed loop."""
    spec, defaults = LOOPS[loop]
    model = model or spec.model
    return ti.Problem(
        model,
        emps("estimation", closed_loop=loop == "closed"),
        p0=p0,
        x0=np.zeros(len(model.states)),
        free_x0=model.states,
        fixed=fixed,
        bounds=None if fixed else spec.bounds,
        **defaults,
        **options,
    )


def rmse(score) -> float:
    return score.rmse["qm"]


def estimate(label: str, loop: str, **options) -> dict:
    """Fit from the model file's start; its scores on both records."""
    started = time.perf_counter()
    res = ti.fit(problem(loop, LOOPS[loop][0].p0, **options), method="gauss-newton")
    seconds = time.perf_counter() - started
    test = res.validate(emps("test", closed_loop=loop == "closed"), EMPS_INIT_WINDOW)[0]
    u = res.uncertainty()
    print(f"{label}: {res.status.value[0]}, cost {res.cost:.6g}, {seconds:.1f} s", flush=True)
    return {
        "label": label,
        "loop": loop,
        "result": res,
        "params": res.params,
        "stderr": dict(zip(u.names, map(float, u.stderr), strict=True)),
        "cost": res.cost,
        "status": res.status.value[0],
        "iterations": res.nit,
        "seconds": seconds,
        "shooting": res.shooting,
        "train_rmse": rmse(res.validate(res.problem.experiments)[0]),
        "test_rmse": rmse(test),
        "test": test,
        "residual_tests": res.residual_tests().lines(),
    }


def held(params: dict, loop: str) -> dict:
    """A parameter set scored in one loop: the initial states fitted on the
    estimation record (parameters held), the test record scored as the benchmark asks."""
    spec = LOOPS[loop][0]
    res = ti.fit(problem(loop, params, fixed=spec.model.params), method="gauss-newton")
    test = res.validate(emps("test", closed_loop=loop == "closed"), EMPS_INIT_WINDOW)[0]
    train = rmse(res.validate(res.problem.experiments)[0])
    return {"train_rmse": train, "test_rmse": rmse(test), "test": test}


def starts(count: int, seed: int = 0) -> dict:
    """Open loop from ``count`` starts (the model file's, then uniform within ±50 % of
    the reference, offset 0): the costs single and multiple shooting end at."""
    rng = np.random.default_rng(seed)
    ref = np.array(list(EMPS_IDIM_LS.values())) * [1, 1, 1, 0]
    p0s = [np.array(list(open_loop.p0.values()))]
    p0s += [ref * rng.uniform(0.5, 1.5, 4) for _ in range(count - 1)]
    ends = {}
    for segments in (None, SEGMENTS):
        ends[segments or 1] = [
            ti.fit(problem("open", p0, segments=segments), method="gauss-newton").cost for p0 in p0s
        ]
        print(f"open loop from {count} starts, {segments or 1} segment(s): done", flush=True)
    return {"starts": [p.tolist() for p in p0s], "costs": ends}


def figures(out: Path, fits: dict, reference: dict) -> list[Path]:
    """The test record as simulated by each loop's estimate and by the reference."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    paths = []
    for loop, unit, scale in (("open", "mm", 1e3), ("closed", "µm", 1e6)):
        fig, (top, bottom) = plt.subplots(2, 1, figsize=(9, 5.5), sharex=True)
        test = reference[loop]
        t, y = test.experiment.t, test.experiment.measured[:, 0]
        what = "position qm (m)" if loop == "open" else "tracking error qg − qm (µm)"
        qg = emps("test", closed_loop=True).u[:, 0]

        def shown(q, loop=loop, qg=qg, scale=scale):
            return q if loop == "open" else (qg - q) * scale

        top.plot(t, shown(y), "k", lw=0.8, label="measured")
        shown_fits = [f for f in fits.values() if f["loop"] == loop and "later" not in f["label"]]
        for label, score, style in (
            *((f["label"], f["test"], "-") for f in shown_fits),
            ("IDIM-LS reference", test, "--"),
        ):
            q = score.simulation.y[:, 0]
            top.plot(t, shown(q), style, lw=0.8, label=label)
            bottom.plot(t, (y - q) * scale, style, lw=0.8, label=label)
        if loop == "closed":  # periodic, with µm detail: one period shows it
            bottom.set_xlim(0, 6)
        top.set_ylabel(what)
        bottom.set_ylabel(f"qm − simulated ({unit})")
        bottom.set_xlabel("t (s)")
        top.set_title(
            f"EMPS test record (DATA_EMPS_PULSES), {loop} loop, "
            f"initial states from the first {EMPS_INIT_WINDOW} samples"
            + ("\n(the first 6 s of 24.8)" if loop == "closed" else "")
        )
        top.legend(fontsize=8, loc="upper right")
        fig.tight_layout()
        path = out / f"emps_test_{loop}_loop.png"
        fig.savefig(path, dpi=110)
        plt.close(fig)
        paths.append(path)
    return paths


def table(rows: list[dict]) -> str:
    """The comparison table of docs/emps.md (markdown)."""
    head = (
        "| parameters | M (kg) | Fv (N s/m) | Fc (N) | offset (N) | open loop: train / test "
        "RMSE (mm) | closed loop: train / test RMSE (µm) |\n|---|---|---|---|---|---|---|\n"
    )
    lines = []
    for r in rows:
        p = r["params"]
        lines.append(
            f"| {r['label']} | {p['M']:.2f} | {p['Fv']:.2f} | {p['Fc']:.3f} | {p['offset']:.3f} "
            f"| {1e3 * r['open']['train_rmse']:.2f} / {1e3 * r['open']['test_rmse']:.2f} "
            f"| {1e6 * r['closed']['train_rmse']:.2f} / {1e6 * r['closed']['test_rmse']:.2f} |"
        )
    return head + "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", type=Path, default=Path("emps-study"))
    parser.add_argument("--figures", type=Path, help="write the figures here instead of --out")
    parser.add_argument(
        "--starts", type=int, default=0, help="also fit the open loop from this many starts"
    )
    args = parser.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    started = time.perf_counter()

    fits = {
        "closed": estimate("closed loop", "closed"),
        "closed-delayed": estimate(
            "closed loop, vir one sample later", "closed", model=closed_loop.make_model(1)
        ),
        "open-single": estimate("open loop, single shooting", "open"),
        "open-shooting": estimate(
            f"open loop, multiple shooting ({SEGMENTS} segments)", "open", segments=SEGMENTS
        ),
    }
    # every parameter set in both loops: what it predicts where it was not fitted
    sets = {"reference": ("IDIM-LS reference", EMPS_IDIM_LS)} | {
        k: (f["label"], f["params"]) for k, f in fits.items() if k != "closed-delayed"
    }
    rows = []
    for key, (label, params) in sets.items():
        row = {"label": label, "params": params}
        for loop in LOOPS:
            own = fits.get(key)
            same = own is not None and own["loop"] == loop
            row[loop] = (
                {k: own[k] for k in ("train_rmse", "test_rmse")} if same else held(params, loop)
            )
        rows.append(row)
        print(f"scored {label}", flush=True)
    reference = {loop: rows[0][loop].pop("test") for loop in LOOPS}
    for row in rows[1:]:
        for loop in LOOPS:
            row[loop].pop("test", None)
    paths = figures(args.figures or args.out, fits, reference)

    keep = ("params", "stderr", "cost", "status", "iterations", "seconds", "shooting")
    results = {
        "init_window": EMPS_INIT_WINDOW,
        "reference": {"source": "IDIM-LS, Janot, Gautier & Brunot 2019", **EMPS_IDIM_LS},
        "fits": {
            k: {
                "label": f["label"],
                **{n: f[n] for n in keep},
                "residual_tests": f["residual_tests"],
            }
            | {n: f[n] for n in ("train_rmse", "test_rmse")}
            for k, f in fits.items()
        },
        "table": rows,
        "open_loop_starts": starts(args.starts) if args.starts else None,
        "seconds": time.perf_counter() - started,
    }
    (args.out / "results.json").write_text(json.dumps(results, indent=1, default=float))
    print()
    print(table(rows))
    print()
    for f in fits.values():
        se = ", ".join(f"{n} ± {f['stderr'][n]:.2g}" for n in f["params"])
        print(
            f"{f['label']}: cost {f['cost']:.6g} ({f['status']}, {f['iterations']} iterations, "
            f"{f['seconds']:.1f} s); std. errors {se}"
        )
        for line in f["residual_tests"]:
            print(f"    {line}")
    if args.starts:
        for segments, costs in results["open_loop_starts"]["costs"].items():
            print(f"open loop, {segments} segment(s), final costs: {np.round(costs, 4).tolist()}")
    print(
        f"\nwrote {args.out / 'results.json'} and {', '.join(map(str, paths))} "
        f"in {results['seconds']:.0f} s"
    )


if __name__ == "__main__":
    main()
