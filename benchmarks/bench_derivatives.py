"""Cost of (J, ∇J, ∇²J) on the paper's Silverbox problem, measured in one process.

    python benchmarks/bench_derivatives.py [--repeats 20] [--substeps 4]

Prints, for P = 1024 samples, N = 2 states, K = 5 unknowns (ẏ(t0), m, d, a, b):
one plain simulation, one (J, g, H) by transition tensors, (J, g, H_GN) by first-order
sensitivities, one Hessian-vector product, (J, g, H) at 8 points in one vmap call
(per point, as multi-start in lock-step uses it), jax.hessian through the same
simulator, and a finite-difference Hessian from cost evaluations (sequential, and
batched with jax.vmap), each as a median wall time after compilation and as a ratio
to one simulation. Compile times are listed separately. Ratios, not seconds, are
what carries across machines.
"""

from __future__ import annotations

import argparse

import jax
import jax.numpy as jnp
import numpy as np
from _timing import time_call

import tensorid as ti
from tensorid.benchmarks import silverbox_problem


def fd_points(theta: np.ndarray, h: np.ndarray) -> tuple[np.ndarray, list]:
    """Points of the standard central-difference Hessian from cost values:
    θ, θ ± h_i e_i, and the four corners θ ± h_i e_i ± h_j e_j of each pair i < j,
    1 + 2K + 2K(K-1) evaluations in all."""
    K = theta.size
    pts, plan = [theta], []
    for i in range(K):
        for sgn in (1, -1):
            e = np.zeros(K)
            e[i] = sgn * h[i]
            pts.append(theta + e)
    for i in range(K):
        for j in range(i + 1, K):
            for si, sj in ((1, 1), (1, -1), (-1, 1), (-1, -1)):
                e = np.zeros(K)
                e[i], e[j] = si * h[i], sj * h[j]
                pts.append(theta + e)
                plan.append((i, j, si * sj))
    return np.array(pts), plan


def fd_hessian(J: np.ndarray, theta: np.ndarray, h: np.ndarray) -> np.ndarray:
    K = theta.size
    H = np.zeros((K, K))
    f0 = J[0]
    for i in range(K):
        H[i, i] = (J[1 + 2 * i] - 2 * f0 + J[2 + 2 * i]) / h[i] ** 2
    k = 1 + 2 * K
    for i in range(K):
        for j in range(i + 1, K):
            pp, pm, mp, mm = J[k : k + 4]
            H[i, j] = H[j, i] = (pp - pm - mp + mm) / (4 * h[i] * h[j])
            k += 4
    return H


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=20)
    ap.add_argument("--substeps", type=int, default=4)
    args = ap.parse_args()

    prob = silverbox_problem(substeps=args.substeps)
    theta = prob.theta0
    sens, (t, u, y) = prob._sweeps, prob._arrays[0]
    x0, p, w = jnp.asarray(prob.x0[0]), jnp.asarray(prob.p0), jnp.asarray(prob.loss_weights)
    th = jnp.asarray(theta)
    K = theta.size

    cost = jax.jit(prob.jax_cost)
    hess = jax.jit(jax.hessian(prob.jax_cost))
    grad = jax.jit(jax.grad(prob.jax_cost))
    h = 1e-4 * np.maximum(np.abs(theta), 1e-3)
    pts, _ = fd_points(theta, h)
    batch_cost = jax.jit(jax.vmap(prob.jax_cost))
    th8 = th * (1 + 0.01 * jnp.arange(8.0)[:, None])

    rows = [
        ("simulation (states only)", lambda: sens.simulate(x0, p, t, u)),
        ("J by plain simulation", lambda: cost(th)),
        ("(J, g, H) transition tensors", lambda: sens.second_order(th, x0, p, t, u, y, w)),
        ("(J, g, H_GN) first-order sens.", lambda: sens.first_order(th, x0, p, t, u, y, w)),
        ("(J, g, Hv) one direction", lambda: sens.hessp(th, jnp.ones(K), x0, p, t, u, y, w)),
        (
            "(J, g, H) for 8 starts, vmap, per start",
            lambda: sens.second_order_batch(th8, x0, p, t, u, y, w),
        ),
        ("jax.grad of J", lambda: grad(th)),
        ("jax.hessian of J", lambda: hess(th)),
        (f"FD Hessian, {len(pts)} costs, batched", lambda: batch_cost(jnp.asarray(pts))),
        (
            f"FD Hessian, {len(pts)} costs, sequential",
            lambda: [cost(jnp.asarray(q)) for q in pts][-1],
        ),
    ]
    print(
        f"Silverbox: P = {t.size}, N = {prob.model.N}, K = {K}, RK4 with "
        f"{args.substeps} substeps, {jax.device_count()} {jax.default_backend()} device(s), "
        f"median of {args.repeats}"
    )
    results = {}
    for name, fn in rows:
        results[name] = time_call(fn, args.repeats)
        if "per start" in name:
            results[name] = (results[name][0] / 8, results[name][1])
    base = results["simulation (states only)"][0]
    print(f"{'':40s} {'run ms':>9s} {'× sim':>7s} {'compile s':>10s}")
    for name, (run, comp) in results.items():
        print(f"{name:40s} {run * 1e3:9.3f} {run / base:7.1f} {comp:10.2f}")
    tt = results["(J, g, H) transition tensors"][0]
    print(f"\ntransition tensors / jax.hessian    = {tt / results['jax.hessian of J'][0]:.2f}")
    print(
        f"transition tensors / FD (batched)   = "
        f"{tt / results[f'FD Hessian, {len(pts)} costs, batched'][0]:.2f}"
    )
    print(
        f"transition tensors / FD (sequential)= "
        f"{tt / results[f'FD Hessian, {len(pts)} costs, sequential'][0]:.2f}"
    )

    # accuracy of each Hessian against the exact one
    _, _, H = prob.cost_grad_hess(theta)
    H_fd = fd_hessian(np.asarray(batch_cost(jnp.asarray(pts))), theta, h)
    H_ad = np.asarray(hess(th))
    s = np.abs(theta) + (theta == 0)
    rel = lambda A: np.abs((A - H) * np.outer(s, s)).max() / np.abs(H * np.outer(s, s)).max()  # noqa: E731
    print(
        f"max scaled difference from the transition-tensor Hessian: jax.hessian "
        f"{rel(H_ad):.1e}, finite differences {rel(H_fd):.1e}"
    )
    print(f"tensorid {ti.__version__}, jax {jax.__version__}")


if __name__ == "__main__":
    main()
