"""Every performance measurement of tensorid, one after the other on this machine:

    python benchmarks/run_all.py [--quick]

1. bench_derivatives: (J, g, H) against one simulation, jax.hessian and
   finite-difference Hessians on Silverbox (ratios);
2. bench_peers: whole Silverbox fits against CasADi + IPOPT and SciPy (skipped
   without the optional [bench] extra);
3. bench_multistart: multi-start throughput, pools and vmap batches;
4. bench_scaling: time against P, K and N, and Newton-CG against Newton;
5. bench_long_record: the whole 131,072-sample record, time and peak memory;
6. bench_shooting and bench_shooting_sqp: multiple against single shooting
   (robustness, cost, scaling with S, the block-arrow solver) and the augmented
   Lagrangian against a line-search SQP;
7. bench_methods: newton, gauss-newton and the default auto side by side, from
   Silverbox to a chain of 32 masses (--quick leaves out the two large chains).

Each runs in its own process (so one's compilation cache or memory does not
flatter the next); --quick passes each script its short form.
"""

from __future__ import annotations

import argparse
import importlib.util
import subprocess
import sys
import time
from pathlib import Path

HERE = Path(__file__).parent


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="short forms, a few minutes in all")
    args = ap.parse_args()
    q = args.quick
    runs = [
        ("bench_derivatives.py", ["--repeats", "5"] if q else []),
        ("bench_peers.py", ["--starts", "2", "--no-scipy"] if q else []),
        ("bench_multistart.py", ["--starts", "8"] if q else []),
        ("bench_scaling.py", ["--quick"] if q else []),
        ("bench_long_record.py", ["--samples", "16384"] if q else []),
        ("bench_shooting.py", ["--quick"] if q else []),
        ("bench_shooting_sqp.py", ["--quick"] if q else []),
        (
            "bench_methods.py",
            ["--quick", "--rows", "Silverbox", "two-tank", "N = 10", "Lotka"] if q else [],
        ),
    ]
    for script, extra in runs:
        print(f"\n# {script} {' '.join(extra)}\n", flush=True)
        if script == "bench_peers.py" and importlib.util.find_spec("casadi") is None:
            print('skipped: CasADi is not installed (python -m pip install -e ".[bench]")')
            continue
        t0 = time.perf_counter()
        rc = subprocess.call([sys.executable, str(HERE / script), *extra])
        print(f"\n({script}: exit {rc}, {time.perf_counter() - t0:.0f} s)", flush=True)


if __name__ == "__main__":
    main()
