"""The extended-Kalman predictor (predictor="ekf") measured: derivative cost against
jax.hessian of a plain JAX filter, a coverage study against a plain JAX reference
and against output error, and EKF against output error on two real records.

    python benchmarks/bench_ekf.py --derivatives [--repeats 5]
    python benchmarks/bench_ekf.py --coverage 200 [--json out.json] [--figure f.png]
    python benchmarks/bench_ekf.py --records

Everything is seeded. The plain filter (``plain_filter``) is the reference of
tests/test_ekf.py with the data as arguments, jitted: a scan over the samples, the
same RK4 of (x, P) between them and the Joseph-form update, so that its cost equals
tensorid's to rounding and ``jax.hessian`` of it is the yardstick.
"""

from __future__ import annotations

import argparse
import json
import statistics
import time

import jax
import jax.numpy as jnp
import numpy as np

import tensorid as ti

jax.config.update("jax_enable_x64", True)


# -- a plainly written continuous-discrete EKF, jitted -----------------------------------


def plain_filter(problem, model):
    """cost(theta, t, u, y) of the problem's one-experiment layout (``model``: the
    user's model, without the noise parameters the problem appends): −2 log L (less
    n log 2π) of a continuous-discrete EKF, written out plainly."""
    aug = problem.model
    n, M = model.N, model.M
    free = jnp.array([aug.params.index(s) for s in problem.free_params], dtype=int)
    fx = jnp.array([model.states.index(s) for s in problem.free_x0], dtype=int)
    K_x = len(problem.free_x0)
    q = [(model.states.index(s[len("log_sigma_w_") :]), aug.params.index(s))
         for s in aug.params if s.startswith("log_sigma_w_")]  # fmt: skip
    r = [aug.params.index(f"log_sigma_e_{o}") for o in model.outputs]
    p_base, x_base = jnp.asarray(problem.p0), jnp.asarray(problem.x0[0])
    substeps, interp = problem.substeps, problem.interpolation

    def cost(theta, t, u, y):
        p_all = p_base.at[free].set(theta[K_x:])
        p, x0 = p_all[:M], x_base.at[fx].set(theta[:K_x])
        Q = jnp.zeros(n)
        for i, k in q:
            Q = Q.at[i].set(jnp.exp(2 * p_all[k]))
        R = jnp.exp(2 * p_all[jnp.array(r)])

        def ode(x, P, uu):
            A = jax.jacfwd(lambda xx: model.f(xx, p, uu))(x)
            return model.f(x, p, uu), A @ P + P @ A.T + jnp.diag(Q)

        def share(x, P, yk):
            C = jax.jacfwd(lambda xx: model.h(xx, p))(x)
            Sg = C @ P @ C.T + jnp.diag(R)
            eps = yk - model.h(x, p)
            return C, Sg, eps, jnp.linalg.slogdet(Sg)[1] + eps @ jnp.linalg.solve(Sg, eps)

        def step(carry, k):
            x, P, J = carry
            C, Sg, eps, dJ = share(x, P, y[k])
            G = P @ C.T @ jnp.linalg.inv(Sg)
            I_GC = jnp.eye(n) - G @ C
            x, P = x + G @ eps, I_GC @ P @ I_GC.T + G @ jnp.diag(R) @ G.T
            h = (t[k + 1] - t[k]) / substeps
            for i in range(substeps):

                def uin(stage, i=i):
                    frac = (i + stage) / substeps
                    return u[k] if interp == "zoh" else u[k] + frac * (u[k + 1] - u[k])

                k1 = ode(x, P, uin(0.0))
                k2 = ode(x + h / 2 * k1[0], P + h / 2 * k1[1], uin(0.5))
                k3 = ode(x + h / 2 * k2[0], P + h / 2 * k2[1], uin(0.5))
                k4 = ode(x + h * k3[0], P + h * k3[1], uin(1.0))
                x = x + h / 6 * (k1[0] + 2 * k2[0] + 2 * k3[0] + k4[0])
                P = P + h / 6 * (k1[1] + 2 * k2[1] + 2 * k3[1] + k4[1])
            return (x, P, J + dJ), None

        init = (x0, jnp.zeros((n, n)), 0.0)
        (x, P, J), _ = jax.lax.scan(step, init, jnp.arange(t.size - 1))
        return J + share(x, P, y[-1])[3]

    return cost


