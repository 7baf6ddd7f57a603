"""The Hessian by second-order adjoints equals the transition tensors' and
jax.hessian's, for every model kind it supports, however the record is cut into
blocks and threads; hessian="auto" picks it where the cost model says it is faster."""

from __future__ import annotations

import cloudpickle
import jax.numpy as jnp
import numpy as np
import pytest
from conftest import autodiff, decay_model, derivative_problems, interpolation_problems

import tensorid as ti
from tensorid.benchmarks import mass_chain_problem, silverbox_problem, two_tank_problem
from tensorid.engine import adjoint


def _close(a, b, tol=1e-9):
    a, b = np.asarray(a), np.asarray(b)
    np.testing.assert_allclose(a, b, rtol=tol, atol=tol * max(np.abs(b).max(), 1e-300))


def _same_as_tensors(prob_adjoint, prob_tensors, theta):
    assert (prob_adjoint.hessian, prob_tensors.hessian) == ("adjoint", "tensors")
    got = prob_adjoint.cost_grad_hess_gn(theta)
    want = prob_tensors.cost_grad_hess_gn(theta)
    for a, b in zip(got, want, strict=True):
        _close(a, b)
    return got


@pytest.mark.slow
def test_the_chain_hessian_equals_tensors_and_jax_hessian():
    """N = 4, K = 5, a record of 101 samples: not a whole number of blocks."""
    prob = mass_chain_problem(2, samples=101, hessian="adjoint")
    theta = prob.theta0 * np.linspace(0.8, 1.2, prob.K)
    J, g, H, _ = _same_as_tensors(
        prob, mass_chain_problem(2, samples=101, hessian="tensors"), theta
    )
    _, g_ad, H_ad = autodiff(prob.jax_cost)(theta)
    _close(H, H_ad)
    _close(g, g_ad)
    # the residual-weighted second-order term is not negligible here
    assert np.abs(H - prob.cost_grad_gn(theta)[2]).max() > 1e-3 * np.abs(H).max()


# conftest's derivative problems and the first interpolation one, built in the test,
# not at collection (2 s at the start of every run, for a slow test)
KINDS = [
    "silverbox", "two-tank fixed x0, zoh", "oscillator multi-output multi-experiment",
    "reactor all x0 free, heun", "decay K=1 N=1 euler", "oscillator, bandlimited input",
]  # fmt: skip


def _pairs(hessian: str) -> list:
    return derivative_problems(hessian=hessian) + interpolation_problems(hessian=hessian)[:1]


@pytest.mark.slow
@pytest.mark.parametrize("case", range(len(KINDS)), ids=KINDS)
def test_every_explicit_problem_kind_gives_the_tensors_hessian(case):
    """Free and fixed x0, zoh, two experiments of different lengths, two outputs with
    a p-dependent output map, weights, heun, euler with K = N = 1, a band-limited
    input (the adjoint's padded grid holds its coefficients past the record)."""
    (name, prob, theta), (_, ref, _) = _pairs("adjoint")[case], _pairs("tensors")[case]
    assert name == KINDS[case]
    _, _, H, _ = _same_as_tensors(prob, ref, theta)
    _close(H, autodiff(prob.jax_cost)(theta)[2])


@pytest.mark.slow
def test_discrete_time_models_and_input_delays():
    from test_delays import first_order
    from test_delays import record as delay_record
    from test_discrete import TRUE, hammerstein
    from test_discrete import record as discrete_record

    data = discrete_record(P=90, noise=0.02)
    probs = [ti.Problem(hammerstein(), data, p0=TRUE, x0=[0.1, -0.2], free_x0=["x1"], hessian=h)
             for h in ("adjoint", "tensors")]  # fmt: skip
    _same_as_tensors(*probs, probs[0].theta0 * 1.1)
    t, u = delay_record(P=100)
    m = first_order({"u": 2.5 * 0.01, "w": 4 * 0.01})
    y = ti.simulate(m, {"k": 2.0, "g": 1.5}, [0.2], ti.Experiment(t, u)).y
    probs = [ti.Problem(m, ti.Experiment(t, u, y + 0.05), p0={"k": 2.3, "g": 1.2}, x0=[0.1],
                        free_x0=["x"], priors={"g": (1.4, 0.2)}, noise=0.05, hessian=h)
             for h in ("adjoint", "tensors")]  # fmt: skip
    _same_as_tensors(*probs, probs[0].theta0)


