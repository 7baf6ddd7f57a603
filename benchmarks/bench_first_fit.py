"""Time to a first fit (issue 43): a new model's first `tensorid fit`, from an empty
cache folder in a new process, against plain JAX compiling the same cost.

    python benchmarks/bench_first_fit.py [--repeats 3] [--models two-tank,cascade]

For the bundled two-tank record (the paper's model, 501 samples, RK4 with 4
substeps, the paper's guess) and a cascaded-tanks-like model of our own (2 states,
10 parameters and both initial levels free: 12 unknowns, 1,024 samples, RK4 with 4
substeps), each repeat runs, each in its own process:

- ``tensorid fit`` with an empty cache folder (TENSORID_CACHE_DIR): its wall time,
  when its first iteration was printed, the seconds JAX reports compiling
  (jax.monitoring's ``/jax/core/compile/`` events, as ``FitResult.compile_seconds``)
  and the number of XLA compilations (``backend_compile_duration`` events);
- the same command again (the cache now filled);
- the command once more after an edit of one equation in the model file (the square
  root of the first level regularised, ``sqrt(h + 1e-9)``), the cache as the first
  two left it (issue 43, item 3: an edit must cost no more than the first fit);
- plain JAX, no tensorid imported and no cache: the same RK4 cost written plainly,
  the compile time (trace, lower, compile) of ``jax.jit(jax.value_and_grad(cost))``
  and of ``jax.jit(jax.hessian(cost))``, the substeps unrolled (four RK4 steps per
  sample interval written out) and rolled (``lax.fori_loop``: one step in the
  program, which compiles in a fraction of the time).

Models: the bundled two-tank record, a cascaded-tanks-like model (``cascade``), and
the same tanks with smooth switches (``switches``, issue 50 item 2: a sigmoid overflow
gate from the upper tank, a softplus dead-zone pump, power-law outflows with a free
exponent; 10 parameters, 1,024 samples, RK4 with 4 substeps).

Medians over the repeats, range in brackets; the load average is printed with them.

``--masked N`` (issue 50 item 2) also times, in a new process per model, the XLA
compile of the fit's two sweeps (second-order and first-order with scores) with y
plain and with y carrying its mask (``Problem.masked``, which lets the model-error
check's halves run the fit's own programs), N pairs in alternating order, no cache:
the median of the paired ratios masked / plain.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
SRC = ROOT / "src"

TWO_TANK = """
rhs = {"x1": "-p1*sqrt(x1) + p2*u", "x2": "-p3*sqrt(x2) + p4*sqrt(x1)"}
output = {"y": "x2"}
inputs = ["u"]
params = ["p1", "p2", "p3", "p4"]
p0 = {"p1": 0.04, "p2": 0.02, "p3": 0.02, "p4": 0.04}
x0 = {"x1": %r, "x2": %r}
"""
CASCADE = """
rhs = {
    "h1": "-k1*sqrt(h1) - q1*h1 + k4*u + o1",
    "h2": "k2*sqrt(h1) - k3*sqrt(h2) - q2*h2 + o2 + c*u",
}
output = {"y": "h2 + y0"}
inputs = ["u"]
params = ["k1", "k2", "k3", "k4", "q1", "q2", "o1", "o2", "c", "y0"]
p0 = %r
x0 = {"h1": 4.0, "h2": 4.0}
free_x0 = ["h1", "h2"]
"""
# issue 50 item 2: cascaded tanks with smooth switches, as users write them: a sigmoid
# overflow gate from the upper tank (level hmax), a smooth dead-zone pump (softplus
# above u0), power-law outflows with a free exponent a
SWITCHES = """
rhs = {
    "h1": "-k1*(h1 + 1e-6)**a + k4*0.1*log(1 + exp((u - u0)/0.1))"
          " - q*h1/(1 + exp(-(h1 - hmax)/0.05))",
    "h2": "k2*(h1 + 1e-6)**a - k3*(h2 + 1e-6)**a + c*q*h1/(1 + exp(-(h1 - hmax)/0.05))",
}
output = {"y": "h2 + y0"}
inputs = ["u"]
params = ["k1", "k2", "k3", "k4", "a", "hmax", "u0", "q", "c", "y0"]
p0 = %r
x0 = {"h1": 4.0, "h2": 4.0}
"""
SWITCHES_TRUE = dict(k1=0.05, k2=0.05, k3=0.04, k4=0.05, a=0.5, hmax=6.0, u0=0.5, q=0.2)
SWITCHES_TRUE.update(c=0.5, y0=0.1)
# one equation edited as a user would (the first square root regularised)
EDITS = {"two-tank": ("sqrt(x1)", "sqrt(x1 + 1e-9)"), "cascade": ("sqrt(h1)", "sqrt(h1 + 1e-9)"),
         "switches": ("(h1 + 1e-6)**a + k4", "(h1 + 1e-7)**a + k4")}  # fmt: skip
CASCADE_TRUE = dict(k1=0.05, k2=0.05, k3=0.04, k4=0.04, q1=0.002, q2=0.003, o1=0.01, o2=0.005)
CASCADE_TRUE.update(c=0.01, y0=0.1)
CASCADE_TS, CASCADE_SAMPLES = 4.0, 1024

# the same cost written plainly: RK4, 4 substeps, the input linear between samples
# (tensorid's default)
PLAIN = """
import json, sys, time
import numpy as np
import jax, jax.numpy as jnp
jax.config.update("jax_enable_x64", True)
d = np.load(sys.argv[1])
kind, t, u, y, theta = str(d["kind"]), d["t"], d["u"], d["y"], jnp.asarray(d["theta"])
step = (t[1] - t[0]) / 4

