"""Time and peak memory on the whole 131,072-sample Silverbox SNLS80mV record.

    python benchmarks/bench_long_record.py [--samples 131072] [--substeps 4]

Each measurement runs in its own process so that its peak resident memory (RSS)
is its own: importing tensorid and loading the record ("baseline"); one plain cost;
one (J, g, H) by transition tensors; jax.hessian through the same simulator; and a
whole Newton fit from the paper's initial guess (model with an input offset u0 and
free y(t0), ẏ(t0); K = 7). Times exclude compilation, which is listed apart.

J, g and H are accumulated sample by sample inside the compiled sweep, so memory
does not grow with the record length: an array of the sensitivities of every
sample (P × N × K × K) is never formed.
"""

from __future__ import annotations

import argparse
import json
import resource
import subprocess
import sys
import time


def _peak_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024  # Linux: kB


def _problem(samples: int, substeps: int):
    from tensorid import benchmarks, datasets

    data = datasets.silverbox_snls80mV(stop=samples)
    return benchmarks.silverbox_problem(substeps=substeps, offset=True, data=data)


def measure(what: str, samples: int, substeps: int) -> dict:
    import jax
    import jax.numpy as jnp

    import tensorid as ti

    prob = _problem(samples, substeps)
    th = prob.theta0
    out: dict = {"what": what, "samples": samples}
    if what == "baseline":
        pass
    elif what == "fit":
        t0 = time.perf_counter()
        res = ti.fit(prob, "newton")
        out.update(
            seconds=time.perf_counter() - t0,
            nit=res.nit,
            cost=res.cost,
            success=res.success,
            params=res.params,
            message=res.message,
        )
    else:
        fn = {
            "cost": lambda: prob.cost(th),
            "tensors": lambda: prob.cost_grad_hess(th),
            "jax.hessian": (lambda h: lambda: jax.block_until_ready(h(jnp.asarray(th))))(
                jax.jit(jax.hessian(prob.jax_cost))
            ),
        }[what]
        t0 = time.perf_counter()
        fn()
        out["compile_s"] = time.perf_counter() - t0
        t0 = time.perf_counter()
        fn()
        out["seconds"] = time.perf_counter() - t0
    out["peak_mb"] = _peak_mb()
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--samples", type=int, default=131_072)
    ap.add_argument("--substeps", type=int, default=4)
    ap.add_argument("--one", help=argparse.SUPPRESS)
    ap.add_argument("--skip-jax-hessian", action="store_true")
    args = ap.parse_args()
    if args.one:
        print(json.dumps(measure(args.one, args.samples, args.substeps)))
        return
    whats = ["baseline", "cost", "tensors", "jax.hessian", "fit"]
    if args.skip_jax_hessian:
        whats.remove("jax.hessian")
    rows = []
    for what in whats:
        cmd = [sys.executable, __file__, "--one", what, "--samples", str(args.samples)]
        cmd += ["--substeps", str(args.substeps)]
        r = subprocess.run(cmd, capture_output=True, text=True)
        if r.returncode:
            rows.append({"what": what, "error": r.stderr.strip().splitlines()[-1]})
        else:
            rows.append(json.loads(r.stdout.strip().splitlines()[-1]))
    base = rows[0]["peak_mb"]
    print(f"Silverbox SNLS80mV, P = {args.samples}, RK4 × {args.substeps}, K = 7 (offset model)")
    print(f"{'':14s} {'run s':>8s} {'compile s':>10s} {'peak RSS MB':>12s} {'above baseline':>15s}")
    for r in rows:
        if "error" in r:
            print(f"{r['what']:14s} failed: {r['error']}")
            continue
        run = f"{r['seconds']:.3f}" if "seconds" in r else ""
        comp = f"{r['compile_s']:.2f}" if "compile_s" in r else ""
        peak = r["peak_mb"]
        print(f"{r['what']:14s} {run:>8s} {comp:>10s} {peak:12.0f} {peak - base:15.0f}")
    fit = next((r for r in rows if r["what"] == "fit" and "error" not in r), None)
    if fit:
        print(
            f"\nNewton fit of the whole record (compilation included): {fit['nit']} iterations, "
            f"cost {fit['cost']:.6g}, success {fit['success']} ({fit['message']})"
        )
        print("  " + ", ".join(f"{k} = {v:.6g}" for k, v in fit["params"].items()))
    N, K = 2, 7
    print(
        f"(one P × N × K × K array of second-order sensitivities would take "
        f"{args.samples * N * K * K * 8 / 2**20:.0f} MB; it is never formed)"
    )


if __name__ == "__main__":
    main()
