"""Events in the records (engine/events.py): doses, infusions, resets and impulses on
the march's grid, with the gradient and the Hessian exact through every jump —
checked against jax.hessian of a plainly written multiple-dose cost."""

from __future__ import annotations

import warnings
from concurrent.futures import ThreadPoolExecutor

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from conftest import autodiff

import tensorid as ti
from tensorid.analysis.residuals import default_lags
from tensorid.analysis.summary import metric_rows
from tensorid.analysis.validation import training_scores
from tensorid.engine.modelling.events import Events
from tensorid.engine.modelling.metrics import gof

PARAMS = ["ka", "ke", "v", "F"]


def _model():
    def rhs(x, p, u):
        ka, ke = p[0], p[1]
        return jnp.stack([-ka * x[0], ka * x[0] - ke * x[1] - 0.05 * x[1] ** 2 / (1 + x[1])])

    return ti.Model(
        rhs=rhs,
        output=lambda x, p: x[1:] / p[2],
        states=["depot", "center"],
        params=PARAMS,
        outputs=["cp"],
    )


T_OBS = np.array([0.5, 1.0, 2.0, 4.0, 7.5, 12.0, 12.5, 14.0, 20.0, 26.0, 30.0])
EVENTS = (
    Events.doses(0.0, "depot", 100.0)
    + Events.doses(12.0, "depot", 80.0, ii=6.0, addl=1)  # 12 and 18
    + Events.doses(24.0, "center", 60.0, rate=30.0)  # an infusion over 24-26
)
THETA = np.array([1.1, 0.15, 9.0, 0.8])


def _plain_cost(theta, t, y, seen, jumps, rates, substeps):
    """RK4 written out (one scan over the grid): the jumps after each grid time's
    observation, the infusion rates held on each interval; F multiplies the depot's
    doses."""
    ka, ke, v, F = theta

    def f(x, r):
        return jnp.stack(
            [-ka * x[0] + r[0], ka * x[0] - ke * x[1] - 0.05 * x[1] ** 2 / (1 + x[1]) + r[1]]
        )

    def rk4(x, dt, r):
        k1 = f(x, r)
        k2 = f(x + dt / 2 * k1, r)
        k3 = f(x + dt / 2 * k2, r)
        k4 = f(x + dt * k3, r)
        return x + dt / 6 * (k1 + 2 * k2 + 2 * k3 + k4)

    def sample(carry, data):
        x, J = carry
        y_h, seen_h, jump_h, rate_h, dt = data
        J = J + seen_h * (y_h - x[1] / v) ** 2
        x = x + jnp.array([F, 1.0]) * jump_h
        x = jax.lax.fori_loop(0, substeps, lambda _, xx: rk4(xx, dt / substeps, rate_h), x)
        return (x, J), None

    dts = jnp.append(jnp.diff(t), 0.0)
    (_, J), _ = jax.lax.scan(sample, (jnp.zeros(2), 0.0), (y, seen, jumps, rates, dts))
    return J


def _record(y=None):
    y = np.ones((T_OBS.size, 1)) if y is None else y
    return ti.Experiment(T_OBS, None, y, events=EVENTS)


def _problem(e, **kw):
    return ti.Problem(
        _model(), e, p0=dict(zip(PARAMS, THETA, strict=True)), x0=[0.0, 0.0],
        doses={"depot": "F * amt"}, **kw,
    )  # fmt: skip


def test_the_grid_holds_every_event_and_rows_without_observation_do_not_count():
    e = _record()
    # 0 (a dose), 18 (a repeat), 24 (an infusion starts; it ends at 26, a sample)
    for extra in (0.0, 18.0, 24.0):
        h = int(np.flatnonzero(e.t == extra)[0])
        assert not e.observed[h, 0]
    assert e.observations == T_OBS.size
    assert e.P == T_OBS.size + 3


def test_cost_gradient_and_hessian_through_bolus_infusion_repeats_and_F_are_exact():
    sim = ti.simulate(
        _model(), dict(zip(PARAMS, THETA, strict=True)), [0, 0], _record(),
        doses={"depot": "F * amt"},
    )  # fmt: skip
    rng = np.random.default_rng(1)
    y = sim.y[_record().observed[:, 0]] * (1 + 0.05 * rng.standard_normal((T_OBS.size, 1)))
    e = _record(y)
    pr = _problem(e, substeps=3)
    theta = THETA * np.array([1.2, 0.9, 1.1, 0.95])
    J, g, H = pr.cost_grad_hess(theta)
    ch = pr.dosing.channels(e).reshape(e.P, 4, -1)
    jumps = np.zeros((e.P, 2))
    jumps[:, list(pr.dosing.targets)] = ch[:, 0]
    rates = np.zeros((e.P, 2))
    rates[:, list(pr.dosing.targets)] = ch[:, 1]
    args = (e.t, e.y[:, 0], e.observed[:, 0].astype(float), jumps, rates, 3)
    Jref, gref, Href = autodiff(lambda th: _plain_cost(th, *args))(theta)
    assert J == pytest.approx(Jref, rel=1e-12)
    np.testing.assert_allclose(g, gref, rtol=1e-9, atol=1e-12 * np.abs(g).max())
    np.testing.assert_allclose(H, Href, rtol=1e-8, atol=1e-10 * np.abs(Href).max())
    # and against finite differences of the cost itself (F moves the doses' amounts)
    steps = np.diag(1e-6 * theta)
    fd = [(pr.cost(theta + s) - pr.cost(theta - s)) / (2 * s[i]) for i, s in enumerate(steps)]
    np.testing.assert_allclose(g, fd, rtol=1e-5)


