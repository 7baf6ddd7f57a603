"""Bit-for-bit fingerprint of the numbers a refactoring must not move: J, ∇J, ∇²J
(``Problem.cost_grad_hess``) and short fits' estimates, iterations and statuses on
the paper's Silverbox and two-tank problems, a chain of masses and the Lotka-Volterra
record (multiple shooting), through every path of ``fit`` (one start, lock-step
batch, starts on workers, priors' noise re-check, a robust loss's stages), and every
plug-in (squared, Huber, Cauchy, Student-t losses; output error and the EKF; both
Hessian paths; the Gauss-Newton part and the residuals beside J, ∇J, ∇²J).

    python benchmarks/numbers_fingerprint.py save /tmp/before.npz
    python benchmarks/numbers_fingerprint.py compare /tmp/before.npz

``compare`` recomputes everything and checks each array with np.array_equal (NaN
equal to NaN); it exits 1 and names every difference otherwise.
"""

from __future__ import annotations

import sys

import numpy as np

import tensorid as ti
from tensorid import datasets
from tensorid.benchmarks import (
    lotka_volterra_problem,
    mass_chain_problem,
    silverbox_problem,
    two_tank_problem,
)


def _fit_record(out: dict, key: str, res) -> None:
    out[f"{key}/x"] = np.asarray(res.x)
    out[f"{key}/fun"] = np.asarray(res.fun)
    out[f"{key}/jac"] = np.asarray(res.jac)
    out[f"{key}/hess"] = np.asarray(res.hess)
    out[f"{key}/nit"] = np.asarray(res.nit)
    out[f"{key}/nfev"] = np.asarray(res.nfev)
    out[f"{key}/status"] = np.asarray(str(res.status))
    out[f"{key}/history_cost"] = np.asarray([h["cost"] for h in res.history])


def record() -> dict:
    out: dict = {}
    problems = {
        "silverbox": silverbox_problem(),
        "two-tank": two_tank_problem(),
        "chain5": mass_chain_problem(5, samples=400),
    }
    for name, p in problems.items():
        J, g, H = p.cost_grad_hess(p.theta0)
        out[f"{name}/J"], out[f"{name}/g"], out[f"{name}/H"] = np.asarray(J), g, H
        for method in ("auto", "newton", "gauss-newton", "newton-cg"):
            _fit_record(out, f"{name}/{method}", ti.fit(p, method, maxiter=15))
    p = problems["two-tank"]
    _fit_record(out, "two-tank/fd-lsq", ti.fit(p, "fd-lsq", maxiter=5))
    starts = ti.fit(p, "auto", starts=3, spread=0.2, workers=1, maxiter=10)
    _fit_record(out, "two-tank/starts", starts)
    out["two-tank/starts/ranked"] = np.asarray([s["cost"] for s in starts.starts])
    thetas = p.theta0 * np.array([[1.0], [1.1], [0.9]])
    for i, r in enumerate(ti.fit_batch(p, "auto", thetas, maxiter=10)):
        _fit_record(out, f"two-tank/batch{i}", r)
    sb = problems["silverbox"]
    priors = {n: (v, abs(v) * 0.5 + 1e-3) for n, v in zip(sb.model.params, sb.p0, strict=True)}
    pp = silverbox_problem(priors=priors)
    _fit_record(out, "silverbox/priors", ti.fit(pp, "auto", maxiter=15))
    rb = two_tank_problem(loss="huber")
    _fit_record(out, "two-tank/huber", ti.fit(rb, "auto", maxiter=15))
    lv = lotka_volterra_problem(segments=4)
    _fit_record(out, "lv/segments", ti.fit(lv, "auto", maxiter=15))
    _method_benchmark_rows(out)
    _plugin_rows(out)
    _inner_solve_rows(out)
    return out


def _inner_solve_rows(out: dict) -> None:
    """The solves that are not fits of a Problem (issue 39's one loop): a profile's
    corrections, validation's initial states, the model-error check's refits, an
    input design's L-BFGS-B runs, and a fleet's outer problem with its units' inner
    Newton (theophylline, FOCEI)."""
    full = datasets.silverbox_train()
    sb = silverbox_problem(data=ti.Experiment(full.t[:400], full.u[:400], full.y[:400]))
    res = ti.fit(sb, maxiter=30)
    for name, p in res.profile(sb.model.params[:2]).items():
        out[f"profile/{name}/interval"] = np.asarray(p.interval)
        out[f"profile/{name}/costs"], out[f"profile/{name}/values"] = p.costs, p.values
    val = datasets.silverbox_validation()
    [score] = res.validate(ti.Experiment(val.t[:300], val.u[:300], val.y[:300]), 50)
    out["validate/x0"], out["validate/rmse"] = score.x0, np.asarray(score.rmse["y"])
    check = res.model_check()
    out["model_check/estimates"] = check.estimates
    out["model_check/stderr"], out["model_check/Q"] = check.stderr, np.asarray(check.statistic)
    from tensorid.fitting.design import step_levels

    first = ti.Model(rhs=lambda x, p, u: -p[0] * x + p[1] * u[0], states=["x"],
                     params=["a", "b"], inputs=["u"], output=lambda x, p: x,
                     outputs=["y"])  # fmt: skip
    T = np.arange(100) * 0.1
    d = ti.design_input(first, {"a": 2.0, "b": 3.0}, T, step_levels(100, 5), np.full(5, 0.5),
                        bounds=[(0.0, 1.0)] * 5, noise=0.05, starts=3)  # fmt: skip
    out["design/a"], out["design/after"] = d.a, np.asarray(list(d.stderr_after.values()))
    fleet = _theophylline()
    pop = ti.fit(fleet, maxiter=30)
    out["population/x"], out["population/etas"] = np.asarray(pop.x), np.asarray(pop.etas)
    out["population/objective"], out["population/hess"] = np.asarray(pop.objective), pop.hess
    out["population/nit"] = np.asarray(pop.nit)
    out["population/status"] = np.asarray(str(pop.status))


