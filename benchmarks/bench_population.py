"""Population fits of simulated fleets: coverage of the error bars, and how the cost
grows with the number of units.

    python benchmarks/bench_population.py coverage --draws 200 --units 50
    python benchmarks/bench_population.py coverage --draws 100 --units 50 --error combined
    python benchmarks/bench_population.py scale --sizes 100 1000 10000
    python benchmarks/bench_population.py workers --units 2000 --workers 1 2

coverage: each draw simulates a fleet of one-compartment units (first-order absorption,
log-normal random effects on ka, cl and v, additive noise; truth below) at the same
eight sample times, fits it by FOCEI from a start 20 % off, and checks whether the
95 % intervals (on the log scale: μ̂ ± 1.96 SE, log ω̂ ± 1.96 SE) hold the truth;
ω's relative bias is reported. With --error combined the noise is σ² = a² + b²ŷ²
(a = 0.3, b = 0.1), fitted as such, and a's and b's intervals are checked too.
scale: one outer iteration (every unit's inner solve, the exact gradient and
Hessian) and a whole fit, timed per fleet size, with the process's peak memory; the
exponent is the slope of log time against log units.
Seeded; results to benchmarks/results/population.json (--json).
"""

from __future__ import annotations

import argparse
import json
import resource
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

import tensorid as ti
from tensorid.population.objective import Objective

TRUTH = {"ka": 1.5, "cl": 2.7, "v": 31.5}
OMEGA = {"ka": 0.5, "cl": 0.3, "v": 0.15}
SIGMA = 0.5
COMBINED = {"additive": 0.3, "proportional": 0.1}  # --error combined: σ² = a² + b²ŷ²
TIMES = np.array([0.0, 0.5, 1.0, 2.0, 4.0, 7.0, 12.0, 24.0])
DOSE = 320.0


def model() -> ti.Model:
    def rhs(x, p, u):
        ka, cl, v = p
        return jnp.stack([-ka * x[0], ka * x[0] - cl / v * x[1]])

    return ti.Model(rhs=rhs, output=lambda x, p: x[1:] / p[2], states=["depot", "center"],
                    params=["ka", "cl", "v"], inputs=["Dose"], outputs=["cp"],
                    name="one-compartment")  # fmt: skip


MODEL = model()


def fleet(n: int, seed: int, error: str = "additive") -> list[ti.Experiment]:
    """n units drawn from the truth, simulated in one vmapped call."""
    rng = np.random.default_rng(seed)
    eta = rng.standard_normal((n, 3)) * np.array(list(OMEGA.values()))
    params = np.array(list(TRUTH.values())) * np.exp(eta)
    u = np.full((TIMES.size, 1), DOSE)
    probe = ti.Problem(MODEL, [ti.Experiment(TIMES, u, np.zeros((TIMES.size, 1)))] * 2,
                       p0=TRUTH, x0={"depot": "Dose", "center": 0.0}, substeps=40,
                       population={"ka": 0.5})  # fmt: skip
    obj = Objective(probe)
    one = tuple(a[0] for a in obj.data)
    data = tuple(jnp.broadcast_to(a, (n, *a.shape)) for a in one)
    sw = obj.sweeps
    sim = jax.jit(jax.vmap(lambda th, d: sw._simulate(d[4], th, d[0], d[1])[1]))
    x0 = np.tile([DOSE, 0.0], (n, 1))
    sims = np.asarray(sim(jnp.asarray(params), (*data[:4], jnp.asarray(x0))))
    sd = SIGMA
    if error == "combined":
        sd = np.sqrt(COMBINED["additive"] ** 2 + (COMBINED["proportional"] * sims) ** 2)
    y = sims + sd * rng.standard_normal(sims.shape)
    return [ti.Experiment(TIMES, u, y[i], name=str(i)) for i in range(n)]


def problem(units, start=1.2, error="additive"):
    return ti.Problem(MODEL, units, p0={k: v * start for k, v in TRUTH.items()},
                      x0={"depot": "Dose", "center": 0.0}, substeps=40,
                      population={k: 0.3 for k in OMEGA}, residual_error=error)  # fmt: skip


