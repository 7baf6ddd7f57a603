"""The extended-Kalman predictor (predictor="ekf"): its likelihood, gradient and
Hessian against a plainly written filter differentiated by jax.grad/jax.hessian, on
four models (one and two outputs, continuous and discrete time, several
experiments), implicit schemes, bad input, and a fit of a record with process noise."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from conftest import autodiff

import tensorid as ti

# -- models ------------------------------------------------------------------------------


def duffing():
    def f(x, p, u):
        return jnp.array([x[1], -p[0] * x[0] - p[1] * x[1] - p[2] * x[0] ** 3 + u[0]])

    return ti.Model(
        f, lambda x, p: x[:1], states=["x", "v"], params=["k", "c", "a"], inputs=["u"],
        outputs=["y"], name="duffing",
    )  # fmt: skip


def lotka():
    def f(x, p, u):
        return jnp.array([p[0] * x[0] - p[1] * x[0] * x[1], p[1] * x[0] * x[1] - p[2] * x[1]])

    return ti.Model(f, states=["prey", "pred"], params=["a", "b", "c"], name="lv")


def tanks():
    def f(x, p, u):
        q1 = p[1] * jnp.sqrt(jnp.abs(x[0]) + 1e-3)
        return jnp.array([p[0] * u[0] - q1, q1 - p[2] * jnp.sqrt(jnp.abs(x[1]) + 1e-3)])

    return ti.Model(
        f, lambda x, p: x[1:], states=["h1", "h2"], params=["k", "a1", "a2"],
        inputs=["u"], outputs=["level"], name="tanks",
    )  # fmt: skip


def first_order_discrete():
    def f(x, p, u):
        return jnp.array([p[0] * x[0] + p[1] * jnp.tanh(u[0])])

    return ti.Model(
        f, lambda x, p: x, states=["x"], params=["a", "b"], inputs=["u"], outputs=["y"],
        discrete=True, name="ar1",
    )  # fmt: skip


def record(model, P, seed, x0, params, noise=0.02, dt=0.1):
    rng = np.random.default_rng(seed)
    t = np.arange(P) * dt
    u = 1.0 + 0.5 * np.sin(0.7 * t)[:, None] + 0.2 * rng.standard_normal((P, model.U))
    u = u[:, : model.U]
    sim = ti.simulate(model, params, x0, ti.Experiment(t, u, np.zeros((P, model.S))))
    return ti.Experiment(t, u, sim.y + noise * rng.standard_normal(sim.y.shape))


# -- a plainly written filter --------------------------------------------------------------


def plain_filter_cost(model, theta, problem, substeps, interpolation):
    """−2 log L (less n log 2π) of a continuous-discrete EKF written out plainly:
    joint RK4 of (x, P) over each interval, Joseph update, scan over samples; with an
    estimated initial state, the first sample left out."""
    J = 0.0
    K_x = len(problem.free_x0)
    E = len(problem.experiments)
    p_all = jnp.asarray(problem.p0)
    free = [problem.model.params.index(n) for n in problem.free_params]
    p_all = p_all.at[jnp.array(free)].set(theta[E * K_x :])
    M = model.M
    p = p_all[:M]
    n = model.N
    qn = [(model.states.index(s[len("log_sigma_w_") :]), problem.model.params.index(s))
          for s in problem.model.params if s.startswith("log_sigma_w_")]  # fmt: skip
    Q = jnp.zeros(n)
    for i, k in qn:
        Q = Q.at[i].set(jnp.exp(2 * p_all[k]))
    R = jnp.array([jnp.exp(2 * p_all[problem.model.params.index(f"log_sigma_e_{o}")])
                   for o in model.outputs])  # fmt: skip

    def ode(x, P, u):
        A = jax.jacfwd(lambda xx: model.f(xx, p, u))(x)
        if model.discrete:
            return model.f(x, p, u), A @ P @ A.T + jnp.diag(Q)
        return model.f(x, p, u), A @ P + P @ A.T + jnp.diag(Q)

    for e, exp in enumerate(problem.experiments):
        x0 = jnp.asarray(problem.x0[e])
        x0 = x0.at[jnp.array([model.states.index(s) for s in problem.free_x0])].set(
            theta[e * K_x : (e + 1) * K_x]
        )
        t, u, y = (jnp.asarray(a) for a in (exp.t, exp.u, exp.y))

        def step(carry, k, t=t, u=u, y=y):
            x, P, J = carry
            C = jax.jacfwd(lambda xx: model.h(xx, p))(x)
            Sg = C @ P @ C.T + jnp.diag(R)
            eps = y[k] - model.h(x, p)
            term = jnp.linalg.slogdet(Sg)[1] + eps @ jnp.linalg.solve(Sg, eps)
            J = J + jnp.where((k > 0) | (K_x == 0), term, 0.0)  # t0 left out
            G = P @ C.T @ jnp.linalg.inv(Sg)
            I_GC = jnp.eye(n) - G @ C
            x, P = x + G @ eps, I_GC @ P @ I_GC.T + G @ jnp.diag(R) @ G.T
            if model.discrete:
                return (*ode(x, P, u[k]), J), None
            h = (t[k + 1] - t[k]) / substeps
            for i in range(substeps):

                def uin(stage, i=i):
                    frac = (i + stage) / substeps
                    return u[k] if interpolation == "zoh" else u[k] + frac * (u[k + 1] - u[k])

                k1 = ode(x, P, uin(0.0))
                k2 = ode(x + h / 2 * k1[0], P + h / 2 * k1[1], uin(0.5))
                k3 = ode(x + h / 2 * k2[0], P + h / 2 * k2[1], uin(0.5))
                k4 = ode(x + h * k3[0], P + h * k3[1], uin(1.0))
                x = x + h / 6 * (k1[0] + 2 * k2[0] + 2 * k3[0] + k4[0])
                P = P + h / 6 * (k1[1] + 2 * k2[1] + 2 * k3[1] + k4[1])
            return (x, P, J), None

        (x, P, Je), _ = jax.lax.scan(step, (x0, jnp.zeros((n, n)), 0.0), jnp.arange(t.size - 1))
        # the last sample's share
        C = jax.jacfwd(lambda xx: model.h(xx, p))(x)
        Sg = C @ P @ C.T + jnp.diag(R)
        eps = y[-1] - model.h(x, p)
        J = J + Je + jnp.linalg.slogdet(Sg)[1] + eps @ jnp.linalg.solve(Sg, eps)
    return J


CASES = {
    "duffing, 2 experiments, linear": (
        duffing, {"k": 2.0, "c": 0.3, "a": 0.5}, [0.1, 0.0], ["x", "v"], {"v": 0.2}, "linear",
    ),
    "lotka-volterra, 2 outputs, zoh": (
        lotka, {"a": 1.0, "b": 0.5, "c": 1.0}, [1.0, 0.5], ["prey"],
        {"prey": 0.05, "pred": 0.1}, "zoh",
    ),
    "two tanks": (tanks, {"k": 0.5, "a1": 0.4, "a2": 0.3}, [1.0, 0.5], ["h1", "h2"],
                  {"h2": 0.05}, "linear"),
    "discrete time": (first_order_discrete, {"a": 0.8, "b": 0.5}, [0.2], ["x"], {"x": 0.1},
                      "zoh"),
}  # fmt: skip


def ekf_problem(case, experiments=None, **kw):
    build, params, x0, free, qn, interp = CASES[case]
    m = build()
    if m.discrete:
        kw.pop("substeps", None)
    E = experiments or (2 if case.startswith("duffing") else 1)
    data = [record(m, 30, seed, x0, params) for seed in range(E)]
    return m, ti.Problem(
        m, data, p0=params, x0=x0, free_x0=free, predictor="ekf", process_noise=qn,
        interpolation=interp, **kw,
    )  # fmt: skip


SLOW = pytest.mark.slow  # each compiles jax.hessian of a filter: ~20 s on 2 idle cores


@pytest.mark.parametrize(
    "case, substeps, experiments",
    # the default run: one record, one step per interval (the reference's program is
    # the slow part to compile); the slow run: every model, two steps per interval
    [("duffing, 2 experiments, linear", 1, 1)]
    + [pytest.param(c, 2, None, marks=SLOW) for c in CASES],
)
def test_ekf_derivatives_equal_jax_hessian_of_a_plain_filter(case, substeps, experiments):
    m, pr = ekf_problem(case, experiments, substeps=substeps)
    rng = np.random.default_rng(3)
    theta = pr.theta0 * (1 + 0.05 * rng.standard_normal(pr.K))
    J, g, H = pr.cost_grad_hess(theta)

    def ref(th):
        return plain_filter_cost(m, th, pr, substeps, pr.interpolation)

    Jr, gr, Hr = autodiff(ref)(theta)
    assert abs(J - Jr) <= 1e-9 * abs(Jr)
    assert np.abs(g - gr).max() <= 1e-9 * np.abs(gr).max()
    assert np.abs(H - Hr).max() <= 1e-9 * np.abs(Hr).max()


@pytest.mark.slow
@pytest.mark.parametrize(
    "case", ["duffing, 2 experiments, linear", "lotka-volterra, 2 outputs, zoh"]
)
def test_ekf_other_sweeps_agree_with_the_hessian(case):
    """The first-order sweep (its Gauss-Newton part is the Fisher information), the
    Hessian-vector product and the lock-step batch give the same numbers."""
    _, pr = ekf_problem(case, substeps=2)
    rng = np.random.default_rng(3)
    theta = pr.theta0 * (1 + 0.05 * rng.standard_normal(pr.K))
    J, g, H = pr.cost_grad_hess(theta)
    J1, g1, H_gn = pr.cost_grad_gn(theta)
    assert abs(J1 - J) <= 1e-12 * abs(J) and np.allclose(g1, g, rtol=0, atol=1e-10 * abs(g).max())
    assert np.all(np.linalg.eigvalsh(H_gn) > -1e-9 * np.abs(H_gn).max())  # Fisher: PSD
    v = rng.standard_normal(pr.K)
    assert np.abs(pr.cost_grad_hessp(theta, v)[2] - H @ v).max() <= 1e-9 * np.abs(H @ v).max()
    Jb, gb, Hb = pr.cost_grad_hess_batch(np.stack([theta, theta]))
    assert np.abs(Hb[1] - H).max() <= 1e-12 * np.abs(H).max()


@pytest.mark.parametrize(
    "scheme", [pytest.param(s, marks=SLOW) for s in ("sdirk2", "implicit-euler", "heun")]
)
def test_ekf_derivatives_on_other_schemes_equal_forward_mode_of_its_cost(scheme):
    _, pr = ekf_problem("duffing, 2 experiments, linear", scheme=scheme)
    theta = jnp.asarray(pr.theta0 * 1.03)
    J, g, H = pr.cost_grad_hess(np.asarray(theta))
    # implicit schemes' Newton loops allow forward mode only
    Hr = np.asarray(jax.jacfwd(jax.jacfwd(pr.jax_cost))(theta))
    gr = np.asarray(jax.jacfwd(pr.jax_cost)(theta))
    assert np.abs(g - gr).max() <= 1e-9 * np.abs(gr).max()
    assert np.abs(H - Hr).max() <= 1e-9 * np.abs(Hr).max()


def test_ekf_noise_parameters_and_defaults():
    m, pr = ekf_problem("duffing, 2 experiments, linear")
    assert pr.theta_names[-2:] == ["log_sigma_w_v", "log_sigma_e_y"]
    assert pr.hessian == "tensors"
    assert pr.theta0[-2] == pytest.approx(np.log(0.2))
    # the measurement noise starts from the data's noise level (0.02 here)
    assert 0.005 < np.exp(pr.theta0[-1]) < 0.08
    fixed = ti.Problem(
        m, pr.experiments, p0=pr.p0[:3], x0=[0.1, 0], predictor="ekf",
        process_noise={"v": 0.2}, fixed=["log_sigma_e_y"],
    )  # fmt: skip
    assert "log_sigma_e_y" not in fixed.theta_names


@pytest.mark.parametrize(
    "kw, words",
    [
        ({"process_noise": {"speed": 0.1}}, ["process_noise", "speed", "states"]),
        ({"measurement_noise": {"z": 0.1}}, ["measurement_noise", "'z'", "outputs"]),
        ({"process_noise": {"v": 0.0}}, ["process_noise['v']", "> 0"]),
        ({"process_noise": {"v": float("nan")}}, ["process_noise['v']"]),
        ({"measurement_noise": {"y": -1}}, ["measurement_noise['y']", "> 0"]),
        ({"loss": "huber"}, ["predictor='ekf'", "loss='huber'"]),
        ({"weights": {"y": 2.0}}, ["predictor='ekf'", "weights"]),
        ({"segments": 3}, ["predictor='ekf'", "segments=3"]),
        ({"hessian": "adjoint"}, ["predictor='ekf'", "hessian='adjoint'", "tensors"]),
        ({"noise": 0.1}, ["predictor='ekf'", "noise=0.1"]),
        ({"weights": "auto"}, ["predictor='ekf'", "weights='auto'"]),
        ({"weights": np.array([2.0])}, ["predictor='ekf'", "weights='ndarray'"]),
        ({"predictor": "kalman"}, ["predictor must be one of", "'kalman'"]),
    ],
)
def test_ekf_bad_input_is_one_line_before_any_work(kw, words):
    m = duffing()
    data = record(m, 20, 0, [0.1, 0.0], {"k": 2.0, "c": 0.3, "a": 0.5})
    args = {"predictor": "ekf", "process_noise": {"v": 0.1}, **kw}
    with pytest.raises(ValueError) as err:
        ti.Problem(m, data, p0={"k": 2.0, "c": 0.3, "a": 0.5}, **args)
    msg = str(err.value)
    assert "\n" not in msg
    for w in words:
        assert w in msg, (w, msg)


def test_a_method_that_cannot_serve_a_filter_is_refused_before_any_work():
    _, pr = ekf_problem("duffing, 2 experiments, linear")
    with pytest.raises(ValueError, match="'fd-lsq' minimises a sum of squared residuals"):
        ti.fit(pr, method="fd-lsq")


def test_noise_without_the_filter_is_refused():
    m = duffing()
    data = record(m, 20, 0, [0.1, 0.0], {"k": 2.0, "c": 0.3, "a": 0.5})
    with pytest.raises(ValueError, match="predictor='ekf'"):
        ti.Problem(m, data, p0={"k": 2.0, "c": 0.3, "a": 0.5}, process_noise={"v": 0.1})


def sde_record(seed, P=400, dt=0.05, sw=0.3, se=0.02, fine=20):
    """The Duffing oscillator with process noise on v by Euler-Maruyama on a grid
    ``fine`` times finer than the samples."""
    rng = np.random.default_rng(seed)
    u = np.repeat(rng.standard_normal(P // 10 + 1), 10)[:P, None]
    p = np.array([2.0, 0.3, 0.5])
    x, ys, h = np.array([0.1, 0.0]), [], dt / fine
    for k in range(P):
        ys.append(x[0] + se * rng.standard_normal())
        for _ in range(fine):
            a = -p[0] * x[0] - p[1] * x[1] - p[2] * x[0] ** 3 + u[k, 0]
            kick = sw * np.sqrt(h) * rng.standard_normal()
            x = x + h * np.array([x[1], a]) + np.array([0.0, kick])
    return ti.Experiment(np.arange(P) * dt, u, np.array(ys)[:, None])


@pytest.mark.slow  # a statistical study of whole filter fits (10 s cold)
def test_ekf_fit_recovers_parameters_and_noise_where_output_error_is_pulled_off():
    data = sde_record(0)
    m = duffing()
    start = {"k": 1.5, "c": 0.5, "a": 0.3}
    pr = ti.Problem(
        m, data, p0=start, x0=[0, 0], free_x0=["x", "v"], predictor="ekf",
        process_noise={"v": 0.1}, measurement_noise={"y": 0.05}, interpolation="zoh",
    )  # fmt: skip
    res = ti.fit(pr)
    assert res.success and np.isfinite(res.cost)
    u = res.uncertainty()
    truth = {"k": 2.0, "c": 0.3, "a": 0.5, "log_sigma_w_v": np.log(0.3),
             "log_sigma_e_y": np.log(0.02)}  # fmt: skip
    for name, value in truth.items():
        i = pr.theta_names.index(name)
        assert abs(res.theta[i] - value) <= 3 * u.stderr[i], (name, res.theta[i], u.stderr[i])
    assert u.sigma2 == 1.0  # J = −2 log L: no residual variance
    assert all(res.residual_tests().whiteness_passed)
    # the same record by output error: white residual tests fail
    oe = ti.fit(ti.Problem(m, data, p0=start, x0=[0, 0], free_x0=["x", "v"], interpolation="zoh"))
    assert not all(oe.residual_tests().whiteness_passed)
    # one-step prediction beats the simulation, and horizons in between lie between
    one, five = pr.predict(res.theta)[0], pr.predict(res.theta, horizon=5)[0]
    rms = [np.sqrt(np.mean((d.measured - d.predicted) ** 2)) for d in (one, five)]
    sim = res.simulate()[0]
    rms_sim = np.sqrt(np.mean((data.y - sim.y) ** 2))
    assert rms[0] < rms[1] < rms_sim
    # the figures: a prediction figure per output beside the simulation's
    from tensorid.analysis.figures import fit_figures

    stems = [stem for stem, _ in fit_figures(res, named=True)]
    assert "prediction_data_y" in stems and "train_data_y" in stems
    assert "noise intensities" in res.summary()


def test_a_filter_fit_with_priors_weighs_them_as_they_are():
    """J = −2 log L: a prior adds ((θ − mean)/sd)² with weight 1, exactly. The noise
    variance check of output error does not apply: it warned that a weight of 1 was
    'given as noise=' and 456,598× too large, which would have made the fit wrong."""
    from tensorid.analysis.validation import training_scores
    from tensorid.app.reports import fit_json, fit_report

    pr = ti.Problem(
        duffing(), sde_record(0, P=200), p0={"k": 1.5, "c": 0.5, "a": 0.3}, x0=[0, 0],
        free_x0=["x", "v"], predictor="ekf", process_noise={"v": 0.1},
        measurement_noise={"y": 0.05}, interpolation="zoh", priors={"k": (2.0, 0.5)},
    )  # fmt: skip
    res = ti.fit(pr)
    assert res.success and res.noise_check is None and pr.noise_variance == 1.0
    assert not any("noise variance" in w for w in res.warnings)
    report = fit_report(res, fit_json(res, []), training_scores(res), [])
    assert "weighed as they are: the cost is −2 log L" in report and "noise=" not in report
    # the data alone's standard errors: 2 H⁻¹ (J = −2 log L may be negative: no J/dof)
    moves = {m["unknown"]: m for m in fit_json(res, [])["prior_moves"]}
    assert np.isfinite(moves["k"]["data_stderr"]) and moves["k"]["data_stderr"] > 0


def test_an_estimated_initial_state_cannot_buy_a_likelihood_without_minimum():
    """P0 = 0: x0 can match the first sample exactly, whose term log R + 0 then fell
    without bound as σ_e → 0; fits ended at σ_e = 1e-61 with x(t0) = y(t0). That
    sample's term is left out, and σ_e comes out near the truth."""
    rng = np.random.default_rng(1)
    P, x, ys = 400, 0.0, []
    u = rng.standard_normal(P)
    for k in range(P):  # x+ = 0.8 x + 0.3 u + w, y = x + e; σ_w 0.1, σ_e 0.05
        ys.append(x + 0.05 * rng.standard_normal())
        x = 0.8 * x + 0.3 * u[k] + 0.1 * rng.standard_normal()
    m = ti.model_from_equations(
        rhs={"x": "a*x + b*u"}, output={"y": "x"}, inputs=["u"], params=["a", "b"],
        discrete=True,
    )  # fmt: skip
    data = ti.Experiment(np.arange(P) * 1.0, u[:, None], np.array(ys)[:, None])
    pr = ti.Problem(m, data, p0={"a": 0.5, "b": 0.5}, x0=[0.0], free_x0=["x"],
                    predictor="ekf", process_noise={"x": 0.05})  # fmt: skip
    res = ti.fit(pr)
    sigma = dict(zip(pr.theta_names, np.exp(res.theta), strict=True))
    assert 0.025 < sigma["log_sigma_e_y"] < 0.1 and 0.05 < sigma["log_sigma_w_x"] < 0.2
    # −2 log L and the criteria against a plain Kalman filter over samples 1..P−1
    th = dict(zip(pr.theta_names, res.theta, strict=True))
    a, b, x = th["a"], th["b"], th["x(t0)"]
    q, r = np.exp(2 * th["log_sigma_w_x"]), np.exp(2 * th["log_sigma_e_y"])
    cov, m2logL = 0.0, 0.0
    for k in range(P):
        S, e = cov + r, ys[k] - x
        m2logL += (np.log(2 * np.pi * S) + e * e / S) if k > 0 else 0.0
        G = cov / S
        x, cov = a * (x + G * e) + b * u[k], a * a * (1 - G) * cov + q
    from tensorid.analysis.residuals import information_criteria

    crit = information_criteria(res)
    assert crit["n"] == P - 1
    assert crit["aic"] - 2 * pr.K == pytest.approx(m2logL, rel=1e-9, abs=1e-9)
    # the hole itself: x(t0) = y(t0) and σ_e → 0 no longer lowers the cost
    hole = res.theta.copy()
    hole[pr.theta_names.index("x(t0)")] = ys[0]
    hole[pr.theta_names.index("log_sigma_e_y")] = -30.0
    assert pr.cost(hole) > res.cost


