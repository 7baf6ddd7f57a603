import numpy as np
import pytest
from scipy.optimize import rosen, rosen_der, rosen_hess

from tensorid.engine.schemes.status import Status
from tensorid.solve.minimize import minimize_trust_region
from tensorid.solve.projected import projected_cauchy
from tensorid.solve.trust_region import (
    _candidate_step,
    solve_subproblem,
    steihaug_cg,
)


def _model(g, H, s):
    return g @ s + 0.5 * s @ H @ s


@pytest.mark.parametrize("seed", range(40))
def test_subproblem_is_the_global_minimiser_in_the_ball(seed):
    rng = np.random.default_rng(seed)
    K = int(rng.integers(1, 6))
    A = rng.standard_normal((K, K))
    H = A @ A.T if seed % 3 == 0 else A + A.T  # convex and indefinite cases
    g = rng.standard_normal(K) * 10 ** rng.uniform(-3, 2)
    if seed % 5 == 0 and K > 1:  # the hard case
        v = np.linalg.eigh(H)[1][:, 0]
        g -= v * (v @ g)
    radius = 10 ** rng.uniform(-2, 1)
    s, _ = solve_subproblem(g, H, radius)
    assert np.linalg.norm(s) <= radius * (1 + 1e-9)
    best = _model(g, H, s)
    samples = rng.standard_normal((4000, K))
    samples *= (
        radius
        * rng.uniform(size=(4000, 1)) ** (1 / K)
        / np.linalg.norm(samples, axis=1, keepdims=True)
    )
    vals = np.einsum("i,ni->n", g, samples) + 0.5 * np.einsum("ni,ij,nj->n", samples, H, samples)
    assert vals.min() >= best - 1e-9 * max(1.0, abs(best))


def test_newton_step_inside_the_region_is_taken_exactly():
    H = np.diag([2.0, 5.0])
    g = np.array([1.0, -1.0])
    s, on_boundary = solve_subproblem(g, H, 10.0)
    np.testing.assert_allclose(s, -np.linalg.solve(H, g))
    assert not on_boundary


def _rosen(x):
    return rosen(x), rosen_der(x), rosen_hess(x)


def test_unbounded_rosenbrock():
    # 2-D: the 4-D function has a second local minimum near (-0.78, 0.61, 0.38, 0.15)
    r = minimize_trust_region(
        _rosen, np.array([-1.2, 1.0]), np.full(2, -np.inf), np.full(2, np.inf)
    )
    assert r.success
    np.testing.assert_allclose(r.x, 1.0, atol=1e-8)
    assert r.nit < 40


def test_bounded_rosenbrock_reaches_a_kkt_point():
    lo, hi = np.full(4, -2.0), np.full(4, 0.5)
    r = minimize_trust_region(_rosen, np.array([-1.2, 1.0, -1.2, 1.0]), lo, hi)
    assert r.success
    assert (r.x >= lo).all() and (r.x <= hi).all()
    pg = np.clip(r.x - r.jac, lo, hi) - r.x
    assert np.abs(pg).max() < 1e-8
    assert r.x[0] == 0.5


def _rosen_hessp(x):
    H = rosen_hess(x)
    return rosen(x), rosen_der(x), lambda v: H @ v


@pytest.mark.parametrize("seed", range(20))
def test_truncated_cg_step_is_feasible_and_decreases_the_model(seed):
    rng = np.random.default_rng(seed)
    n = int(rng.integers(1, 8))
    A = rng.standard_normal((n, n))
    H = A + A.T  # indefinite in general
    g = rng.standard_normal(n)
    radius = float(rng.uniform(0.05, 3.0))
    s, Hs, gHg = steihaug_cg(g, lambda v: H @ v, radius, 2 * n + 2)
    assert np.linalg.norm(s) <= radius * (1 + 1e-12)
    np.testing.assert_allclose(Hs, H @ s, atol=1e-10 * max(1.0, np.abs(H @ s).max()))
    np.testing.assert_allclose(gHg, g @ H @ g)
    # at least the Cauchy decrease: never worse than the best step along -g
    tau = radius / np.linalg.norm(g)
    if g @ H @ g > 0:
        tau = min(tau, (g @ g) / (g @ H @ g))
    assert _model(g, H, s) <= _model(g, H, -tau * g) + 1e-12


