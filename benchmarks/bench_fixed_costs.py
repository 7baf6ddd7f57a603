"""The time around the fits: imports, the command line, and compilation in a second
process, each in fresh processes.

    python benchmarks/bench_fixed_costs.py [--repeats 5]

Prints medians (and the range) of:

- ``python -c "import jax"`` and ``python -c "import tensorid"``;
- ``tensorid fit --help``;
- the README's command-line fit of the bundled Silverbox example (with validation,
  report and four figures), warm: run once to fill the caches (Python's bytecode
  of tensorid's modules too, even where PYTHONDONTWRITEBYTECODE is set), then
  timed, wall and CPU (user + system, the figure renderers included), with a cache
  folder of its own that the first run filled (``--user-cache``: the user's, as it is);
- the benchmarks' scoring of that fit on the validation record, ``tensorid compare``
  (one figure), warm;
- the same fit from Python in a second process against the first, with an empty
  cache folder: the seconds JAX spent compiling (``FitResult.compile_seconds``) and
  the whole wall time.

Each command runs in its own process, alternating, so that a change in the machine's
load falls on all of them alike; the load average is printed with the results.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
EXAMPLE = ROOT / "examples" / "silverbox"
FIT = [
    "fit",
    str(EXAMPLE / "model.py"),
    str(EXAMPLE / "train.csv"),
    "--validate",
    str(EXAMPLE / "validate.csv"),
    "--no-progress",
]
PYTHON_FIT = """
import json, sys, time
t0 = time.perf_counter()
import tensorid as ti
spec = ti.load_model(sys.argv[1])
data = ti.load_data(sys.argv[2], spec.model)
prob = ti.Problem(spec.model, data, p0=spec.p0, x0=spec.x0_array(), free_x0=spec.free_x0,
                  bounds=spec.bounds)
res = ti.fit(prob)
res.summary()  # the error bars, as a user asks for them
print(json.dumps({"compile": res.compile_seconds, "wall": time.perf_counter() - t0}))
"""


def _timed(args: list[str], env: dict | None = None) -> tuple[float, float]:
    """(wall seconds, CPU seconds of the process and its children)."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    subprocess.run(args, check=True, capture_output=True, env=env)
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return wall, cpu


