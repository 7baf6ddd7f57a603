"""Every performance measurement of tensorid, one after the other on this machine:

    python benchmarks/run_all.py [--quick]

1. bench_derivatives: (J, g, H) against one simulation, jax.hessian and
   finite-difference Hessians on Silverbox (ratios); bench_edge: the same ratios
   measured interleaved, at K = 4, 5 and 33 (issue 43, item 4);
2. bench_peers: whole Silverbox fits against CasADi + IPOPT and SciPy (skipped
   without the optional [bench] extra);
3. bench_multistart: multi-start throughput, pools and vmap batches;
4. bench_scaling: time against P, K and N, and Newton-CG against Newton;
5. bench_long_record: the whole 131,072-sample record, time and peak memory;
6. bench_shooting and bench_shooting_sqp: multiple against single shooting
   (robustness, cost, scaling with S, the block-arrow solver) and the augmented
   Lagrangian against a line-search SQP;
7. bench_methods: newton, gauss-newton and the default auto side by side, from
   Silverbox to a chain of 32 masses (--quick leaves out the two large chains);
8. bench_start_panel and bench_chain_cubic: auto against newton and gauss-newton
   from seeded perturbed starts, and the chain with cubic springs where newton
   stalled;
9. bench_adjoint: exact Hessians of large models, tensors against adjoints,
   jax.hessian and CasADi's generated C code; then the chain of 16 masses alone on
   one core (--one-core);
10. bench_fixed_costs: imports, the command line, compilation in a second process.

Each runs in its own process (so one's compilation cache or memory does not
flatter the next); --quick passes each script its short form. Everything printed
also goes to benchmarks/results/run_all.md (--out to choose), headed by the date,
the machine, the versions and the load average before and after each script, so
that every figure quoted from it carries when and under what load it was measured.
"""

from __future__ import annotations

import argparse
import importlib.util
import subprocess
import sys
import time
from pathlib import Path

HERE = Path(__file__).parent


def _header() -> str:
    import os
    import platform

    import jax

    import tensorid

    return (
        f"# benchmarks/run_all.py, {time.strftime('%Y-%m-%d %H:%M %Z')}\n\n"
        f"tensorid {tensorid.__version__}, jax {jax.__version__}, Python "
        f"{platform.python_version()}, {platform.processor() or platform.machine()}, "
        f"{os.cpu_count()} cores, load average {os.getloadavg()[0]:.1f} at the start\n"
    )


def main() -> None:
    import os

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="short forms, a few minutes in all")
    ap.add_argument("--out", type=Path, default=HERE / "results" / "run_all.md")
    ap.add_argument(
        "--only",
        nargs="+",
        help="scripts (names without .py) or steps (their headings) to run, added to --out",
    )
    args = ap.parse_args()
    q = args.quick
    runs = [
        ("bench_derivatives.py", ["--repeats", "5"] if q else []),
        ("bench_edge.py", ["--repeats", "50"] if q else []),
        ("bench_peers.py", ["--starts", "2", "--no-scipy"] if q else ["--no-scipy"]),
        ("bench_multistart.py", ["--starts", "8"] if q else []),
        ("bench_scaling.py", ["--quick"] if q else []),
        ("bench_long_record.py", ["--samples", "16384"] if q else []),
        ("bench_shooting.py", ["--quick"] if q else []),
        ("bench_shooting_sqp.py", ["--quick"] if q else []),
        (
            "bench_methods.py",
            ["--quick", "--rows", "Silverbox", "two-tank", "N = 10", "Lotka"] if q else [],
        ),
        ("bench_start_panel.py", ["--repeats", "1"] if q else []),
        ("bench_chain_cubic.py", ["--starts", "1", "6"] if q else []),
        ("bench_adjoint.py", ["--quick"] if q else []),
        ("bench_adjoint.py", ["--one-core", "--repeats", "3" if q else "5"]),
        ("bench_fixed_costs.py", ["--repeats", "3"] if q else []),
    ]
    if args.only:
        # a name runs every step of that script; a step's heading ("bench_adjoint.py
        # --one-core --repeats 5") runs that step alone
        runs = [
            (s, e)
            for s, e in runs
            if s.removesuffix(".py") in args.only or " ".join([s, *e]) in args.only
        ]
    args.out.parent.mkdir(parents=True, exist_ok=True)
    with open(args.out, "a" if args.only else "w") as log:  # --only adds to the run

        def say(text: str) -> None:
            print(text, flush=True)
            log.write(text + "\n")
            log.flush()

        say(_header())
        for script, extra in runs:
            say(f"\n## {script} {' '.join(extra)}\n")
            if script in ("bench_peers.py",) and importlib.util.find_spec("casadi") is None:
                say('skipped: CasADi is not installed (python -m pip install -e ".[bench]")')
                continue
            load, t0 = os.getloadavg()[0], time.perf_counter()
            proc = subprocess.run(
                [sys.executable, str(HERE / script), *extra], capture_output=True, text=True
            )
            say(proc.stdout.rstrip())
            if proc.returncode:
                say(f"```\n{proc.stderr[-2000:]}\n```")
            say(
                f"\n({script}: exit {proc.returncode}, {time.perf_counter() - t0:.0f} s, "
                f"load {load:.1f} → {os.getloadavg()[0]:.1f})"
            )


if __name__ == "__main__":
    main()
