"""Shared models and synthetic data for the tests."""

from __future__ import annotations

import os
import tempfile

# the CLI keeps compiled code on disk; keep the tests' copies out of the home folder, in
# one folder of the system's temporary space that the next run reuses (CI's slow run
# reuses what its default run compiled). Set before tensorid is imported: its import
# turns the cache on in the folder named then.
_USER = os.getuid() if hasattr(os, "getuid") else "user"
os.environ.setdefault(
    "TENSORID_CACHE_DIR", os.path.join(tempfile.gettempdir(), f"tensorid-test-cache-{_USER}")
)
# each test compiles its programs once: writing them for a next process would only cost
# (10-20 % more compile time); tests/test_programs.py turns them on where it checks them
os.environ.setdefault("TENSORID_PROGRAMS", "0")

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402
import pytest  # noqa: E402

import tensorid as ti  # noqa: E402

# a reference program runs once: LLVM's optimisations would only lengthen its compile,
# the larger part of a derivative test's time (XLA's own passes still run)
REFERENCE_OPTIONS = {"xla_backend_optimization_level": 0}


def autodiff(f, *, hessian=True):
    """``θ -> (J, ∇J, ∇²J)`` of the scalar ``f`` by JAX (forward over reverse mode: what
    jax.hessian takes), as NumPy arrays, from one program compiled at the first call
    (three separately jitted references compiled the common reverse pass three times);
    ``hessian=False``: (J, ∇J)."""

    def value_grad_hess(z):
        if not hessian:
            return jax.value_and_grad(f)(z)

        def along(v):
            return jax.jvp(jax.value_and_grad(f), (z,), (v,))

        eye = jnp.eye(z.size, dtype=z.dtype)
        (J, g), (_, H) = jax.vmap(along, out_axes=((None, None), 0))(eye)
        return J, g, H.T  # row i is H's column i (H is symmetric up to rounding)

    compiled = {}

    def at(theta):
        th = jnp.asarray(theta, dtype=float)
        if th.shape not in compiled:
            lowered = jax.jit(value_grad_hess).lower(th)
            compiled[th.shape] = lowered.compile(compiler_options=REFERENCE_OPTIONS)
        out = compiled[th.shape](th)
        return (float(out[0]), *(np.asarray(a) for a in out[1:]))

    return at


SILVERBOX_P = {"m": 5.27e-6, "d": 2.15e-4, "a": 0.9675, "b": 3.975}
TS_SILVERBOX = 2**14 / 1e7


def silverbox_rhs(x, p, u):
    m, d, a, b = p
    return jnp.stack([x[1], (u[0] - d * x[1] - a * x[0] - b * x[0] ** 3) / m])


def silverbox_model(**overrides) -> ti.Model:
    args = dict(
        rhs=silverbox_rhs,
        output=lambda x, p: x[:1],
        states=["y", "v"],
        params=["m", "d", "a", "b"],
        inputs=["u"],
        outputs=["y"],
        name="silverbox",
    )
    args.update(overrides)
    return ti.Model(**args)


def multisine(P: int, Ts: float, amplitude: float, seed: int, harmonics=range(1, 120, 2)):
    rng = np.random.default_rng(seed)
    t = np.arange(P) * Ts
    u = sum(np.cos(2 * np.pi * k * t / (P * Ts) + rng.uniform(0, 2 * np.pi)) for k in harmonics)
    return t, amplitude * u / np.abs(u).max()


def silverbox_data(P=512, seed=0, noise=0.0, x0=(0.0, 0.0)):
    t, u = multisine(P, TS_SILVERBOX, 0.1, seed)
    sim = ti.simulate(silverbox_model(), SILVERBOX_P, np.array(x0), ti.Experiment(t, u))
    y = sim.y + noise * np.random.default_rng(seed + 1).standard_normal(sim.y.shape)
    return ti.Experiment(t, u, y, name=f"sb{seed}")


def two_tank_model() -> ti.Model:
    def rhs(x, p, u):
        s1, s2 = jnp.sqrt(x[0]), jnp.sqrt(x[1])
        return jnp.stack([-p[0] * s1 + p[1] * u[0], -p[2] * s2 + p[3] * s1])

    return ti.Model(
        rhs=rhs,
        output=lambda x, p: x[1:],
        states=["x1", "x2"],
        params=["p1", "p2", "p3", "p4"],
        inputs=["u"],
        outputs=["y"],
        name="two-tank",
    )


