"""Event records fitted from NONMEM-style tables by the command line alone, beside R's
nlme on the same model and data (issue 48):

- phenobarbital in 59 neonates (nlme's Phenobarb, bundled in NONMEM's layout):
  repeated IV doses, one compartment, random effects on clearance and volume;
- a multiple-dose study with oral (II/ADDL into the depot, bioavailability F) and
  IV subjects, simulated with a fixed seed by benchmarks/peers/multiple_dose_nlme.R,
  which fits it by nlme with a closed-form superposition model;
- a steady-state study (SS = 1: every subject at steady state when its record starts,
  oral every 12 h or IV every 24 h), simulated by benchmarks/peers/steady_state_nlme.R,
  which fits it by nlme with the closed-form steady state; tensorid fits it with the
  multiple-dose study's model file (the same one compartment).

Each fit runs twice, each time a new `tensorid fit` process: first with an empty cache
folder of its own (its wall time includes compiling everything), then again reading
the programs the first kept. Each estimate is set beside nlme's, on the log scale
where nlme estimates it, with the difference in units of nlme's standard error. nlme
fits by its alternating (Lindstrom-Bates) approximation of the marginal likelihood,
tensorid by FOCEI: the two optima differ slightly by construction.

    python benchmarks/bench_events.py            (needs Rscript with nlme:
                                                   apt-get install r-base-core r-cran-nlme)
"""

from __future__ import annotations

import json
import math
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PEERS = ROOT / "benchmarks" / "peers"


def _rscript(script: Path, *args: str) -> dict:
    out = subprocess.run(["Rscript", str(script), *args], capture_output=True, text=True,
                         check=True)  # fmt: skip
    return json.loads(out.stdout.strip().splitlines()[-1])


def _tensorid(model: str, data: Path, out: Path, *extra: str) -> tuple[dict, str]:
    """The fit (fit.json) and its wall times: a first process with an empty cache
    folder of its own (compiling everything), then a second that reads its programs."""
    env = {**os.environ, "TENSORID_CACHE_DIR": str(out.parent / f"{out.name}-cache")}
    walls = []
    for run in ("cold", "warm"):
        start = time.perf_counter()
        subprocess.run(
            [sys.executable, "-m", "tensorid", "fit", str(ROOT / model), str(data),
             "--records", "ID", "--out", str(out / run), *extra],
            check=True, capture_output=True, text=True, env=env,
        )  # fmt: skip
        walls.append(time.perf_counter() - start)
    fit = json.loads((out / "warm" / "fit.json").read_text())
    return fit, f"{walls[0]:.1f} s wall (a second process: {walls[1]:.1f} s)"


def _rows(fit: dict, peer: dict, names: list[str]) -> list[str]:
    rows = []
    for name in names:
        pop = fit["population"].get(name)
        value = pop["typical"] if pop else fit["params"][name]
        lv, se = peer[f"log_{name}"]
        ours = math.log(value)
        rows.append(f"| log {name} | {ours:.4f} | {lv:.4f} ({se:.4f}) | {(ours - lv) / se:+.2f} |")
    omegas = [fit["population"][n]["omega"] for n in names if n in fit["population"]]
    rows.append(
        "| ω | " + " / ".join(f"{w:.4f}" for w in omegas) + " | "
        + " / ".join(f"{w:.4f}" for w in peer["omega"]) + " | |"
    )  # fmt: skip
    sd = next(iter(fit["residual_sd"].values()))
    rows.append(f"| residual SD | {sd:.4f} | {peer['sigma']:.4f} | |")
    rows.append(f"| −2 log L | {fit['objective']:.4f} | {peer['m2ll']:.4f} | |")
    return rows


def main() -> None:
    if shutil.which("Rscript") is None:
        sys.exit("bench_events needs Rscript with nlme: apt-get install r-base-core r-cran-nlme")
    work = Path(tempfile.mkdtemp(prefix="tensorid-events-"))
    data = ROOT / "src" / "tensorid" / "datasets" / "phenobarbital.csv"
    peer = _rscript(PEERS / "phenobarbital_nlme.R")
    fit, wall = _tensorid("examples/phenobarbital/model.py", data, work / "pheno",
                          "--columns", "t=TIME,conc=DV")  # fmt: skip
    print("## Phenobarbital (59 neonates, repeated IV doses)\n")
    print(f"tensorid fit (CLI, FOCEI): {wall}; nlme: {peer['seconds']:.2f} s\n")
    print("| | tensorid | nlme (SE) | difference / SE |\n|---|---|---|---|")
    print("\n".join(_rows(fit, peer, ["cl", "v"])))
    _simulated(work, "multiple_dose", "Multiple doses, oral (II/ADDL, F) and IV (24 subjects)")
    _simulated(work, "steady_state", "Steady state, oral and IV (SS = 1, 24 subjects)")


def _simulated(work: Path, study: str, title: str) -> None:
    """A study its peer script simulates and fits (benchmarks/peers/<study>_nlme.R),
    fitted by the multiple-dose model file beside it."""
    table = work / f"{study}.csv"
    peer = _rscript(PEERS / f"{study}_nlme.R", str(table))
    fit, wall = _tensorid("examples/multiple_dose/model.py", table, work / study,
                          "--columns", "t=TIME,cp=DV", "--substeps", "16")  # fmt: skip
    print(f"\n## {title}\n")
    print(f"tensorid fit (CLI, FOCEI, --substeps 16): {wall}; nlme: "
          f"{peer['seconds']:.2f} s\n")  # fmt: skip
    print("| | tensorid | nlme (SE) | difference / SE |\n|---|---|---|---|")
    print("\n".join(_rows(fit, peer, ["ka", "cl", "v", "F"])))


if __name__ == "__main__":
    main()
