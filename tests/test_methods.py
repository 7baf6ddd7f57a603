"""Methods as objects (fitting/solvers.py, looked up by name in fitting/registry.py),
results built once and immutable, workers returning the same FitResult."""

from __future__ import annotations

import dataclasses
import pickle

import numpy as np
import pytest
from conftest import SILVERBOX_P, silverbox_data, silverbox_model

import tensorid as ti
from tensorid.solve import registry
from tensorid.solve.solvers import Method, Sweep, TrustRegion


@pytest.fixture(scope="module")
def problem():
    data = silverbox_data(P=256, seed=0, x0=(0.0, 0.0))
    p0 = {k: v * 1.1 for k, v in SILVERBOX_P.items()}
    return ti.Problem(silverbox_model(), data, p0=p0, x0=[0.0, 0.0])


class GaussNewtonDiagonal(TrustRegion):
    """The worked example of docs/architecture.md: Gauss-Newton's model with the
    exact Hessian's diagonal in place of its own."""

    name = "gn-diagonal"
    needs_hessian = True
    supports_batch = True
    sweep_kind = Sweep.BOTH

    def scaled(self, state, v):
        H = v.G + np.diag(np.diag(v.H) - np.diag(v.G))
        return state.tr.scaled(state.point, v.J, v.g, H)


def test_the_registry_names_every_method_and_the_markers_say_what_each_can_do():
    assert tuple(registry.REGISTRY) == ti.METHODS
    # the built-ins that march in lock-step (a new method joins by its marker alone)
    assert {"auto", "newton", "gauss-newton"} <= set(ti.fitting.LOCKSTEP)
    assert not {"newton-cg", "fd-bfgs", "fd-lsq"} & set(ti.fitting.LOCKSTEP)
    for name in ti.METHODS:
        m = registry.resolve(name)
        assert isinstance(m, Method) and m.name == name and m.supports_bounds
        assert m.exact_derivatives == (not name.startswith("fd-")) == m.supports_segments
    assert registry.resolve("newton").needs_hessian
    assert not registry.resolve("gauss-newton").needs_hessian
    with pytest.raises(ValueError, match="unknown method 'lbfgs'"):
        registry.resolve("lbfgs")


def test_a_new_method_is_one_class_and_one_registry_line(problem, monkeypatch):
    newton = ti.fit(problem, "newton")
    monkeypatch.setitem(registry.REGISTRY, GaussNewtonDiagonal.name, GaussNewtonDiagonal)
    res = ti.fit(problem, "gn-diagonal")
    assert res.success and res.method == "gn-diagonal"
    assert res.cost == pytest.approx(newton.cost, rel=1e-9)
    # the same class marches in lock-step, and from the object itself
    together = ti.fit_batch(problem, GaussNewtonDiagonal(), [problem.theta0] * 2)
    assert [r.nit for r in together] == [res.nit] * 2
    assert together[0].cost == pytest.approx(res.cost, rel=1e-9)


def test_a_result_is_built_once_and_its_counters_are_a_read_only_mapping(problem):
    res = ti.fit(problem, "gauss-newton")
    with pytest.raises(dataclasses.FrozenInstanceError):
        res.nit = 0
    with pytest.raises(dataclasses.FrozenInstanceError):
        res.stats.nfev = 0
    assert dict(res.stats) == {
        "nit": res.nit,
        "nfev": res.nfev,
        "nhev": 0,
        "nit_total": res.nit,
        "nfev_best": res.nfev,
    }
    assert res.nit == len(res.history) - 1 > 0  # iteration 0 is the start
    later = dataclasses.replace(res, stats=res.stats.then(res.stats))
    assert later.nit == 2 * res.nit and res.nit == later.nit // 2  # res unchanged
    assert later.uncertainty().stderr == pytest.approx(res.uncertainty().stderr)


def test_workers_return_fit_results_without_their_problem(problem):
    from tensorid.fitting.methods import fit_task
    from tensorid.solve.solution import Solution

    thetas = np.stack([problem.theta0, problem.theta0 * 1.05])
    done = fit_task("newton", ti.FitOptions())(problem, thetas)
    # the solver's plain records (fit() makes them FitResults: FitResult.of)
    assert all(isinstance(r, Solution) and r.problem is None for r in done)
    back = pickle.loads(pickle.dumps(done))  # as a pool sends them back
    alone = ti.fit(problem, "newton", theta0=thetas[1])
    assert back[1].status is alone.status and back[1].nit == alone.nit
    assert back[1].attached(problem).cost == pytest.approx(alone.cost, rel=1e-9)