def f(x, p, u):
    if kind == "two-tank":
        s1, s2 = jnp.sqrt(x[0]), jnp.sqrt(x[1])
        return jnp.stack([-p[0] * s1 + p[1] * u, -p[2] * s2 + p[3] * s1])
    if kind == "switches":
        k1, k2, k3, k4, a, hmax, u0, q, c = p[:9]
        gate = q * x[0] / (1 + jnp.exp(-(x[0] - hmax) / 0.05))
        pump = k4 * 0.1 * jnp.log(1 + jnp.exp((u - u0) / 0.1))
        o1, o2 = (x[0] + 1e-6) ** a, (x[1] + 1e-6) ** a
        return jnp.stack([-k1 * o1 + pump - gate, k2 * o1 - k3 * o2 + c * gate])
    k1, k2, k3, k4, q1, q2, o1, o2, c = p[:9]
    s1, s2 = jnp.sqrt(x[0]), jnp.sqrt(x[1])
    h2 = k2 * s1 - k3 * s2 - q2 * x[1] + o2 + c * u
    return jnp.stack([-k1 * s1 - q1 * x[0] + k4 * u + o1, h2])

def out(x, p):
    return x[1] if kind == "two-tank" else x[1] + p[9]

def rk4(x, p, ua, ub, i):
    um, ue = ua + (ub - ua) * (i + 0.5) / 4, ua + (ub - ua) * (i + 1) / 4
    k1 = f(x, p, ua + (ub - ua) * i / 4); k2 = f(x + step / 2 * k1, p, um)
    k3 = f(x + step / 2 * k2, p, um); k4 = f(x + step * k3, p, ue)
    return x + step / 6 * (k1 + 2 * k2 + 2 * k3 + k4)

def cost(theta, rolled=False):
    x0, p = (jnp.asarray(d["x0"]), theta) if kind != "cascade" else (theta[:2], theta[2:])
    def interval(x, uu):
        ua, ub = uu
        if rolled:  # the substeps as a loop: one RK4 step in the program, not four
            x = jax.lax.fori_loop(0, 4, lambda i, x: rk4(x, p, ua, ub, i), x)
        else:
            for i in range(4):
                x = rk4(x, p, ua, ub, i)
        return x, out(x, p)
    _, yh = jax.lax.scan(interval, x0, (u[:-1], u[1:]))
    r = jnp.concatenate([jnp.atleast_1d(out(x0, p)), yh]) - y
    return 0.5 * jnp.sum(r * r)