def test_truncated_cg_gives_the_newton_step_for_a_convex_model():
    rng = np.random.default_rng(0)
    A = rng.standard_normal((6, 6))
    H = A @ A.T + 6 * np.eye(6)
    g = 1e-3 * rng.standard_normal(6)  # small gradient: tight forcing tolerance
    s, _, _ = steihaug_cg(g, lambda v: H @ v, 10.0, 20)
    # the forcing tolerance: the Newton equations hold to sqrt(||g||) relative
    gn = np.linalg.norm(g)
    assert np.linalg.norm(g + H @ s) <= 1.001 * np.sqrt(gn) * gn
    assert np.linalg.norm(s + np.linalg.solve(H, g)) <= 0.05 * np.linalg.norm(s)


def test_hessian_vector_products_reach_the_same_minimiser():
    inf = np.full(2, np.inf)
    r = minimize_trust_region(_rosen_hessp, np.array([-1.2, 1.0]), -inf, inf)
    assert r.success and r.hess is None and r.nhev > 0
    np.testing.assert_allclose(r.x, 1.0, atol=1e-7)
    lo, hi = np.full(4, -2.0), np.full(4, 0.5)
    r = minimize_trust_region(_rosen_hessp, np.array([-1.2, 1.0, -1.2, 1.0]), lo, hi)
    dense = minimize_trust_region(_rosen, np.array([-1.2, 1.0, -1.2, 1.0]), lo, hi)
    assert r.success
    np.testing.assert_allclose(r.x, dense.x, atol=1e-7)


def test_non_finite_trial_points_shrink_the_region():
    def fun(x):
        if x[0] > 0.5:
            return np.inf, np.full(1, np.nan), np.full((1, 1), np.nan)
        return (x[0] - 0.4) ** 2 - x[0], np.array([2 * (x[0] - 0.4) - 1]), np.array([[2.0]])

    r = minimize_trust_region(
        fun, np.array([0.0]), np.array([-np.inf]), np.array([np.inf]), radius=5.0
    )
    assert np.isfinite(r.fun) and r.x[0] <= 0.5
    assert any(not h["accepted"] for h in r.history)


def test_each_way_of_stopping_says_why():
    start, lo, hi = np.array([-1.2, 1.0]), np.full(2, -np.inf), np.full(2, np.inf)
    r = minimize_trust_region(_rosen, start, lo, hi, maxiter=3)
    assert not r.success and "iteration limit reached (maxiter=3)" in r.message

    # nowhere finite beyond the start: every step is rejected
    def cliff(x):
        if np.any(x != 1.0):
            return np.inf, np.full(2, np.nan), np.full((2, 2), np.nan)
        return 1.0, np.array([1.0, 1.0]), np.eye(2)

    r = minimize_trust_region(cliff, np.ones(2), lo, hi, gtol=1e-14)
    assert not r.success and "trust region collapsed without a decrease" in r.message
    assert r.fun == 1.0 and np.isfinite(r.x).all()


@pytest.mark.parametrize("weight", [1.0, 1e-4])
def test_a_radius_that_collapses_under_accepted_steps_is_not_convergence(weight):
    # the gradient overstates the slope fivefold (as a kink, a noisy cost or
    # inconsistent derivatives do): every step is accepted at ρ = 0.2 and shrinks the
    # radius, until the steps were so short that they passed xtol (weight 1) or ftol
    # (weight 1e-4, a small gradient) and the fit was "converged" at x ≈ 0.09, 3
    # short of the minimum
    def fun(x):
        J = 1.0 + weight * float((x - 3.0) @ (x - 3.0))
        return J, 5.0 * weight * 2.0 * (x - 3.0), 2.0 * weight * np.eye(2)

    free = np.full(2, np.inf)
    r = minimize_trust_region(fun, np.zeros(2), -free, free)
    assert r.status is Status.RADIUS_COLLAPSED and not r.success
    assert r.history[-1]["accepted"] and "accepted" in r.message
    assert np.all(np.abs(r.x - 3.0) > 2.5)


