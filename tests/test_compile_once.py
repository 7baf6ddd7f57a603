"""Compiled sweeps are shared by every Problem with the same model, θ layout and
discretisation, and a fit reports the time JAX spent compiling."""

from __future__ import annotations

import cloudpickle
from conftest import SILVERBOX_P, silverbox_data, silverbox_model

import tensorid as ti


def _problem(model, data, **kw):
    p0 = {k: 1.05 * v for k, v in SILVERBOX_P.items()}
    return ti.Problem(model, data, p0=p0, x0=[0.0, 0.0], **kw)


def test_a_second_problem_of_the_same_structure_compiles_nothing():
    model, data = silverbox_model(), silverbox_data(P=256, seed=7)
    first = ti.fit(_problem(model, data, substeps=3))
    second_problem = _problem(model, data, substeps=3, bounds={"m": (1e-7, 1e-3)})
    second = ti.fit(second_problem)
    assert first.compile_seconds > 0.05
    assert second.compile_seconds < 0.05 * first.compile_seconds
    assert second.params == first.params and second.nit == first.nit


def test_another_layout_or_discretisation_gets_its_own_sweeps():
    model, data = silverbox_model(), silverbox_data(P=64, seed=8)
    a = _problem(model, data)
    assert _problem(model, data)._sweeps is a._sweeps
    assert _problem(model, data, fixed=["a"])._sweeps is not a._sweeps
    assert _problem(model, data, scheme="heun")._sweeps is not a._sweeps
    assert _problem(silverbox_model(), data)._sweeps is not a._sweeps  # another model


def test_every_layout_of_a_model_shares_one_simulation_program():
    """A simulation depends on the model and the discretisation only: a fit's problem,
    its validation's initial-state problem and a plain simulation run one program
    (a command-line fit read it three times), while another discretisation has its own."""
    from tensorid.engine.assembly.simulate import run_simulation

    model, data = silverbox_model(), silverbox_data(P=64, seed=10)
    a = _problem(model, data)._sweeps
    b = _problem(model, data, fixed=list(SILVERBOX_P), free_x0=list(model.states))._sweeps
    assert a is not b and a.simulate is b.simulate
    p = model.params_array(SILVERBOX_P)
    first = run_simulation(a, data, [0.0, 0.0], p)
    with ti.engine.compilation.compile_clock() as again:
        second = run_simulation(b, data, [0.0, 0.0], p)
    assert again[0] == 0.0 and (first.y == second.y).all()
    assert _problem(model, data, scheme="heun")._sweeps.simulate is not a.simulate


def test_repeated_simulations_compile_once_and_problems_still_travel_to_workers():
    model, data = silverbox_model(), silverbox_data(P=64, seed=9)
    with ti.engine.compilation.compile_clock() as first:
        ti.simulate(model, SILVERBOX_P, [0.0, 0.0], data)
    with ti.engine.compilation.compile_clock() as again:
        ti.simulate(model, SILVERBOX_P, [0.01, 0.0], data)
    assert first[0] > 0 and again[0] == 0.0
    prob = _problem(model, data)
    copy = cloudpickle.loads(cloudpickle.dumps(prob))
    assert copy.cost(copy.theta0) == prob.cost(prob.theta0)


def test_fit_json_reports_compile_time():
    from tensorid.app.reports import fit_json

    model, data = silverbox_model(), silverbox_data(P=64, seed=10)
    d = fit_json(ti.fit(_problem(model, data), maxiter=2), [])
    assert 0.0 < d["compile_seconds"] <= d["seconds"]  # a new model: its sweeps compile


def test_a_model_that_is_gone_takes_its_compiled_sweeps_with_it():
    import gc
    import weakref

    model, data = silverbox_model(), silverbox_data(P=32, seed=11)
    prob = _problem(model, data)
    prob.cost(prob.theta0)
    gone = weakref.ref(model)
    assert model.compiled_sweeps
    del model, prob
    gc.collect()
    assert gone() is None


def test_the_suite_compiles_into_the_folder_conftest_names():
    # conftest names a temporary folder before tensorid is imported; imported first,
    # tensorid would already have put the cache in the home folder
    import os

    import jax

    folder = jax.config.values.get("jax_compilation_cache_dir")
    assert folder == os.environ["TENSORID_CACHE_DIR"]


def test_a_fits_first_order_step_and_the_scores_share_one_program(monkeypatch):
    """The first-order sweep keeps each sample's share of ∇J: a fit's Gauss-Newton
    step and the error bars' scores run one program, whose scores sum to ∇J; a record
    long enough that keeping them would cost every step gets the program without
    them, with the same numbers."""
    import numpy as np

    from tensorid.analysis.sandwich import scores
    from tensorid.engine import sweeps as sweeps_module

    pr = _problem(silverbox_model(), silverbox_data(P=128, seed=9), free_x0=["y"])
    theta = pr.theta0 * 1.01
    J, g, H = pr.cost_grad_gn(theta)
    (s,) = scores(pr, theta)
    np.testing.assert_allclose(s.sum(axis=0), g, rtol=1e-12, atol=1e-12 * np.abs(g).max())
    sw = pr._sweeps
    assert len(sw.first_order._runs) == 1 and "first_order_only" not in vars(sw)
    monkeypatch.setattr(sweeps_module, "SCORES_KEPT_UP_TO", 0)
    for a, b in zip(pr.cost_grad_gn(theta), (J, g, H), strict=True):
        assert np.array_equal(a, b)
    assert len(sw.first_order_only._runs) == 1