def test_output_error_predictions_are_the_simulation_at_every_horizon():
    m = duffing()
    data = record(m, 40, 0, [0.1, 0.0], {"k": 2.0, "c": 0.3, "a": 0.5})
    pr = ti.Problem(m, data, p0={"k": 2.0, "c": 0.3, "a": 0.5}, x0=[0.1, 0], free_x0=["x"])
    sim = pr.simulate(pr.theta0)[0].y
    for k in (1, 3):
        pred = pr.predict(pr.theta0, horizon=k)[0]
        assert np.abs(pred.predicted - sim).max() <= 1e-12
        assert pred.covariance is None
    with pytest.raises(ValueError, match="horizon"):
        pr.predict(pr.theta0, horizon=0)
    # scored on a record "as 3-step prediction": the simulation, labelled as it is
    res = ti.fit(pr)
    (score,) = res.validate(data, horizon=3)
    (plain,) = res.validate(data)
    assert score.horizon is None and "prediction" not in score.label
    assert score.gof == plain.gof
    for bad in (0, -3, 10**6):
        with pytest.raises(ValueError, match="horizon"):
            res.validate(data, horizon=bad)


@pytest.mark.slow
def test_ekf_profile_intervals_use_the_likelihood_ratio_and_agree_with_wald_here():
    """J = −2 log L: the profile's threshold is χ²(1) = 3.84 on the rise of J itself;
    on this well-determined record the profile and Wald intervals nearly agree."""
    m, data = duffing(), sde_record(0, P=300)
    pr = ti.Problem(
        m, data, p0={"k": 1.5, "c": 0.5, "a": 0.3}, x0=[0, 0], free_x0=["x", "v"],
        predictor="ekf", process_noise={"v": 0.1}, interpolation="zoh",
    )  # fmt: skip
    res = ti.fit(pr)
    prof = res.profile(["k", "log_sigma_w_v"])
    u = res.uncertainty()
    for name, p in prof.items():
        i = pr.theta_names.index(name)
        assert p.threshold == pytest.approx(3.841458820694124)
        lo, hi = p.interval
        assert lo < res.theta[i] < hi
        width = u.ci95[i, 1] - u.ci95[i, 0]
        assert abs((hi - lo) - width) < 0.15 * width