def test_steps_bend_at_a_bound_instead_of_stopping_there():
    # x0 starts 1e-9 above its bound, pushed onto it; the way down is along x1. A step
    # cut off at the first bound it meets is 1e-9 long (the Cauchy and truncated
    # Newton steps before the projected path); the projected path bends there and
    # goes on along x1, to the radius (negative curvature)
    x, lo, hi = np.array([1e-9, 0.0]), np.zeros(2), np.full(2, np.inf)
    g, H = np.array([1.0, -1.0]), np.array([[1.0, 0.0], [0.0, -0.5]])
    d, m = projected_cauchy(x, g, H, lo, hi, np.ones(2, bool), radius=1.0)
    assert x[0] + d[0] == 0.0 and np.linalg.norm(d) == pytest.approx(1.0)
    assert m == pytest.approx(g @ d + 0.5 * d @ H @ d) and m < -1.0


def test_a_newton_step_out_of_the_box_is_taken_with_that_variable_held():
    # x0 sits 1e-6 above its bound with the gradient pushing it up, so the Cauchy point
    # moves it off the bound and holds nothing; but the model's minimiser in the ball
    # takes x0 below the bound (its strong coupling to x1), so the projected Newton
    # step rises and the truncated one is 1e-5 long. Exact Newton on a cubic chain
    # crept so, 1e-4 per step at a radius of 0.07, for 150 iterations. Holding x0 at
    # its bound and solving in (x1, x2) goes to the radius along x2's negative curvature
    x, lo, hi = np.array([1e-6, 0.0, 0.0]), np.array([0.0, -np.inf, -np.inf]), np.full(3, np.inf)
    g = np.array([-1.0, -10.0, -0.1])
    H = np.array([[1e4, 999.0, 0.0], [999.0, 100.0, 0.0], [0.0, 0.0, -1.0]])
    d, pred = _candidate_step(x, g, H, lo, hi, np.ones(3, bool), 1.0, [0])
    assert x[0] + d[0] == 0.0 and np.linalg.norm(d) == pytest.approx(1.0)
    assert pred == pytest.approx(-_model(g, H, d)) and pred > 1.0  # the Cauchy point: 0.128


def test_a_gradient_small_only_by_its_scale_is_not_converged():
    # J = 1e-6 + ½ h (x - 1000)² with h = 1e-14: at x = 0 the gradient (1e-11) passes
    # gtol, but a Newton step would still lower J by 5e-9, 0.5 % of it: the gradient
    # is small only because the scales (chosen at some other point) make it so
    h, xs = 1e-14, 1000.0

    def fun(x):
        return 1e-6 + 0.5 * h * float((x[0] - xs) ** 2), h * (x - xs), np.array([[h]])

    inf = np.array([np.inf])
    r = minimize_trust_region(fun, np.zeros(1), -inf, inf)
    assert r.status.success and r.x[0] == pytest.approx(xs, rel=1e-6)
    assert r.fun == pytest.approx(1e-6, rel=1e-12)


def test_negative_curvature_does_not_depend_on_the_units_of_the_unknowns():
    # a saddle whose downward curvature is 1e-10 of the other: in these units the
    # eigenvalues are -1e-10 and 1, below rounding relative to the largest; rescaled,
    # the same saddle. The verdict is made in Jacobi units, where both are the same
    from tensorid.solve.curvature import negative_curvature

    rng = np.random.default_rng(0)
    saddle = np.array([[1.0, 1e-6], [1e-6, -1e-10]])
    minimum = np.array([[1.0, 1e-6], [1e-6, 1e-10]])  # 1e-10 - 1e-12 > 0: positive
    for _ in range(20):
        S = np.diag(10.0 ** rng.uniform(-8, 8, 2))
        assert negative_curvature(S @ saddle @ S)
        assert not negative_curvature(S @ minimum @ S)
    # no curvature (a zero row, an unknown that does not enter) is not negative
    # curvature, nor is a row that is not finite, nor nothing at all
    assert not negative_curvature(np.diag([1.0, 0.0, 1e-300]))
    assert not negative_curvature(np.array([[1.0, np.nan], [np.nan, np.inf]]))
    assert not negative_curvature(np.zeros((0, 0)))
    # rounding at 1e-12 of the diagonal in a positive definite matrix: no saddle
    A = rng.standard_normal((6, 6))
    H = A @ A.T + 1e-3 * np.eye(6)
    E = rng.standard_normal((6, 6)) * 1e-12 * np.sqrt(np.outer(np.diag(H), np.diag(H)))
    assert not negative_curvature(H + E + E.T)