def test_a_reset_and_an_impulse_jump_the_state_and_its_derivatives():
    m = ti.Model(
        rhs=lambda x, p, u: jnp.stack([p[0] - p[1] * x[0]]),
        states=["level"], params=["q", "k"],
    )  # fmt: skip
    t = np.linspace(0, 10, 21)
    ev = Events.resets(4.0, "level", 0.5) + Events.impulses(7.0, 0, -0.3)
    e0 = ti.Experiment(t, None, np.zeros((21, 1)), events=ev)
    sim = ti.simulate(m, {"q": 1.0, "k": 0.5}, [0.0], e0)
    h4, h7 = 8, 14
    assert sim.y[h4 + 1, 0] < sim.y[h4, 0]  # the reset after the sample at t = 4
    e = ti.Experiment(t, None, sim.y + 0.01 * np.sin(t)[:, None], events=ev)
    pr = ti.Problem(m, e, p0={"q": 0.8, "k": 0.6}, x0=[0.0], free_x0=["level"])
    theta = np.array([0.1, 0.8, 0.6])
    _, g, H = pr.cost_grad_hess(theta)
    _, gref, Href = autodiff(pr.jax_cost)(theta)
    np.testing.assert_allclose(H, Href, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(g, gref, rtol=1e-9)
    # after the reset the initial state no longer matters: its sensitivity is cut
    res = ti.fit(pr)
    assert res.success
    np.testing.assert_allclose(res.params["q"], 1.0, rtol=0.05)
    del h7


def test_a_fit_on_doses_recovers_the_truth():
    truth = dict(zip(PARAMS, THETA, strict=True))
    sim = ti.simulate(_model(), truth, [0, 0], _record(), doses={"depot": "F * amt"}, substeps=8)
    y = sim.y[_record().observed[:, 0]]
    e = _record(y * (1 + 0.01 * np.random.default_rng(3).standard_normal(y.shape)))
    pr = ti.Problem(
        _model(), e, p0={"ka": 1.5, "ke": 0.2, "v": 7.0, "F": 0.8}, x0=[0, 0],
        fixed=["F"], doses={"depot": "F * amt"}, substeps=8,
    )  # fmt: skip
    res = ti.fit(pr)
    assert res.success
    se = dict(zip(res.problem.theta_names, res.uncertainty().stderr, strict=True))
    for k in ("ka", "ke", "v"):
        assert abs(res.params[k] - truth[k]) < 3 * se[k], (k, res.params[k], se[k])
    # scored at the 11 observations, not at the 3 dose rows (y a placeholder 0 there:
    # they had made the GOF of this fit to 1 % noise 0.52, where it is 0.96)
    [score] = training_scores(res)
    seen = e.observed[:, 0]
    assert score.scored == {"cp": T_OBS.size} and metric_rows([score])[1][0][-1] == "11"
    assert score.gof["cp"] == gof(e.measured[seen, 0], score.simulation.y[seen, 0]) > 0.9
    assert res.gof() == [score.gof["cp"]]
    assert default_lags(pr) == 11 // 4  # the residual tests' N/4: not 14 // 4
    from tensorid.fitting.priors import _per_output  # (a prior's noise check)

    r = e.measured[seen, 0] - score.simulation.y[seen, 0]
    assert _per_output(res)["cp"]["residual_variance"] == pytest.approx(np.mean(r**2), rel=1e-12)
    # the model-error check's halves: 7 rows each, holding 6 and 5 measurements
    why = res.model_check().not_available
    assert "halves (6 and 5 measured samples) are shorter than 20" in why


@pytest.mark.parametrize(
    "build, words",
    [
        (lambda: Events.doses(0.0, "depot", -5.0), "negative amount"),
        (lambda: Events.doses(0.0, "depot", 5.0, rate=-1.0), "negative rate"),
        (lambda: Events.doses(0.0, "depot", 5.0, ii=12.0), "no ADDL"),
        (lambda: Events.doses(0.0, "depot", 5.0, addl=2), "no II"),
    ],
)
def test_bad_events_get_one_line(build, words):
    with pytest.raises(ValueError, match=words):
        build()


def test_an_event_for_a_state_the_model_lacks_is_refused_before_any_work():
    e = ti.Experiment(T_OBS, None, np.ones((T_OBS.size, 1)), events=Events.doses(0, "gut", 1.0))
    with pytest.raises(ValueError, match="no state 'gut'"):
        _problem(e)
    e = ti.Experiment(T_OBS, None, np.ones((T_OBS.size, 1)), events=Events.doses(0, 5, 1.0))
    with pytest.raises(ValueError, match="state 5 does not exist"):
        _problem(e)
    with pytest.raises(ValueError, match="names \\['G'\\]"):
        ti.Problem(_model(), _record(), p0=dict(zip(PARAMS, THETA, strict=True)),
                   doses={"depot": "G * amt"})  # fmt: skip


def test_a_filter_or_segments_with_events_is_refused():
    with pytest.raises(ValueError, match="single shooting"):
        _problem(_record(), segments=2)
    with pytest.raises(ValueError, match="not 'adjoint'"):
        _problem(_record(), hessian="adjoint")


def test_a_lag_moves_the_dose_and_its_derivatives_are_exact():
    """lags={"depot": "tlag"}: the dose's node moves with tlag (across samples as the
    fit goes); J equals the same record with the dose given at t + tlag, and ∇J, ∇²J
    equal jax.hessian's of the same discretised cost and finite differences."""
    m = ti.Model(
        rhs=lambda x, p, u: jnp.stack([-p[0] * x[0], p[0] * x[0] - p[1] * x[1]]),
        output=lambda x, p: x[1:] / p[2],
        states=["depot", "center"], params=["ka", "ke", "v", "tlag"], outputs=["cp"],
    )  # fmt: skip
    t = np.array([0.25, 0.5, 1.0, 2.0, 4.0, 8.0, 12.5, 13.0, 16.0])
    y = np.array([[0.0, 1.0, 4.0, 5.5, 5.0, 2.5, 1.5, 3.0, 4.5]]).T
    doses = Events.doses([0.0, 12.0], "depot", 100.0)
    p0 = {"ka": 1.0, "ke": 0.2, "v": 10.0, "tlag": 0.4}
    record = ti.Experiment(t, None, y, events=doses)
    pr = ti.Problem(m, record, x0=[0, 0], substeps=3, p0=p0, lags={"depot": "tlag"})
    theta = np.array([1.1, 0.15, 9.0, 0.4])
    # the same grid: the doses' own times are nodes too (nothing happens there)
    moved = Events.doses([0.4, 12.4], "depot", 100.0) + Events.impulses([0.0, 12.0], 0, 0.0)
    shifted = ti.Experiment(t, None, y, events=moved)
    ref = ti.Problem(m, shifted, p0=dict(zip(m.params, theta, strict=True)), x0=[0, 0],
                     substeps=3, fixed=["tlag"])  # fmt: skip
    assert pr.cost(theta) == pytest.approx(ref.cost(theta[:3]), rel=1e-12)
    J, g, H = pr.cost_grad_hess(theta)
    reference = autodiff(pr.jax_cost)  # compiled once, called at both points
    _, gref, Href = reference(theta)
    np.testing.assert_allclose(g, gref, rtol=1e-9)
    np.testing.assert_allclose(H, Href, rtol=1e-8, atol=1e-10)
    steps = np.diag(1e-6 * theta)
    fd = [(pr.cost(theta + s) - pr.cost(theta - s)) / (2 * s[i]) for i, s in enumerate(steps)]
    np.testing.assert_allclose(g, fd, rtol=1e-5)
    # past a sample: the lagged dose at 0.6 now follows the sample at 0.5
    th2 = theta.copy()
    th2[3] = 0.6
    _, g2, H2 = pr.cost_grad_hess(th2)
    np.testing.assert_allclose(H2, reference(th2)[2], rtol=1e-8, atol=1e-10)
    fd = (pr.cost(th2 + steps[3]) - pr.cost(th2 - steps[3])) / (2 * steps[3, 3])
    assert g2[3] == pytest.approx(fd, rel=1e-5)
    sim, e = pr.simulate(th2)[0], pr.experiments[0]
    h = list(e.t).index(0.5)
    assert sim.y.shape == (e.P, 1) and sim.x[h, 0] == 0.0  # nothing in the depot at 0.5
    assert sim.x[h + 1, 0] > 50.0  # but at 1.0


def test_a_modelled_infusion_s_duration_moves_its_end_with_exact_derivatives():
    """durations={"center": "D"} with rate −2 (NONMEM's RATE = −2): the amount over
    D(p); J equals the record with the infusion at amount/D given as data, and ∇J,
    ∇²J equal jax.hessian's and finite differences'."""
    m = ti.Model(
        rhs=lambda x, p, u: jnp.stack([-p[0] * x[0]]),
        output=lambda x, p: x / p[1],
        states=["center"], params=["ke", "v", "D"], outputs=["cp"],
    )  # fmt: skip
    t = np.array([0.5, 1.0, 1.5, 2.5, 4.0, 6.0, 12.5, 13.0, 14.0])
    y = np.array([[2.0, 3.5, 4.5, 4.0, 3.0, 2.0, 1.5, 3.0, 4.5]]).T
    doses = Events.doses([0.0, 12.0], "center", 100.0, rate=-2.0)
    p0 = {"ke": 0.2, "v": 20.0, "D": 1.6}
    pr = ti.Problem(m, ti.Experiment(t, None, y, events=doses), x0=[0.0], p0=p0,
                    substeps=3, durations={"center": "D"})  # fmt: skip
    theta = np.array([0.15, 18.0, 1.6])  # ends at 1.6 and 13.6 (no sample there: a kink)
    given = Events.doses([0.0, 12.0], "center", 100.0, rate=62.5)
    ref = ti.Problem(m, ti.Experiment(t, None, y, events=given), x0=[0.0], p0=p0,
                     substeps=3, fixed=["D"])  # fmt: skip
    assert pr.cost(theta) == pytest.approx(ref.cost(theta[:2]), rel=1e-12)
    reference = autodiff(pr.jax_cost)
    for th in (theta, np.array([0.15, 18.0, 1.2])):  # D = 1.2: its end before the sample at 1.5
        _, g, H = pr.cost_grad_hess(th)
        np.testing.assert_allclose(H, reference(th)[2], rtol=1e-8, atol=1e-10)
        steps = np.diag(1e-6 * th)
        fd = [(pr.cost(th + s) - pr.cost(th - s)) / (2 * s[i]) for i, s in enumerate(steps)]
        np.testing.assert_allclose(g, fd, rtol=1e-5)
    with pytest.raises(ValueError, match="no duration is stated for 'center'"):
        ti.Problem(m, ti.Experiment(t, None, y, events=doses), x0=[0.0], p0=p0)


def test_a_reset_of_every_state_stops_the_infusions_running():
    """NONMEM's EVID 3: every state to 0 and the infusions stopped."""
    m = ti.Model(rhs=lambda x, p, u: -p[0] * x, states=["c"], params=["k"])
    t = np.linspace(0.0, 10.0, 21)
    ev = Events.doses(0.0, "c", 100.0, rate=10.0) + Events.resets(4.0, None)
    sim = ti.simulate(m, {"k": 0.1}, [0.0], ti.Experiment(t, None, np.zeros((21, 1)), events=ev))
    h = list(t).index(4.0)
    assert sim.y[h, 0] > 10.0  # the sample at the reset sees the state before it
    np.testing.assert_array_equal(sim.y[h + 1 :, 0], 0.0)  # nothing runs after it


def _steady_model():
    return ti.Model(
        rhs=lambda x, p, u: jnp.stack([-p[0] * x[0] - 0.02 * x[0] ** 2 / (1 + x[0])]),
        output=lambda x, p: x / p[1], states=["c"], params=["k", "v"], outputs=["cp"],
    )  # fmt: skip


T_SS = np.array([0.5, 2.0, 6.0, 11.0, 14.0])
Y_SS = np.array([[9.0, 8.0, 6.0, 4.0, 8.5]]).T


def test_a_steady_state_dose_starts_from_its_cycle():
    """NONMEM's SS = 1: the states at the dose are those of the dose given every II for
    ever (a bolus: A e^{-k II} / (1 − e^{-k II}) before it, for elimination k); an
    infusion at steady state matches a long dosing history."""
    linear = ti.Model(rhs=lambda x, p, u: -p[0] * x, output=lambda x, p: x / p[1],
                      states=["c"], params=["k", "v"], outputs=["cp"])  # fmt: skip
    ss = Events.doses(0.0, "c", 100.0, ii=12.0, addl=1, ss=True)
    e = ti.Experiment(T_SS, None, Y_SS, events=ss)
    sim = ti.simulate(linear, {"k": 0.1, "v": 10.0}, [0.0], e, substeps=16)
    q = np.exp(-0.1 * 12.0)
    trough = 100.0 * q / (1 - q)
    h = list(e.t).index(0.5)
    assert sim.x[h, 0] == pytest.approx((trough + 100.0) * np.exp(-0.05), rel=1e-6)
    # an infusion at steady state (2 h of every 12) against 30 cycles of history
    m = _steady_model()
    inf = Events.doses(0.0, "c", 100.0, rate=50.0, ii=12.0, addl=1, ss=True)
    history = Events.doses(-360.0, "c", 100.0, rate=50.0, ii=12.0, addl=31)
    e1 = ti.Experiment(T_SS, None, Y_SS, events=inf)
    e2 = ti.Experiment(np.concatenate([[-360.0], T_SS]), None, np.vstack([[0.0], Y_SS]),
                       events=history)  # fmt: skip
    at = {"k": 0.12, "v": 9.0}
    a = ti.simulate(m, at, [0.0], e1, substeps=32).y[list(e1.t).index(0.5) :]
    b = ti.simulate(m, at, [0.0], e2, substeps=32).y[list(e2.t).index(0.5) :]
    np.testing.assert_allclose(a[: len(b)], b[: len(a)], rtol=1e-4)
    with pytest.raises(ValueError, match="II > 0"):
        Events.doses(0.0, "c", 100.0, ss=True)


@pytest.mark.slow  # two Hessian programs through the steady state (5 s)
def test_the_derivatives_through_a_steady_state_are_exact():
    """The gradient and Hessian through the steady state (a nonlinear model: Newton on
    the dosing cycle, differentiated by the implicit function's rule) equal
    jax.hessian's and finite differences' (of the cost, and of the exact gradient:
    jax.hessian uses the same rule, finite differences do not)."""
    ss = Events.doses(0.0, "c", 100.0, ii=12.0, addl=1, ss=True)
    e = ti.Experiment(T_SS, None, Y_SS, events=ss)
    pr = ti.Problem(_steady_model(), e, p0={"k": 0.1, "v": 10.0}, x0=[0.0], substeps=4)
    theta = np.array([0.12, 9.0])
    _, g, H = pr.cost_grad_hess(theta)
    np.testing.assert_allclose(H, autodiff(pr.jax_cost)(theta)[2], rtol=1e-8)
    steps = np.diag(1e-6 * theta)
    fd = [(pr.cost(theta + s) - pr.cost(theta - s)) / (2 * s[i]) for i, s in enumerate(steps)]
    np.testing.assert_allclose(g, fd, rtol=1e-5)
    grad = lambda th: pr.cost_grad_hess(th)[1]  # noqa: E731
    fdH = np.array([(grad(theta + s) - grad(theta - s)) / (2 * s[i]) for i, s in enumerate(steps)])
    np.testing.assert_allclose(H, fdH, rtol=1e-5, atol=1e-6 * np.abs(H).max())


def test_a_steady_state_is_converged_at_any_scale_and_needs_an_explicit_scheme():
    """Newton stops when its step is small against x_ss itself: a saturable model in
    units of 1e-15 reaches the steady state that the same model in units of 1 does,
    scaled (an absolute floor had stopped it after one step, 1.4e-5 off). A scheme
    the cycle cannot take is named in one line, by simulate too."""

    def ss_state(scale, scheme="rk4"):
        m = ti.Model(rhs=lambda x, p, u: -p[0] * x / (scale + x), output=lambda x, p: x,
                     states=["c"], params=["vm"], outputs=["c"])  # fmt: skip
        e = ti.Experiment(
            T_SS[:2],
            None,
            Y_SS[:2],
            events=Events.doses(0.0, "c", 5 * scale, ii=12.0, addl=1, ss=True),
        )
        return ti.simulate(m, {"vm": scale}, [0.0], e, substeps=4, scheme=scheme).x[1, 0]

    assert ss_state(1e-15) / 1e-15 == pytest.approx(ss_state(1.0), rel=1e-12)
    with pytest.raises(ValueError, match="steady-state doses take an explicit fixed-step"):
        ss_state(1.0, "dopri5")


def _equations(jaxpr) -> int:
    """The equations of a jaxpr, those of the loops and branches inside it counted."""
    n = 0
    for eq in jaxpr.eqns:
        n += 1
        for v in eq.params.values():
            for sub in v if isinstance(v, list | tuple) else [v]:
                inner = getattr(sub, "jaxpr", sub)
                n += _equations(inner) if hasattr(inner, "eqns") else 0
    return n


def test_no_newton_step_is_differentiated_through_a_steady_state():
    """x_ss's derivatives are the implicit function's (steady.py's rule): the Hessian's
    program through a steady-state dose stays a few times the one through a plain dose
    (differentiating the six Newton steps made it 63 times: its compile took minutes)."""
    sizes = []
    for ss in (True, False):
        ev = Events.doses(0.0, "c", 100.0, ii=12.0, addl=1, ss=ss)
        pr = ti.Problem(_steady_model(), ti.Experiment(T_SS, None, Y_SS, events=ev),
                        p0={"k": 0.1, "v": 10.0}, x0=[0.0], substeps=4)  # fmt: skip
        sizes.append(_equations(jax.make_jaxpr(jax.hessian(pr.jax_cost))(jnp.ones(2)).jaxpr))
    assert sizes[0] < 12 * sizes[1], sizes


def test_an_output_not_finite_at_a_dose_s_row_is_no_failure_and_no_sample():
    """log c is −∞ at the first dose's row (nothing is in the body yet), which holds no
    observation: the simulation is not a failure there (compare and simulate had
    exited 1, "not finite at sample 0"), and the data sensitivity, the scores and the
    robust loss's noise level count the 11 observations alone (the doses' rows had
    been the samples that "pulled most", and the Huber scale came from their zeros)."""
    from tensorid.engine.sweeping.losses import robust_sd
    from tensorid.fitting.robust import residual_noise

    m = ti.Model(rhs=lambda x, p, u: jnp.stack([-p[0] * x[0], p[0] * x[0] - p[1] * x[1]]),
                 output=lambda x, p: jnp.log(x[1:] / p[2]), states=["depot", "center"],
                 params=["ka", "ke", "v"], outputs=["log cp"])  # fmt: skip
    truth = {"ka": 1.1, "ke": 0.15, "v": 9.0}
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)  # ("stops being finite at sample 0")
        sim = ti.simulate(m, truth, [0, 0], _record(), substeps=8)
    assert sim.status.name == "OK" and np.isneginf(sim.y[0, 0])
    seen = _record().observed[:, 0]
    noise = 0.02 * np.random.default_rng(4).standard_normal((seen.sum(), 1))
    e = _record(sim.y[seen] + noise)
    res = ti.fit(ti.Problem(m, e, p0={"ka": 1.5, "ke": 0.2, "v": 7.0}, x0=[0, 0], substeps=8))
    assert res.success and res.simulate()[0].status.name == "OK"
    sens = res.data_sensitivity()
    assert f"{T_OBS.size} samples" in sens.blocks()[0]
    for name in res.problem.theta_names:
        for by in ("pull", "scaled"):
            assert all(seen[k] for _, k, _, _ in sens.most_influential(name, 5, by))
    [score] = training_scores(res)
    assert score.samples == T_OBS.size and np.isfinite(score.gof["log cp"])
    r = e.measured[seen, 0] - res.simulate()[0].y[seen, 0]
    assert residual_noise(res)[0] == robust_sd(r)