def plain_derivatives(problem, model):
    """Jitted value, gradient and jax.hessian of the plain filter (data as arguments)."""
    cost = plain_filter(problem, model)
    return jax.jit(cost), jax.jit(jax.grad(cost)), jax.jit(jax.hessian(cost))


def data_args(problem):
    e = problem.experiments[0]
    return tuple(jnp.asarray(a, dtype=float) for a in (e.t, e.u, e.y))


# -- 1a: derivative cost -------------------------------------------------------------------


def derivative_problems() -> dict:
    from tensorid.benchmarks import silverbox_problem, two_tank_problem
    from tensorid.paper.problems import silverbox_model, two_tank_model

    ekf = {"predictor": "ekf"}
    return {
        "Silverbox (1,024 samples)": (
            lambda: silverbox_problem(process_noise={"ydot": 1e-3}, **ekf),
            silverbox_model(),
        ),
        "two-tank (501 samples)": (
            lambda: two_tank_problem(process_noise={"x2": 0.01}, **ekf),
            two_tank_model(),
        ),
    }


def _first(fn) -> float:
    """Seconds of the first (compiling) call."""
    t0 = time.perf_counter()
    jax.block_until_ready(fn())
    return time.perf_counter() - t0


def derivatives(repeats: int, rows=None) -> dict:
    """(J, g, H) of tensorid against the value + jax.hessian of the jitted plain
    filter: compile (first call) and warm medians, interleaved in one process."""
    out = {}
    print("| problem | K | tensorid compile s | jax.hessian compile s | tensorid warm s "
          "| jax.hessian warm s | ratio | max rel. diff of H |")  # fmt: skip
    print("|---|---|---|---|---|---|---|---|")
    for name, (make, model) in derivative_problems().items():
        if rows and not any(r.lower() in name.lower() for r in rows):
            continue
        pr = make()
        value, _, hess = plain_derivatives(pr, model)
        args = data_args(pr)
        theta = np.asarray(pr.theta0)

        def ours(pr=pr, theta=theta):
            return pr.cost_grad_hess(theta)

        def theirs(value=value, hess=hess, theta=theta, args=args):
            th = jnp.asarray(theta)
            return jax.block_until_ready((value(th, *args), hess(th, *args)))

        compile_ours, compile_ref = _first(ours), _first(theirs)
        warm_ours, warm_ref = [], []
        for _ in range(repeats):  # interleaved
            for fn, acc in ((ours, warm_ours), (theirs, warm_ref)):
                t0 = time.perf_counter()
                jax.block_until_ready(fn())
                acc.append(time.perf_counter() - t0)
        J, _, H = ours()
        Jr, Hr = theirs()
        diff = float(np.abs(H - np.asarray(Hr)).max() / np.abs(Hr).max())
        a, b = statistics.median(warm_ours), statistics.median(warm_ref)
        out[name] = {"K": pr.K, "compile_tensorid_s": compile_ours,
                     "compile_jax_hessian_s": compile_ref, "warm_tensorid_s": a,
                     "warm_jax_hessian_s": b, "ratio": a / b, "max_rel_diff_H": diff,
                     "rel_diff_J": abs(J - float(Jr)) / abs(float(Jr)),
                     "repeats": repeats}  # fmt: skip
        print(f"| {name} | {pr.K} | {compile_ours:.1f} | {compile_ref:.1f} | {a:.3f} "
              f"| {b:.3f} | {a / b:.2f}x | {diff:.1e} |", flush=True)  # fmt: skip
    return out


# -- 1b: coverage ----------------------------------------------------------------------------

TRUE = {"k": 2.0, "c": 0.3, "a": 0.5}
START = {"k": 1.5, "c": 0.5, "a": 0.3}
SIGMA_E = 0.02
LEVELS = (0.1, 0.3, 0.6)  # σ_w of v, per √s
SAMPLES, DT, FINE = 400, 0.05, 20


def duffing():
    def f(x, p, u):
        return jnp.array([x[1], -p[0] * x[0] - p[1] * x[1] - p[2] * x[0] ** 3 + u[0]])

    return ti.Model(
        f, lambda x, p: x[:1], states=["x", "v"], params=["k", "c", "a"], inputs=["u"],
        outputs=["y"], name="duffing",
    )  # fmt: skip