def test_a_badly_scaled_saddle_is_not_converged():
    # J = 1 + ½ x0² + ε (¼ x1⁴ - ½ x1²), ε = 1e-10, near its saddle (0, 0): the
    # gradient passes gtol, and the Hessian's eigenvalues are -1e-10 and 1 in the
    # trust region's units: "no negative curvature" by a test relative to the largest,
    # and the run stopped there, "converged". Its minima are x1 = ±1, in basins
    # |x1| > 1/√3 where J is convex (the run may stop short of x1 = 1 in one: the
    # gradient there, ε (x1³ - x1), passes gtol)
    eps = 1e-10

    def fun(x):
        J = 1.0 + 0.5 * x[0] ** 2 + eps * (0.25 * x[1] ** 4 - 0.5 * x[1] ** 2)
        g = np.array([x[0], eps * (x[1] ** 3 - x[1])])
        return J, g, np.diag([1.0, eps * (3.0 * x[1] ** 2 - 1.0)])

    inf = np.full(2, np.inf)
    r = minimize_trust_region(fun, np.array([1e-12, 0.0]), -inf, inf)
    assert r.status.success and abs(r.x[1]) > 1.0 / np.sqrt(3.0), (r.x, r.status)
    assert r.fun < 1.0 - 0.15 * eps  # the saddle's is 1


def test_small_steps_or_a_collapsed_radius_at_a_saddle_are_not_convergence():
    # FTOL and XTOL at a point where H curves downward (in Jacobi units: -1e-12 beside
    # 1 is -1 beside 1) go on; a radius collapsed under rejected steps there is a
    # collapse, not a rounding floor. Where H does not curve downward, as before
    from tensorid.solve.trust_region import _unless_saddle

    saddle, minimum, free = np.diag([1.0, -1e-12]), np.diag([1.0, 1e-12]), np.ones(2, bool)
    for ended in (Status.FTOL, Status.XTOL):
        assert _unless_saddle(ended, saddle, free) is None
        assert _unless_saddle(ended, minimum, free) is ended
    assert _unless_saddle(False, saddle, free) is Status.RADIUS_COLLAPSED
    assert _unless_saddle(False, minimum, free) is False
    assert _unless_saddle(None, saddle, free) is None
    assert _unless_saddle(Status.RADIUS_COLLAPSED, saddle, free) is Status.RADIUS_COLLAPSED
    # the unknown held at its bound is left out: a minimum on a bound is a minimum
    assert _unless_saddle(Status.FTOL, saddle, np.array([True, False])) is Status.FTOL


def test_a_collapse_where_the_cost_curves_downward_says_so():
    # the exact Hessian curves down along x2, but the cost rises every way: each step
    # is rejected until the radius collapses; the message's general reasons (noise,
    # inconsistent derivatives) are joined by what was seen there
    def fun(x):
        d = x - 1.0
        return 1.0 + float(d @ d), 2.0 * d, np.diag([1.0, -1.0])

    inf = np.full(2, np.inf)
    r = minimize_trust_region(fun, np.ones(2), -inf, inf)
    assert r.status is Status.RADIUS_COLLAPSED and not r.success
    assert "where the cost curves downward: a saddle, or a flat valley" in r.message


def test_a_boundary_step_is_not_cut_short_where_the_model_is_tiny():
    # the trust region's units came from a start whose cost was 1e3-1e18 times the
    # current one, so g and H are tiny (a filter fit's at its saddle, in its two main
    # eigen-directions); the secular equation stopped at an absolute width of 1e-15 in
    # λ, where the λ it needed was within 3e-20 of 1.3e-18, and the step along the
    # slight negative curvature was 8e-5 long at a radius of 1.6. Filter fits from
    # σ = 1e-9 crawled so for 200 iterations; now they converge in 18-19
    g, H = np.array([-4e-20, 1e-14]), np.diag([-1.3e-18, 1e-9])
    s, on_boundary = solve_subproblem(g, H, 1.6)
    assert on_boundary and np.linalg.norm(s) == pytest.approx(1.6, rel=1e-9)
    assert s[0] > 1.59  # downhill along the first unknown