def test_a_huber_scale_below_the_residuals_counts_the_measured_samples():
    """The sandwich's bread for a Huber scale below what the residuals resolve counts
    the 40 observations, not the 3 added rows of the doses (where log c is −∞ at the
    first: its error bars had been inf)."""
    from tensorid.analysis.sandwich import unresolved_scale

    t, rng = np.linspace(0.5, 24, 40), np.random.default_rng(0)
    times, amounts = [0.0, 6.25, 12.25], [100.0, 50.0, 50.0]
    c = sum(np.where(t >= d, a / 10 * np.exp(-0.2 * (t - d)), 0)
            for d, a in zip(times, amounts, strict=True))  # fmt: skip
    e = ti.Experiment(t, None, (np.log(c) + 0.02 * rng.standard_normal(t.size))[:, None],
                      events=Events.doses(times, "a", amounts))  # fmt: skip
    m = ti.Model(rhs=lambda x, p, u: -p[0] / p[1] * x, output=lambda x, p: jnp.log(x / p[1]),
                 states=["a"], params=["cl", "v"], outputs=["log c"])  # fmt: skip
    pr = ti.Problem(m, e, p0={"cl": 2.0, "v": 10.0}, x0=[0.0], loss="huber", loss_scale=0.001)
    res = ti.fit(pr)
    H, why = unresolved_scale(pr, res.theta)
    assert e.P == 43 and "of 40 residuals inside" in why and np.isfinite(H).all()
    assert np.isfinite(res.uncertainty().stderr).all()