def test_several_stretches(monkeypatch):
    """Three threads over a 41-sample record: the stretch starts, the padding and the
    threads give the tensors' Hessian."""
    monkeypatch.setattr(adjoint, "threads", lambda cap=None: 3)
    t = np.linspace(0, 2, 41)
    data = ti.Experiment(t, np.sin(3 * t), np.exp(-t) + 0.05 * np.cos(5 * t))
    probs = [ti.Problem(decay_model(), data, p0={"k": 0.7}, x0=[0.9], free_x0=["x"], hessian=h)
             for h in ("adjoint", "tensors")]  # fmt: skip
    _same_as_tensors(*probs, np.array([1.1, 0.6]))


def test_the_problems_threads_cap_the_adjoints_threads(monkeypatch):
    """Problem(threads=1), as each multi-start worker is given: an explicit argument
    down to the adjoint, not an environment variable."""
    real, caps = adjoint.threads, []
    monkeypatch.setattr(adjoint, "threads", lambda cap=None: caps.append(cap) or real(cap))
    t = np.linspace(0, 2, 41)
    data = ti.Experiment(t, np.sin(3 * t), np.exp(-t) + 0.05 * np.cos(5 * t))
    prob = ti.Problem(decay_model(), data, p0={"k": 0.7}, x0=[0.9], free_x0=["x"],
                      hessian="adjoint", threads=1)  # fmt: skip
    prob.cost_grad_hess(np.array([1.1, 0.6]))
    assert caps and set(caps) == {1} and real(1) == 1


def test_a_step_past_the_record_that_is_not_finite_changes_nothing():
    """A draining tank, x' = -k sqrt(x): the record ends at x = 0.01, where one more
    step would go negative. The adjoint never takes that step into a sum."""

    def rhs(x, p, u):
        return -p[0] * jnp.sqrt(x) + 0.0 * u[0]

    model = ti.Model(rhs=rhs, output=lambda x, p: x, states=["x"], params=["k"],
                     inputs=["u"], outputs=["y"], name="tank")  # fmt: skip
    t = np.array([0.0, 0.6, 1.2, 1.8])
    y = ti.simulate(model, {"k": 1.0}, [1.0], ti.Experiment(t, np.zeros(4))).y + 0.01
    data = ti.Experiment(t, np.zeros(4), y)
    probs = [ti.Problem(model, data, p0={"k": 1.0}, x0=[1.0], hessian=h)
             for h in ("adjoint", "tensors")]  # fmt: skip
    J, _, H, _ = _same_as_tensors(*probs, np.array([1.0]))
    assert np.isfinite(J) and np.isfinite(H).all()


@pytest.mark.slow
def test_threads_do_not_change_the_result(monkeypatch):
    prob = mass_chain_problem(2, samples=77, hessian="adjoint")
    theta = prob.theta0 * 1.1
    ref = prob.cost_grad_hess_gn(theta)
    for threads in (1, 3, 2):
        monkeypatch.setattr(adjoint, "threads", lambda cap=None, n=threads: n)
        for a, b in zip(prob.cost_grad_hess_gn(theta), ref, strict=True):
            _close(a, b, 1e-12)


@pytest.mark.slow
@pytest.mark.parametrize("loss", ["huber", "cauchy"])
def test_robust_losses_give_the_tensors_hessian_in_stretches_and_batches(monkeypatch, loss):
    """A robust loss's Gauss-Newton part differs from its curvature part (the squared
    loss's do not), and the adjoint carries both: against the tensors, with stretches
    that do not divide the record evenly, one start and a batch."""
    probs = [
        mass_chain_problem(2, samples=53, loss=loss, hessian=h) for h in ("adjoint", "tensors")
    ]
    theta = probs[0].theta0 * (1 + 0.1 * np.random.default_rng(0).standard_normal(probs[0].K))
    thetas = np.stack([theta, probs[0].theta0, 0.95 * theta])
    for threads in (1, 3):
        monkeypatch.setattr(adjoint, "threads", lambda cap=None, n=threads: n)
        one = [p.cost_grad_hess_gn(theta) for p in probs]
        batch = [p.cost_grad_hess_batch(thetas, both=True) for p in probs]
        for a, b in zip(one[0] + batch[0], one[1] + batch[1], strict=True):
            _close(a, b, 1e-11)


@pytest.mark.slow
def test_a_batch_of_starts_equals_one_start_at_a_time():
    prob = mass_chain_problem(2, samples=60, hessian="adjoint")
    thetas = prob.theta0 * np.array([[1.0], [1.2], [0.7]])
    J, g, H, Hgn = prob.cost_grad_hess_batch(thetas, both=True)
    for i, th in enumerate(thetas):
        for a, b in zip((J[i], g[i], H[i], Hgn[i]), prob.cost_grad_hess_gn(th), strict=True):
            _close(a, b, 1e-12)
    _close(prob.cost_grad_hess_batch(thetas)[2], H, 1e-12)


