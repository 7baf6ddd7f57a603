# EMPS positioning system, closed loop, with Stribeck friction in place of Coulomb's:
#     M q'' = gtau·vir − Fv q' − (Fc + (Fs − Fc)·exp(−(q'/vs)²))·sign(q') − offset,
# Fs the break-away (static) friction, Fc the sliding (Coulomb) one. Physics wants
# Fs >= Fc (friction peaks at break-away); the record alone need not say so, so the
# fit keeps it as a constraint (docs/emps.md, "Stribeck friction, kept physical"):
#   tensorid fit examples/emps/stribeck.py src/tensorid/datasets/emps.npz --ts 1e-3 \
#       --columns qg=estimation_qg,qm=estimation_qm,pulses=0 --method newton \
#       --constraint "Fs >= Fc" --out emps-stribeck
# (or constraints = ["Fs >= Fc"] in this file; without it the fit ends at Fs < Fc).
# The controller, the hold and the states are those of closed_loop.py.
import jax.numpy as jnp

import tensorid as ti

TS = 1e-3  # s
KP, KV, GTAU = 160.18, 243.45, 35.15065188248547  # the record's kp, kv and gtau
SUBSTEPS = 4
VS = 0.01  # m/s: the Stribeck velocity, fixed (the record reverses too fast to tell it)


def _acceleration(v, force, p):
    M, Fv, Fc, Fs, offset = p
    friction = ti.stribeck_friction(v, Fc, Fs, VS, Fv, eps=1e-3)
    return (GTAU * force - friction - offset) / M


def _hold(q, v, force, p):
    """One sample of the mechanics with the force held: RK4 on (q, v)."""
    h = TS / SUBSTEPS
    for _ in range(SUBSTEPS):
        k1 = _acceleration(v, force, p)
        k2 = _acceleration(v + h / 2 * k1, force, p)
        k3 = _acceleration(v + h / 2 * k2, force, p)
        k4 = _acceleration(v + h * k3, force, p)
        q = q + h * (v + h / 6 * (k1 + k2 + k3))
        v = v + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
    return q, v


def step(x, p, u):
    q, v, q_prev = x
    vir = KV * (KP * (u[0] - q) - (q - q_prev) / TS) + u[1]
    q1, v1 = _hold(q, v, vir, p)
    return jnp.array([q1, v1, q])


model = ti.Model(
    step,
    output=lambda x, p: x[:1],
    states=["q", "v", "q_prev"],
    params=["M", "Fv", "Fc", "Fs", "offset"],
    inputs=["qg", "pulses"],
    outputs=["qm"],
    name="emps-stribeck",
    discrete=True,
)
p0 = {"M": 80.0, "Fv": 150.0, "Fc": 15.0, "Fs": 15.0, "offset": 0.0}
x0 = {"q": 0.0, "v": 0.0, "q_prev": 0.0}
free_x0 = ["q", "v", "q_prev"]
bounds = {"M": (1.0, 1e3), "Fv": (0.0, 1e4), "Fc": (0.0, 1e3), "Fs": (0.0, 1e3)}