def test_a_simulation_whose_log_output_is_minus_inf_before_the_first_dose_is_no_blow_up():
    """log c at the first dose's row, c = 0 before the dose: the warning said "the
    simulation stops being finite at sample 0", of a simulation finite ever after."""
    m = ti.Model(rhs=lambda x, p, u: -p[0] * x, output=lambda x, p: jnp.log(x[:1] / p[1]),
                 states=["c"], params=["k", "v"], outputs=["logc"])  # fmt: skip
    e = ti.Experiment(
        np.arange(1.0, 24.0), None, None, events=ti.Events.doses([0.0, 12.0], "c", 100.0)
    )
    with pytest.warns(RuntimeWarning, match="not finite at 1 of the 24 samples.*not a blow-up"):
        sim = ti.simulate(m, {"k": 0.1, "v": 10.0}, [0.0], e)
    assert np.isneginf(sim.y[0, 0]) and np.isfinite(sim.y[1:]).all()
    np.testing.assert_allclose(sim.y[1, 0], np.log(10.0) - 0.1)


def test_reverse_mode_through_jax_cost_skips_a_log_output_where_it_is_minus_inf():
    """c is 0 before the first dose: log c is -inf at the dose's own row, where nothing
    is measured. The sweeps skipped the row, but jax.grad of Problem.jax_cost met
    0 · ∞ in log's derivative there and was NaN."""
    m = ti.Model(rhs=lambda x, p, u: -p[0] * x, states=["c"], params=["k", "v"],
                 output=lambda x, p: jnp.stack([x[0] / p[1], jnp.log(x[0] / p[1])]),
                 outputs=["c", "logc"])  # fmt: skip
    t = np.array([1.0, 2.0, 4.0, 6.0, 8.0])
    c = 10.0 * np.exp(-0.2 * t) + 5.0 * np.exp(-0.2 * (t - 3)) * (t > 3)
    seen = np.stack([t > 0, t != 2], axis=1)  # logc not measured at t = 2 (c is > 0)
    ev = ti.Events.doses([0.0, 3.0], "c", [100.0, 50.0])  # rows of a dose alone
    e = ti.Experiment(t, None, np.stack([c, np.log(c)], axis=1), observed=seen, events=ev)
    prob = ti.Problem(m, e, p0={"k": 0.25, "v": 9.0}, x0=[0.0])
    theta = prob.theta0
    J, g, H = prob.cost_grad_hess(theta)
    J_ad, g_ad, H_ad = autodiff(prob.jax_cost)(jnp.asarray(theta))
    assert np.isfinite([J, *g, *H.ravel()]).all()
    np.testing.assert_allclose([J_ad, *g_ad], [J, *g], rtol=1e-10)
    np.testing.assert_allclose(H_ad, H, rtol=1e-8)