def _line(name: str, values: list[float], command: str) -> str:
    med = statistics.median(values)
    return f"| {name} | {med:.2f} s | {min(values):.2f}–{max(values):.2f} s | `{command}` |"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument(
        "--module",
        action="store_true",
        help="run the command as python -m tensorid (e.g. another checkout on PYTHONPATH)",
    )
    ap.add_argument(
        "--user-cache",
        action="store_true",
        help="time the commands with the user's cache folder as it is, not a fresh one",
    )
    args = ap.parse_args()
    tensorid = None if args.module else shutil.which("tensorid")
    cli = [tensorid] if tensorid else [sys.executable, "-m", "tensorid"]
    out = Path(tempfile.mkdtemp(prefix="tensorid-fixed-costs-"))
    fit = [*cli, *FIT, "--out", str(out / "fit")]
    compare = [*cli, "compare", FIT[1], str(EXAMPLE / "validate.csv")]
    compare += ["--params", str(out / "fit" / "fit.json"), "--out", str(out / "compare")]
    # fill the caches, Python's bytecode of tensorid's modules among them: where the
    # environment says not to write it (PYTHONDONTWRITEBYTECODE, as on our machines),
    # every timed run would compile tensorid's sources again (0.1 s of a fit),
    # which a user's installation does once
    warm = {k: v for k, v in os.environ.items() if k != "PYTHONDONTWRITEBYTECODE"}
    # the commands' caches as a user has them after one run of this version: a fresh
    # folder, filled by the warm-up (a folder that JAX's cache filled under an earlier
    # version holds compiled code under which no executable is kept:
    # engine/compiling/executables.py)
    own = {} if args.user_cache else {"TENSORID_CACHE_DIR": str(out / "cache" / "jax")}
    warm.update(own)
    commands = dict(os.environ, **own)
    subprocess.run(fit, check=True, capture_output=True, env=warm)
    subprocess.run(compare, check=True, capture_output=True, env=warm)
    load0 = os.getloadavg()[0]
    names = ("jax", "tensorid", "help", "fit", "cpu", "compare")
    rows: dict[str, list[float]] = {k: [] for k in names}
    for _ in range(args.repeats):
        rows["jax"].append(_timed([sys.executable, "-c", "import jax"])[0])
        rows["tensorid"].append(_timed([sys.executable, "-c", "import tensorid"])[0])
        rows["help"].append(_timed([*cli, "fit", "--help"])[0])
        wall, cpu = _timed(fit, commands)
        rows["fit"].append(wall)
        rows["cpu"].append(cpu)
        rows["compare"].append(_timed(compare, commands)[0])
    firsts, seconds = [], []
    for _ in range(max(1, args.repeats // 2)):
        cache = Path(tempfile.mkdtemp(prefix="tensorid-cache-"))
        env = dict(os.environ, TENSORID_CACHE_DIR=str(cache / "jax"))
        runs = []
        for _ in range(2):
            done = subprocess.run(
                [sys.executable, "-c", PYTHON_FIT, *FIT[1:3]],
                check=True,
                capture_output=True,
                text=True,
                env=env,
            )
            runs.append(json.loads(done.stdout.strip().splitlines()[-1]))
        firsts.append(runs[0])
        seconds.append(runs[1])
        shutil.rmtree(cache, ignore_errors=True)
    load1 = os.getloadavg()[0]
    shutil.rmtree(out, ignore_errors=True)
    when = time.strftime("%Y-%m-%d %H:%M %Z")
    print(f"{when}, {os.cpu_count()} cores, load {load0:.1f} → {load1:.1f}")
    print("(the commands with the user's cache folder)" if args.user_cache else
          "(the commands with a fresh cache folder, filled by one run first)")  # fmt: skip
    if os.environ.get("PYTHONDONTWRITEBYTECODE"):
        print("(PYTHONDONTWRITEBYTECODE is set here: the warm-up wrote tensorid's bytecode)")
    print("\n| what | median | range | command |\n|---|---|---|---|")
    print(_line("import jax", rows["jax"], 'python -c "import jax"'))
    print(_line("import tensorid", rows["tensorid"], 'python -c "import tensorid"'))
    print(_line("tensorid fit --help", rows["help"], "tensorid fit --help"))
    print(
        _line(
            "warm CLI fit of the Silverbox example, wall",
            rows["fit"],
            "tensorid " + " ".join(FIT[:1]) + " examples/silverbox/… --validate …",
        )
    )
    print(_line("the same, CPU (user + system, renderers included)", rows["cpu"], "(same)"))
    print(
        _line(
            "warm `tensorid compare` of that fit on the validation record",
            rows["compare"],
            "tensorid compare examples/silverbox/model.py …/validate.csv --params fit.json",
        )
    )
    extra = statistics.median(rows["tensorid"]) - statistics.median(rows["jax"])
    print(f"\nimport tensorid − import jax: {extra:+.2f} s")
    ratio = [s["compile"] / f["compile"] for f, s in zip(firsts, seconds, strict=True)]
    print(
        "Python fit in a second process / the first (empty cache folder): compile "
        f"{statistics.median(ratio):.2f}× ({', '.join(f'{r:.2f}' for r in ratio)}; first "
        f"{statistics.median(f['compile'] for f in firsts):.2f} s, second "
        f"{statistics.median(s['compile'] for s in seconds):.2f} s), whole process "
        f"{statistics.median(f['wall'] for f in firsts):.2f} s → "
        f"{statistics.median(s['wall'] for s in seconds):.2f} s"
    )


if __name__ == "__main__":
    main()
