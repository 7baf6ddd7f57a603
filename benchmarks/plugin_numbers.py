"""J, ∇J, ∇²J and a short fit's estimates, iterations and status on the bundled
problems (Silverbox, two-tank; squared, Huber, Cauchy, Student-t losses; output error
and the EKF; both Hessian paths), written to an .npz, or compared bit for bit with
one written before: the check that moving the plug-ins (losses, predictors, methods,
schemes, Hessian paths) to classes and registries (issue 39) moved no number.

    python benchmarks/plugin_numbers.py record before.npz
    python benchmarks/plugin_numbers.py compare before.npz
"""

from __future__ import annotations

import sys

import numpy as np

import tensorid as ti
from tensorid import datasets
from tensorid.paper import problems

CASES = [  # (name, problem builder, keywords)
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
METHODS = ("auto", "gauss-newton", "newton")


def problem(which: str, kw: dict):
    if which == "silverbox":
        full = datasets.silverbox_train()
        data = ti.Experiment(full.t[:300], full.u[:300], full.y[:300])
        return problems.silverbox_problem(data=data, **kw)
    return problems.two_tank_problem(samples=200, **kw)


def numbers() -> dict[str, np.ndarray]:
    out: dict[str, np.ndarray] = {}
    for name, which, kw in CASES:
        pr = problem(which, kw)
        J, g, H = pr.cost_grad_hess(pr.theta0)
        _, _, G = pr.cost_grad_gn(pr.theta0)
        out[f"{name}/J"], out[f"{name}/g"], out[f"{name}/H"] = np.asarray(J), g, H
        out[f"{name}/G"] = G
        out[f"{name}/r"] = pr.residuals(pr.theta0)
        for method in METHODS:
            res = ti.fit(pr, method=method, maxiter=6)
            key = f"{name}/{method}"
            out[f"{key}/x"] = np.asarray(res.x)
            out[f"{key}/fun"] = np.asarray(res.fun)
            out[f"{key}/nit"] = np.asarray(res.nit)
            out[f"{key}/status"] = np.asarray(str(res.status))
        print(name, "done", flush=True)
    return out


def main(argv: list[str]) -> int:
    mode, path = argv
    now = numbers()
    if mode == "record":
        np.savez(path, **now)
        print(f"{len(now)} arrays written to {path}")
        return 0
    before = dict(np.load(path))
    keys = sorted(set(before) | set(now))
    differ = [k for k in keys if k not in before or k not in now]
    differ += [
        k for k in keys if k in before and k in now and not np.array_equal(before[k], now[k])
    ]
    for k in differ:
        print("DIFFERS:", k)
    print(f"{len(now)} arrays, {len(differ)} differ (np.array_equal)")
    return 1 if differ else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
