# EMPS positioning system, closed loop: the same rigid-body friction model inside the
# recorded digital controller, driven by the reference position qg (and, on the test
# record, the force pulses added to the controller's output). Sampled at Ts = 1 ms:
#     vir[k]   = kv·(kp·(qg[k] − q[k]) − (q[k] − q[k−1])/Ts) + pulses[k]
#     q, v     : M q'' = gtau·vir[k] − Fv q' − Fc sign(q') − offset over [k, k+1),
#                vir held (zero-order hold), integrated by 4 RK4 substeps
# so the model is a discrete-time map (discrete = True) with states q[k], v[k] and the
# previous position q[k−1] that the controller's velocity estimate needs. The law, with
# these gains, reproduces the recorded vir to an RMS of 0.05 (vir's RMS: 1.5).
# The loop's one-sample delay is the hold: vir computed at k from q[k] first moves
# q[k+1]. make_model(delay=1) applies it one sample later instead (a computation delay);
# the records fit that worse (examples/emps/run.py measures both).
# The estimation record has no pulses: hold them at zero with --columns ...,pulses=0
# (the command lines are in docs/emps.md); examples/emps/run.py does it all in Python.
import jax.numpy as jnp

import tensorid as ti

TS = 1e-3  # s
KP, KV, GTAU = 160.18, 243.45, 35.15065188248547  # the record's kp, kv and gtau
SUBSTEPS = 4


def _acceleration(v, force, p):
    M, Fv, Fc, offset = p
    return (GTAU * force - Fv * v - ti.coulomb_friction(v, Fc, 1e-3) - offset) / M


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


def controller(q, q_prev, qg, pulses):
    """The recorded controller's output vir: cascaded proportional position and
    velocity loops, velocity by backward difference, plus the test record's pulses."""
    return KV * (KP * (qg - q) - (q - q_prev) / TS) + pulses


def step(x, p, u):
    q, v, q_prev = x
    q1, v1 = _hold(q, v, controller(q, q_prev, u[0], u[1]), p)
    return jnp.array([q1, v1, q])


def step_delayed(x, p, u):
    """vir computed at k acts over [k+1, k+2): one more state holds it."""
    q, v, q_prev, vir_prev = x
    q1, v1 = _hold(q, v, vir_prev, p)
    return jnp.array([q1, v1, q, controller(q, q_prev, u[0], u[1])])


def make_model(delay: int = 0) -> ti.Model:
    """The closed loop with the controller's output acting ``delay`` samples after
    the hold (0: the recorded loop; 1: one sample later)."""
    if delay not in (0, 1):
        raise ValueError(f"delay must be 0 or 1 samples, got {delay!r}")
    return ti.Model(
        step_delayed if delay else step,
        output=lambda x, p: x[:1],
        states=["q", "v", "q_prev"] + (["vir_prev"] if delay else []),
        params=["M", "Fv", "Fc", "offset"],
        inputs=["qg", "pulses"],
        outputs=["qm"],
        name="emps-closed-loop" + (f"-delay{delay}" if delay else ""),
        discrete=True,
    )


model = make_model()
p0 = {"M": 80.0, "Fv": 150.0, "Fc": 15.0, "offset": 0.0}
x0 = {"q": 0.0, "v": 0.0, "q_prev": 0.0}
free_x0 = ["q", "v", "q_prev"]
bounds = {"M": (1.0, 1e3), "Fv": (0.0, 1e4), "Fc": (0.0, 1e3)}
