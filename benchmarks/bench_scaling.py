"""How the cost of exact derivatives grows with samples P, unknowns K and states N,
and where Newton-CG on Hessian-vector products overtakes the full Hessian.

    python benchmarks/bench_scaling.py [--quick] [--repeats 5]

Three tables, each measured in this one process, times after compilation:

P  the paper's Silverbox problem (N = 2, K = 5) on the first P samples of the
   bundled SNLS80mV record, P = 1,024 .. 131,072: one cost, one (J, g, H) by
   transition tensors, jax.hessian through the same simulator.
K  a forced oscillator whose spring force is a Chebyshev series with K - 2
   coefficients (unknowns: mass, damping and the coefficients; N = 2, P = 1,024):
   one (J, g, H), one (J, g) by first-order sensitivities, one (J, g, Hv), and
   whole fits from a ±10 % start by "newton" (full Hessian) and "newton-cg"
   (truncated CG on Hessian-vector products), on noise-free data.
N  a chain of N/2 masses with shared spring, cubic spring, coupling and ground
   damping (K = 5, P = 1,024): one (J, g, H) and jax.hessian.
Ratios are to one plain simulation of the same problem (the cost sweep). Use
--quick for a shorter run with fewer points.
"""

from __future__ import annotations

import argparse
import time

import jax
import jax.numpy as jnp
import numpy as np
from _timing import time_call

import tensorid as ti
from tensorid import benchmarks, datasets


def _sweeps(prob: ti.Problem):
    """Compiled single-experiment calls (no Python-side assembly in the timings)."""
    sens, (t, u, y) = prob._sweeps, prob._arrays[0]
    x0, p, w = jnp.asarray(prob.x0[0]), jnp.asarray(prob.p0), jnp.asarray(prob.loss_weights)
    th = jnp.asarray(prob.theta0)
    v = jnp.ones_like(th)
    return {
        "cost": lambda: sens.cost(th, x0, p, t, u, y, w),
        "grad": lambda: sens.gradient(th, x0, p, t, u, y, w),
        "hess": lambda: sens.second_order(th, x0, p, t, u, y, w),
        "hessp": lambda: sens.hessp(th, v, x0, p, t, u, y, w),
    }


def _against_autodiff(size: int, prob: ti.Problem, repeats: int) -> None:
    """One table row: cost, (J, g, H) and jax.hessian through the same simulator."""
    s = _sweeps(prob)
    c, _ = time_call(s["cost"], repeats)
    h, _ = time_call(s["hess"], repeats)
    ad = jax.jit(jax.hessian(prob.jax_cost))
    th = jnp.asarray(prob.theta0)
    a, _ = time_call(lambda: ad(th), repeats)
    print(f"| {size} | {c * 1e3:.2f} | {h * 1e3:.1f} | {h / c:.0f} | {a * 1e3:.1f} | {h / a:.2f} |")