def test_a_saddle_of_couplings_alone_is_not_converged():
    # J = 1 + x0 x1 + (x0⁴ + x1⁴)/4 from (0, 0): g = 0 and H = [[0, 1], [1, 0]]. With
    # the unknowns of zero diagonal left out of the Jacobi-scaled test, nothing was
    # left and the run stopped there, "converged" (as a fit of y' = -y + a·b·u from
    # a = b = 0 did, cost 578.6, where the base version reached 0.79). Its minima are
    # at x0 = -x1 = ±1, J = 0.5
    from tensorid.solve.curvature import negative_curvature

    assert negative_curvature(np.array([[0.0, -385.0], [-385.0, 0.0]]))
    assert negative_curvature(np.array([[0.0, 1.0], [1.0, 1.0]]))  # det -1
    assert negative_curvature(np.diag([1e-320, -1.0]))  # a subnormal entry: no overflow

    def fun(x):
        J = 1.0 + x[0] * x[1] + 0.25 * (x[0] ** 4 + x[1] ** 4)
        g = np.array([x[1] + x[0] ** 3, x[0] + x[1] ** 3])
        return J, g, np.array([[3.0 * x[0] ** 2, 1.0], [1.0, 3.0 * x[1] ** 2]])

    inf = np.full(2, np.inf)
    r = minimize_trust_region(fun, np.zeros(2), -inf, inf)
    assert r.status.success and r.fun == pytest.approx(0.5, rel=1e-9), (r.x, r.status)


def test_an_inner_solve_ends_through_the_one_loop():
    # issue 39: minimize_trust_region (profiles, validation's initial states, the
    # model-error check, the population's outer problem) runs in endings.iterate:
    # Ctrl-C and a failing eigen-solver end the run at its best point, with a status
    from tensorid.solve.minimize import interrupted

    lo, hi = np.full(2, -np.inf), np.full(2, np.inf)
    seen = []

    def stopping(x, error):
        seen.append(x.copy())
        if len(seen) == 6:
            raise error
        return _rosen(x)

    for error, status in ((KeyboardInterrupt, Status.INTERRUPTED),
                          (np.linalg.LinAlgError("eigh"), Status.SOLVER_FAILED)):  # fmt: skip
        seen.clear()
        r = minimize_trust_region(lambda x, e=error: stopping(x, e), np.array([-1.2, 1.0]), lo, hi)
        assert r.status is status and len(seen) == 6  # nothing evaluated after it
        best = min(seen[:5], key=lambda x: _rosen(x)[0])
        np.testing.assert_array_equal(r.x, best)
        assert r.fun == _rosen(best)[0] and r.nfev == 5
        if status is Status.SOLVER_FAILED:
            assert "LinAlgError: eigh" in r.message
    seen.clear()
    with pytest.raises(KeyboardInterrupt):  # for callers whose own work must stop too
        interrupted(
            minimize_trust_region(lambda x: stopping(x, KeyboardInterrupt), np.ones(2) * 3, lo, hi)
        )
    # and a run that ends by itself is unchanged by the loop
    r = minimize_trust_region(_rosen, np.array([-1.2, 1.0]), lo, hi)
    assert r.success and np.allclose(r.x, 1.0)


def test_no_optimisation_loop_outside_the_one_loop():
    # issue 39 item 3, grep-able: a trust-region generator is advanced, and SciPy's
    # minimisers are called, only in a method's step (which endings.iterate calls; the
    # finite-difference baselines' step calls their ``minimize``)
    import ast
    from pathlib import Path

    src = Path(__file__).resolve().parents[1] / "src" / "tensorid"
    for path in src.rglob("*.py"):
        tree = ast.parse(path.read_text())
        for fn in ast.walk(tree):
            if not isinstance(fn, ast.FunctionDef | ast.AsyncFunctionDef):
                continue
            for node in ast.walk(fn):
                call = isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute)
                if call and node.func.attr == "send" and fn.name != "step":
                    raise AssertionError(f"{path.name}: {fn.name} advances a solve itself")
                scipy = call and node.func.attr in ("minimize", "least_squares")
                allowed = ("step", "minimize")  # baselines.py: Baseline.step -> minimize
                if scipy and fn.name not in allowed and "optimize" in ast.unparse(node.func):
                    raise AssertionError(f"{path.name}: {fn.name} runs SciPy's minimiser itself")
