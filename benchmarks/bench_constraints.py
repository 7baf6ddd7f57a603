"""Constrained fits (issue 40 item 7): iterations, augmented-Lagrangian (outer)
iterations and seconds of each exact-derivative method, and the multiplier against the
KKT value from jax.grad; then the unconstrained path checked bit for bit against a
fit with a constraint that never binds.

    python benchmarks/bench_constraints.py [--emps]

The first problem is tests/test_constraints.py's (ẋ = −a x + b u, data from a = 1,
b = 2, constraint "a >= b", which binds). With --emps, the Stribeck EMPS closed loop
(examples/emps/stribeck.py) free and with "Fs >= Fc" (docs/emps.md), method newton.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

import tensorid as ti

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))
from test_constraints import MODEL, _data  # noqa: E402


def small() -> None:
    print("method        iterations  outer  seconds  λ (AL)     λ (KKT, jax.grad)  a − b")
    for method in ("auto", "newton", "gauss-newton", "newton-cg"):
        prob = ti.Problem(MODEL, _data(), p0={"a": 0.5, "b": 0.5}, x0=[0.0],
                          constraints=["a >= b"])  # fmt: skip
        t0 = time.perf_counter()
        res = ti.fit(prob, method)
        seconds = time.perf_counter() - t0
        g = np.asarray(jax.grad(prob.jax_cost)(jnp.asarray(res.theta)))
        kkt = float(np.linalg.lstsq(np.array([[1.0], [-1.0]]), g, rcond=None)[0][0])
        (item,) = res.constraints.items
        print(f"{method:13s} {res.nit:10d} {res.constraints.outer:6d} {seconds:8.2f}  "
              f"{item['multiplier']:.7g}  {kkt:.7g}  {item['value']:.2e}")  # fmt: skip
    free = ti.fit(ti.Problem(MODEL, _data(), p0={"a": 0.5, "b": 0.5}, x0=[0.0]))
    loose = ti.fit(ti.Problem(MODEL, _data(), p0={"a": 0.5, "b": 0.5}, x0=[0.0],
                              constraints=["b >= a"]))  # fmt: skip
    same = np.array_equal(free.theta, loose.theta) and free.cost == loose.cost
    print(f"a constraint that does not bind: the unconstrained fit bit for bit: {same}")


def emps() -> None:
    from tensorid.datasets import emps as record

    spec = ti.load_model(ROOT / "examples/emps/stribeck.py")
    data = record("estimation", closed_loop=True)
    for cons in (None, ["Fs >= Fc"]):
        prob = ti.Problem(spec.model, data, p0=spec.p0, x0=spec.x0_array(),
                          free_x0=spec.free_x0, bounds=spec.bounds, constraints=cons)  # fmt: skip
        t0 = time.perf_counter()
        res = ti.fit(prob, "newton")
        p = res.params
        line = f"{cons or 'free'}: cost {res.cost:.6g}, Fc {p['Fc']:.5g}, Fs {p['Fs']:.5g}, "
        line += f"{res.nit} iterations, {time.perf_counter() - t0:.1f} s"
        if res.constraints:
            (item,) = res.constraints.items
            line += f", {res.constraints.outer} outer, λ {item['multiplier']:.5g}"
        print(line)


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--emps", action="store_true", help="also the Stribeck EMPS fits")
    args = parser.parse_args()
    small()
    if args.emps:
        emps()