res = {}
rolled = lambda theta: cost(theta, True)
for name, fn in (("value_and_grad", jax.value_and_grad(cost)), ("hessian", jax.hessian(cost)),
                 ("hessian_rolled", jax.hessian(rolled))):
    t0 = time.perf_counter()
    compiled = jax.jit(fn).lower(theta).compile()
    res[name] = time.perf_counter() - t0
    jax.block_until_ready(compiled(theta))
print(json.dumps(res))
"""

# the fit's two sweeps compiled with y masked and plain, in pairs (--masked)
MASKED = """
import json, statistics, sys, time
import jax, jax.numpy as jnp, numpy as np
import tensorid as ti
from tensorid.app.files import load_model
jax.config.update("jax_enable_compilation_cache", False)
spec, d = load_model(sys.argv[1]), np.genfromtxt(sys.argv[2], delimiter=",", names=True)
prob = ti.Problem(spec.model, ti.Experiment(d["t"], d["u"], d["y"]), p0=spec.p0, x0=spec.x0,
                  free_x0=spec.free_x0)
if not prob.masked:  # (the adjoint's Hessian path takes y plain)
    print(json.dumps({}))
    sys.exit()
sw, (t, u, y) = prob._sweeps, prob._arrays[0]
x0, p, w = jnp.asarray(prob.x0[0]), jnp.asarray(prob.p0), jnp.asarray(prob.loss_weights)
th = jnp.asarray(prob.theta0)
def seconds(fn, yy):  # a new function each time: nothing cached in the process
    t0 = time.perf_counter()
    jax.jit(lambda *a: fn(*a)).lower(th, x0, p, t, u, yy, w).compile()
    return time.perf_counter() - t0
out = {}
for name, fn in (("second", sw._second_order_both), ("first", sw._first_order_scores)):
    pairs = []
    for r in range(int(sys.argv[3])):
        a, b = (y, y["y"]) if r % 2 else (y["y"], y)
        ta, tb = seconds(fn, a), seconds(fn, b)
        pairs.append((ta, tb) if r % 2 else (tb, ta))
    out[name] = [statistics.median(m / q for m, q in pairs),
                 statistics.median(q for _, q in pairs)]
print(json.dumps(out))
"""

# tensorid's command line with JAX's compile events counted
CLI = """
import json, sys, atexit
import jax.monitoring as m
n = {"xla": 0, "hits": 0, "loaded": 0, "compile_s": 0.0}
def hit(event, **_):
    n["hits"] += event == "/jax/compilation_cache/cache_hits"
m.register_event_listener(hit)
def on(event, secs, **_):
    if event.startswith("/jax/core/compile/"):
        n["compile_s"] += secs
    if event == "/jax/core/compile/backend_compile_duration":
        n["xla"] += 1
    if event == "/jax/core/compile/tensorid_load":
        n["loaded"] += 1