EKF_MODEL_FILE = """
import jax.numpy as jnp
import tensorid

def rhs(x, p, u):
    k, c, a = p
    return jnp.stack([x[1], -k * x[0] - c * x[1] - a * x[0] ** 3 + u[0]])

model = tensorid.Model(rhs=rhs, output=lambda x, p: x[:1], states=["x", "v"],
                       params=["k", "c", "a"], inputs=["u"], outputs=["y"])
p0 = {"k": 1.5, "c": 0.5, "a": 0.3}
free_x0 = ["x", "v"]
predictor = "ekf"
process_noise = {"v": 0.1}
"""


@pytest.mark.slow  # a command-line filter fit with its figures and report (10 s cold)
def test_ekf_from_the_command_line(tmp_path, capsys):
    import json

    from tensorid import cli

    (tmp_path / "model.py").write_text(EKF_MODEL_FILE)
    for name, seed in (("train", 0), ("val", 1)):
        d = sde_record(seed, P=300)
        rows = ["t,u,y"] + [
            f"{a:.10g},{b:.10g},{c:.10g}" for a, b, c in zip(d.t, d.u[:, 0], d.y[:, 0], strict=True)
        ]
        (tmp_path / f"{name}.csv").write_text("\n".join(rows) + "\n")
    out = tmp_path / "out"
    argv = ["fit", str(tmp_path / "model.py"), str(tmp_path / "train.csv"), "--validate",
            str(tmp_path / "val.csv"), "--horizon", "5", "--interpolation", "zoh",
            "--measurement-noise", "y=0.05", "--no-progress", "--out", str(out)]  # fmt: skip
    assert cli.main(argv) == 0
    printed = capsys.readouterr().out
    assert "noise intensities" in printed and "5-step prediction" in printed
    # the training row is the filter fit's simulation, beside the prediction: said so
    assert "GOF train, simulation: y" in printed and "│ training, simulation " in printed
    d = json.loads((out / "fit.json").read_text())
    assert d["predictor"] == "ekf" and d["horizon"] == 5
    noise = d["noise_intensities"]
    assert 0.15 < noise["process"]["v"]["sigma"] < 0.6  # the record's 0.3
    assert 0.01 < noise["measurement"]["y"]["sigma"] < 0.04  # its 0.02
    assert "log_sigma_w_v" in d["stderr"]
    assert "## Noise model" in (out / "report.md").read_text()
    assert (out / "prediction_train_y.png").exists()
    # tensorid compare on the saved fit scores the same 5-step predictions
    cmp = tmp_path / "cmp"
    argv_cmp = ["compare", str(tmp_path / "model.py"), str(tmp_path / "val.csv"), "--params",
                str(out / "fit.json"), "--horizon", "5", "--out", str(cmp)]  # fmt: skip
    assert cli.main(argv_cmp) == 0
    c = json.loads((cmp / "compare.json").read_text())
    assert c["horizon"] == 5 and c["scored_as"] == "5-step prediction"
    rmse = c["outputs"]["y"]["rmse"]
    assert rmse == pytest.approx(d["rmse"]["validation"]["val"]["y"], rel=1e-9)
    # a filter refuses what it cannot serve, in one line, before any work
    assert cli.main([*argv[:3], "--data-sensitivity", "--out", str(tmp_path / "o2")]) != 0
    assert "--data-sensitivity is for output error" in capsys.readouterr().err


