"""docs/architecture.md's recipes, worked through for real: a dummy of each kind of
plug-in (a loss, a predictor, a fitting method, a scheme, a Hessian path) is written
here, registered by name (and passed as an object), and its exact derivatives are
checked against jax.hessian; the command line's choices (tensorid/names.py, no JAX)
are the registries' names; and `compare`'s reading of a fit.json goes through the
fit's predictor object, never silently by simulation. Each dummy touches this file
only: the count of files each recipe names."""

from __future__ import annotations

from typing import ClassVar

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from conftest import autodiff, oscillator_model

import tensorid as ti
from tensorid import names
from tensorid.engine import hessians, integrators, losses, predictors
from tensorid.engine.schemes.integrators import ExplicitRungeKutta
from tensorid.fitting.methods import FLEET_METHODS
from tensorid.solve import registry
from tensorid.solve.solvers import Sweep, TrustRegion

TRUE = {"k": 2.0, "c": 0.3, "g": 1.0, "q": 0.7}


def _problem(**kw):
    """Two outputs, 40 samples, one free initial state, three free parameters."""
    m = oscillator_model()
    t = np.arange(40) * 0.05
    u = np.stack([np.sin(1.3 * t), 0.5 * np.cos(0.7 * t)], axis=1)
    y = ti.simulate(m, TRUE, [0.3, -0.2], ti.Experiment(t, u)).y
    y = y + 0.02 * np.random.default_rng(0).standard_normal(y.shape)
    y[::9] += 0.5  # a few outliers, so that a robust loss's tails are reached
    p0 = {k: 1.1 * v for k, v in TRUE.items()}
    e = ti.Experiment(t, u, y)
    return ti.Problem(m, e, p0=p0, x0=[0.3, -0.2], free_x0=["om"], fixed=["g"], **kw)


def _against_jax(prob, rtol=1e-8):
    """J, ∇J, ∇²J of the Problem's own path against jax.grad/jax.hessian of J(θ)."""
    th = prob.theta0
    J, g, H = prob.cost_grad_hess(th)
    J_ad, g_ad, H_ad = autodiff(prob.jax_cost)(th)
    np.testing.assert_allclose(J, J_ad, rtol=1e-12)
    np.testing.assert_allclose(g, g_ad, rtol=rtol, atol=1e-10 * abs(J))
    np.testing.assert_allclose(H, H_ad, rtol=rtol, atol=1e-9 * abs(J))
    return J, g, H


# -- a loss: one class ------------------------------------------------------------------


@losses.register_loss
class Welsch(losses.Loss):
    """ρ(z) = 1 − exp(−z²) (a redescending loss: ρ ≈ z² near 0)."""

    name: ClassVar[str] = "welsch"
    squared: ClassVar[bool] = False
    robust: ClassVar[bool] = True
    tuning: ClassVar[float] = 2.985

    def rho(self, z):
        return 1.0 - jnp.exp(-z * z)

    def _dpsi(self, z):  # (ρ', ρ'', ρ'/z)
        e = jnp.exp(-z * z)
        return 2.0 * z * e, 2.0 * e * (1.0 - 2.0 * z * z), 2.0 * e


losses.REGISTRY.pop("welsch")  # registered where a test asks for it (below)


@pytest.fixture
def welsch(monkeypatch):
    monkeypatch.setitem(losses.REGISTRY, "welsch", Welsch)


@pytest.mark.parametrize("hessian", ["tensors", "adjoint"])
def test_a_loss_is_one_class(welsch, hessian):
    prob = _problem(loss="welsch", loss_scale=0.05, hessian=hessian)
    assert isinstance(prob.loss, Welsch) and prob.hessian == hessian
    _, _, H = _against_jax(prob)
    # the plainly written loss, differentiated by JAX: the class's ρ is what is summed
    sw, th = prob._sweeps, prob.theta0
    (t, u, _), c = prob._arrays[0], 0.05 * np.sqrt(prob.weights)
    y = prob.experiments[0].y  # the measurements (the sweeps' y carries a mask)

    def plain(theta):
        x0, p = sw.expand(theta, jnp.asarray(prob.x0[0]), jnp.asarray(prob.p0))
        ys = sw._simulate(x0, p, t, u)[1]
        e = jnp.sqrt(prob.weights) * (y - ys)
        return jnp.sum(c**2 * (1.0 - jnp.exp(-((e / c) ** 2))))

    np.testing.assert_allclose(H, autodiff(plain)(th)[2], rtol=1e-8)
    # by object as well as by name, and an estimated scale uses its tuning constant
    assert _problem(loss=Welsch()).loss_scale["y1"] > 0
    with pytest.raises(ValueError, match="loss must be one of .*'welsch'"):
        _problem(loss="welsh")