m.register_event_duration_secs_listener(on)
where = sys.argv[1]
atexit.register(lambda: open(where, "w").write(json.dumps(n)))
from tensorid.cli import main
sys.argv = ["tensorid", *sys.argv[2:]]
sys.exit(main())
"""


def _two_tank(folder: Path) -> tuple[Path, Path, dict]:
    from tensorid import datasets

    e, levels = datasets.two_tank(501), datasets.two_tank_levels(501)
    model = folder / "two_tank.py"
    model.write_text(TWO_TANK % (float(levels[0][0]), float(levels[0][1])))
    data = folder / "two_tank.csv"
    np.savetxt(data, np.c_[e.t, e.u[:, 0], e.y[:, 0]], delimiter=",", header="t,u,y", comments="")
    plain = dict(kind="two-tank", t=e.t, u=e.u[:, 0], y=e.y[:, 0], x0=levels[0])
    plain["theta"] = np.array([0.04, 0.02, 0.02, 0.04])
    return model, data, plain


def _tanks(folder: Path, name: str, text: str, truth: dict, guess: dict, seed: int):
    """(model file, data file, the plain cost's record) of a synthetic tanks record:
    the model file ``text`` with p0 = ``guess``, simulated at ``truth`` from levels
    (4, 4) over 1,024 samples at 4 s, the input a staircase of 32-sample steps in
    [1, 6], noise SD 0.02 on the lower level."""
    import tensorid as ti

    rng = np.random.default_rng(seed)
    t = np.arange(CASCADE_SAMPLES) * CASCADE_TS
    u = np.repeat(rng.uniform(1.0, 6.0, CASCADE_SAMPLES // 32 + 1), 32)[:CASCADE_SAMPLES]
    model = folder / f"{name}.py"
    model.write_text(text % guess)
    m = ti.load_model(model).model
    e = ti.Experiment(t, u, np.zeros(CASCADE_SAMPLES))
    x = ti.simulate(m, list(truth.values()), [4.0, 4.0], e).y[:, 0]
    y = x + 0.02 * rng.standard_normal(CASCADE_SAMPLES)
    data = folder / f"{name}.csv"
    np.savetxt(data, np.c_[t, u, y], delimiter=",", header="t,u,y", comments="")
    return model, data, dict(kind=name, t=t, u=u, y=y)


def _cascade(folder: Path) -> tuple[Path, Path, dict]:
    guess = {k: v * (1.2 if i % 2 else 0.85) for i, (k, v) in enumerate(CASCADE_TRUE.items())}
    model, data, plain = _tanks(folder, "cascade", CASCADE, CASCADE_TRUE, guess, 43)
    plain.update(x0=np.zeros(2), theta=np.r_[4.0, 4.0, list(guess.values())])  # (x0 free)
    return model, data, plain


def _switches(folder: Path) -> tuple[Path, Path, dict]:
    guess = {k: v * (1.1 if i % 2 else 0.9) for i, (k, v) in enumerate(SWITCHES_TRUE.items())}
    model, data, plain = _tanks(folder, "switches", SWITCHES, SWITCHES_TRUE, guess, 50)
    plain.update(x0=np.array([4.0, 4.0]), theta=np.array(list(guess.values())))
    return model, data, plain


def _cli(model: Path, data: Path, cache: Path, folder: Path, mpl: str) -> dict:
    env = {k: v for k, v in os.environ.items() if k != "TENSORID_CACHE"}
    env.update(PYTHONPATH=str(SRC), TENSORID_CACHE_DIR=str(cache), MPLCONFIGDIR=mpl)
    counts = folder / "counts.json"
    cmd = [sys.executable, "-c", CLI, str(counts), "fit", str(model), str(data)]
    cmd += ["--out", str(folder / "fit")]
    t0 = time.perf_counter()
    proc = subprocess.Popen(
        cmd, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True
    )
    first, compile_lines = None, []
    for line in proc.stdout or []:
        if first is None and line.startswith("iteration 0"):
            first = time.perf_counter() - t0
        if line.startswith("compil"):
            compile_lines.append(line.strip())
    if proc.wait() not in (0, 1):
        raise RuntimeError(f"tensorid fit failed: {' '.join(cmd)}")
    wall = time.perf_counter() - t0
    n = json.loads(counts.read_text())
    return dict(wall=wall, first_iteration=first, **n, lines=compile_lines)


def _plain(spec: dict, folder: Path) -> dict:
    path = folder / "plain.npz"
    np.savez(path, **spec)
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    done = subprocess.run(
        [sys.executable, "-c", PLAIN, str(path)],
        env=env,
        check=True,
        capture_output=True,
        text=True,
    )
    return json.loads(done.stdout.strip().splitlines()[-1])


def _masked(model: Path, data: Path, pairs: int) -> dict:
    env = {**os.environ, "PYTHONPATH": str(SRC), "TENSORID_CACHE": "0"}
    cmd = [sys.executable, "-c", MASKED, str(model), str(data), str(pairs)]
    done = subprocess.run(cmd, env=env, check=True, capture_output=True, text=True)
    return json.loads(done.stdout.strip().splitlines()[-1])


def _med(values) -> str:
    values = [v for v in values if v is not None]
    if not values:
        return "-"
    if isinstance(values[0], int):
        return f"{statistics.median(values):g} [{min(values)}-{max(values)}]"
    return f"{statistics.median(values):.1f} [{min(values):.1f}-{max(values):.1f}]"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--models", default="two-tank,cascade,switches")
    parser.add_argument("--masked", type=int, default=0, help="pairs of masked/plain compiles")
    args = parser.parse_args()
    sys.path.insert(0, str(SRC))
    os.environ["TENSORID_CACHE"] = "0"  # this process only makes the data: no cache
    work = Path(tempfile.mkdtemp(prefix="tensorid-first-fit-"))
    # Matplotlib's settings folder for the figure renderer, filled once before the
    # runs: a stale lock in the user's own (a killed process's) makes each import wait 5 s
    mpl = str(work / "matplotlib")
    prime = "import matplotlib; matplotlib.use('Agg'); import matplotlib.pyplot"
    subprocess.run([sys.executable, "-c", prime], env={**os.environ, "MPLCONFIGDIR": mpl})
    makers = {"two-tank": _two_tank, "cascade": _cascade, "switches": _switches}
    cases = {name: makers[name](work) for name in args.models.split(",")}
    rows: dict = {name: [] for name in cases}
    load = [os.getloadavg()[0]]
    for r in range(args.repeats):
        for name, (model, data, plain) in cases.items():  # alternating: load falls alike
            folder = Path(tempfile.mkdtemp(prefix=f"{name}-{r}-", dir=work))
            cold = _cli(model, data, folder / "cache", folder, mpl)
            warm = _cli(model, data, folder / "cache", folder, mpl)
            edited = folder / model.name
            edited.write_text(model.read_text().replace(*EDITS[name], 1))
            edit = _cli(edited, data, folder / "cache", folder, mpl)
            runs = dict(cold=cold, warm=warm, edit=edit, plain=_plain(plain, folder))
            rows[name].append(runs)
            load.append(os.getloadavg()[0])
            print(f"{name} #{r}: {json.dumps(rows[name][-1])}", file=sys.stderr)
    import jax

    print(f"JAX {jax.__version__}, {os.cpu_count()} cores; load average (1 min) during the")
    print(f"runs {min(load):.1f}-{max(load):.1f}; medians of {args.repeats} [range], seconds\n")
    print(
        "| model | first fit, wall | first iteration printed | compile (JAX) | XLA programs "
        "compiled | second fit, wall | its compile (loading included) | its XLA compilations "
        "(cache hits) | after an edit, wall (XLA programs compiled) | plain value_and_grad "
        "compile | plain hessian compile | plain hessian, substeps rolled |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|---|---|")
    for name, runs in rows.items():
        c, w, e, p = ([x[k] for x in runs] for k in ("cold", "warm", "edit", "plain"))
        print(
            f"| {name} | {_med([x['wall'] for x in c])} | {_med([x['first_iteration'] for x in c])}"
            f" | {_med([x['compile_s'] for x in c])} | {_med([x['xla'] - x['hits'] for x in c])}"
            f" | {_med([x['wall'] for x in w])} | {_med([x['compile_s'] for x in w])}"
            f" | {_med([x['xla'] - x['hits'] for x in w])} ({_med([x['hits'] for x in w])})"
            f" | {_med([x['wall'] for x in e])} ({_med([x['xla'] - x['hits'] for x in e])})"
            f" | {_med([x['value_and_grad'] for x in p])}"
            f" | {_med([x['hessian'] for x in p])} | {_med([x['hessian_rolled'] for x in p])} |"
        )
    if args.masked:
        print(f"\nXLA compile with y masked / plain, median of {args.masked} pairs (plain s):")
        for name, (model, data, _) in cases.items():
            m = _masked(model, data, args.masked)
            if not m:
                print(f"    {name}: y plain (its Hessian path, the adjoint's, takes no mask)")
                continue
            print(f"    {name}: second-order sweep {m['second'][0]:.3f} ({m['second'][1]:.2f} s),"
                  f" first-order sweep {m['first'][0]:.3f} ({m['first'][1]:.2f} s)")  # fmt: skip
    for name, runs in rows.items():
        print(f"\n{name}, the first fit's compile lines (last repeat):")
        for line in runs[-1]["cold"]["lines"]:
            print(f"    {line}")
    shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    main()