@pytest.mark.slow  # four command-line filter fits (20-27 s cold)
def test_the_command_line_s_predictor_overrides_the_model_file_s(tmp_path, capsys):
    """--predictor simulation on a model file set up for the filter fits by output
    error (the file's noise goes with its predictor: it was refused, 'add
    predictor=ekf', which the file had); an error the flags may have caused names them."""
    import json

    from tensorid import cli

    (tmp_path / "model.py").write_text(EKF_MODEL_FILE)
    d = sde_record(0, P=200)
    cols = zip(d.t, d.u[:, 0], d.y[:, 0], strict=True)
    rows = ["t,u,y"] + [f"{a:.10g},{b:.10g},{c:.10g}" for a, b, c in cols]
    (tmp_path / "d.csv").write_text("\n".join(rows) + "\n")
    argv = ["fit", str(tmp_path / "model.py"), str(tmp_path / "d.csv"), "--no-progress"]
    assert cli.main([*argv, "--predictor", "simulation", "--out", str(tmp_path / "oe")]) == 0
    assert json.loads((tmp_path / "oe" / "fit.json").read_text())["predictor"] == "simulation"
    capsys.readouterr()
    assert cli.main([*argv, "--loss", "huber", "--out", str(tmp_path / "h")]) != 0
    err = capsys.readouterr().err
    assert "model.py with --loss huber:" in err and len(err.strip().splitlines()) == 1
    # the flag's setting named as the flag, the model file's by its name in the file
    assert "predictor='ekf' cannot take --loss huber" in err and "(drop --loss)" in err
    # the noise intensities fixed, bounded and freed from the command line, as in the file
    assert cli.main([*argv, "--fix", "log_sigma_e_y=-4", "--out", str(tmp_path / "f")]) == 0
    noise = json.loads((tmp_path / "f" / "fit.json").read_text())["noise_intensities"]
    assert noise["measurement"]["y"]["fixed"]
    assert noise["measurement"]["y"]["sigma"] == pytest.approx(np.exp(-4.0), rel=1e-12)
    bounded = [*argv, "--bounds", "log_sigma_w_v=-4:-2", "--out", str(tmp_path / "b")]
    assert cli.main(bounded) == 0
    noise = json.loads((tmp_path / "b" / "fit.json").read_text())["noise_intensities"]
    assert noise["process"]["v"]["sigma"] <= np.exp(-2.0) * (1 + 1e-12)  # the truth: 0.3
    held = EKF_MODEL_FILE + 'measurement_noise = {"y": 0.02}\nfixed = ["log_sigma_e_y"]\n'
    (tmp_path / "held.py").write_text(held)
    freed = [argv[0], str(tmp_path / "held.py"), *argv[2:], "--free", "log_sigma_e_y"]
    assert cli.main([*freed, "--out", str(tmp_path / "fr")]) == 0
    noise = json.loads((tmp_path / "fr" / "fit.json").read_text())["noise_intensities"]
    assert not noise["measurement"]["y"]["fixed"]