def test_a_loss_name_no_registry_knows_is_refused_not_taken_for_another():
    with pytest.raises(ValueError, match="loss must be one of"):
        _problem(loss="welsch")  # not registered here
    assert losses.Loss("huber") == losses.Huber()  # the spelling from before the classes


# -- a predictor: one class ---------------------------------------------------------------


@predictors.register_predictor
class Observer(predictors.OutputError):
    """A fixed-gain observer: output error whose state is nudged towards each sample,
    x ← x + L (y − ŷ) on the first state (a filter without a noise model)."""

    name: ClassVar[str] = "observer"
    supports_segments: ClassVar[bool] = False
    supports_fleet: ClassVar[bool] = False
    supports_adjoint: ClassVar[bool] = False

    def update(self, model, z, p, y):
        return z.at[0].add(0.3 * (y[0] - model.h(z, p)[0]))


predictors.REGISTRY.pop("observer")


@pytest.fixture
def observer(monkeypatch):
    monkeypatch.setitem(predictors.REGISTRY, "observer", Observer)


def test_a_predictor_is_one_class(observer):
    prob = _problem(predictor="observer", loss="huber", loss_scale=0.05)
    assert isinstance(prob.predictor, Observer) and prob.predictor.filters
    assert prob.hessian == "tensors"  # "auto": the adjoint does not read a predictor
    _against_jax(prob)
    # its state is corrected: one step ahead is not the simulation
    one = prob.predict(prob.theta0)[0].predicted
    assert not np.allclose(one, prob.simulate(prob.theta0)[0].y)
    # what it does not support, its markers refuse (one line, before any work)
    with pytest.raises(ValueError, match="predictor='observer' cannot take segments=2"):
        _problem(predictor=Observer(), segments=2)
    with pytest.raises(ValueError, match="predictor='observer' cannot take hessian='adjoint'"):
        _problem(predictor="observer", hessian="adjoint")
    with pytest.raises(ValueError, match="process_noise is for"):
        _problem(predictor="observer", process_noise={"th": 0.1})


def test_compare_reads_a_fit_of_a_new_predictor_through_its_object(observer):
    """tensorid compare/simulate on a fit.json: the predictor comes from the
    registry by the name fit.json records, and predicts k samples ahead with it; a
    name no registry knows is one line (it fell through to plain simulation)."""
    from tensorid.analysis.validation import score_record
    from tensorid.app.files import ModelSpec
    from tensorid.app.filter_fits import filter_of

    prob = _problem(predictor="observer")
    spec = ModelSpec(model=prob.model, path="model.py")
    fitted = {"predictor": "observer", "loss": "squared", "params": dict(TRUE)}
    e = prob.experiments[0]
    spec2, pair = filter_of(spec, fitted, e)
    assert pair is not None and isinstance(pair[1], Observer)
    x0 = prob.x0[0]
    ahead = score_record(spec2.model, TRUE, x0, [], e, prob.discretisation, horizon=2,
                         predictor=pair)  # fmt: skip
    sim = score_record(spec2.model, TRUE, x0, [], e, prob.discretisation)
    assert ahead.horizon == 2 and not np.allclose(ahead.simulation.y, sim.simulation.y)
    assert filter_of(spec, {**fitted, "predictor": "simulation"}, e)[1] is None
    with pytest.raises(ValueError, match="predictor must be one of .*got 'ukf'"):
        filter_of(spec, {**fitted, "predictor": "ukf"}, e)


def test_the_old_name_of_output_error_still_works_and_says_so():
    with pytest.warns(DeprecationWarning, match="OutputError"):
        assert predictors.Simulation is predictors.OutputError


# -- a fitting method: one class ----------------------------------------------------------


class GaussNewtonDiagonal(TrustRegion):
    """Gauss-Newton's model with the exact Hessian's diagonal in place of its own."""

    name = "gn-diagonal"
    needs_hessian = True
    supports_batch = True
    sweep_kind = Sweep.BOTH

    def scaled(self, state, v):
        H = v.G + np.diag(np.diag(v.H) - np.diag(v.G))
        return state.tr.scaled(state.point, v.J, v.g, H)


