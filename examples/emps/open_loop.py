# EMPS positioning system, open loop: the rigid-body friction model driven by the
# recorded controller output vir (the force on the load is gtau·vir),
#     M q'' = gtau·vir − Fv q' − Fc sign(q') − offset,   output the position q (m).
# sign is smoothed (tensorid.coulomb_friction, eps = 1 mm/s: the record moves at up to
# 0.2 m/s) so the cost has the derivatives the fit needs.
# A double integrator: position errors accumulate, so fit it with multiple shooting:
#   tensorid fit examples/emps/open_loop.py src/tensorid/datasets/emps.npz --ts 1e-3 \
#       --columns vir=estimation_vir,qm=estimation_qm \
#       --validate src/tensorid/datasets/emps.npz --validate-columns vir=test_vir,qm=test_qm \
#       --init-window 20 --segments 100 --substeps 1 --method gauss-newton --out emps-open-loop
# (docs/emps.md; the record ships with tensorid)
import jax.numpy as jnp

import tensorid as ti

GTAU = 35.15065188248547  # N per unit of vir (drive gain, the record's gtau)


def rhs(x, p, u):
    q, v = x
    M, Fv, Fc, offset = p
    force = GTAU * u[0] - Fv * v - ti.coulomb_friction(v, Fc, 1e-3) - offset
    return jnp.array([v, force / M])


model = ti.Model(
    rhs,
    output=lambda x, p: x[:1],
    states=["q", "v"],
    params=["M", "Fv", "Fc", "offset"],
    inputs=["vir"],
    outputs=["qm"],
    name="emps-open-loop",
)
p0 = {"M": 80.0, "Fv": 150.0, "Fc": 15.0, "offset": 0.0}
x0 = {"q": 0.0, "v": 0.0}
free_x0 = ["q", "v"]
bounds = {"M": (1.0, 1e3), "Fv": (0.0, 1e4), "Fc": (0.0, 1e3)}