def test_a_steady_state_near_saturation_is_found_or_refused_never_wrong():
    """Michaelis-Menten elimination, 100 every 12 h against Vmax 8.4/h: Newton from 0
    needs about 15 steps, and stopped after 6 at 1228 where the steady state is 1292
    (phenytoin's case), silently. It is now found to the cycle's accuracy (here against
    brentq on the cycle of scipy's solve_ivp), and a dose rate above Vmax, which has no
    steady state, is a failed simulation (NaN), not a number."""
    from scipy.integrate import solve_ivp
    from scipy.optimize import brentq

    m = ti.Model(rhs=lambda x, p, u: -p[0] * x / (10.0 + x), output=lambda x, p: x,
                 states=["c"], params=["vm"], outputs=["c"])  # fmt: skip
    e = ti.Experiment(np.array([0.0, 1.0]), None, np.zeros((2, 1)),
                      events=Events.doses(0.0, "c", 100.0, ii=12.0, addl=1, ss=True))  # fmt: skip

    def after(z, hours, vm=8.4):
        f = solve_ivp(lambda t, x: -vm * x / (10 + x), (0, hours), [z + 100], rtol=1e-12,
                      atol=1e-10)  # fmt: skip
        return f.y[0, -1]

    trough = brentq(lambda z: after(z, 12) - z, 0, 1e5, xtol=1e-10)
    sim = ti.simulate(m, {"vm": 8.4}, [0.0], e, substeps=64)
    assert sim.x[1, 0] == pytest.approx(after(trough, 1), rel=1e-6)
    with pytest.warns(RuntimeWarning, match="stops being finite"):
        none = ti.simulate(m, {"vm": 5.0}, [0.0], e, substeps=64)
    assert np.isnan(none.x[1, 0])


