"""Multiple shooting: the lifted problem's derivatives against autodiff of the
discretised Lagrangian, exact recovery, bounds, the user's θ layout, bad requests."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from conftest import autodiff
from test_sensitivity import PROBLEMS

import tensorid as ti
from tensorid.benchmarks import LOTKA_VOLTERRA_TRUE as LV_TRUE
from tensorid.benchmarks import lotka_volterra_model as lotka_volterra


def segmented(prob: ti.Problem, segments, **kw) -> ti.Problem:
    """The same problem cut into segments."""
    args = dict(
        p0=prob.p0,
        x0=prob.x0,
        free_x0=prob.free_x0,
        fixed=prob.fixed,
        weights=prob.weights,
        discretisation=prob.discretisation,
        segments=segments,
    )
    args.update(kw)
    return ti.Problem(prob.model, prob.experiments, **args)


def lv_data(P=301, T=30.0, noise=0.0, seed=1):
    t = np.linspace(0, T, P)
    sim = ti.simulate(lotka_volterra(), LV_TRUE, [2.0, 1.0], ti.Experiment(t, np.zeros((P, 0))))
    y = sim.y * (1 + noise * np.random.default_rng(seed).standard_normal(sim.y.shape))
    return ti.Experiment(t, np.zeros((P, 0)), y)


def _check_lagrangian(sh, z, rtol=1e-9, forward=False):
    """``forward``: forward-over-forward autodiff for the reference (the while loops of
    adaptive steps and implicit stages have no reverse mode)."""
    lam = np.random.default_rng(0).normal(size=len(sh.defect_rows) * sh.N)
    L = sh.evaluate(z)
    g, H = L.g + L.A.T @ lam, L.H + sh.curvature(L, lam)

    def lagrangian(zz):
        J, c = sh.jax_pieces(zz)
        return J + c @ lam

    zj = jnp.asarray(z)
    J_ref, c_ref = sh.jax_pieces(zj)
    if forward:
        g_ref = np.asarray(jax.jacfwd(lagrangian)(zj))
        H_ref = np.asarray(jax.jacfwd(jax.jacfwd(lagrangian))(zj))
    else:
        _, g_ref, H_ref = autodiff(lagrangian)(zj)
    A_ref = np.asarray(jax.jacfwd(lambda zz: sh.jax_pieces(zz)[1])(zj))
    assert L.J == pytest.approx(float(J_ref), rel=1e-12)
    np.testing.assert_allclose(L.c, c_ref, atol=1e-12 * (1 + np.abs(c_ref).max()))
    np.testing.assert_allclose(L.A, A_ref, atol=rtol * np.abs(A_ref).max())
    np.testing.assert_allclose(g, g_ref, atol=rtol * np.abs(g_ref).max())
    np.testing.assert_allclose(H, H_ref, atol=rtol * np.abs(H_ref).max())
    # the Gauss-Newton variant: same cost, gradient and constraints
    gn = sh.evaluate(z, exact=False)
    np.testing.assert_allclose(gn.g, L.g, rtol=1e-12, atol=1e-14 * np.abs(L.g).max())
    # two compiled programs integrate the same states: equal to rounding, not to the
    # bit (XLA fuses each loop its own way once it compiles it as one function)
    np.testing.assert_allclose(gn.c, L.c, rtol=1e-13, atol=1e-14 * np.abs(L.c).max())


# the autodiff reference compiles every segment unrolled (8-40 s a model): all of them
# in the slow run (the default run keeps under five minutes)
QUICK: tuple[str, ...] = ()
CASES = [p if p[0] in QUICK else pytest.param(*p, marks=pytest.mark.slow) for p in PROBLEMS]


@pytest.mark.parametrize("name, prob, theta", CASES, ids=[p[0] for p in PROBLEMS])
def test_lagrangian_gradient_and_hessian_equal_autodiff(name, prob, theta):
    """∇L and ∇²L of L = J + λᵀc from the segments' transition tensors equal
    jax.grad/jax.hessian of the discretised Lagrangian (plain simulations), on every
    model of the sensitivity tests (several experiments, fixed parameters, fixed and
    free x0, weights, schemes)."""
    sh = segmented(prob, 3).shooting
    z = sh.start(theta)
    z = z * (1 + 0.02 * np.random.default_rng(1).standard_normal(z.size))  # open the gaps
    _check_lagrangian(sh, z)


@pytest.mark.slow
@pytest.mark.parametrize("scheme", ["dopri5", "sdirk3"])
def test_lagrangian_is_exact_with_adaptive_and_implicit_schemes(scheme):
    data = lv_data(P=61, T=12.0, noise=0.02)
    prob = ti.Problem(
        lotka_volterra(), data, p0=LV_TRUE, x0=[2.0, 1.0], free_x0=["pred"], scheme=scheme
    )
    sh = segmented(prob, 4).shooting
    _check_lagrangian(sh, sh.start(prob.theta0 * 1.1), forward=True)


@pytest.mark.slow  # compile-bound; keeps the default run under five minutes
def test_noise_free_record_is_recovered_exactly_from_a_far_start():
    data = lv_data(P=201, T=40.0)
    prob = ti.Problem(
        lotka_volterra(),
        data,
        p0={"a": 1.5, "b": 0.3, "c": 0.6, "d": 0.45},
        x0=[1.0, 2.0],
        free_x0=["prey", "pred"],
        segments=8,
    )
    for method in ("newton", "gauss-newton"):
        res = ti.fit(prob, method)
        assert res.success, res.message
        assert res.shooting["max_defect"] <= 1e-8
        assert res.shooting["polished"]
        for k, v in LV_TRUE.items():
            assert res.params[k] == pytest.approx(v, rel=1e-7)
        np.testing.assert_allclose(res.x0, [2.0, 1.0], rtol=1e-7)
        # the user's layout: the result is the single-shooting problem's
        assert res.theta.shape == (prob.K,) and res.cost == pytest.approx(prob.cost(res.theta))


@pytest.mark.slow  # compile-bound; keeps the default run under five minutes
def test_without_polish_the_segments_solution_is_one_continuous_trajectory():
    data = lv_data(P=201, T=30.0, noise=0.05)
    prob = ti.Problem(
        lotka_volterra(),
        data,
        p0={"a": 1.3, "b": 0.6, "c": 0.8, "d": 0.25},
        x0=[2.0, 1.0],
        free_x0=["prey", "pred"],
        segments=5,
    )
    res = ti.fit(prob, options=ti.FitOptions(polish=False))
    polished = ti.fit(prob)
    assert res.success and not res.shooting["polished"]
    assert res.shooting["max_defect"] <= 1e-8
    # the segments' cost is the single-shooting cost of (params, x0) up to the defects
    assert res.shooting["cost"] == pytest.approx(res.cost, rel=1e-6)
    assert res.cost == pytest.approx(polished.cost, rel=1e-8)
    np.testing.assert_allclose(res.theta, polished.theta, rtol=1e-5)


@pytest.mark.slow  # compile-bound; keeps the default run under five minutes
def test_an_active_bound_at_the_solution_converges():
    data = lv_data(P=201, T=30.0, noise=0.02)
    prob = ti.Problem(
        lotka_volterra(),
        data,
        p0={"a": 0.8, "b": 0.5, "c": 1.0, "d": 0.3},
        x0=[2.0, 1.0],
        bounds={"a": (0.5, 0.9)},
        segments=6,
    )
    res = ti.fit(prob)
    assert res.success, res.message
    assert res.params["a"] == pytest.approx(0.9, abs=1e-12)
    assert res.shooting["max_defect"] <= 1e-8
    single = ti.fit(
        ti.Problem(prob.model, data, p0=res.params, x0=[2.0, 1.0], bounds={"a": (0.5, 0.9)})
    )
    assert res.cost == pytest.approx(single.cost, rel=1e-9)


@pytest.mark.slow  # compile-bound; keeps the default run under five minutes
def test_segments_per_experiment_and_by_length():
    data = [lv_data(P=121, T=20.0, noise=0.02, seed=s) for s in (1, 2)]
    prob = ti.Problem(lotka_volterra(), data, p0=LV_TRUE, x0=[2.0, 1.0], segments=[3, 1])
    assert prob.segments == [3, 1] and prob.shooting.segments == 4
    by_length = ti.Problem(lotka_volterra(), data, p0=LV_TRUE, x0=[2.0, 1.0], segment_length=41)
    assert by_length.segments == [3, 3]
    assert (
        ti.Problem(lotka_volterra(), data, p0=LV_TRUE, x0=[2.0, 1.0], segments=1).shooting is None
    )
    res = ti.fit(prob, "gauss-newton")
    assert res.success and res.shooting["segments"] == [3, 1]


def test_segment_states_start_from_the_data_where_an_output_measures_them():
    data = lv_data(P=101, T=20.0, noise=0.0)
    prob = ti.Problem(
        lotka_volterra(), data, p0=LV_TRUE, x0=[5.0, 5.0], free_x0=["prey"], segments=4
    )
    sh = prob.shooting
    assert sh.measured_states() == {0: 0, 1: 1}
    z = sh.start(prob.theta0)
    k = sh.bounds[0]
    assert z[sh.state_slice(0, 0)] == pytest.approx(data.y[0, :1])  # free prey from the data
    for i in range(1, 4):
        np.testing.assert_allclose(z[sh.state_slice(0, i)], data.y[k[i]])


@pytest.mark.parametrize(
    "kwargs, message",
    [
        (dict(segments=0), "positive integers"),
        (dict(segments=[2]), "2 experiments"),
        (dict(segments=100), "at most 60"),
        (dict(segments=2, segment_length=10), "not both"),
        (dict(segment_length=2), "at least 3"),
    ],
)
def test_bad_segment_requests_are_one_clear_line(kwargs, message):
    data = [lv_data(P=121, T=20.0), lv_data(P=121, T=20.0, seed=2)]
    with pytest.raises(ValueError, match=message):
        ti.Problem(lotka_volterra(), data, p0=LV_TRUE, x0=[2.0, 1.0], **kwargs)


def test_finite_difference_baselines_refuse_segments():
    prob = ti.Problem(lotka_volterra(), lv_data(), p0=LV_TRUE, x0=[2.0, 1.0], segments=3)
    with pytest.raises(ValueError, match="single shooting only"):
        ti.fit(prob, "fd-lsq")


@pytest.mark.slow
def test_multiple_shooting_escapes_the_local_minima_of_single_shooting():
    """The issue's case: 9 periods, 5 % noise, starts within ±50 %: single shooting
    reaches the best cost from about a third of them, multiple shooting from all."""
    from tensorid.solve.multistart import draw_starts

    data = lv_data(P=601, T=60.0, noise=0.05)
    kw = dict(p0=LV_TRUE, x0=[2.0, 1.0], free_x0=["prey", "pred"])
    kw["bounds"] = {k: (1e-3, None) for k in LV_TRUE}
    single = ti.Problem(lotka_volterra(), data, **kw)
    multiple = ti.Problem(lotka_volterra(), data, segments=10, **kw)
    starts = draw_starts(
        single.theta0, single.lower, single.upper, 21, spread=0.5, sampling="uniform", seed=3
    )[1:]
    c1 = np.array([ti.fit(single, theta0=s).cost for s in starts])
    cm = np.array([ti.fit(multiple, theta0=s).cost for s in starts])
    best = min(c1.min(), cm.min())
    assert (cm <= best * (1 + 1e-6)).mean() >= 0.95
    assert (c1 <= best * (1 + 1e-6)).mean() <= 0.6


def test_multistart_with_segments_keeps_the_shooting_report():
    from tensorid.benchmarks import lotka_volterra_problem

    prob = lotka_volterra_problem(samples=201, segments=4)
    res = ti.fit(prob, "gauss-newton", starts=3, workers=1, spread=0.3, batch=3)
    assert res.success and len(res.starts) == 3
    assert res.shooting["segments"] == [4] and res.shooting["max_defect"] <= 1e-8
    assert all(s["shooting"]["segments"] == [4] for s in res.starts)


@pytest.mark.slow  # 8 s
def test_cli_fit_with_segments_records_them(tmp_path):
    import json

    from tensorid.cli import main

    data = lv_data(P=151, T=25.0, noise=0.02)
    csv = tmp_path / "lv.csv"
    np.savetxt(csv, np.column_stack([data.t, data.y]), delimiter=",", header="t,prey,pred",
               comments="")  # fmt: skip
    model = tmp_path / "lv.py"
    model.write_text(
        'states = ["prey", "pred"]\nparams = ["a", "b", "c", "d"]\n'
        'rhs = {"prey": "a*prey - b*prey*pred", "pred": "-c*pred + d*prey*pred"}\n'
        'p0 = {"a": 1.3, "b": 0.4, "c": 0.8, "d": 0.35}\nx0 = {"prey": 2.0, "pred": 1.0}\n'
        'free_x0 = ["prey", "pred"]\n'
    )
    out = tmp_path / "out"
    args = ["fit", str(model), str(csv), "--segments", "5", "--out", str(out), "--no-progress"]
    assert main(args) == 0
    d = json.loads((out / "fit.json").read_text())
    assert d["segments"] == [5] and d["shooting"]["polished"] and d["success"]
    assert d["shooting"]["max_defect"] <= 1e-8
    assert d["params"]["a"] == pytest.approx(1.0, rel=0.05)


def _arrow(rng, S, N, P, shift):
    """A random symmetric block-arrow matrix: S overlapping 2N-blocks, a dense border."""
    nb = S * N
    H = np.zeros((nb + P, nb + P))
    for i in range(S):
        blk = rng.normal(size=(2 * N, 2 * N))
        j = slice(i * N, min((i + 2) * N, nb))
        m = j.stop - j.start
        H[j, j] += (blk @ blk.T)[:m, :m]
    C = rng.normal(size=(nb, P))
    H[:nb, nb:], H[nb:, :nb] = C, C.T
    D = rng.normal(size=(P, P))
    H[nb:, nb:] = D @ D.T
    return H + shift * np.eye(nb + P), nb


@pytest.mark.parametrize("shift", [5.0, 0.0, -2.0])
@pytest.mark.parametrize("radius", [0.01, 1.0, 100.0])
def test_the_block_arrow_subproblem_solver_matches_the_dense_one(shift, radius):
    """Positive definite, semidefinite-ish and indefinite Hessians; interior and
    boundary solutions; some variables held on bounds: the model value of the
    structured solver's step equals the dense solver's to 1e-6."""
    from tensorid.solve.arrow import ArrowSolver
    from tensorid.solve.trust_region import solve_subproblem

    rng = np.random.default_rng(int(100 * (shift + 3) + radius))
    H, nb = _arrow(rng, 60, 3, 4, shift)
    g = rng.normal(size=H.shape[0])
    for free in (np.ones(g.size, bool), rng.uniform(size=g.size) > 0.1):
        Hf, gf = H[np.ix_(free, free)], g[free]
        solver = ArrowSolver(nb)
        s, _ = solver(gf, Hf, radius, free)
        ref, _ = solve_subproblem(gf, Hf, radius)
        assert np.linalg.norm(s) <= radius * (1 + 1e-9)

        def model(d, gf=gf, Hf=Hf):
            return gf @ d + 0.5 * d @ Hf @ d

        assert model(s) <= model(ref) + 1e-6 * abs(model(ref))
        assert solver.fallbacks == 0


@pytest.mark.slow  # compile-bound; keeps the default run under five minutes
def test_many_segments_use_the_block_arrow_solver_and_agree_with_the_dense_one(monkeypatch):
    from tensorid.benchmarks import lotka_volterra_problem
    from tensorid.solve import shooting

    prob = lotka_volterra_problem(samples=301, segments=60)
    assert prob.shooting.nz >= shooting.ARROW_FROM
    arrow = ti.fit(prob, "gauss-newton")
    monkeypatch.setattr(shooting, "ARROW_FROM", 10**9)
    dense = ti.fit(prob, "gauss-newton")
    assert arrow.success and dense.success
    assert arrow.cost == pytest.approx(dense.cost, rel=1e-9)


def test_ctrl_c_ends_a_batch_of_segmented_starts_at_once():
    prob = ti.Problem(lotka_volterra(), lv_data(noise=0.05), p0=LV_TRUE, x0=[2.0, 1.0],
                      free_x0=["prey", "pred"], segments=4)  # fmt: skip
    calls = []

    def stop(entry):
        calls.append(entry)
        if len(calls) == 2:
            raise KeyboardInterrupt

    starts = prob.theta0 * np.array([[1.3], [0.8], [1.2]])
    opts = ti.FitOptions(callback=stop)
    with pytest.raises(ti.FitInterrupted) as caught:
        ti.fit_batch(prob, "gauss-newton", starts, options=opts)
    assert len(calls) == 2
    assert [str(r.status) for r in caught.value.results] == ["interrupted"] * 3
    # an interrupted fit never returns a point worse than its start
    for r, th in zip(caught.value.results, starts, strict=True):
        assert r.cost <= prob.cost(th)


def test_without_polish_multistart_keeps_the_segments_solution():
    from tensorid.benchmarks import lotka_volterra_problem

    prob = lotka_volterra_problem(samples=201, segments=4)
    res = ti.fit(prob, "gauss-newton", starts=2, workers=1, spread=0.3, polish=False)
    assert res.success and not res.shooting["polished"]
    assert all(h.get("stage") == "multiple shooting" for h in res.history)
    assert all(np.isfinite(h["cost"]) and "lagrangian" in h for h in res.history)


def test_a_segment_that_blows_up_from_the_data_starts_from_the_simulation_instead():
    """x' = a·x² − x: from the measured x(0) = 1.5 and a = 0.9 the first segment (2 s)
    blows up (at t = 1.35 s), while the user's start x0 = 1 does not."""
    m = ti.Model(rhs=lambda x, p, u: p[0] * x**2 - x, states=["x"], params=["a"])
    t = np.linspace(0, 4, 81)
    y = ti.simulate(m, [0.5], [1.5], ti.Experiment(t, None)).y
    prob = ti.Problem(m, ti.Experiment(t, None, y), p0=[0.9], x0=[1.0], free_x0=["x"], segments=2)
    assert np.isfinite(prob.cost(prob.theta0))
    sh = prob.shooting
    assert not sh.evaluate(sh.start(prob.theta0)).finite
    res = ti.fit(prob)
    assert res.success, res.message
    assert res.params["a"] == pytest.approx(0.5, rel=1e-7)