def test_ekf_problems_of_one_model_share_their_compiled_sweeps():
    """A filter's model (the user's, noise intensities appended) is built once per model
    and set of noisy states, so a second Problem compiles nothing."""
    m = duffing()
    data = [record(m, 20, seed, [0.1, 0.0], {"k": 2.0, "c": 0.3, "a": 0.5}) for seed in (0, 1)]
    kw = {"p0": {"k": 2.0, "c": 0.3, "a": 0.5}, "x0": [0.1, 0.0], "predictor": "ekf"}
    a = ti.Problem(m, data[0], process_noise={"v": 0.1}, **kw)
    b = ti.Problem(m, data[1], process_noise={"v": 0.3}, **kw)
    assert b.model is a.model and b.sweeps is a.sweeps
    c = ti.Problem(m, data[0], process_noise={"x": 0.1, "v": 0.1}, **kw)
    assert c.sweeps is not a.sweeps and list(c.model.params[-3:]) == [
        "log_sigma_w_x", "log_sigma_w_v", "log_sigma_e_y"
    ]  # fmt: skip
    assert ti.Problem(duffing(), data[0], process_noise={"v": 0.1}, **kw).sweeps is not a.sweeps


def test_a_filter_problem_at_its_rounding_floor_is_not_a_collapse():
    """A likelihood's J is negative: the trust region's rounding-floor test uses |J|."""
    from tensorid.engine.schemes.status import Status
    from tensorid.solve.trust_region import _collapsed

    assert _collapsed(-1.0, 1e-20, 1e-12, 1e-10) is Status.MACHINE_PRECISION
    assert _collapsed(-1.0, 1e-3, 1e-12, 1e-10) is Status.RADIUS_COLLAPSED