def _oral(substeps=None):
    """Four oral doses 12 h apart, sampled from 0.5 h to 60 h: RK4 with 4 substeps takes
    12-h steps of 3 h, too coarse for ka = 1/h."""
    ka, cl, v = 1.0, 2.5, 25.0
    m = ti.Model(rhs=lambda x, p, u: jnp.stack([-p[0] * x[0], p[0] * x[0] - p[1] / p[2] * x[1]]),
                 output=lambda x, p: x[1:] / p[2], states=["depot", "central"],
                 params=["ka", "cl", "v"], outputs=["cp"])  # fmt: skip
    t = np.array([0.5, 1, 2, 4, 8, 12, 12.5, 13, 18, 24, 30, 36, 48, 60])
    k = cl / v
    c = sum(100 * ka / (v * (ka - k)) * (np.exp(-k * (t - d)) - np.exp(-ka * (t - d))) * (t > d)
            for d in (0, 12, 24, 36))  # fmt: skip
    y = (c * (1 + 0.02 * np.random.default_rng(0).standard_normal(14)))[:, None]
    e = ti.Experiment(t, None, y, events=Events.doses(0.0, "depot", 100.0, ii=12.0, addl=3))
    return ti.Problem(m, e, p0={"ka": 1.0, "cl": 2.5, "v": 25.0}, x0=[0.0, 0.0], substeps=substeps)