def oscillator_model() -> ti.Model:
    """Two inputs, two outputs; the output map is nonlinear and depends on p."""

    def rhs(x, p, u):
        k, c, g, q = p
        return jnp.stack([x[1], -k * jnp.sin(x[0]) - c * x[1] + g * u[0] + 0.3 * u[1] * x[0]])

    def output(x, p):
        k, c, g, q = p
        return jnp.stack([q * x[0] ** 2 + x[1], jnp.tanh(q * x[1]) * k + x[0]])

    return ti.Model(
        rhs=rhs,
        output=output,
        states=["th", "om"],
        params=["k", "c", "g", "q"],
        inputs=["u1", "u2"],
        outputs=["y1", "y2"],
        name="oscillator",
    )


def reactor_model() -> ti.Model:
    """Three states, two inputs, one output that mixes states and a parameter."""

    def rhs(x, p, u):
        k1, k2, k3, V = p
        r1 = k1 * x[0] * x[1]
        r2 = k2 * x[2] ** 2 / (1.0 + x[2] ** 2)
        return jnp.stack(
            [u[0] - r1 - 0.1 * x[0], u[1] - r1 + r2 - 0.2 * x[1], r1 - r2 - k3 * x[2] / V]
        )

    return ti.Model(
        rhs=rhs,
        output=lambda x, p: jnp.stack([x[2] * p[3] + 0.5 * x[0] * x[1]]),
        states=["A", "B", "C"],
        params=["k1", "k2", "k3", "V"],
        inputs=["qA", "qB"],
        outputs=["z"],
        name="reactor",
    )


def decay_model() -> ti.Model:
    """One state, one parameter, scalar output: the K = 1 and N = 1 edge case."""
    return ti.Model(
        rhs=lambda x, p, u: -p[0] * x + u[0],
        output=lambda x, p: x[0] ** 2,
        states=["x"],
        params=["k"],
        inputs=["u"],
        outputs=["y"],
        name="decay",
    )


@pytest.fixture
def silverbox():
    return silverbox_model()


ROBERTSON_K = {"k1": 0.04, "k2": 3e7, "k3": 1e4}


def robertson_model() -> ti.Model:
    """Robertson's stiff chemical kinetics (rate constants spanning 9 decades)."""

    def rhs(x, p, u):
        k1, k2, k3 = p
        return jnp.stack(
            [
                -k1 * x[0] + k3 * x[1] * x[2],
                k1 * x[0] - k2 * x[1] ** 2 - k3 * x[1] * x[2],
                k2 * x[1] ** 2,
            ]
        )

    return ti.Model(
        rhs=rhs,
        output=lambda x, p: jnp.stack([x[0], 1e4 * x[1], x[2]]),
        states=["A", "B", "C"],
        params=["k1", "k2", "k3"],
        inputs=["u"],
        outputs=["a", "b_x1e4", "c"],
        name="robertson",
    )


def robertson_data() -> ti.Experiment:
    """Noise-free samples on a log grid out to t = 100 from an implicit reference
    solver (scipy's Radau at rtol 1e-12), independent of tensorid."""
    from scipy.integrate import solve_ivp

    k1, k2, k3 = ROBERTSON_K.values()

    def f(_, x):
        return [
            -k1 * x[0] + k3 * x[1] * x[2],
            k1 * x[0] - k2 * x[1] ** 2 - k3 * x[1] * x[2],
            k2 * x[1] ** 2,
        ]

    t = np.concatenate([[0.0], np.logspace(-4, 2, 40)])
    sol = solve_ivp(
        f, (0, t[-1]), [1.0, 0.0, 0.0], t_eval=t, method="Radau", rtol=1e-12, atol=1e-16
    )
    y = np.stack([sol.y[0], 1e4 * sol.y[1], sol.y[2]], axis=1)
    return ti.Experiment(t, np.zeros((t.size, 1)), y, name="robertson")


def noisy_experiment(model, p, x0, t, u, seed, noise, **kw):
    sim = ti.simulate(model, p, x0, ti.Experiment(t, u), **kw)
    rng = np.random.default_rng(seed)
    return ti.Experiment(t, u, sim.y + noise * rng.standard_normal(sim.y.shape), name=f"e{seed}")