def test_a_method_is_one_class(monkeypatch):
    prob = _problem()
    monkeypatch.setitem(registry.REGISTRY, "gn-diagonal", GaussNewtonDiagonal)
    res = ti.fit(prob, "gn-diagonal")
    newton = ti.fit(prob, "newton")
    assert res.success and res.method == "gn-diagonal"
    assert res.cost == pytest.approx(newton.cost, rel=1e-9)
    _, g, H = prob.cost_grad_hess(res.theta)  # the end: a minimum by the exact Hessian
    np.testing.assert_allclose(H, autodiff(prob.jax_cost)(res.theta)[2], rtol=1e-8)
    assert np.all(np.linalg.eigvalsh(H) > 0)
    together = ti.fit_batch(prob, GaussNewtonDiagonal(), [prob.theta0] * 2)
    assert [r.nit for r in together] == [res.nit] * 2


# -- a scheme: one object ---------------------------------------------------------------

RALSTON = ExplicitRungeKutta("ralston", ((), (2 / 3,)), (1 / 4, 3 / 4), (0.0, 2 / 3), 2)


@pytest.mark.parametrize("hessian", ["tensors", "adjoint"])
def test_a_scheme_is_one_object(monkeypatch, hessian):
    monkeypatch.setitem(integrators.SCHEMES, "ralston", RALSTON)
    prob = _problem(scheme="ralston", hessian=hessian)
    assert prob.scheme is RALSTON and prob.hessian == hessian
    _against_jax(prob)


# -- a Hessian path: one class ------------------------------------------------------------


class ReverseMode(hessians.HessianPath):
    """∇²J by jax.hessian of the compiled cost (reverse over forward mode through
    the whole march): a path that knows nothing of the tensors or the adjoint."""

    name: ClassVar[str] = "reverse-mode"
    supports_predictors: ClassVar[bool] = True

    def sweep(self, sweeps, batched: bool, threads_cap):
        def one(theta, x0, p, t, u, y, w):
            J = sweeps._cost(theta, x0, p, t, u, y, w)
            g = jax.grad(sweeps._cost)(theta, x0, p, t, u, y, w)
            H = jax.hessian(sweeps._cost)(theta, x0, p, t, u, y, w)
            return J, g, H, H  # no Gauss-Newton part of its own: the exact Hessian

        f = jax.vmap(one, in_axes=(0,) + (None,) * 6) if batched else one
        return jax.jit(f), "JgHH"


def test_a_hessian_path_is_one_class(monkeypatch):
    monkeypatch.setitem(hessians.REGISTRY, "reverse-mode", ReverseMode)
    prob = _problem(loss="huber", loss_scale=0.05, hessian="reverse-mode")
    assert isinstance(prob.hessian_path, ReverseMode) and prob.hessian == "reverse-mode"
    J, g, H = prob.cost_grad_hess(prob.theta0)
    tensors = _problem(loss="huber", loss_scale=0.05, hessian="tensors")
    Jt, gt, Ht = tensors.cost_grad_hess(tensors.theta0)
    assert J == pytest.approx(Jt, rel=1e-13)
    np.testing.assert_allclose(g, gt, rtol=1e-9, atol=1e-12 * abs(J))
    np.testing.assert_allclose(H, Ht, rtol=1e-8, atol=1e-10 * abs(J))
    # its sweep is made once per Sweeps (its own jax.jit is not traced again per call)
    made = prob.hessian_path.made(prob._sweeps, False, prob.threads)
    assert made is prob.hessian_path.made(prob._sweeps, False, prob.threads)
    # by object too, and a fit steps by it
    assert ti.fit(_problem(hessian=ReverseMode()), "newton", maxiter=3).nit == 3


# -- the command line's names -------------------------------------------------------------


def test_the_command_lines_names_are_the_registries():
    """tensorid/names.py spells the CLI's choices out so that the parser imports no
    JAX; they must be the registries' built-in names, in their order."""
    assert names.LOSSES == tuple(losses.REGISTRY) == losses.LOSSES
    assert names.PREDICTORS == tuple(predictors.REGISTRY) == predictors.PREDICTORS
    assert names.HESSIANS == tuple(hessians.REGISTRY) == hessians.HESSIANS
    assert names.METHODS == tuple(registry.REGISTRY) == ti.METHODS
    assert names.FLEET_METHODS == FLEET_METHODS
    assert names.SCHEMES == tuple(integrators.SCHEMES)
    from tensorid.population.errors import ERROR_MODELS

    assert names.RESIDUAL_ERRORS == tuple(ERROR_MODELS)


def test_the_names_module_imports_nothing():
    import ast
    from pathlib import Path

    tree = ast.parse(Path(names.__file__).read_text())
    assert not [n for n in ast.walk(tree) if isinstance(n, ast.Import | ast.ImportFrom)]