def test_a_fit_whose_default_substeps_are_too_coarse_for_its_intervals_refits_finer():
    """A fit of one system's event record at the default substeps converged to the
    scheme's answer (ka 0.76 for 1.0 in the helper's noise-free case), with no word: the
    fleet's substeps check is now a single fit's too. Raised from 4 to 16, the fit
    recovers the model's answer and says so; substeps the user chose are kept, with a
    note that they are too coarse."""
    res = ti.fit(_oral())
    assert res.problem.discretisation.substeps == 16
    assert abs(res.params["ka"] - 1.0) < 0.05 and abs(res.params["v"] - 25.0) < 1.0
    assert any("substeps were raised from 4 to 16" in n for n in res.notes)
    with ThreadPoolExecutor(1) as pool:  # (no process to spawn)
        ranked = ti.fit(_oral(), starts=2, executor=pool)  # the refit keeps their ranking
    assert len(ranked.starts) == 2 and ranked.problem.discretisation.substeps == 16
    kept = ti.fit(_oral(substeps=4))
    assert kept.problem.discretisation.substeps == 4 and abs(kept.params["ka"] - 1.0) > 0.1
    assert any("integrated too coarsely" in n for n in kept.notes)


def test_a_dose_between_samples_leaves_held_inputs_held():
    """With inputs held (zoh), a dose into another state between two samples made a
    row whose input was interpolated (0.5 at t = 5 between 0 and 1), and the output
    that reads the input changed; it is now the row before's, as without the dose."""
    m = ti.Model(rhs=lambda x, p, u: jnp.stack([-p[0] * x[0], u[0] - p[0] * x[1]]),
                 output=lambda x, p: x[1:], states=["a", "b"], params=["k"], inputs=["u"],
                 outputs=["y"])  # fmt: skip
    t, u = np.array([0.0, 10.0, 20.0]), np.array([[0.0], [1.0], [1.0]])

    def y(events, interpolation):
        e = ti.Experiment(t, u, events=events)
        sim = ti.simulate(m, {"k": 0.1}, [0.0, 0.0], e, interpolation=interpolation, substeps=32)
        return sim.y[np.isin(sim.t, t), 0]

    dose = Events.doses(5.0, "a", 5.0)
    np.testing.assert_allclose(y(dose, "zoh"), y(None, "zoh"), rtol=1e-12)
    np.testing.assert_allclose(y(dose, "zoh")[-1], 10 * (1 - np.exp(-1.0)), rtol=1e-8)
    np.testing.assert_allclose(y(dose, "linear"), y(None, "linear"), rtol=1e-8)
    half = ti.Experiment(t, u, events=dose).window(0, 3)  # a window keeps the row added
    assert np.array_equal(half.inputs_held("zoh")[:, 0], [0.0, 0.0, 1.0])