def _oscillator(**kw):
    """(problem, theta): two outputs with a p-dependent nonlinear output map, two
    inputs (multisines), two experiments of different lengths, one free and one fixed
    initial state, one fixed parameter, weights."""
    m = oscillator_model()
    ptrue = {"k": 2.0, "c": 0.3, "g": 1.0, "q": 0.7}
    exps = []
    for seed, P in ((4, 150), (5, 110)):
        t = np.arange(P) * 0.05
        u = np.stack(
            [
                multisine(P, 0.05, 1.0, seed, range(1, 20))[1],
                multisine(P, 0.05, 0.5, seed + 10, range(2, 15))[1],
            ],
            axis=1,
        )
        sim_kw = {k: v for k, v in kw.items() if k in ("interpolation", "scheme")}
        exps.append(noisy_experiment(m, ptrue, [0.3, -0.2], t, u, seed, 0.05, **sim_kw))
    prob = ti.Problem(
        m,
        exps,
        p0=ptrue,
        x0=[[0.3, -0.2], [0.1, 0.4]],
        free_x0=["om"],
        fixed=["g"],
        weights={"y2": 2.5},
        **kw,
    )
    return prob, prob.theta0 + np.array([0.1, -0.2, 0.3, -0.05, 0.1])


def interpolation_problems(**kw):
    """(id, problem, theta): the oscillator case with each smooth input interpolation
    (an adaptive scheme's: tests/test_integrate.py)."""
    out = []
    for interpolation in ("bandlimited", "periodic", "cubic"):
        prob, theta = _oscillator(interpolation=interpolation, **kw)
        out.append((f"oscillator, {interpolation} input", prob, theta))
    return out


def derivative_problems(**kw):
    """(id, problem, theta) with theta away from the optimum, so that the residual-
    weighted second-order term of the Hessian matters: explicit schemes, zoh, free
    and fixed initial states, two experiments, two outputs. ``kw`` goes to every
    Problem (e.g. hessian="adjoint")."""
    out = []

    m = silverbox_model()
    data = silverbox_data(P=300, seed=3, noise=1e-3, x0=(0.02, 0.0))
    prob = ti.Problem(m, data, p0=SILVERBOX_P, x0=[0.02, 0.0], free_x0=["v"], **kw)
    out.append(
        (
            "silverbox",
            prob,
            prob.theta0 * np.array([1, 1.04, 0.97, 1.02, 0.9]) + np.array([0.5, 0, 0, 0, 0]),
        )
    )

    m = two_tank_model()
    t = np.arange(200) * 5.0
    u = np.repeat(np.random.default_rng(1).uniform(0.3, 2.0, 10), 20)
    ptrue = {"p1": 0.04, "p2": 0.02, "p3": 0.02, "p4": 0.05}
    data = noisy_experiment(m, ptrue, [2.0, 1.0], t, u, 2, 0.01, interpolation="zoh")
    prob = ti.Problem(
        m, data, p0=ptrue, x0=[2.0, 1.0], interpolation="zoh", bounds={"p1": (0, 1)}, **kw
    )
    out.append(("two-tank fixed x0, zoh", prob, prob.theta0 * np.array([1.1, 0.9, 1.05, 0.95])))

    out.append(("oscillator multi-output multi-experiment", *_oscillator(**kw)))

    m = reactor_model()
    ptrue = {"k1": 0.8, "k2": 0.5, "k3": 0.3, "V": 2.0}
    t = np.arange(120) * 0.1
    u = np.stack(
        [
            1 + multisine(120, 0.1, 0.5, 7, range(1, 10))[1],
            0.5 + multisine(120, 0.1, 0.3, 8, range(1, 10))[1],
        ],
        axis=1,
    )
    data = noisy_experiment(m, ptrue, [1.0, 0.5, 0.2], t, u, 9, 0.02, scheme="heun", substeps=3)
    prob = ti.Problem(
        m,
        data,
        p0=ptrue,
        x0=[1.0, 0.5, 0.2],
        free_x0=["A", "B", "C"],
        scheme="heun",
        substeps=3,
        **kw,
    )
    out.append(("reactor all x0 free, heun", prob, prob.theta0 * 1.07))

    m = decay_model()
    t = np.linspace(0, 3, 40)
    data = noisy_experiment(m, {"k": 1.3}, [1.0], t, np.sin(t), 11, 0.01, scheme="euler")
    prob = ti.Problem(m, data, p0={"k": 1.0}, x0=[1.0], scheme="euler", substeps=2, **kw)
    out.append(("decay K=1 N=1 euler", prob, np.array([1.4])))
    return out
