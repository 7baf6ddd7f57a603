"""The alternative to tensorid's augmented Lagrangian for multiple shooting, measured:
a line-search SQP on the same lifted problem, with the same exact Hessian of the
Lagrangian (segments' end transition tensors contracted with the multipliers).

    python benchmarks/bench_shooting_sqp.py [--quick]

Each SQP iteration solves the KKT system [[W + δI, Aᵀ], [A, 0]] (d, λ⁺) = −(∇J, c),
with δ raised until W + δI is positive definite on the null space of A, and backtracks
on the ℓ1 merit function J + ν‖c‖₁ (ν >= 1.1 ‖λ⁺‖∞); it stops when the scaled KKT
residual is below 1e-8 relative and the defects below 1e-8 of the state scale, then
polishes by single shooting as fit() does. Same starts as bench_shooting.py Part 1
(Lotka-Volterra, 10 segments, ±50 %), against ti.fit(method="newton").
"""

from __future__ import annotations

import argparse
import statistics
import time

import numpy as np
from bench_shooting import starts  # noqa: E402
from scipy.linalg import null_space

import tensorid as ti
from tensorid.benchmarks import lotka_volterra_problem
from tensorid.solve.options import FitOptions
from tensorid.solve.registry import resolve
from tensorid.solve.shooting import _Run


def sqp(problem, theta0, maxiter=200):
    """(θ, iterations, converged) by line-search SQP in the augmented Lagrangian's
    scaled units."""
    sh = problem.shooting
    z = sh.start(theta0)
    first = sh.evaluate(z, exact=False)
    if not first.finite:  # as fit() does: start the segments from the simulation
        z = sh.start(theta0, from_data=False)
        first = sh.evaluate(z, exact=False)
    run = _Run(problem, resolve("newton"), z, first.J, FitOptions())
    s, cs, Jr = run.scale, run.cscale, run.J_ref
    lam, nu = np.zeros(cs.size), 1.0

    def merit(zz):
        L = sh.evaluate(zz, exact=False)
        return L.J / Jr + nu * np.abs(L.c / cs).sum() if L.finite else np.inf

    for it in range(1, maxiter + 1):
        L = sh.evaluate(z)
        if not L.finite:
            return sh.to_theta(z), it, False
        g, c = L.g * s / Jr, L.c / cs
        A = L.A / cs[:, None] * s
        W = (L.H / Jr + sh.curvature(L, lam / cs)) * np.outer(s, s)
        if not np.isfinite(W).all():
            return sh.to_theta(z), it, False
        if np.abs(g + A.T @ lam).max() < 1e-8 and np.abs(c).max() < 1e-8:
            return sh.to_theta(z), it, True
        Z = null_space(A)
        delta = 0.0
        while np.linalg.eigvalsh(Z.T @ (W + delta * np.eye(W.shape[0])) @ Z).min() <= 1e-10:
            delta = max(2 * delta, 1e-4)
        n, m = W.shape[0], A.shape[0]
        K = np.block([[W + delta * np.eye(n), A.T], [A, np.zeros((m, m))]])
        sol = np.linalg.solve(K, -np.concatenate([g, c]))
        d, lam_new = sol[:n], sol[n:]
        nu = max(nu, 1.1 * np.abs(lam_new).max())
        phi0 = L.J / Jr + nu * np.abs(c).sum()
        slope = g @ d - nu * np.abs(c).sum()
        alpha = 1.0
        while alpha > 1e-10 and merit(z + alpha * d * s) > phi0 + 1e-4 * alpha * slope:
            alpha *= 0.5
        z = np.clip(z + alpha * d * s, run.lo * s, run.hi * s)
        lam = lam + alpha * (lam_new - lam)
    return sh.to_theta(z), maxiter, False


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="one seed of 20 starts")
    args = ap.parse_args()
    single = lotka_volterra_problem()
    multiple = lotka_volterra_problem(segments=10)
    thetas = starts(single, [3] if args.quick else [3, 4, 5])
    sqp(multiple, thetas[0], maxiter=2)  # compile
    ti.fit(multiple, "newton")
    rows = {"augmented Lagrangian (ti.fit)": [], "line-search SQP": []}
    for th in thetas:
        t0 = time.perf_counter()
        r = ti.fit(multiple, "newton", theta0=th)
        rows["augmented Lagrangian (ti.fit)"].append(
            (r.cost, r.shooting["nit"], time.perf_counter() - t0)
        )
        t0 = time.perf_counter()
        theta, nit, _ = sqp(multiple, th)
        r = ti.fit(single, "newton", theta0=theta)  # the same single-shooting polish
        rows["line-search SQP"].append((r.cost, nit, time.perf_counter() - t0))
    best = min(c for v in rows.values() for c, _, _ in v)
    print(f"\nLotka-Volterra, S = 10, {len(thetas)} starts within ±50 % (best cost {best:.6g})\n")
    print("| constrained solver | reach the best | median iterations | median s/fit |")
    print("|---|---|---|---|")
    for name, v in rows.items():
        hits = sum(c <= best * (1 + 1e-6) for c, _, _ in v)
        print(f"| {name} | {hits}/{len(v)} | {statistics.median(n for _, n, _ in v):.0f} | "
              f"{statistics.median(t for _, _, t in v):.3f} |")  # fmt: skip


if __name__ == "__main__":
    main()