def test_a_repeated_dose_s_time_is_its_row_s_to_rounding():
    """II 0.7 from 0: the third repeat is 3 × 0.7 = 2.0999999999999996, which made a
    node of its own just before the row at 2.1, whose observation then saw the dose
    (the trough rule broken). It is now at the row, after its observation."""
    e = ti.Experiment(np.array([0.0, 1.4, 2.1]), None, np.ones((3, 1)),
                      events=Events.doses(0.0, "c", 100.0, ii=0.7, addl=3))  # fmt: skip
    assert np.array_equal(e.t, [0.0, 0.7, 1.4, 2.1])
    m = ti.Model(rhs=lambda x, p, u: -p[0] * x, output=lambda x, p: x, states=["c"],
                 params=["k"], outputs=["c"])  # fmt: skip
    c = ti.simulate(m, {"k": 0.1}, [0.0], e).x[:, 0]
    trough = 100 * sum(np.exp(-0.1 * (2.1 - d)) for d in (0.0, 0.7, 1.4))
    assert c[-1] == pytest.approx(trough, rel=1e-6)


def test_doses_given_together_meet_an_amount_not_linear_in_amt_with_one_line():
    """Two doses of 100 at one time into one state were summed before the model's
    amount expression: amt/(1 + amt/d50) gave f(200) = 67, not 2 f(100) = 100, with no
    word. A linear one (F · amt) sums as it should; a nonlinear one is refused."""
    m = ti.Model(rhs=lambda x, p, u: -p[0] * x, output=lambda x, p: x, states=["central"],
                 params=["k", "d50"], outputs=["c"])  # fmt: skip
    e = ti.Experiment(np.array([1.0, 2.0]), None, None,
                      events=Events.doses([0.0, 0.0], "central", [100.0, 100.0]))  # fmt: skip
    p = {"k": 0.1, "d50": 100.0}
    linear = ti.simulate(m, p, [0.0], e, doses={"central": "d50 / 100 * amt"})
    assert linear.y[-1, 0] == pytest.approx(200 * np.exp(-0.2), rel=1e-6)
    with pytest.raises(ValueError, match="not linear in amt, and two doses into it at t = 0"):
        ti.simulate(m, p, [0.0], e, doses={"central": "amt / (1 + amt / d50)"})


def test_a_steady_state_beside_a_state_a_billion_times_larger_and_epoch_times():
    """Newton's step was judged against the largest state: beside 5e9 cells/L, the
    drug's state "converged" at 4.25 where it is 12.9 (brentq on scipy's cycle here).
    And an event 1 s before a row at epoch seconds (1.7e9) was moved onto the row (a
    tolerance of 1e-9 · |t|)."""
    from scipy.integrate import solve_ivp
    from scipy.optimize import brentq

    def after(z, hours):
        f = solve_ivp(lambda t, x: -0.084 * x / (0.1 + x), (0, hours), [z + 1.0], rtol=1e-12,
                      atol=1e-12)  # fmt: skip
        return f.y[0, -1]

    trough = brentq(lambda z: after(z, 12) - z, 0, 1e3, xtol=1e-12)
    m = ti.Model(rhs=lambda x, p, u: jnp.stack([-p[0] * x[0] / (0.1 + x[0]), 5e8 - 0.1 * x[1]]),
                 output=lambda x, p: x[:1], states=["c", "cells"], params=["vm"],
                 outputs=["c"])  # fmt: skip
    e = ti.Experiment(np.array([0.0, 1.0]), None, None,
                      events=Events.doses(0.0, "c", 1.0, ii=12.0, addl=1, ss=True))  # fmt: skip
    c = ti.simulate(m, {"vm": 0.084}, [0.0, 0.0], e, substeps=16).x[1, 0]
    assert c == pytest.approx(after(trough, 1), rel=1e-6)
    t0 = 1.7e9
    e = ti.Experiment(t0 + np.array([0.0, 3600.0, 7200.0]), None, None,
                      events=Events.doses([t0, t0 + 3599.0], "c", 100.0))  # fmt: skip
    assert t0 + 3599.0 in e.t and e.P == 4


def test_summed_doses_are_checked_with_a_lag_elsewhere_and_a_parameter_named_as_sympy():
    """The check of doses given together was skipped when another state had a lag (its
    grid sums them too), and a parameter named like a SymPy function (ff) could not be
    parsed by it."""
    m = ti.Model(rhs=lambda x, p, u: jnp.stack([-x[0], x[0] - p[0] * x[1]]),
                 output=lambda x, p: x[1:], states=["depot", "central"],
                 params=["k", "d50", "tlag", "ff"], outputs=["c"])  # fmt: skip
    e = ti.Experiment(np.array([1.0, 2.0]), None, None,
                      events=Events.doses([0.0, 0.0], "central", [100.0, 100.0]))  # fmt: skip
    p = {"k": 0.1, "d50": 100.0, "tlag": 0.5, "ff": 1.0}
    with pytest.raises(ValueError, match="not linear in amt, and two doses into it"):
        ti.simulate(m, p, [0.0, 0.0], e, doses={"central": "amt / (1 + amt / d50)"},
                    lags={"depot": "tlag"})  # fmt: skip
    both = ti.simulate(m, p, [0.0, 0.0], e, doses={"central": "ff * amt"})
    assert both.y[-1, 0] == pytest.approx(200 * np.exp(-0.2), rel=1e-6)