def test_a_filters_model_without_measured_outputs_needs_every_sigma_e_given():
    from tensorid.engine.sweeping.predictors import make_predictor

    m = duffing()
    model, filt, starts = make_predictor(m, "ekf", {"v": 0.1}, {"y": 0.02}, [None])
    assert list(starts) == ["log_sigma_w_v", "log_sigma_e_y"] and filt.update is not None
    with pytest.raises(ValueError, match="measurement_noise"):
        make_predictor(m, "ekf", {"v": 0.1}, None, [None])


@pytest.mark.slow  # compiles two filters of a 501-sample record (about 9 s cold)
def test_a_filter_that_diverges_at_the_start_is_named_not_blamed_on_the_data():
    """The two-tank record with process noise on the unmeasured upper level only: the
    filter's covariance loses positive-definiteness at sample 483 (its estimate of x1
    has run below zero and back), so the likelihood is not finite although the
    simulation is. The message said "rescale the data"; it names the filter now."""
    from tensorid import datasets
    from tensorid.paper.problems import TWO_TANK_GUESS, two_tank_model

    prob = ti.Problem(two_tank_model(), datasets.two_tank(501), p0=TWO_TANK_GUESS,
                      x0=datasets.two_tank_levels(501)[0], free_x0=["x1"], predictor="ekf",
                      process_noise={"x1": 0.01})  # fmt: skip
    res = ti.fit(prob)
    assert res.status is ti.Status.NONFINITE_START and not res.success
    assert "the filter fails at" in res.message and "rescale" not in res.message
    assert "not positive definite at t = 2415 (sample 483 of 501)" in res.message
    assert "x1=6.629" in res.message
    # where the filter keeps S positive definite, nothing to say
    good = ti.Problem(two_tank_model(), datasets.two_tank(501), p0=TWO_TANK_GUESS,
                      x0=datasets.two_tank_levels(501)[0], predictor="ekf",
                      process_noise={"x1": 0.01, "x2": 0.01})  # fmt: skip
    assert good.diagnose(good.theta0) is None


def test_a_noise_intensity_at_zero_is_reported_without_nan_or_warnings():
    """σ_w → 0 (log σ = −800) with an unbounded standard error: σ's is unbounded too
    (0 × inf was NaN with a RuntimeWarning), its interval [0, inf] (exp overflowed)."""
    import types
    import warnings

    from tensorid.analysis.summary import noise_intensities

    names = ["log_sigma_w_v", "log_sigma_e_y"]
    res = types.SimpleNamespace(
        problem=types.SimpleNamespace(loss=types.SimpleNamespace(likelihood=True),
                                      theta_names=names),
        params={"log_sigma_w_v": -800.0, "log_sigma_e_y": -3.0},
    )  # fmt: skip
    u = types.SimpleNamespace(
        stderr=np.array([np.inf, 0.1]), ci95=np.array([[-np.inf, 1e4], [-3.2, -2.8]])
    )
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        noise = noise_intensities(res, u)
    w, e = noise["process"]["v"], noise["measurement"]["y"]
    assert w["sigma"] == 0.0 and w["stderr"] == np.inf and w["ci95"] == [0.0, np.inf]
    assert e["stderr"] == pytest.approx(np.exp(-3.0) * 0.1)


def test_noise_intensities_without_error_bars_print_no_nan():
    """Too few samples for error bars: the noise line said "[nan, nan]" (console and
    report.md); it says the interval is not available, from fit.json's nulls too."""
    from tensorid.analysis.summary import noise_text

    nan = float("nan")
    noise = {
        "process": {"v": {"sigma": 1e-7, "stderr": nan, "ci95": [nan, nan], "fixed": False}},
        "measurement": {"y": {"sigma": 0.005, "stderr": None, "ci95": [None, None],
                              "fixed": False}},
    }  # fmt: skip
    line = noise_text(noise)
    assert "nan" not in line.lower()
    assert line.count("[interval not available]") == 2
    noise["measurement"]["y"]["ci95"] = [0.004, 0.006]
    assert "σ_e(y) = 0.005 [0.004, 0.006]" in noise_text(noise)


def test_noise_flags_without_the_filter_name_the_flags(tmp_path, capsys):
    """Noise flags on an output-error model file were refused with the Problem's
    keywords ("process_noise is for predictor='ekf'; add predictor='ekf'"), and a
    record with no noise to start from asked for measurement_noise={'y': σ}."""
    from tensorid import cli

    (tmp_path / "oe.py").write_text(EKF_MODEL_FILE.replace('predictor = "ekf"', ""))
    (tmp_path / "d.csv").write_text("t,u,y\n" + "".join(f"{k},1,{k % 3}\n" for k in range(20)))
    argv = ["fit", str(tmp_path / "oe.py"), str(tmp_path / "d.csv"), "--out", str(tmp_path / "o")]
    for flags, named in [
        (["--process-noise", "v=0.1"], "--process-noise:"),
        (["--measurement-noise", "y=0.1"], "--measurement-noise:"),
        (["--fix", "log_sigma_e_y=-4"], "--fix log_sigma_e_y:"),
        (["--free", "log_sigma_e_y"], "--free log_sigma_e_y:"),  # was ignored: fitted OE
        (["--bounds", "log_sigma_w_v=-5:-1"], "--bounds log_sigma_w_v:"),
    ]:
        assert cli.main([*argv, *flags]) == 2
        err = capsys.readouterr().err
        assert named in err and "add --predictor ekf" in err, err
        assert "predictor='ekf'" not in err and len(err.strip().splitlines()) == 1
    (tmp_path / "c.csv").write_text("t,u,y\n" + "".join(f"{k},1,0.5\n" for k in range(20)))
    argv[2] = str(tmp_path / "c.csv")
    assert cli.main([*argv, "--predictor", "ekf", "--process-noise", "v=0.1"]) == 2
    err = capsys.readouterr().err
    assert "give --measurement-noise y=σ" in err and "measurement_noise=" not in err
    assert not (tmp_path / "o").exists()  # refused before any work


def test_noise_flags_on_a_state_without_process_noise_are_refused(tmp_path, capsys):
    """--free log_sigma_w_x on a filter fit whose state x has no process noise was
    ignored without a word (the fit ran with v's noise alone); --bounds on it named
    no flag. Both name the flag and --process-noise x=σ, before any work."""
    from tensorid import cli

    (tmp_path / "m.py").write_text(EKF_MODEL_FILE)
    (tmp_path / "d.csv").write_text("t,u,y\n" + "".join(f"{k},1,{k % 3}\n" for k in range(20)))
    argv = ["fit", str(tmp_path / "m.py"), str(tmp_path / "d.csv"), "--out", str(tmp_path / "o")]
    for flags in (["--free", "log_sigma_w_x"], ["--bounds", "log_sigma_w_x=-5:-1"]):
        assert cli.main([*argv, *flags]) == 2
        err = capsys.readouterr().err
        assert f"{flags[0]} log_sigma_w_x: the state x has no process noise" in err, err
        assert "--process-noise x=σ" in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "o").exists()