def test_cli_segment_mistakes_name_the_flag(tmp_path, capsys):
    from tensorid.cli import main

    data = lv_data(P=101, T=20.0)
    csv = tmp_path / "lv.csv"
    np.savetxt(csv, np.column_stack([data.t, data.y]), delimiter=",", header="t,prey,pred",
               comments="")  # fmt: skip
    model = tmp_path / "lv.py"
    model.write_text(
        'states = ["prey", "pred"]\nparams = ["a", "b", "c", "d"]\n'
        'rhs = {"prey": "a*prey - b*prey*pred", "pred": "-c*pred + d*prey*pred"}\n'
        'p0 = {"a": 1.0, "b": 0.5, "c": 1.0, "d": 0.3}\nx0 = {"prey": 2.0, "pred": 1.0}\n'
    )
    assert (
        main(["fit", str(model), str(csv), "--segments", "1000", "--out", str(tmp_path / "o")]) == 2
    )
    err = capsys.readouterr().err
    assert "--segments" in err and "at most 50" in err and "lv.py" not in err


@pytest.mark.slow  # five seconds of compilation for one corner
@pytest.mark.filterwarnings("error::RuntimeWarning")
def test_a_tiny_state_scale_gives_no_raw_runtime_warning():
    # outputs of 1e-200: trial defects overflow in scaled units; such points are
    # rejected like a blow-up, and no numpy RuntimeWarning reaches the user
    t = np.arange(20) * 0.1
    m = ti.Model(
        rhs=lambda x, p, u: p[0] * x**3 + p[1] * u[0], states=["x"], params=["a", "b"],
        inputs=["u"], output=lambda x, p: x, outputs=["y"],
    )  # fmt: skip
    e = ti.Experiment(t, np.sin(3 * t), 1e-200 * np.sin(t))
    res = ti.fit(ti.Problem(m, e, p0={"a": 1.0, "b": 1.0}, free_x0=["x"], segments=3))
    assert np.isfinite(res.cost) and res.summary()


@pytest.mark.slow  # five seconds of compilation for one message
def test_a_polish_after_defects_remained_is_warned_about():
    # the shooting stage cannot meet a tolerance of 1e-300; the polish converges, and
    # the result says that it started from a discontinuous trajectory
    t = np.arange(20) * 0.1
    m = ti.Model(
        rhs=lambda x, p, u: -p[0] * x + p[1] * u[0], states=["x"], params=["a", "b"],
        inputs=["u"], output=lambda x, p: x, outputs=["y"],
    )  # fmt: skip
    e = ti.Experiment(t, np.sin(2 * t), np.sin(t))
    prob = ti.Problem(m, e, p0={"a": 1.0, "b": 1.0}, segments=2)
    res = ti.fit(prob, options=ti.FitOptions(defect_tol=1e-300))
    assert res.success and res.shooting["status"] == "defects_remain"
    assert any("multiple-shooting stage ended with a continuity defect" in w for w in res.warnings)
