"""(J, ∇J, ∇²J) against ``jax.hessian`` of the plain cost and against one simulation,
measured interleaved in one process (issue 43, item 4).

    python benchmarks/bench_edge.py [--repeats 200] [--only silverbox|chain16]
    python benchmarks/bench_edge.py --filter [--fits 3]

Each round calls every computation of a problem once, in turn, so that the load of a
shared machine falls on all of them alike; each row is the median over the rounds,
and each ratio the median of the per-round ratios. Problems: the paper's Silverbox
(N = 2, K = 5, P = 1,024, RK4 with 4 substeps), the paper's two-tank (N = 2, K = 4,
P = 501) and the chain of 16 masses (N = 32, K = 33, 400 samples), each by the path
``Problem(hessian="auto")`` picks (the transition tensors; the second-order adjoint
for the chain), called as a fit calls it (``Problem.cost_grad_hess``) and as the
bare compiled sweep.

``--filter`` (item 5): ``tensorid fit`` of the bundled two-tank record (the paper's
model and guess, 501 samples) as output error and with ``--predictor ekf``, each in
a new process with an empty cache folder and then again with it filled, alternating:
wall time, the seconds JAX reports compiling (``/jax/core/compile/`` events), XLA
compilations, and each program's first call (compiled, or read from the cache) by
name, as tensorid announces them.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

import tensorid as ti
from tensorid import benchmarks


def calls(prob: ti.Problem) -> dict:
    """The computations timed for one problem, each a function of nothing."""
    sw, (t, u, y) = prob._sweeps, prob._arrays[0]
    x0, p, w = jnp.asarray(prob.x0[0]), jnp.asarray(prob.p0), jnp.asarray(prob.loss_weights)
    theta = prob.theta0 * 1.02
    th = jnp.asarray(theta)
    hess = jax.jit(jax.hessian(prob.jax_cost))
    sweep = sw.adjoint if prob.hessian == "adjoint" else sw.second_order_both
    return {
        "simulation": lambda: sw.simulate(x0, p, t, u),
        "cost": lambda: sw.cost(th, x0, p, t, u, y, w),
        f"(J, g, H) sweep ({prob.hessian})": lambda: sweep(th, x0, p, t, u, y, w),
        "(J, g, H) Problem.cost_grad_hess": lambda: prob.cost_grad_hess(theta),
        "jax.hessian": lambda: hess(th),
    }


def interleaved(fns: dict, repeats: int) -> dict:
    """Per computation, the list of its wall times, one per round."""
    for fn in fns.values():  # compile
        jax.block_until_ready(fn())
    times: dict = {k: [] for k in fns}
    names = list(fns)
    for r in range(repeats):
        for k in names[r % len(names) :] + names[: r % len(names)]:
            t0 = time.perf_counter()
            jax.block_until_ready(fns[k]())
            times[k].append(time.perf_counter() - t0)
    return times


def report(title: str, prob: ti.Problem, repeats: int) -> dict:
    times = interleaved(calls(prob), repeats)
    med = {k: statistics.median(v) for k, v in times.items()}
    sweep = next(k for k in times if k.startswith("(J, g, H) sweep"))
    ratios = {}
    print(f"\n### {title}: N = {prob.model.N}, K = {prob.K}, P = {prob.experiments[0].P}, "
          f"path {prob.hessian}, {repeats} rounds\n")  # fmt: skip
    print("| computation | median ms | × simulation | × jax.hessian |")
    print("|---|---:|---:|---:|")
    for k, v in times.items():
        per_sim = statistics.median(np.array(v) / np.array(times["simulation"]))
        per_ad = statistics.median(np.array(v) / np.array(times["jax.hessian"]))
        ratios[k] = (med[k], per_sim, per_ad)
        print(f"| {k} | {med[k] * 1e3:.3f} | {per_sim:.2f} | {per_ad:.2f} |")
    q = np.array(times[sweep]) / np.array(times["jax.hessian"])
    print(f"\nsweep / jax.hessian per round: quartiles {np.percentile(q, 25):.2f}–"
          f"{np.percentile(q, 75):.2f}")  # fmt: skip
    return ratios


PROBLEMS = {
    "silverbox": ("Silverbox (paper)", lambda: benchmarks.silverbox_problem()),
    "two-tank": ("two-tank (paper)", lambda: benchmarks.two_tank_problem()),
    "chain16": ("chain of 16 masses", lambda: benchmarks.mass_chain_problem(16, samples=400)),
}


# the command line with JAX's compile events and tensorid's program announcements counted
CLI = """
import json, sys, atexit, collections
import jax.monitoring as m
n = {"xla": 0, "compile_s": 0.0, "programs": collections.Counter(), "program_s": {}}
def on(event, secs, **kw):
    if event.startswith("/jax/core/compile/"):
        n["compile_s"] += secs
    if event == "/jax/core/compile/backend_compile_duration":
        n["xla"] += 1
    if event == "/tensorid/compile/end":
        what = kw.get("what", "?")
        n["programs"][what] += 1
        n["program_s"][what] = n["program_s"].get(what, 0.0) + secs