PLUGINS = [  # (name, problem, keywords): the plug-ins' paths (issue 39)
    ("silverbox-squared-tensors", "silverbox", {"hessian": "tensors"}),
    ("silverbox-squared-adjoint", "silverbox", {"hessian": "adjoint"}),
    ("silverbox-huber", "silverbox", {"loss": "huber", "hessian": "tensors"}),
    ("silverbox-huber-adjoint", "silverbox", {"loss": "huber", "hessian": "adjoint"}),
    ("silverbox-cauchy", "silverbox", {"loss": "cauchy", "hessian": "tensors"}),
    ("silverbox-student-t", "silverbox", {"loss": "student-t", "hessian": "tensors"}),
    ("two-tank-squared", "two-tank", {}),
    ("two-tank-huber", "two-tank", {"loss": "huber"}),
    ("two-tank-ekf", "two-tank", {"predictor": "ekf", "process_noise": {"x2": 0.01}}),
    ("silverbox-ekf", "silverbox", {"predictor": "ekf", "process_noise": {"ydot": 1e-3}}),
]


def _plugin_rows(out: dict) -> None:
    """Each plug-in's J, ∇J, ∇²J, Gauss-Newton part and residuals on 300 Silverbox or
    200 two-tank samples, and six iterations of three methods."""
    for name, which, kw in PLUGINS:
        if which == "silverbox":
            full = datasets.silverbox_train()
            data = ti.Experiment(full.t[:300], full.u[:300], full.y[:300])
            pr = silverbox_problem(data=data, **kw)
        else:
            pr = two_tank_problem(samples=200, **kw)
        J, g, H = pr.cost_grad_hess(pr.theta0)
        out[f"{name}/J"], out[f"{name}/g"], out[f"{name}/H"] = np.asarray(J), g, H
        out[f"{name}/G"] = pr.cost_grad_gn(pr.theta0)[2]
        out[f"{name}/r"] = pr.residuals(pr.theta0)
        for method in ("auto", "gauss-newton", "newton"):
            _fit_record(out, f"{name}/{method}", ti.fit(pr, method=method, maxiter=6))


def _method_benchmark_rows(out: dict) -> None:
    """bench_methods.py's rows beyond the paper's two: a chain of 16 masses (K = 33)
    from a seeded start, and 20 Lotka-Volterra starts in lock-step (its last table);
    the old module path of draw_starts on purpose (it must keep importing)."""
    from tensorid.fitting.multistart import draw_starts

    chain = mass_chain_problem(16, samples=400)
    th = draw_starts(chain.theta0, chain.lower, chain.upper, 2, spread=0.2,
                     sampling="uniform", seed=0)[1]  # fmt: skip
    J, g, H = chain.cost_grad_hess(th)
    out["chain16/J"], out["chain16/g"], out["chain16/H"] = np.asarray(J), g, H
    for method in ("newton", "gauss-newton", "auto"):
        _fit_record(out, f"chain16/{method}", ti.fit(chain, method, theta0=th, maxiter=10))
    lv = lotka_volterra_problem()
    thetas = draw_starts(lv.theta0, lv.lower, lv.upper, 21, spread=0.5,
                         sampling="uniform", seed=0)[1:]  # fmt: skip
    for method in ("newton", "gauss-newton", "auto"):
        for i, r in enumerate(ti.fit_batch(lv, method, thetas, maxiter=10)):
            _fit_record(out, f"lv/batch/{method}/{i}", r)


def _theophylline() -> ti.Problem:
    """The bundled theophylline record as tests/test_population.py builds it."""
    import csv

    import jax.numpy as jnp

    def rhs(x, p, u):
        return jnp.stack([-p[0] * x[0], p[0] * x[0] - p[1] / p[2] * x[1]])

    model = ti.Model(rhs=rhs, output=lambda x, p: x[1:] / p[2], states=["depot", "center"],
                     params=["ka", "cl", "v"], inputs=["Dose"], outputs=["cp"])  # fmt: skip
    rows = list(csv.DictReader(datasets.theophylline_csv().open()))
    exps = []
    for i in dict.fromkeys(r["ID"] for r in rows):
        rr = [r for r in rows if r["ID"] == i]
        t = np.array([float(r["Time"]) for r in rr])
        u = np.array([[float(r["Dose"]) * float(r["Wt"])] for r in rr])
        exps.append(ti.Experiment(t, u, [float(r["conc"]) for r in rr], name=i))
    return ti.Problem(
        model, exps, p0={"ka": 1.57, "cl": 2.72, "v": 31.5},
        x0={"depot": "Dose", "center": 0.0}, substeps=40,
        population={"ka": 0.6**0.5, "cl": 0.3**0.5, "v": 0.1**0.5},
    )  # fmt: skip


def _same(a, b) -> bool:
    """Bit for bit (NaN equal to NaN); False where either is missing."""
    if a is None or b is None:
        return False
    return bool(np.array_equal(a, b, equal_nan=a.dtype.kind == "f"))


def main() -> int:
    mode, path = sys.argv[1], sys.argv[2]
    now = record()
    if mode == "save":
        np.savez(path, **now)
        print(f"saved {len(now)} arrays to {path}")
        return 0
    before = dict(np.load(path))
    bad = [k for k in sorted(set(before) | set(now)) if not _same(before.get(k), now.get(k))]
    for k in bad:
        print(f"DIFFERS: {k}")
    print(f"{len(now) - len(bad)} of {len(now)} arrays bit-identical")
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