def table_p(sizes, repeats: int) -> None:
    print("\n## Time against the number of samples P (Silverbox, N = 2, K = 5)\n")
    print("| P | cost ms | (J, g, H) ms | × cost | jax.hessian ms | (J, g, H) / jax.hessian |")
    print("|---:|---:|---:|---:|---:|---:|")
    for P in sizes:
        prob = benchmarks.silverbox_problem(data=datasets.silverbox_snls80mV(stop=P))
        _against_autodiff(P, prob, max(1, repeats if P <= 16384 else repeats // 2))


def chebyshev_model(q: int) -> ti.Model:
    """m ÿ + d ẏ + Σ_i k_i T_i(y) = u with Chebyshev polynomials T_i, i = 1..q."""

    def rhs(x, p, u):
        y, v = x[0], x[1]
        spring, t_prev, t_cur = 0.0, 1.0, y
        for i in range(q):
            spring = spring + p[2 + i] * t_cur
            t_prev, t_cur = t_cur, 2.0 * y * t_cur - t_prev
        return jnp.stack([v, (u[0] - p[1] * v - spring) / p[0]])

    return ti.Model(
        rhs=rhs,
        output=lambda x, p: x[0],
        states=["y", "v"],
        params=["m", "d", *[f"k{i + 1}" for i in range(q)]],
        inputs=["u"],
        outputs=["y"],
        name=f"chebyshev{q}",
    )


def chebyshev_problem(K: int, P: int = 1024, start: float = 0.1, **kw):
    q = K - 2
    springs = [4.0] + [0.5 / (i + 2) ** 2 for i in range(q - 1)] if q else []
    truth = np.array([1.0, 0.4, *springs])
    rng = np.random.default_rng(K)
    Ts = 0.05
    t = np.arange(P) * Ts
    u = sum(np.cos(2 * np.pi * k * t / (P * Ts) + rng.uniform(0, 2 * np.pi)) for k in range(1, 60))
    u = 2.0 * u / np.abs(u).max()
    model = chebyshev_model(q)
    sim = ti.simulate(model, truth, [0.0, 0.0], ti.Experiment(t, u))
    data = ti.Experiment(t, u, sim.y)
    p0 = truth * (1 + start * rng.uniform(-1, 1, truth.size))
    kw.setdefault("hessian", "tensors")  # the K table measures the transition tensors
    return ti.Problem(model, data, p0=p0, x0=[0.0, 0.0], **kw)


def _fit_time(prob, method) -> tuple[float, ti.FitResult]:
    ti.fit(prob, method=method)  # compile
    t0 = time.perf_counter()
    res = ti.fit(prob, method=method)
    return time.perf_counter() - t0, res


def table_k(sizes, repeats: int) -> None:
    print("\n## Time against the number of unknowns K (Chebyshev oscillator, N = 2, P = 1024)\n")
    print(
        "| K | cost ms | (J, g) ms | (J, g, Hv) ms | (J, g, H) ms | (J, g, H) × cost | "
        "newton fit s (its) | newton-cg fit s (its, Hv) | cg / newton | final costs |"
    )
    print("|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|")
    for K in sizes:
        prob = chebyshev_problem(K)
        s = _sweeps(prob)
        c, _ = time_call(s["cost"], repeats)
        g, _ = time_call(s["grad"], repeats)
        hv, _ = time_call(s["hessp"], repeats)
        h, _ = time_call(s["hess"], repeats)
        tn, rn = _fit_time(prob, "newton")
        tc, rc = _fit_time(prob, "newton-cg")
        flag = "" if rn.success and rc.success else " (not converged)"
        print(
            f"| {K} | {c * 1e3:.2f} | {g * 1e3:.2f} | {hv * 1e3:.2f} | {h * 1e3:.1f} | {h / c:.0f} "
            f"| {tn:.2f} ({rn.nit}) | {tc:.2f} ({rc.nit}, {rc.nhev}) | {tc / tn:.2f} "
            f"| {rn.cost:.1e}, {rc.cost:.1e}{flag} |"
        )


def chain_model(n: int) -> ti.Model:
    """n masses in a line, the first forced: shared mass m, spring k, cubic spring a,
    coupling damping d and damping to ground c; output: the last mass's position."""

    def rhs(x, p, u):
        m, k, a, d, c = p[0], p[1], p[2], p[3], p[4]
        q, v = x[:n], x[n:]
        dq = jnp.diff(q, prepend=0.0)  # stretch of the link to the left (wall at 0)
        dv = jnp.diff(v, prepend=0.0)
        link = k * dq + a * dq**3 + d * dv
        right = jnp.concatenate([link[1:], jnp.zeros(1)])
        force = right - link - c * v
        force = force.at[0].add(u[0])
        return jnp.concatenate([v, force / m])

    return ti.Model(
        rhs=rhs,
        output=lambda x, p: x[n - 1],
        states=[f"q{i + 1}" for i in range(n)] + [f"v{i + 1}" for i in range(n)],
        params=["m", "k", "a", "d", "c"],
        inputs=["u"],
        outputs=["y"],
        name=f"chain{n}",
    )


def table_n(sizes, repeats: int) -> None:
    print("\n## Time against the number of states N (mass chain, K = 5, P = 1024)\n")
    print("| N | cost ms | (J, g, H) ms | × cost | jax.hessian ms | (J, g, H) / jax.hessian |")
    print("|---:|---:|---:|---:|---:|---:|")
    P, Ts = 1024, 0.05
    t = np.arange(P) * Ts
    u = np.sin(0.7 * t) + 0.5 * np.sin(2.3 * t)
    truth = np.array([1.0, 3.0, 0.5, 0.2, 0.05])
    for N in sizes:
        model = chain_model(N // 2)
        sim = ti.simulate(model, truth, np.zeros(N), ti.Experiment(t, u[:, None]))
        prob = ti.Problem(model, ti.Experiment(t, u[:, None], sim.y), p0=truth * 1.05)
        _against_autodiff(N, prob, repeats)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--quick", action="store_true", help="fewer points, for a smoke run")
    ap.add_argument("--only", choices=["P", "K", "N"], help="one table only")
    ap.add_argument("--ks", type=int, nargs="+", help="the K values of the K table")
    args = ap.parse_args()
    ti.enable_compilation_cache()
    if args.quick:
        ps, ks, ns = [1024, 8192], [2, 10], [2, 6]
    else:
        ps = [1024, 4096, 16384, 65536, 131072]
        ks = [2, 5, 10, 15, 20, 30]
        ns = [2, 4, 8, 12, 16, 20]
    ks = args.ks or ks
    print(
        f"tensorid {ti.__version__}, jax {jax.__version__}, {jax.device_count()} "
        f"{jax.default_backend()} device(s), RK4 with 4 substeps, median of {args.repeats}"
    )
    if args.only in (None, "P"):
        table_p(ps, args.repeats)
    if args.only in (None, "K"):
        table_k(ks, args.repeats)
    if args.only in (None, "N"):
        table_n(ns, args.repeats)


if __name__ == "__main__":
    main()
