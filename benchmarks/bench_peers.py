"""tensorid against what a Python user would write instead, on the paper's Silverbox
problem (P = 1024, θ = (ẏ(t0), m, d, a, b), from the paper's initial guess and from
±20 % starts around it), whole-fit time and final cost side by side:

  tensorid        trust-region Newton, exact Hessian from transition tensors
  casadi+ipopt    CasADi single shooting, the same RK4 scheme with 4 substeps and
                  linear input interpolation, IPOPT with its exact Hessian (CasADi's
                  algorithmic differentiation)
  scipy           scipy.optimize.least_squares (trf) with a finite-difference
                  Jacobian over scipy.integrate.solve_ivp (RK45, rtol 1e-6)

    python -m pip install casadi        # optional peer, not a tensorid dependency
    python benchmarks/bench_peers.py [--starts 5] [--no-scipy]

Times are after compilation / function construction, which is listed apart. All
three minimise the same J = Σ (y - ŷ)²; the costs are directly comparable (the
scipy fit has its own integrator, so its J differs by that scheme's error).
"""

from __future__ import annotations

import argparse
import statistics
import time

import numpy as np

import tensorid as ti
from tensorid.benchmarks import SILVERBOX_GUESS, silverbox_problem


def starts(prob, n: int) -> list[np.ndarray]:
    th0 = prob.theta0
    rng = np.random.default_rng(0)
    out = [th0]
    for _ in range(n - 1):
        th = th0 * rng.uniform(0.8, 1.2, th0.size)
        th[0] = th0[0] + rng.uniform(-1e-3, 1e-3)  # ẏ(t0) starts at 0: an absolute spread
        out.append(th)
    return out


def run_tensorid(prob, thetas):
    ti.fit(prob, "newton", theta0=thetas[0])  # compile
    rows = []
    for th in thetas:
        t0 = time.perf_counter()
        r = ti.fit(prob, "newton", theta0=th)
        rows.append((time.perf_counter() - t0, r.cost, r.nit, r.success))
    return rows


def casadi_solver(prob, scale):
    import casadi as ca

    e = prob.experiments[0]
    t, u, y = e.t, e.u[:, 0], e.measured[:, 0]
    dt = float(t[1] - t[0])
    assert np.allclose(np.diff(t), dt)
    n_sub = prob.substeps

    def f(x, p, uu):
        return ca.vertcat(x[1], (uu - p[1] * x[1] - p[2] * x[0] - p[3] * x[0] ** 3) / p[0])

    x, p = ca.SX.sym("x", 2), ca.SX.sym("p", 4)
    ua, ub = ca.SX.sym("ua"), ca.SX.sym("ub")
    h, xx = dt / n_sub, x
    for i in range(n_sub):
        s0, ds = i / n_sub, 1 / n_sub

        def uu(s, s0=s0):
            return ua + s * (ub - ua)

        k1 = f(xx, p, uu(s0))
        k2 = f(xx + h / 2 * k1, p, uu(s0 + ds / 2))
        k3 = f(xx + h / 2 * k2, p, uu(s0 + ds / 2))
        k4 = f(xx + h * k3, p, uu(s0 + ds))
        xx = xx + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
    step = ca.Function("step", [x, p, ua, ub], [xx])
    P = t.size
    sweep = step.mapaccum("sweep", P - 1)
    phi = ca.MX.sym("phi", 5)
    th = phi * scale
    x0 = ca.vertcat(float(prob.x0[0, 0]), th[0])
    X = sweep(x0, ca.repmat(th[1:], 1, P - 1), u[:-1].reshape(1, -1), u[1:].reshape(1, -1))
    ysim = ca.horzcat(x0[0], X[0, :])
    J = ca.sumsqr(y.reshape(1, -1) - ysim)
    opts = {"ipopt.print_level": 0, "print_time": 0, "ipopt.sb": "yes", "ipopt.tol": 1e-10}
    return ca.nlpsol("s", "ipopt", {"x": phi, "f": J}, opts)


def run_casadi(prob, thetas):
    t0 = time.perf_counter()
    scale = np.abs(prob.theta0) + (prob.theta0 == 0) * 1e-3
    solver = casadi_solver(prob, scale)
    build = time.perf_counter() - t0
    rows = []
    for th in thetas:
        t0 = time.perf_counter()
        sol = solver(x0=th / scale)
        dt = time.perf_counter() - t0
        stats = solver.stats()
        th_hat = np.asarray(sol["x"]).ravel() * scale
        rows.append((dt, prob.cost(th_hat), stats["iter_count"], stats["success"]))
    return rows, build


def run_scipy(prob, theta):
    from scipy.integrate import solve_ivp
    from scipy.optimize import least_squares

    e = prob.experiments[0]
    t, u, y = e.t, e.u[:, 0], e.measured[:, 0]
    y0 = float(prob.x0[0, 0])
    scale = np.abs(theta) + (theta == 0) * 1e-3

    def resid(phi):
        v0, m, d, a, b = phi * scale

        def rhs(tt, x):
            uu = np.interp(tt, t, u)
            return [x[1], (uu - d * x[1] - a * x[0] - b * x[0] ** 3) / m]

        sol = solve_ivp(rhs, (t[0], t[-1]), [y0, v0], t_eval=t, rtol=1e-6, atol=1e-9)
        if not sol.success or sol.y.shape[1] != t.size:
            return np.full(t.size, 1e3)
        return y - sol.y[0]

    t0 = time.perf_counter()
    r = least_squares(resid, theta / scale, method="trf")
    dt = time.perf_counter() - t0
    return dt, prob.cost(r.x * scale), float(r.fun @ r.fun), r.nfev, r.success


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--starts", type=int, default=5)
    ap.add_argument("--no-scipy", action="store_true", help="skip the slow scipy peer")
    args = ap.parse_args()
    prob = silverbox_problem(p0=SILVERBOX_GUESS)
    thetas = starts(prob, args.starts)
    print(f"Silverbox, P = 1024, K = 5, RK4 × {prob.substeps}; {len(thetas)} starts")
    print(f"{'':14s} {'median s/fit':>12s} {'max s':>8s} {'best cost':>11s} {'worst cost':>11s}")

    def line(name, rows):
        secs = [r[0] for r in rows]
        costs = [r[1] for r in rows]
        print(
            f"{name:14s} {statistics.median(secs):12.3f} {max(secs):8.3f} "
            f"{min(costs):11.6g} {max(costs):11.6g}   iterations {[r[2] for r in rows]}"
        )
        return statistics.median(secs)

    t_ti = line("tensorid", run_tensorid(prob, thetas))
    try:
        rows, build = run_casadi(prob, thetas)
        t_ca = line("casadi+ipopt", rows)
        print(f"{'':14s} (CasADi graph and solver construction {build:.2f} s, not counted)")
        print(f"\ntensorid is {t_ca / t_ti:.1f}x faster per fit than CasADi + IPOPT")
    except ImportError:
        print("casadi+ipopt   not installed (python -m pip install casadi)")
    if not args.no_scipy:
        dt, cost, own, nfev, ok = run_scipy(prob, thetas[0])
        print(
            f"scipy (1 start) {dt:.1f} s, cost on tensorid's simulator {cost:.6g} "
            f"(on its own {own:.6g}), {nfev} residual evaluations, success {ok}"
        )


if __name__ == "__main__":
    main()
