"""A population fit's substeps check (population/refine.py) compares every unit's
predictions at s and 2s substeps: both come from one program, which reads the number of
substeps when it runs (Discretisation.at_run_time), and its predictions are the fit's."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from test_population import fleet_problem, one_compartment

import tensorid as ti
from tensorid.engine.modelling.events import Events
from tensorid.engine.sweeping.sweeps import shared_sweeps
from tensorid.population.objective import Objective
from tensorid.population.start import start_point


@pytest.mark.parametrize("scheme", ["rk4", "sdirk2"])
def test_substeps_read_at_run_time_simulate_as_those_compiled_in(scheme):
    m = one_compartment()
    t = np.array([0.0, 0.5, 1.0, 3.0, 8.0, 24.0])
    u = np.full((t.size, 1), 300.0)
    x0, p = jnp.array([300.0, 0.0]), jnp.array([1.4, 2.5, 30.0])
    d = ti.Discretisation.of(scheme, 1)

    @jax.jit
    def at(steps):
        sw = shared_sweeps(m, (), (), d.at_run_time(steps))
        return sw._simulate(x0, p, jnp.asarray(t), jnp.asarray(u))[1]

    for s in (3, 8):
        fixed = shared_sweeps(m, (), (), ti.Discretisation.of(scheme, s))
        want = np.asarray(fixed._simulate(x0, p, jnp.asarray(t), jnp.asarray(u))[1])
        np.testing.assert_allclose(np.asarray(at(jnp.int32(s))), want, rtol=1e-14, atol=0)
    assert at._cache_size() == 1  # one program for both


def test_one_program_predicts_the_fleet_at_every_substeps_as_the_fit_does():
    problem = fleet_problem(3)
    obj, finer = Objective(problem, "focei"), Objective(problem.with_substeps(40), "focei")
    psi, etas = start_point(obj), obj.start_etas()
    etas[:, 0] = [0.3, -0.2, 0.1]
    fit_own = jax.vmap(obj.predict, in_axes=(None, 0, 0))  # ŷ as the fit's ℓ sees it
    own = np.asarray(fit_own(jnp.asarray(psi), jnp.asarray(etas), obj.data))
    np.testing.assert_array_equal(np.asarray(obj.predict_all(psi, etas)), own)
    program = obj._compiled("predict_all")
    runs = len(program._runs)  # (other tests' fleets of this structure may have added)
    fine = np.asarray(jax.vmap(finer.predict, in_axes=(None, 0, 0))(psi, etas, finer.data))
    np.testing.assert_allclose(np.asarray(obj.predict_all(psi, etas, 40)), fine, rtol=1e-13)
    np.testing.assert_allclose(np.asarray(finer.predict_all(psi, etas)), fine, rtol=1e-13)
    assert finer._compiled("predict_all") is program  # (kept as at 1 substep)
    assert len(program._runs) == runs  # compiled once, for 20 and 40 substeps alike


def test_only_a_fixed_step_scheme_reads_its_substeps_at_run_time():
    with pytest.raises(TypeError, match="dopri5 scheme does not take a fixed number"):
        ti.Discretisation.of("dopri5").at_run_time(jnp.int32(3))


def test_a_steady_state_dose_s_cycle_takes_its_own_steps_at_run_time_substeps():
    """A steady-state dose integrates each part of its cycle with CYCLE_STEPS times the
    substeps (engine/sweeping/steady.py): the run-time substeps multiply those too, so
    the predictions stay the fit's (RK4 at 4 steps over a 24 h cycle is unstable)."""
    m = ti.Model(rhs=lambda x, p, u: jnp.stack([-p[0] * x[0] - 0.02 * x[0] ** 2 / (1 + x[0])]),
                 output=lambda x, p: x / p[1], states=["c"], params=["k", "v"],
                 outputs=["cp"])  # fmt: skip
    T, rng, units = np.array([0.5, 2.0, 6.0, 11.0, 14.0]), np.random.default_rng(0), []
    for i in range(3):
        y = np.array([[9.0, 8.0, 6.0, 4.0, 8.5]]).T * np.exp(0.02 * rng.standard_normal((5, 1)))
        ev = Events.doses(0.0, "c", 100.0, ii=24.0, addl=1, ss=True)
        units.append(ti.Experiment(T, None, y, events=ev, name=f"u{i}"))
    problem = ti.Problem(m, units, p0={"k": 0.3, "v": 10.0}, x0=[0.0], population={"k": 0.3})
    obj, finer = Objective(problem, "focei"), Objective(problem.with_substeps(8), "focei")
    psi, etas = start_point(obj), obj.start_etas()
    etas[:, 0] = [0.8, 0.0, -0.8]
    for o, s in ((obj, None), (finer, None), (obj, 8)):
        own = o if s is None else finer
        fit_own = np.asarray(jax.vmap(own.predict, in_axes=(None, 0, 0))(psi, etas, own.data))
        np.testing.assert_allclose(np.asarray(o.predict_all(psi, etas, s)), fit_own, rtol=1e-13)


def test_predictions_at_substeps_that_are_not_a_positive_integer_are_refused():
    obj = Objective(fleet_problem(2), "focei")
    psi, etas = start_point(obj), obj.start_etas()
    for bad in (0, -4, 2.7):
        with pytest.raises(ValueError, match="substeps must be a positive integer"):
            obj.predict_all(psi, etas, bad)


@pytest.mark.slow  # the reverse-mode programs of a batch and of each unit (8 s)
def test_a_fleet_that_mixes_steady_state_and_plain_doses_is_exact_unit_by_unit():
    """In a batch of units the steady state's loops run for the units that hold one
    and take no step for the others (steady.py): every unit's ℓ and its gradient
    (reverse mode, through both branches) are those of the unit alone, and finite."""
    m = ti.Model(rhs=lambda x, p, u: jnp.stack([-p[0] * x[0] - 0.02 * x[0] ** 2 / (1 + x[0])]),
                 output=lambda x, p: x / p[1], states=["c"], params=["k", "v"],
                 outputs=["cp"])  # fmt: skip
    T, Y = np.array([0.5, 2.0, 6.0, 11.0, 14.0]), np.array([[9.0, 8.0, 6.0, 4.0, 8.5]]).T
    units = [ti.Experiment(T, None, Y * (1 + 0.05 * i), name=f"u{i}",
                           events=Events.doses(0.0, "c", 100.0, ii=12.0, addl=1, ss=i == 0))
             for i in range(2)]  # fmt: skip
    fleet = Objective(ti.Problem(m, units, p0={"k": 0.3, "v": 10.0}, x0=[0.0],
                                 population={"k": 0.3}), "focei")  # fmt: skip
    psi, etas = start_point(fleet), fleet.start_etas() + 0.2

    def ell(e, d):  # ℓ and ∇ℓ (reverse mode) of a unit at η
        return jax.value_and_grad(fleet.ell)(e, psi, d)

    @jax.jit
    def both(etas, data):  # the batch's, and each unit's alone (its own branch taken)
        alone = [ell(etas[i], jax.tree.map(lambda a: a[i], data)) for i in range(2)]  # noqa: B023
        return jax.vmap(ell)(etas, data), alone

    batch, alone = both(etas, fleet.data)
    for i in range(2):
        for a, b in zip(batch, alone[i], strict=True):
            assert np.isfinite(np.asarray(a[i])).all()
            np.testing.assert_allclose(np.asarray(a[i]), np.asarray(b), rtol=1e-12)