m.register_event_duration_secs_listener(on)
where = sys.argv[1]
atexit.register(lambda: open(where, "w").write(json.dumps(n)))
from tensorid.cli import main
sys.argv = ["tensorid", *sys.argv[2:]]
sys.exit(main())
"""


def _fit(model: Path, data: Path, cache: Path, out: Path, extra: list) -> dict:
    env = {k: v for k, v in os.environ.items() if k != "TENSORID_CACHE"}
    src = Path(__file__).resolve().parent.parent / "src"
    env.update(PYTHONPATH=str(src), TENSORID_CACHE_DIR=str(cache), MPLCONFIGDIR=str(out / "mpl"))
    out.mkdir(parents=True, exist_ok=True)
    counts = out / "counts.json"
    cmd = [sys.executable, "-c", CLI, str(counts), "fit", str(model), str(data), *extra]
    t0 = time.perf_counter()
    done = subprocess.run(cmd + ["--out", str(out / "fit")], env=env, capture_output=True)
    wall = time.perf_counter() - t0
    if done.returncode not in (0, 1):
        raise RuntimeError(done.stderr.decode()[-2000:])
    fit = json.loads((out / "fit" / "fit.json").read_text())
    keep = {k: fit.get(k) for k in ("iterations", "seconds", "compile_seconds")}
    return dict(wall=wall, **keep, **json.loads(counts.read_text()))


# the Python API's fit, twice in one process: the FitResult's own seconds
API = """
import json, sys
import tensorid as ti
from tensorid import benchmarks
out = []
for _ in range(2):
    prob = benchmarks.two_tank_problem(**json.loads(sys.argv[1]))
    res = ti.fit(prob)
    out.append(dict(seconds=res.seconds, compile_seconds=res.compile_seconds, nit=res.nit))
print(json.dumps(out))
"""


def _api(cache: Path, kw: dict) -> list:
    env = {k: v for k, v in os.environ.items() if k != "TENSORID_CACHE"}
    src = Path(__file__).resolve().parent.parent / "src"
    env.update(PYTHONPATH=str(src), TENSORID_CACHE_DIR=str(cache))
    cmd = [sys.executable, "-c", API, json.dumps(kw)]
    done = subprocess.run(cmd, env=env, capture_output=True, text=True, check=True)
    return json.loads(done.stdout.strip().splitlines()[-1])


def filter_fits(fits: int) -> None:
    """Item 5: the EKF fit against the output-error fit of two-tank, cold and warm."""
    from bench_first_fit import _two_tank

    work = Path(tempfile.mkdtemp(prefix="tensorid-edge-"))
    model, data, _ = _two_tank(work)
    kinds = {"output error": [], "ekf": ["--predictor", "ekf"]}
    rows: dict = {k: [] for k in kinds}
    api: dict = {k: [] for k in kinds}
    load = [os.getloadavg()[0]]
    for r in range(fits):
        for kind, extra in kinds.items():  # alternating: the load falls on both alike
            folder = work / f"{kind.replace(' ', '-')}-{r}"
            folder.mkdir()
            cold = _fit(model, data, folder / "cache", folder / "cold", extra)
            warm = _fit(model, data, folder / "cache", folder / "warm", extra)
            rows[kind].append((cold, warm))
            kw = {"predictor": "ekf"} if extra else {}
            api[kind].append(_api(folder / "api-cache", kw) + _api(folder / "api-cache", kw))
            load.append(os.getloadavg()[0])
    print(f"\nload average {min(load):.1f}-{max(load):.1f}; medians of {fits}")
    print("\n### two-tank: ti.fit (Python), FitResult.seconds (compilation included)\n")
    print(
        "| fit | new cache: 1st fit s (compile s) | same process: 2nd fit s | "
        "cache filled, new process: 1st fit s (compile s) | iterations |"
    )
    print("|---|---:|---:|---:|---:|")
    for kind, runs in api.items():
        m = [statistics.median(r[i][k] for r in runs) for i in (0, 1, 2)
             for k in ("seconds", "compile_seconds")]  # fmt: skip
        print(
            f"| {kind} | {m[0]:.2f} ({m[1]:.2f}) | {m[2]:.2f} | {m[4]:.2f} ({m[5]:.2f}) "
            f"| {runs[0][0]['nit']} |"
        )
    print("\n### two-tank: tensorid fit, output error against --predictor ekf\n")
    print("| fit | cold wall s | cold compile s | compile share | XLA compilations | "
          "warm wall s | warm compile s | iterations |")  # fmt: skip
    print("|---|---:|---:|---:|---:|---:|---:|---:|")
    for kind, runs in rows.items():
        cold = [c for c, _ in runs]
        warm = [w for _, w in runs]
        cells = [
            f"{_median(cold, 'wall'):.2f}",
            f"{_median(cold, 'compile_s'):.2f}",
            f"{statistics.median(c['compile_s'] / c['wall'] for c in cold):.0%}",
            f"{_median(cold, 'xla'):g}",
            f"{_median(warm, 'wall'):.2f}",
            f"{_median(warm, 'compile_s'):.2f}",
            f"{cold[0]['iterations']}",
        ]
        print(f"| {kind} | " + " | ".join(cells) + " |")
    for kind, runs in rows.items():
        cold = runs[len(runs) // 2][0]
        progs = sorted(cold["program_s"].items(), key=lambda kv: -kv[1])
        text = ", ".join(_program(w, s, cold["programs"][w]) for w, s in progs)
        print(f"\n{kind}, programs' first calls in a cold run ({len(progs)}): {text}")


def _median(runs: list, key: str) -> float:
    return statistics.median(r[key] for r in runs)


def _program(what: str, seconds: float, count: int) -> str:
    return f"{what} {seconds:.2f} s" + (f" (×{count})" if count > 1 else "")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=200)
    ap.add_argument("--only", choices=list(PROBLEMS))
    ap.add_argument("--filter", action="store_true", help="item 5: EKF fit against output error")
    ap.add_argument("--fits", type=int, default=3)
    args = ap.parse_args()
    if args.filter:
        filter_fits(args.fits)
        return
    for key, (title, make) in PROBLEMS.items():
        if args.only in (None, key):
            n = max(5, args.repeats // 10) if key == "chain16" else args.repeats
            report(title, make(), n)
    print(f"\ntensorid {ti.__version__}, jax {jax.__version__}, {jax.default_backend()}")


if __name__ == "__main__":
    main()
