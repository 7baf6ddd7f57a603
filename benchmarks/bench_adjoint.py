"""Exact Hessians for large models: the transition tensors against second-order
adjoints, jax.hessian and CasADi, and what hessian="auto" picks.

    python benchmarks/bench_adjoint.py [--quick] [--repeats 5] [--no-casadi]

One (J, ∇J, ∇²J) of one experiment, times after compilation, each row in its own
process (the paths of a row side by side in it), on problems from the paper's
sizes (Silverbox, two-tank: N = 2, K = 4-5) to a chain of 32 masses (N = 64,
K = 65); the cost model of hessian="auto" (engine/sweeping/adjoint.py) is fitted to them:

- tensors: the paper's forward transition tensors (Problem(hessian="tensors"));
- adjoint: second-order adjoints (engine/sweeping/adjoint.py), with every core this
  process may use and with one thread (TENSORID_THREADS=1);
- jax.hessian: forward-over-reverse automatic differentiation of the same simulator;
- auto: the path Problem(hessian="auto") picks, and how many times faster it is
  than the tensors and than jax.hessian; "predicted" is the cost model's
  tensors/adjoint ratio; "÷ GN" the adjoint Hessian in first-order (Gauss-Newton)
  sweeps.
- diff: largest |H_adjoint − H_tensors| / largest |H_tensors|.

With the optional casadi package (pip install casadi, the [bench] extra), the mass
chain of 5 masses (N = 10, K = 11, 2,000 samples) is also timed in CasADi: the same
RK4 scheme, its exact Hessian interpreted and as generated C code compiled by gcc -O1.
--quick leaves out the chain of 32 masses and CasADi.

--one-core times the chain of 16 masses (N = 32, K = 33) alone in a process held to
one core (CPU 0, as ``taskset -c 0``; so one thread everywhere) with the persistent
compilation cache off: the speed issue's "adjoint ≤ 0.5× jax.hessian on one core".
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
from _timing import time_call
from bench_scaling import chebyshev_problem

import tensorid as ti
from tensorid import benchmarks
from tensorid.engine import adjoint


def _chain5(N: int, h: str) -> ti.Problem:
    """bench_scaling's chain of N/2 masses sharing five parameters (K = 5)."""
    from bench_scaling import chain_model

    model = chain_model(N // 2)
    t = np.arange(1024) * 0.05
    u = np.sin(0.7 * t) + 0.5 * np.sin(1.9 * t)
    p = dict(zip(model.params, [1.0, 2.0, 0.5, 1.0, 0.1], strict=True))
    y = ti.simulate(model, p, np.zeros(N), ti.Experiment(t, u)).y
    return ti.Problem(model, ti.Experiment(t, u, 1.01 * y + 0.01), p0=p, x0=np.zeros(N), hessian=h)


ROWS = [
    ("Silverbox (paper)", lambda h: benchmarks.silverbox_problem(hessian=h)),
    ("two-tank (paper)", lambda h: benchmarks.two_tank_problem(hessian=h)),
    ("Lotka-Volterra", lambda h: benchmarks.lotka_volterra_problem(hessian=h)),
    ("Chebyshev K = 10", lambda h: chebyshev_problem(10, hessian=h)),
    ("Chebyshev K = 16", lambda h: chebyshev_problem(16, hessian=h)),
    ("chain, 1 mass", lambda h: benchmarks.mass_chain_problem(1, hessian=h)),
    ("chain, 2 masses", lambda h: benchmarks.mass_chain_problem(2, hessian=h)),
    ("chain, 3 masses", lambda h: benchmarks.mass_chain_problem(3, hessian=h)),
    ("chain, 5 masses", lambda h: benchmarks.mass_chain_problem(5, hessian=h)),
    ("chain, 8 masses", lambda h: benchmarks.mass_chain_problem(8, samples=400, hessian=h)),
    ("chain, 16 masses", lambda h: benchmarks.mass_chain_problem(16, samples=400, hessian=h)),
    ("chain K = 5, 4 masses", lambda h: _chain5(8, h)),
    ("chain K = 5, 16 masses", lambda h: _chain5(32, h)),
    ("chain, 32 masses", lambda h: benchmarks.mass_chain_problem(32, samples=400, hessian=h)),
]


def _hessian_call(prob: ti.Problem):
    """One experiment's (J, g, H, H_gn) by the problem's own path, no assembly."""
    sw, (t, u, y) = prob._sweeps, prob._arrays[0]
    x0, p, w = jnp.asarray(prob.x0[0]), jnp.asarray(prob.p0), jnp.asarray(prob.loss_weights)
    th = jnp.asarray(prob.theta0 * 1.02)
    sweep = sw.adjoint if prob.hessian == "adjoint" else sw.second_order_both
    return lambda: sweep(th, x0, p, t, u, y, w)


def _one_thread(fn):
    """fn() with the adjoint on one thread, the caller's TENSORID_THREADS kept."""
    before = os.environ.get("TENSORID_THREADS")
    os.environ["TENSORID_THREADS"] = "1"
    try:
        return fn(), None
    finally:
        if before is None:
            del os.environ["TENSORID_THREADS"]
        else:
            os.environ["TENSORID_THREADS"] = before


def row(name: str, make, repeats: int) -> None:
    ten, adj = make("tensors"), make("adjoint")
    auto = make("auto").hessian
    theta = ten.theta0 * 1.02
    H_t, H_a = ten.cost_grad_hess(theta)[2], adj.cost_grad_hess(theta)[2]
    diff = np.abs(H_a - H_t).max() / np.abs(H_t).max()
    t_ten, _ = time_call(_hessian_call(ten), max(1, repeats if ten.K < 40 else 2))
    t_adj, _ = time_call(_hessian_call(adj), repeats)
    t_one, _ = _one_thread(lambda: time_call(_hessian_call(adj), repeats)[0])
    sw, (t, u, y) = adj._sweeps, adj._arrays[0]
    x0, p, w = jnp.asarray(adj.x0[0]), jnp.asarray(adj.p0), jnp.asarray(adj.loss_weights)
    th0 = jnp.asarray(theta)
    t_gn, _ = time_call(lambda: sw.first_order(th0, x0, p, t, u, y, w), repeats)
    hess = jax.jit(jax.hessian(ten.jax_cost))
    th = jnp.asarray(theta)
    t_jax, _ = time_call(lambda: hess(th), repeats)
    t_auto = t_adj if auto == "adjoint" else t_ten
    N, K, P = ten.model.N, ten.K, ten.experiments[0].P
    pred = adjoint.predicted_seconds(N, K, P)
    print(
        f"| {name} | {N} | {K} | {P} | {t_ten * 1e3:.1f} | {t_adj * 1e3:.1f} | "
        f"{t_one * 1e3:.1f} | {t_jax * 1e3:.1f} | {auto} | {t_ten / t_auto:.2f} | "
        f"{t_jax / t_auto:.2f} | {t_ten / t_adj:.2f} ({pred['tensors'] / pred['adjoint']:.2f}) "
        f"| {t_adj / t_gn:.1f} | {diff:.0e} |",
        flush=True,
    )


CASADI_CHAIN = """
import sys, time, numpy as np, casadi as ca
import tensorid as ti
from tensorid import benchmarks
n, folder = 5, sys.argv[1]
prob = benchmarks.mass_chain_problem(n)
e = prob.experiments[0]
t, u, y = e.t, e.u[:, 0], e.measured
dt, sub = float(t[1] - t[0]), prob.substeps
def f(x, p, uu):
    m, k, d = p[0], p[1 : n + 1], p[n + 1 :]
    q, v = x[:n], x[n:]
    dq = ca.vertcat(q[0], q[1:] - q[:-1])
    dv = ca.vertcat(v[0], v[1:] - v[:-1])
    link = k * (dq + dq**3) + d * dv
    force = ca.vertcat(link[1:], 0) - link
    force[0] += uu
    return ca.vertcat(v, force / m)
x, p = ca.SX.sym("x", 2 * n), ca.SX.sym("p", 2 * n + 1)
ua, ub = ca.SX.sym("ua"), ca.SX.sym("ub")
h, xx = dt / sub, x
for i in range(sub):
    s0 = i / sub
    uu = lambda s: ua + s * (ub - ua)
    k1 = f(xx, p, uu(s0))
    k2 = f(xx + h / 2 * k1, p, uu(s0 + 0.5 / sub))
    k3 = f(xx + h / 2 * k2, p, uu(s0 + 0.5 / sub))
    k4 = f(xx + h * k3, p, uu(s0 + 1 / sub))
    xx = xx + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
step = ca.Function("step", [x, p, ua, ub], [xx])
P = t.size
th = ca.MX.sym("th", 2 * n + 1)
U0, U1 = u[:-1].reshape(1, -1), u[1:].reshape(1, -1)
X = step.mapaccum("sweep", P - 1)(np.zeros(2 * n), ca.repmat(th, 1, P - 1), U0, U1)
J = ca.sumsqr(y[1:].T - X[:n, :]) + float(np.sum(y[0] ** 2))
H, g = ca.hessian(J, th)
F = ca.Function("chain_hess", [th], [J, g, H])
theta = prob.theta0 * 1.02
def timed(fn, reps=5):
    fn(theta); ts = []
    for _ in range(reps):
        t0 = time.perf_counter(); fn(theta); ts.append(time.perf_counter() - t0)
    return float(np.median(ts))
import json
Href = prob.cost_grad_hess(theta)[2]
out = {"interpreted": timed(F)}
t0 = time.perf_counter()
F.generate("chain_hess.c", {"with_header": False})
import subprocess, os
cc = ["gcc", "-O1", "-fPIC", "-shared", "chain_hess.c", "-o", "chain_hess.so"]
subprocess.run(cc, check=True)
build = time.perf_counter() - t0
G = ca.external("chain_hess", os.path.abspath("chain_hess.so"))
out["codegen"] = timed(G)
Hc = np.asarray(G(theta)[2])
out["diff"] = float(np.abs(Hc - Href).max() / np.abs(Href).max())
out["build"] = build
print(json.dumps(out))
"""


def casadi_rows(repeats: int) -> None:
    """CasADi's exact Hessian of the N = 10 chain, interpreted and generated C code,
    in its own process (its code generation and compilation take a while)."""
    try:
        import casadi  # noqa: F401
    except ImportError:
        print("\n(casadi is not installed: pip install casadi for the CasADi rows)")
        return
    with tempfile.TemporaryDirectory() as folder:
        script = Path(folder) / "chain.py"
        script.write_text(CASADI_CHAIN)
        done = subprocess.run(
            [sys.executable, str(script), folder], cwd=folder, capture_output=True, text=True
        )
        if done.returncode:
            print(f"\nCasADi run failed:\n{done.stderr[-2000:]}")
            return
        r = json.loads(done.stdout.strip().splitlines()[-1])
    prob = benchmarks.mass_chain_problem(5)
    t_auto, _ = time_call(_hessian_call(prob), repeats)
    print("\n## CasADi on the chain of 5 masses (N = 10, K = 11, P = 2,000)\n")
    print("| (J, g, H) by | ms | tensorid auto is faster by |")
    print("|---|---:|---:|")
    print(f"| tensorid, hessian=auto ({prob.hessian}) | {t_auto * 1e3:.1f} | |")
    for k in ("interpreted", "codegen"):
        print(f"| CasADi {k} | {r[k] * 1e3:.1f} | {r[k] / t_auto:.2f}× |")
    print(
        f"\nCasADi's generated code took {r['build']:.1f} s to write and compile; its "
        f"Hessian differs from tensorid's by {r['diff']:.0e} (relative)."
    )


def one_core(repeats: int, index: int = 10) -> None:
    """ROWS[index] in a child held to CPU 0, compiled afresh (TENSORID_CACHE=0)."""
    cmd = [sys.executable, __file__, "--row", str(index), "--repeats", str(repeats)]
    env = {**os.environ, "TENSORID_CACHE": "0"}
    print(f"# {ROWS[index][0]} on one core (CPU 0 only, one thread), median of {repeats}\n")
    print("| problem | N | K | P | tensors ms | adjoint ms | adjoint, 1 thread ms | "
          "jax.hessian ms | auto picks | tensors / auto | jax.hessian / auto | "
          "tensors / adjoint (predicted) | adjoint ÷ GN | diff |")  # fmt: skip
    print("|---|---:|---:|---:|---:|---:|---:|---:|---|---:|---:|---:|---:|---:|", flush=True)
    out = subprocess.run(cmd, env=env, preexec_fn=lambda: os.sched_setaffinity(0, {0}),
                         check=True, capture_output=True, text=True).stdout  # fmt: skip
    print(out.rstrip())
    cells = [c.strip() for c in out.strip().splitlines()[-1].split("|")]
    print(f"\nadjoint / jax.hessian on one core = {float(cells[6]) / float(cells[8]):.2f}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="no 32-mass chain, no CasADi")
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--no-casadi", action="store_true")
    ap.add_argument("--one-core", action="store_true", help="the 16-mass chain on CPU 0")
    ap.add_argument("--row", type=int, default=None, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.one_core:
        one_core(args.repeats)
        return
    if args.row is not None:  # one row, in a process of its own
        row(*ROWS[args.row], args.repeats)
        return
    print(f"# Exact Hessians: transition tensors and second-order adjoints ({adjoint.threads()} "
          f"threads)\n")  # fmt: skip
    print(
        "| problem | N | K | P | tensors ms | adjoint ms | adjoint, 1 thread ms | "
        "jax.hessian ms | auto picks | tensors / auto | jax.hessian / auto | "
        "tensors / adjoint (predicted) | adjoint ÷ GN | diff |"
    )
    print("|---|---:|---:|---:|---:|---:|---:|---:|---|---:|---:|---:|---:|---:|")
    t0 = time.perf_counter()
    for i in range(len(ROWS) - 1 if args.quick else len(ROWS)):
        cmd = [sys.executable, __file__, "--row", str(i), "--repeats", str(args.repeats)]
        subprocess.run(cmd, check=True)
    if not (args.quick or args.no_casadi):
        casadi_rows(args.repeats)
    print(f"\n({time.perf_counter() - t0:.0f} s)")


if __name__ == "__main__":
    main()