def test_a_discrete_model_s_process_noise_is_labelled_per_step():
    """P⁺ = A P Aᵀ + Q: a discrete-time model's σ_w is per step, not per √time."""
    from tensorid.analysis.summary import noise_text

    noise = {"process": {"x": {"sigma": 0.05, "ci95": [0.04, 0.06], "fixed": False}},
             "measurement": {}}  # fmt: skip
    assert noise_text(noise).endswith("σ_w(x) = 0.05 [0.04, 0.06] per √time")
    assert noise_text(noise, discrete=True).endswith("σ_w(x) = 0.05 [0.04, 0.06] per step")
    m = first_order_discrete()
    e = record(m, 60, 0, [0.5], {"a": 0.8, "b": 0.5}, dt=1.0)
    res = ti.fit(ti.Problem(m, e, p0={"a": 0.7, "b": 0.4}, x0=[0.5], predictor="ekf",
                            process_noise={"x": 0.05}))  # fmt: skip
    assert "per step" in res.summary() and "per √time" not in res.summary()


def test_a_method_the_filter_cannot_use_is_refused_in_flags(tmp_path, capsys):
    """--method fd-lsq with --predictor ekf was refused as "method 'fd-lsq' ...
    (predictor='ekf') ... use 'auto', ...": the command line's own words now."""
    from tensorid import cli

    (tmp_path / "m.py").write_text(EKF_MODEL_FILE)
    (tmp_path / "d.csv").write_text("t,u,y\n" + "".join(f"{k},1,{k % 3}\n" for k in range(20)))
    argv = ["fit", str(tmp_path / "m.py"), str(tmp_path / "d.csv"), "--out", str(tmp_path / "o"),
            "--process-noise", "v=0.1", "--method", "fd-lsq"]  # fmt: skip
    assert cli.main(argv) == 2
    err = capsys.readouterr().err
    assert "--method fd-lsq minimises a sum of squared residuals" in err
    # the model file chose the filter, not a flag: said so (it said --predictor ekf)
    assert f'(predictor = "ekf" in {tmp_path / "m.py"})' in err
    assert "use --method auto, newton," in err
    assert "'fd" not in err and "='" not in err and not (tmp_path / "o").exists()
    assert cli.main([*argv, "--predictor", "ekf"]) == 2
    assert "(--predictor ekf)" in capsys.readouterr().err


def test_a_measurement_noise_gone_to_zero_is_warned_of():
    """σ_e → 0 (a tester's Silverbox filter fit from σ_e = 1e-7 ended "converged" at
    3.4e-27, cost -12807, where a larger start reached -13136): a warning names the
    output and how to start elsewhere; an ordinary or a fixed σ_e gives none."""
    import types

    from tensorid.analysis.summary import collapsed_noise

    def res(log_sigma_e, names=("log_sigma_e_y", "log_sigma_e_z"), step=None):
        y = np.column_stack([np.sin(np.arange(50.0)), np.cos(np.arange(50.0))])
        if step is not None:  # a quantised sensor: an encoder's counts, times its step
            counts = np.concatenate([np.arange(25.0), 60000.0 * np.arange(25.0)])
            y = step * np.column_stack([counts, counts[::-1]])  # spread 0.02: EMPS's 0.07
        problem = types.SimpleNamespace(
            loss=types.SimpleNamespace(likelihood=True), theta_names=list(names),
            model=types.SimpleNamespace(outputs=("y", "z")),
            experiments=[types.SimpleNamespace(measured=y)],
        )  # fmt: skip
        return types.SimpleNamespace(
            problem=problem, params={"log_sigma_e_y": log_sigma_e, "log_sigma_e_z": -3.0}
        )

    (line,) = collapsed_noise(res(-60.0))
    assert "measurement noise of y went to σ_e = 8.8e-27" in line
    assert "--measurement-noise y=σ" in line and "--fix log_sigma_e_y" in line
    assert collapsed_noise(res(-5.0)) == []  # 0.0067 of a spread of 0.7: a sensor's
    assert collapsed_noise(res(-60.0, names=("log_sigma_e_z",))) == []  # y's held
    # EMPS's σ_e = 2e-8 m (2e-7 of the spread) is its encoder's 5e-8 m steps, q/√12:
    # the sensor's own noise, not a collapse (it was warned of)
    q = 5e-8
    assert collapsed_noise(res(np.log(q / np.sqrt(12)), step=q)) == []
    assert len(collapsed_noise(res(np.log(q / 1000), step=q))) == 1  # far below it
    assert len(collapsed_noise(res(np.log(q / np.sqrt(12))))) == 1  # y not on a grid


@pytest.mark.slow  # two fits of 65 iterations: about 10 s on 2 idle cores
def test_a_filter_fit_from_a_tiny_measurement_noise_does_not_stop_at_a_saddle():
    """From σ_e = 1e-7 Newton stopped "converged" at cost −2185 with σ_e at 1e-10 (the
    minimum, from σ_e = 0.1, is −2546.9): the cost curves down along log σ_e there,
    by −3e-15 beside 1.7e3 along x(t0), which in the units chosen at the start was
    −9e-17 beside 4e-6, taken for rounding. Auto's check of a Gauss-Newton end by the
    exact Hessian (seed 1) let the same kind of point through at −2064 (its minimum
    −2467.7). Jacobi-scaled, the downward curvature is −1 beside ≤ 3 (curvature.py)."""
    m, start = duffing(), {"k": 1.5, "c": 0.5, "a": 0.3}
    for seed, interpolation, method, best in [(0, "linear", "newton", -2546.9),
                                               (1, "zoh", "auto", -2467.69)]:  # fmt: skip
        pr = ti.Problem(
            m, sde_record(seed), p0=start, x0=[0, 0], free_x0=["x", "v"], predictor="ekf",
            process_noise={"v": 0.1}, measurement_noise={"y": 1e-7},
            interpolation=interpolation,
        )  # fmt: skip
        res = ti.fit(pr, method=method)
        assert res.success and res.cost < best, (method, res.cost, res.message)
        assert abs(res.params["log_sigma_e_y"] - np.log(0.02)) < 0.2  # 0.019 and 0.020


