"""Theophylline by FOCEI from the command line, at its default settings, side by side
with R's nlme fitting the same model to the same file (issue 50): the whole `tensorid
fit` process cold (an empty cache folder) and warm (a second process on that folder),
against the whole `Rscript` process.

    python benchmarks/bench_theophylline.py              (needs Rscript with nlme:
    python benchmarks/bench_theophylline.py --laplace     apt-get install r-base-core
                                                          r-cran-nlme)

The model: one compartment, first-order absorption, log-normal random effects on ka,
cl and v (diagonal Ω), additive error; nlme's is the same in closed form
(benchmarks/peers/theophylline_nlme.R), fitted by ML with its own (Lindstrom-Bates)
approximation, so its −2 log L and estimates differ from FOCEI's in the third digit.
Each tensorid process is timed whole (imports, the fit, its files and figures); the
medians of --repeats warm runs and of as many Rscript runs. Ratios printed, and
written to benchmarks/results/theophylline.json with --json.
"""

from __future__ import annotations

import argparse
import json
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT / "src" / "tensorid" / "datasets" / "theophylline.csv"
MODEL = ROOT / "examples" / "theophylline" / "model.py"
PEER = ROOT / "benchmarks" / "peers" / "theophylline_nlme.R"


def _timed(cmd: list[str], env: dict | None = None) -> tuple[float, str]:
    import os

    t = time.perf_counter()
    out = subprocess.run(cmd, capture_output=True, text=True, env={**os.environ, **(env or {})})
    took = time.perf_counter() - t
    if out.returncode != 0:
        sys.exit(f"{' '.join(cmd)} failed ({out.returncode}):\n{out.stderr[-2000:]}")
    return took, out.stdout


def _tensorid(cache: Path, out: Path, method: str) -> tuple[float, dict]:
    cmd = ["tensorid", "fit", str(MODEL), str(DATA), "--records", "ID", "--columns",
           "t=Time,cp=conc", "--method", method, "--out", str(out), "--no-progress"]  # fmt: skip
    took, _ = _timed(cmd, {"TENSORID_CACHE_DIR": str(cache)})
    return took, json.loads((out / "fit.json").read_text())


def _method(method: str, repeats: int, work: Path) -> dict:
    cache = work / f"cache-{method}"
    cold, _ = _tensorid(cache, work / f"cold-{method}", method)
    runs = [_tensorid(cache, work / f"warm-{method}", method) for _ in range(repeats)]
    warm, fit = [t for t, _ in runs], runs[-1][1]
    return {"cold_s": cold, "warm_s": statistics.median(warm), "warm_runs_s": warm,
            "fit_seconds_warm": fit["seconds"], "objective": fit["objective"],
            "params": fit["params"],
            "omega": {n: v["omega"] for n, v in fit["population"].items()},
            "sigma": fit["residual_sd"]["cp"]}  # fmt: skip


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--laplace", action="store_true", help="Laplace too (its own programs)")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()
    if shutil.which("Rscript") is None:
        sys.exit("bench_theophylline needs Rscript with nlme: apt-get install r-base-core "
                 "r-cran-nlme")  # fmt: skip
    runs = [_timed(["Rscript", str(PEER), str(DATA)]) for _ in range(args.repeats)]
    peer = json.loads(runs[-1][1].strip().splitlines()[-1])
    peer["process_s"] = statistics.median(r[0] for r in runs)
    with tempfile.TemporaryDirectory() as tmp:
        ours = {"focei": _method("focei", args.repeats, Path(tmp))}
        if args.laplace:
            ours["laplace"] = _method("laplace", args.repeats, Path(tmp))
    r = peer["process_s"]
    print(
        f"R nlme: Rscript process {r:.2f} s (its fit {peer['seconds']:.2f} s), "
        f"-2 log L {peer['m2ll']:.4f}, ka {peer['ka']:.4f}, cl {peer['cl']:.4f}, "
        f"v {peer['v']:.3f}, omega {peer['omega']}, sigma {peer['sigma']:.4f}"
    )
    for name, o in ours.items():
        p = o["params"]
        print(f"tensorid {name}: cold {o['cold_s']:.1f} s ({o['cold_s'] / r:.0f}x Rscript), "
              f"warm {o['warm_s']:.1f} s ({o['warm_s'] / r:.1f}x; the fit itself "
              f"{o['fit_seconds_warm']:.1f} s), -2 log L {o['objective']:.4f}, ka "
              f"{p['ka']:.4f}, cl {p['cl']:.4f}, v {p['v']:.3f}, omega "
              f"{[round(v, 5) for v in o['omega'].values()]}, sigma {o['sigma']:.4f}")  # fmt: skip
    if args.laplace:
        ratio = ours["laplace"]["warm_s"] / ours["focei"]["warm_s"]
        print(f"Laplace / FOCEI, warm: {ratio:.2f}")
    if args.json:
        path = ROOT / "benchmarks" / "results" / "theophylline.json"
        path.write_text(json.dumps({"nlme": peer, "tensorid": ours}, indent=2) + "\n")
        print(f"wrote {path}")


if __name__ == "__main__":
    main()