@pytest.mark.slow  # jax.hessian reference compile; the default run compares with the tensors
def test_a_short_record_and_a_blow_up():
    """A record of 3 samples (one block, mostly padding), free x0, and a simulation
    that overflows: J is inf, as from the tensors, and nothing raises."""
    t = np.array([0.0, 0.1, 0.2])
    data = ti.Experiment(t, np.sin(t), 1.0 + 0.1 * t)
    probs = [ti.Problem(decay_model(), data, p0={"k": 0.5}, x0=[0.9], free_x0=["x"], hessian=h)
             for h in ("adjoint", "tensors")]  # fmt: skip
    theta = np.array([0.8, 0.6])
    _, _, H, _ = _same_as_tensors(*probs, theta)
    _close(H, autodiff(probs[0].jax_cost)(theta)[2])
    J, g, H, _ = probs[0].cost_grad_hess_gn(np.array([0.9, -1e30]))  # x ~ (1e28)^8
    assert J == np.inf


def test_auto_picks_the_tensors_at_paper_sizes_and_the_adjoint_for_large_models():
    assert silverbox_problem().hessian == "tensors"
    assert two_tank_problem().hessian == "tensors"
    # (at 200 samples the chain's adjoint saves less per call than its longer compile:
    # issue 50 item 2; at 2,000, 0.16 s a call)
    assert mass_chain_problem(5, samples=200).hessian == "tensors"
    assert mass_chain_problem(5, samples=2000).hessian == "adjoint"
    # schemes that reverse mode cannot differentiate keep the tensors
    assert mass_chain_problem(5, samples=200, scheme="dopri5").hessian == "tensors"
    assert mass_chain_problem(5, samples=200, scheme="sdirk2").hessian == "tensors"
    with pytest.raises(ValueError, match="hessian='adjoint' needs an explicit"):
        mass_chain_problem(2, samples=50, scheme="sdirk2", hessian="adjoint")
    with pytest.raises(ValueError, match="hessian must be one of"):
        mass_chain_problem(2, samples=50, hessian="reverse")
    # the model's prediction grows with K and N, the adjoint's more slowly
    t = [adjoint.predicted_seconds(n, n + 1, 1000, 2) for n in (2, 8, 32)]
    ratios = [p["tensors"] / p["adjoint"] for p in t]
    assert ratios == sorted(ratios) and ratios[0] < 1 < ratios[-1]


def test_auto_weighs_the_adjoints_longer_compile_as_the_docs_say():
    """Issue 50 item 2: the picks that README.md and docs/benchmarks.md state."""
    from pathlib import Path

    from tensorid.engine.sweeping.adjoint import adjoint_pays

    def pays(N, K, P):
        return adjoint_pays(adjoint.predicted_seconds(N, K, P, 2))

    crossover = [next(K for K in range(1, 100) if pays(N, K, 1024)) for N in (2, 4, 8)]
    assert crossover == [29, 20, 14]
    readme = " ".join((Path(__file__).resolve().parents[1] / "README.md").read_text().split())
    assert "the adjoint from about K = 29 at N = 2, K = 20 at N = 4 and K = 14 at N = 8" in readme
    adjoint_rows = [(10, 11, 2000), (16, 17, 400), (32, 33, 400), (64, 65, 400)]
    tensor_rows = [(2, 10, 1024), (2, 16, 1024), (4, 5, 2000), (6, 7, 2000), (8, 5, 1024),
                   (32, 5, 1024), (2, 5, 1024), (2, 4, 501)]  # fmt: skip
    assert all(pays(*r) for r in adjoint_rows) and not any(pays(*r) for r in tensor_rows)


def test_a_problem_pickles_after_its_adjoint_ran():
    t = np.linspace(0, 3, 40)
    data = ti.Experiment(t, np.sin(t), np.cos(t))
    prob = ti.Problem(decay_model(), data, p0={"k": 1.0}, x0=[1.0], hessian="adjoint")
    H = prob.cost_grad_hess(prob.theta0)[2]
    again = cloudpickle.loads(cloudpickle.dumps(prob))  # as to a Dask worker
    assert again.hessian == "adjoint"
    _close(again.cost_grad_hess(prob.theta0)[2], H, 1e-12)


@pytest.mark.slow
def test_newton_fits_by_either_hessian_agree():
    fits = [
        ti.fit(mass_chain_problem(2, samples=300, p0=None, hessian=h), method="newton")
        for h in ("adjoint", "tensors")
    ]
    assert all(f.success for f in fits)
    _close(fits[0].theta, fits[1].theta, 1e-8)
    assert fits[0].nit == fits[1].nit