# -- records with gaps ---------------------------------------------------------------------


def plain_filter_with_gaps(model, theta, problem, substeps):
    """−2 log L of a continuous-discrete EKF (no inputs) on a record with gaps, written
    out plainly: at each sample the update and the likelihood term of the outputs
    measured there alone (C, R and ε cut to them, one branch per subset), none where
    nothing was."""
    e = problem.experiments[0]
    S, n, names = model.S, model.N, problem.model.params
    p_all = jnp.asarray(problem.p0).at[jnp.array([names.index(k) for k in problem.free_params])]
    p_all = p_all.set(theta[len(problem.free_x0) :])
    p = p_all[: model.M]
    noisy = [s for s in names if s.startswith("log_sigma_w_")]
    Q = jnp.zeros(n).at[jnp.array([model.states.index(s[12:]) for s in noisy])]
    Q = Q.set(jnp.exp(2 * jnp.array([p_all[names.index(s)] for s in noisy])))
    R = jnp.exp(2 * jnp.array([p_all[names.index(f"log_sigma_e_{o}")] for o in model.outputs]))
    x = jnp.asarray(problem.x0[0]).at[jnp.array([model.states.index(s) for s in problem.free_x0])]
    x = x.set(theta[: len(problem.free_x0)])

    def ode(x, P):
        A = jax.jacfwd(lambda xx: model.f(xx, p, None))(x)
        return model.f(x, p, None), A @ P + P @ A.T + jnp.diag(Q)

    def measure(x, P, yk, idx):
        if not idx:
            return x, P, jnp.zeros((), x.dtype)
        sel = jnp.array(idx)
        C = jax.jacfwd(lambda xx: model.h(xx, p)[sel])(x)
        Sg = C @ P @ C.T + jnp.diag(R[sel])
        eps = yk[sel] - model.h(x, p)[sel]
        G = P @ C.T @ jnp.linalg.inv(Sg)
        I_GC = jnp.eye(n) - G @ C
        term = jnp.linalg.slogdet(Sg)[1] + eps @ jnp.linalg.solve(Sg, eps)
        return x + G @ eps, I_GC @ P @ I_GC.T + G @ jnp.diag(R[sel]) @ G.T, term

    subsets = [tuple(j for j in range(S) if (c >> j) & 1) for c in range(2**S)]
    branches = [lambda x, P, yk, idx=idx: measure(x, P, yk, idx) for idx in subsets]
    codes = jnp.asarray((e.seen * (1 << np.arange(S))).sum(axis=1))
    counted = jnp.asarray((np.arange(e.P) > 0) | (not problem.free_x0))  # t0 left out
    dts = jnp.asarray(np.append(np.diff(e.t), 0.0) / substeps)

    def step(carry, k):
        x, P, J = carry
        x, P, term = jax.lax.switch(codes[k], branches, x, P, jnp.asarray(e.y)[k])
        h = dts[k]
        for _ in range(substeps):
            k1 = ode(x, P)
            k2 = ode(x + h / 2 * k1[0], P + h / 2 * k1[1])
            k3 = ode(x + h / 2 * k2[0], P + h / 2 * k2[1])
            k4 = ode(x + h * k3[0], P + h * k3[1])
            x = x + h / 6 * (k1[0] + 2 * k2[0] + 2 * k3[0] + k4[0])
            P = P + h / 6 * (k1[1] + 2 * k2[1] + 2 * k3[1] + k4[1])
        return (x, P, J + jnp.where(counted[k], term, 0.0)), None

    (_, _, J), _ = jax.lax.scan(step, (x, jnp.zeros((n, n)), 0.0), jnp.arange(e.P))
    return J


@pytest.mark.slow  # compiles the masked filter, its reference and two fits (18 s cold)
def test_a_filter_on_a_record_with_gaps_updates_with_what_was_measured():
    """Lotka-Volterra, both populations counted at some samples, one at others, none
    at a few: the filter's J, ∇J and ∇²J are those of a filter that updates with the
    measured outputs alone (records with gaps were refused: "fitted by output
    error"), and the innovations and one-step predictions skip what was not measured."""
    m = lotka()
    params, x0 = {"a": 1.0, "b": 0.5, "c": 1.0}, [1.0, 0.5]
    e = record(m, 24, 5, x0, params)
    seen = np.random.default_rng(1).random((24, 2)) > 0.35
    seen[[3, 9]] = False  # nothing measured: predicted, not corrected
    y = np.where(seen, e.y, 0.0)
    gaps = ti.Experiment(e.t, None, y, observed=seen)
    noise = {"prey": 0.05, "pred": 0.1}
    pr = ti.Problem(m, gaps, p0=params, x0=x0, free_x0=["prey"], predictor="ekf",
                    process_noise=noise, interpolation="zoh", substeps=1)  # fmt: skip
    theta = pr.theta0 * (1 + 0.05 * np.random.default_rng(3).standard_normal(pr.K))
    J, g, H = pr.cost_grad_hess(theta)
    Jr, gr, Hr = autodiff(lambda th: plain_filter_with_gaps(m, th, pr, 1))(theta)
    assert abs(J - Jr) <= 1e-9 * abs(Jr)
    assert np.abs(g - gr).max() <= 1e-9 * np.abs(gr).max()
    assert np.abs(H - Hr).max() <= 1e-9 * np.abs(Hr).max()
    innov = pr.predict(theta)[0].innovations
    assert np.isfinite(innov).all() and (innov[~seen] == 0).all() and (innov[seen] != 0).all()
    # one step ahead on the record itself, its noise held where the filter's gains
    # matter: no correction by the 0 placed where nothing was measured (GOF of the
    # measured samples was below 0)
    held = ti.Problem(m, gaps, p0=params, x0=x0, free_x0=["prey"], predictor="ekf",
                      process_noise=noise, measurement_noise={"prey": 0.02, "pred": 0.02},
                      fixed=[n for n in pr.model.params if n.startswith("log_sigma")],
                      interpolation="zoh", substeps=1)  # fmt: skip
    res = ti.fit(held)
    assert res.success and res.residual_tests().samples == int(seen[1:].sum(axis=0).min())
    full = ti.Experiment(e.t, None, e.y)
    gofs = [res.validate(r, horizon=1)[0].gof for r in (gaps, full)]
    assert all(v > 0.85 for g in gofs for v in g.values())