def sde_record(seed: int, sw: float) -> ti.Experiment:
    """The Duffing oscillator with process noise σ_w = sw on v (per √s), simulated by
    Euler–Maruyama on a grid FINE times finer than the samples; σ_e = 0.02."""
    rng = np.random.default_rng(seed)
    u = np.repeat(rng.standard_normal(SAMPLES // 10 + 1), 10)[:SAMPLES, None]
    p = np.array([TRUE["k"], TRUE["c"], TRUE["a"]])
    x, ys, h = np.array([0.1, 0.0]), [], DT / FINE
    kicks = sw * np.sqrt(h) * rng.standard_normal((SAMPLES, FINE))
    noise = SIGMA_E * rng.standard_normal(SAMPLES)
    for k in range(SAMPLES):
        ys.append(x[0] + noise[k])
        for j in range(FINE):
            a = -p[0] * x[0] - p[1] * x[1] - p[2] * x[0] ** 3 + u[k, 0]
            x = np.array([x[0] + h * x[1], x[1] + h * a + kicks[k, j]])
    return ti.Experiment(np.arange(SAMPLES) * DT, u, np.array(ys)[:, None])


def _covers(theta, se, names, truth) -> dict:
    return {n: bool(abs(theta[names.index(n)] - v) <= 1.96 * se[names.index(n)])
            for n, v in truth.items()}  # fmt: skip


def reference_fit(derivs, theta0, args):
    """The textbook optimiser: scipy's trust-exact with jax.grad and jax.hessian."""
    from scipy.optimize import minimize

    value, grad, hess = derivs
    r = minimize(
        lambda th: float(value(jnp.asarray(th), *args)), np.asarray(theta0),
        jac=lambda th: np.asarray(grad(jnp.asarray(th), *args)),
        hess=lambda th: np.asarray(hess(jnp.asarray(th), *args)),
        method="trust-exact", options={"gtol": 1e-8, "maxiter": 200},
    )  # fmt: skip
    H = np.asarray(hess(jnp.asarray(r.x), *args))
    return r, np.sqrt(np.diag(2 * np.linalg.inv(H)))


def one_draw(model, seed: int, sw: float, derivs_cache: dict) -> dict:
    data = sde_record(seed, sw)
    kw = {"p0": START, "x0": [0.0, 0.0], "free_x0": ["x", "v"], "interpolation": "zoh"}
    pr = ti.Problem(model, data, predictor="ekf", process_noise={"v": 0.1}, **kw)
    names = pr.theta_names
    truth = {**TRUE, "log_sigma_w_v": np.log(sw), "log_sigma_e_y": np.log(SIGMA_E)}
    if "d" not in derivs_cache:
        derivs_cache["d"] = plain_derivatives(pr, model)
    t0 = time.perf_counter()
    res = ti.fit(pr)
    t_ekf = time.perf_counter() - t0
    u = res.uncertainty()
    t0 = time.perf_counter()
    ref, se_ref = reference_fit(derivs_cache["d"], pr.theta0, data_args(pr))
    t_ref = time.perf_counter() - t0
    t0 = time.perf_counter()
    oe = ti.fit(ti.Problem(model, data, **kw))
    t_oe = time.perf_counter() - t0
    oe_names = oe.problem.theta_names
    return {
        "seed": seed, "sigma_w": sw, "names": names,
        "ekf": {"theta": res.theta.tolist(), "cost": float(res.cost), "success": bool(res.success),
                "stderr": u.stderr.tolist(), "covers": _covers(res.theta, u.stderr, names, truth),
                "seconds": t_ekf},
        "reference": {"theta": ref.x.tolist(), "cost": float(ref.fun), "success": bool(ref.success),
                      "stderr": se_ref.tolist(), "nit": int(ref.nit),
                      "covers": _covers(ref.x, se_ref, names, truth), "seconds": t_ref},
        "oe": {"theta": oe.theta.tolist(), "names": oe_names, "seconds": t_oe,
               "status": oe.status.value[0], "success": bool(oe.success),
               "covers_white": _covers(oe.theta, oe.uncertainty().stderr, oe_names, TRUE),
               "covers_robust": _covers(oe.theta, oe.uncertainty("robust").stderr, oe_names,
                                        TRUE)},
    }  # fmt: skip


def coverage(draws: int, path: str, first_seed: int = 0) -> list[dict]:
    """``draws`` records per noise level, the levels interleaved draw by draw so that
    a run stopped early has as many draws at each; the JSON is rewritten as it grows."""
    model, cache, rows = duffing(), {}, []
    for i in range(first_seed, first_seed + draws):
        for j, sw in enumerate(LEVELS):
            try:
                rows.append(one_draw(model, 1000 * j + i, sw, cache))
            except Exception as err:  # noqa: BLE001 - a failed draw is a result too
                rows.append({"seed": 1000 * j + i, "sigma_w": sw, "error": repr(err)})
        with open(path, "w") as fh:
            json.dump({"levels": LEVELS, "sigma_e": SIGMA_E, "true": TRUE, "start": START,
                       "samples": SAMPLES, "dt": DT, "fine": FINE, "draws": rows}, fh)  # fmt: skip
        print(f"draw {i}: {len(rows)} fits written to {path}", flush=True)
    return rows


def summarise(rows: list[dict]) -> dict:
    """Per level: coverage per parameter and their mean (EKF, reference, OE white and
    robust), RMSE of k, c, a (EKF, OE), median fit seconds, agreement of the optima."""
    out = {}
    for sw in sorted({r["sigma_w"] for r in rows}):
        ok = [r for r in rows if r["sigma_w"] == sw and "error" not in r]
        cov = {}
        for key, sub in (("ekf", "covers"), ("reference", "covers"), ("oe white", "covers_white"),
                         ("oe robust", "covers_robust")):  # fmt: skip
            src = key.split()[0]
            names = list(ok[0][src][sub])
            per = {n: float(np.mean([r[src][sub][n] for r in ok])) for n in names}
            cov[key] = {"per_parameter": per, "mean": float(np.mean(list(per.values()))),
                        "mean_k_c_a": float(np.mean([per[n] for n in TRUE]))}  # fmt: skip
        rmse = {}
        for src in ("ekf", "oe"):
            names = ok[0]["names"] if src == "ekf" else ok[0]["oe"]["names"]
            rmse[src] = {n: float(np.sqrt(np.mean([(r[src]["theta"][names.index(n)] - v) ** 2
                                                   for r in ok])))
                         for n, v in TRUE.items()}  # fmt: skip
        dJ = [abs(r["ekf"]["cost"] - r["reference"]["cost"]) for r in ok]
        out[str(sw)] = {
            "draws": len(ok), "failed": sum(1 for r in rows if r["sigma_w"] == sw) - len(ok),
            "coverage": cov, "rmse": rmse,
            "median_seconds": {s: float(np.median([r[s]["seconds"] for r in ok]))
                               for s in ("ekf", "reference", "oe")},
            "ekf_not_success": sum(not r["ekf"]["success"] for r in ok),
            "reference_not_success": sum(not r["reference"]["success"] for r in ok),
            "oe_not_success": sum(not r["oe"].get("success", True) for r in ok),
            "max_cost_difference": float(max(dJ)),
            "ekf_cost_above_reference_by_1e-6": sum(
                r["ekf"]["cost"] > r["reference"]["cost"] + 1e-6 * abs(r["reference"]["cost"])
                for r in ok),
        }  # fmt: skip
    return out


def print_summary(summary: dict) -> None:
    print(
        "| σ_w | draws | coverage, all 5: EKF | reference | k, c, a: EKF | reference "
        "| OE white | OE robust | RMSE k, c, a: EKF | OE | median s: EKF / reference / OE |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for sw, s in summary.items():
        c, r, t = s["coverage"], s["rmse"], s["median_seconds"]
        m = {k: v["mean_k_c_a"] for k, v in c.items()}
        print(f"| {sw} | {s['draws']} | {c['ekf']['mean']:.3f} | {c['reference']['mean']:.3f} "
              f"| {m['ekf']:.3f} | {m['reference']:.3f} "
              f"| {m['oe white']:.3f} | {m['oe robust']:.3f} "
              f"| {', '.join(f'{v:.3f}' for v in r['ekf'].values())} "
              f"| {', '.join(f'{v:.3f}' for v in r['oe'].values())} "
              f"| {t['ekf']:.2f} / {t['reference']:.2f} / {t['oe']:.2f} |")  # fmt: skip
    print("\nper parameter (EKF / reference / OE white / OE robust):")
    for sw, s in summary.items():
        c = s["coverage"]
        cells = []
        for n in c["ekf"]["per_parameter"]:
            vals = [c[k]["per_parameter"].get(n) for k in ("ekf", "reference", "oe white",
                                                           "oe robust")]  # fmt: skip
            cells.append(f"{n} " + " / ".join("–" if v is None else f"{v:.2f}" for v in vals))
        print(f"σ_w = {sw}: " + "; ".join(cells))


def coverage_figure(summary: dict, path: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(1, 2, figsize=(10, 3.8))
    levels = list(summary)
    x = np.arange(len(levels))
    for i, key in enumerate(("ekf", "reference", "oe white", "oe robust")):
        ax[0].bar(x + (i - 1.5) * 0.2,
                  [summary[s]["coverage"][key]["mean_k_c_a"] for s in levels], 0.2,
                  label=key)  # fmt: skip
    ax[0].axhline(0.95, color="k", lw=0.8, ls="--", label="0.95: the intervals' nominal level")
    ax[0].axhline(0.85, color="grey", lw=0.8, ls=":", label="0.85: the target asked of the EKF")
    ax[0].set_xticks(x, [f"σ_w = {s}" for s in levels])
    ax[0].set_ylabel("coverage of k, c, a (mean)")
    ax[0].set_title("95 % intervals covering the truth", fontsize=9)
    ax[0].set_ylim(0, 1.32)
    ax[0].legend(fontsize=7, loc="upper center", ncol=3)
    names = list(TRUE)
    for i, src in enumerate(("ekf", "oe")):
        for j, n in enumerate(names):
            ax[1].bar(x + (j - 1) * 0.27 + (i - 0.5) * 0.12,
                      [summary[s]["rmse"][src][n] / TRUE[n] for s in levels], 0.12,
                      color=f"C{j}", alpha=1.0 if src == "ekf" else 0.45,
                      label=f"{n}: {'EKF' if src == 'ekf' else 'output error'}")  # fmt: skip
    ax[1].set_xticks(x, [f"σ_w = {s}" for s in levels])
    ax[1].set_ylabel("RMSE / true value")
    ax[1].set_yscale("log")
    ax[1].set_title("parameter RMSE: EKF (dark) and output error (light)", fontsize=9)
    ax[1].legend(fontsize=7, ncol=2)
    n = min(s["draws"] for s in summary.values())
    fig.suptitle(f"Duffing with process noise: {n} draws per level", fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=100)


# -- 1c: real records --------------------------------------------------------------------

HORIZON = 10  # samples: the k of the k-step-ahead prediction


def record_problems() -> dict:
    """name: (problem maker taking predictor options, test record, init window)."""
    import sys
    from pathlib import Path

    from tensorid import datasets
    from tensorid.paper.problems import TWO_TANK_GUESS, two_tank_model

    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "examples" / "emps"))
    import open_loop  # the EMPS open-loop model file

    full = datasets.two_tank(2500)
    levels = datasets.two_tank_levels(2500)
    test = ti.Experiment(full.t[501:] - full.t[501], full.u[501:], full.y[501:],
                         name="two-tank test")  # fmt: skip

    def tank(**kw):
        return ti.Problem(two_tank_model(), datasets.two_tank(501), p0=TWO_TANK_GUESS,
                          x0=levels[0], free_x0=["x1"], **kw)  # fmt: skip

    def emps(**kw):
        m = open_loop.model
        return ti.Problem(m, datasets.emps("estimation"), p0=open_loop.p0, x0=[0.0, 0.0],
                          free_x0=m.states, bounds=open_loop.bounds, substeps=1, **kw)  # fmt: skip

    return {
        "two-tank (train 0-500, test 501-2499)": (
            tank, {"process_noise": {"x1": 0.01, "x2": 0.01}}, test, 20),
        "EMPS open loop (DATA_EMPS / DATA_EMPS_PULSES)": (
            emps, {"process_noise": {"v": 0.01}}, datasets.emps("test"),
            datasets.EMPS_INIT_WINDOW),
    }  # fmt: skip


def _lag1(res) -> float:
    c = res.residual_tests().whiteness[0]
    return float(c.values[list(c.lags).index(1)])


def score_fit(label, res, seconds, test, window) -> dict:
    rmse = {}
    for name, k in (("one-step", 1), (f"{HORIZON}-step", HORIZON), ("simulation", None)):
        rmse[name] = float(list(res.validate(test, init_window=window, horizon=k)[0]
                                .rmse.values())[0])  # fmt: skip
    names = res.problem.theta_names
    noise = {n[len("log_"):]: float(np.exp(res.theta[i])) for i, n in enumerate(names)
             if n.startswith("log_sigma")}  # fmt: skip
    rt = res.residual_tests()
    return {"fit": label, "status": res.status.value[0], "cost": float(res.cost),
            "whiteness_passed": bool(all(rt.whiteness_passed)), "lag1": _lag1(res),
            "test_rmse": rmse, "noise": noise, "seconds": seconds,
            "compile_seconds": float(res.compile_seconds),
            "params": {k: float(v) for k, v in res.params.items()}}  # fmt: skip


def records() -> dict:
    """EKF against output error on two real records, one table."""
    out = {}
    print(f"| record | fit | whiteness (lag-1 r) | test RMSE: one-step | {HORIZON}-step "
          f"| simulation | noise σ | fit s (compiling) |")  # fmt: skip
    print("|---|---|---|---|---|---|---|---|")
    for name, (make, noise, test, window) in record_problems().items():
        rows = []
        for label, kw in (("output error", {}), ("EKF", {"predictor": "ekf", **noise})):
            t0 = time.perf_counter()
            res = ti.fit(make(**kw))
            seconds = time.perf_counter() - t0
            r = score_fit(label, res, seconds, test, window)
            rows.append(r)
            white = "passes" if r["whiteness_passed"] else "FAILS"
            sig = ", ".join(f"{k} {v:.3g}" for k, v in r["noise"].items()) or "–"
            e = r["test_rmse"]
            print(f"| {name} | {label} ({r['status']}) | {white} ({r['lag1']:.2f}) "
                  f"| {e['one-step']:.4g} | {e[f'{HORIZON}-step']:.4g} | {e['simulation']:.4g} "
                  f"| {sig} | {seconds:.1f} ({r['compile_seconds']:.1f}) |",
                  flush=True)  # fmt: skip
        out[name] = rows
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--derivatives", action="store_true", help="(J, g, H) against jax.hessian")
    ap.add_argument("--repeats", type=int, default=5, help="warm calls per side")
    ap.add_argument("--rows", nargs="+", help="derivative rows (substrings) to run")
    ap.add_argument("--coverage", type=int, nargs="?", const=200, help="draws per level")
    ap.add_argument("--first-seed", type=int, default=0)
    ap.add_argument("--json", default="ekf_coverage.json", help="coverage results")
    ap.add_argument("--merge", nargs="+", help="summarise these coverage JSONs together")
    ap.add_argument("--figure", default="docs/figures/ekf_coverage.png")
    ap.add_argument("--redraw", metavar="SUMMARY.json", help="only draw --figure from a summary")
    ap.add_argument("--records", action="store_true", help="two-tank and EMPS")
    ap.add_argument("--records-json", default="ekf_records.json")
    args = ap.parse_args()
    print(f"tensorid {ti.__version__}, jax {jax.__version__}, {jax.default_backend()}\n")
    if args.redraw:  # e.g. benchmarks/results/ekf_coverage_summary.json
        with open(args.redraw) as fh:
            coverage_figure(json.load(fh), args.figure)
    if args.derivatives:
        derivatives(args.repeats, args.rows)
    if args.coverage or args.merge:
        if args.merge:
            rows = [r for p in args.merge for r in json.load(open(p))["draws"]]
        else:
            rows = coverage(args.coverage, args.json, args.first_seed)
        summary = summarise(rows)
        print_summary(summary)
        with open(args.json.replace(".json", "_summary.json"), "w") as fh:
            json.dump(summary, fh, indent=1)
        coverage_figure(summary, args.figure)
    if args.records:
        with open(args.records_json, "w") as fh:
            json.dump(records(), fh, indent=1)


if __name__ == "__main__":
    main()