def coverage(draws: int, n_units: int, error: str = "additive") -> dict:
    hits = {f"typical {k}": 0 for k in TRUTH} | {f"omega {k}": 0 for k in OMEGA}
    noise = COMBINED if error == "combined" else {}
    hits |= {f"residual {k}": 0 for k in noise}
    rel_bias: dict[str, list] = {k: [] for k in OMEGA}
    failed, seconds = 0, []
    for d in range(draws):
        t0 = time.perf_counter()
        res = ti.fit(problem(fleet(n_units, seed=d, error=error), error=error))
        seconds.append(time.perf_counter() - t0)
        if not res.success:
            failed += 1
            continue
        se = res.stderr
        for k, name in enumerate(TRUTH):
            hits[f"typical {name}"] += abs(res.x[k] - np.log(TRUTH[name])) < 1.96 * se[k]
            j = 3 + k
            hits[f"omega {name}"] += abs(res.x[j] - np.log(OMEGA[name])) < 1.96 * se[j]
            rel_bias[name].append(np.exp(res.x[j]) / OMEGA[name] - 1)
        for k, (name, value) in enumerate(noise.items()):
            hits[f"residual {name}"] += abs(res.x[6 + k] - np.log(value)) < 1.96 * se[6 + k]
        if (d + 1) % 20 == 0:
            print(f"{d + 1} draws, {failed} failed, median {np.median(seconds):.2f} s per fit")
    ok = draws - failed
    return {
        "draws": draws, "units": n_units, "failed": failed,
        "coverage_95": {k: v / ok for k, v in hits.items()},
        "omega_relative_bias": {k: float(np.mean(v)) for k, v in rel_bias.items()},
        "median_fit_seconds": float(np.median(seconds[1:] or seconds)),
        "truth": {"typical": TRUTH, "omega": OMEGA, "sigma": noise or SIGMA},
        "error": error,
    }  # fmt: skip


def scale(sizes: list[int]) -> dict:
    rows = []
    for n in sizes:
        pr = problem(fleet(n, seed=1))
        obj = Objective(pr)
        psi = np.r_[np.log(list(TRUTH.values())), np.log(list(OMEGA.values())), np.log(SIGMA)]
        etas = np.zeros((n, 3))
        obj.solve_inner(psi, etas)  # compiles
        obj.evaluation(psi, etas)
        t0 = time.perf_counter()
        etas, _ = obj.solve_inner(psi, etas)
        t1 = time.perf_counter()
        obj.evaluation(psi, etas)  # O, its gradient and Hessian, the inner Hessians
        t3 = time.perf_counter()
        res = ti.fit(pr)
        t4 = time.perf_counter()
        rows.append({
            "units": n, "inner_solve_s": t1 - t0, "gradient_hessian_s": t3 - t1,
            "iteration_s": t3 - t0, "fit_s": t4 - t3, "fit_iterations": res.nit,
            "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
        })  # fmt: skip
        print(rows[-1])
    u = np.log([r["units"] for r in rows])
    out = {"rows": rows}
    if len(rows) > 1:
        out["exponent_iteration"] = float(
            np.polyfit(u, np.log([r["iteration_s"] for r in rows]), 1)[0]
        )
        out["exponent_fit"] = float(np.polyfit(u, np.log([r["fit_s"] for r in rows]), 1)[0])
    return out


def workers(n_units: int, counts: list[int], repeats: int = 3) -> dict:
    """One outer evaluation (every unit's inner solve, O, ∇O, ∇²O) on a local pool of
    each count of workers, against the same in this process; after a warm-up call
    that compiles in every worker."""
    from tensorid.population.distributed import UnitMap, evaluate_chunk

    obj = Objective(problem(fleet(n_units, seed=2)))
    psi = np.r_[np.log(list(TRUTH.values())), np.log(list(OMEGA.values())), np.log(SIGMA)]
    etas = obj.solve_inner(psi, obj.start_etas())[0]
    rows = []
    evaluate_chunk(obj, psi, etas)  # compiles here
    t0 = time.perf_counter()
    for _ in range(repeats):
        evaluate_chunk(obj, psi, etas)
    here = (time.perf_counter() - t0) / repeats
    for n in counts:
        units = UnitMap(obj, None, n)
        units(psi, etas)  # compiles in the workers
        t0 = time.perf_counter()
        for _ in range(repeats):
            units(psi, etas)
        rows.append({"workers": n, "evaluation_s": (time.perf_counter() - t0) / repeats})
        units.close()
        print(rows[-1])
    return {"units": n_units, "here_s": here, "rows": rows}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("study", choices=["coverage", "scale", "workers"])
    ap.add_argument("--workers", type=int, nargs="+", default=[1, 2])
    ap.add_argument("--draws", type=int, default=200)
    ap.add_argument("--error", choices=["additive", "combined"], default="additive")
    ap.add_argument("--units", type=int, default=50)
    ap.add_argument("--sizes", type=int, nargs="+", default=[100, 1000, 10000])
    ap.add_argument(
        "--json", type=Path, default=Path(__file__).parent / "results" / "population.json"
    )
    a = ap.parse_args()
    if a.study == "workers":
        out = workers(2000 if a.units == 50 else a.units, a.workers)
    else:
        out = coverage(a.draws, a.units, a.error) if a.study == "coverage" else scale(a.sizes)
    print(json.dumps(out, indent=2))
    old = json.loads(a.json.read_text()) if a.json.exists() else {}
    key = a.study if a.error == "additive" or a.study != "coverage" else "coverage_combined"
    old[key] = out
    a.json.write_text(json.dumps(old, indent=2) + "\n")


if __name__ == "__main__":
    main()
