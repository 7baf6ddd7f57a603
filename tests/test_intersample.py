"""The input between samples: "cubic", "bandlimited" and "periodic" give the signal a
multisine's samples came from (or a cubic polynomial's), the march integrates that
signal, and every setting that takes an interpolation name takes them."""

from __future__ import annotations

import json

import jax.numpy as jnp
import numpy as np
import pytest

import tensorid as ti
from tensorid.engine import intersample
from tensorid.engine.schemes.discretisation import Discretisation, input_at

TS = 0.01


def tones(P, harmonics, seed=0, period=None):
    """(u(t), its frequencies (rad/s), amplitudes, phases): a multisine of the given
    harmonics of 1/period (default: the record, P samples, so it holds whole periods)."""
    rng = np.random.default_rng(seed)
    period = P * TS if period is None else period
    w = 2 * np.pi * np.asarray(harmonics, dtype=float) / period
    a, ph = rng.uniform(0.5, 1.0, w.size) / np.sqrt(w.size), rng.uniform(0, 2 * np.pi, w.size)

    def u(t):
        return np.cos(np.outer(t, w) + ph) @ a

    return u, w, a, ph


def between(kind, t, u, s):
    """The input the march sees at fraction s of every interval."""
    model = ti.Model(lambda x, p, u: -x, lambda x, p: x, ["x"], ["k"], inputs=["u"], outputs=["y"])
    track = Discretisation.of(interpolation=kind).inputs(model, t, u[:, None])
    rows = jnp.asarray(track[:-1])
    nxt = jnp.asarray(track[1:])
    return np.array([float(input_at(rows[h], nxt[h], s, kind)[0]) for h in range(len(t) - 1)])


def test_periodic_is_the_multisine_between_its_samples():
    """Harmonics up to 90 % of the Nyquist frequency, whole periods: the trigonometric
    interpolant is the signal itself, at every interval, the ends included."""
    P = 200
    u, *_ = tones(P, range(1, 90))
    t = np.arange(P) * TS
    for s in (0.5, 0.137):
        got = between("periodic", t, u(t), s)
        np.testing.assert_allclose(got, u(t[:-1] + s * TS), rtol=0, atol=1e-12)
    linear = between("linear", t, u(t), 0.5)
    assert np.abs(linear - u(t[:-1] + 0.5 * TS)).max() > 0.1  # what linear makes of it


def test_bandlimited_is_the_signal_away_from_the_ends_of_any_record():
    """Not whole periods (non-integer harmonics), content up to half the Nyquist
    frequency: the windowed sinc is the signal to 1e-7 beyond its TAPS samples from
    each end, and at the ends still better than linear interpolation."""
    P = 300
    u, *_ = tones(P, np.arange(1, 75) + 0.37, seed=2)
    t = np.arange(P) * TS
    truth = u(t[:-1] + 0.5 * TS)
    got = between("bandlimited", t, u(t), 0.5)
    err = np.abs(got - truth)
    inner = slice(intersample.TAPS, -intersample.TAPS)
    assert err[inner].max() < 1e-7 * np.abs(truth).max()
    lin = np.abs(between("linear", t, u(t), 0.5) - truth)
    assert err.max() < lin.max() / 3
    assert np.sqrt(np.mean(err**2)) < np.sqrt(np.mean(lin**2)) / 30  # 1/77 measured


def test_cubic_reproduces_a_cubic_polynomial_on_any_grid():
    rng = np.random.default_rng(3)
    t = np.sort(rng.uniform(0, 3, 25))
    poly = np.polynomial.Polynomial([1.0, -2.0, 0.5, -0.3])
    track = intersample.coefficients(t, poly(t), "cubic")
    for s in (0.0, 0.3, 0.5, 0.91):
        tq = t[:-1] + s * np.diff(t)
        got = [float(intersample.chebyshev_at(jnp.asarray(track[h]), s)[0]) for h in range(24)]
        np.testing.assert_allclose(got, poly(tq), rtol=0, atol=1e-12)
    # and a delay is read from the same spline
    np.testing.assert_allclose(
        intersample.evaluate(track, t, t[5:] - 0.01, "cubic")[:, 0], poly(t[5:] - 0.01), atol=1e-12
    )


def first_order():
    return ti.Model(
        rhs=lambda x, p, u: -p[0] * x + p[1] * u,
        output=lambda x, p: x,
        states=["x"],
        params=["a", "b"],
        inputs=["u"],
        outputs=["y"],
    )


def test_the_march_integrates_the_interpolated_input():
    """x' = −a x + b u with u a multisine of whole periods (to 40 % of the Nyquist
    frequency) from its periodic steady state: 'periodic' simulates the exact response
    to RK4's error everywhere, 'bandlimited' beyond its edge intervals; the others
    not."""
    P, a, b = 256, 20.0, 2.0
    u, w, amp, ph = tones(P, range(1, 100), seed=4)
    t = np.arange(P) * TS
    gain = b * amp / np.sqrt(a**2 + w**2)
    steady = np.cos(np.outer(t, w) + ph - np.arctan2(w, a)) @ gain
    data = ti.Experiment(t, u(t))
    err, inner = {}, slice(2 * intersample.TAPS, -2 * intersample.TAPS)
    for kind in ("periodic", "bandlimited", "cubic", "linear", "zoh"):
        sim = ti.simulate(first_order(), {"a": a, "b": b}, [steady[0]], data,
                          interpolation=kind, substeps=8)  # fmt: skip
        err[kind] = np.abs(sim.y[:, 0] - steady)
    scale = np.abs(steady).max()
    assert err["periodic"].max() < 1e-6 * scale  # 3.5e-7 measured: RK4's
    assert err["bandlimited"][inner].max() < 1e-6 * scale
    worst = {k: e.max() for k, e in err.items()}
    assert worst["periodic"] < 1e-3 * worst["cubic"]
    assert worst["cubic"] < worst["linear"] < worst["zoh"]


def test_an_adaptive_scheme_reads_the_input_at_any_fraction():
    P, a, b = 128, 3.0, 2.0
    u, w, amp, ph = tones(P, range(1, 40), seed=5)
    t = np.arange(P) * TS
    gain = b * amp / np.sqrt(a**2 + w**2)
    steady = np.cos(np.outer(t, w) + ph - np.arctan2(w, a)) @ gain
    kw = dict(interpolation="periodic", scheme="dopri5", rtol=1e-10, atol=1e-12)
    sim = ti.simulate(first_order(), {"a": a, "b": b}, [steady[0]], ti.Experiment(t, u(t)), **kw)
    np.testing.assert_allclose(sim.y[:, 0], steady, rtol=0, atol=1e-8)


def test_segments_and_delays_see_the_whole_records_input():
    """A multiple-shooting segment reads its intervals' rows of the whole record (not
    a track of its own slice): the cost with the segments' starts on the simulated
    trajectory equals single shooting's; a whole-sample delay is the record shifted."""
    P = 120
    u, *_ = tones(P, range(1, 40), seed=6)
    t = np.arange(P) * TS
    m = first_order()
    y = ti.simulate(m, {"a": 3.0, "b": 2.0}, [0.1], ti.Experiment(t, u(t)),
                    interpolation="bandlimited").y  # fmt: skip
    data = ti.Experiment(t, u(t), y + 0.01)
    kw = dict(p0={"a": 2.5, "b": 2.2}, x0=[0.1], free_x0=["x"], interpolation="bandlimited")
    single = ti.Problem(m, data, **kw)
    multi = ti.Problem(m, data, segments=3, **kw)
    lifted = multi.shooting.evaluate(multi.shooting.start(multi.theta0, from_data=False))
    np.testing.assert_allclose(lifted.J, single.cost(single.theta0), rtol=1e-10)
    np.testing.assert_allclose(lifted.c, 0.0, atol=1e-12)

    delayed = ti.Model(m.rhs, m.output, ["x"], ["a", "b"], inputs=["u"], outputs=["y"],
                       input_delays={"u": 3 * TS})  # fmt: skip
    shifted = np.concatenate([np.full(3, u(t)[0]), u(t)[:-3]])
    for kind in ("bandlimited", "cubic"):
        a = ti.simulate(delayed, {"a": 3.0, "b": 2.0}, [0.1], ti.Experiment(t, u(t)),
                        interpolation=kind).y  # fmt: skip
        b = ti.simulate(m, {"a": 3.0, "b": 2.0}, [0.1], ti.Experiment(t, shifted),
                        interpolation=kind).y  # fmt: skip
        np.testing.assert_allclose(a, b, rtol=0, atol=1e-12)


def test_unequal_samples_and_misspelt_names_are_one_line():
    t = np.array([0.0, 0.01, 0.02, 0.04, 0.05])
    data = ti.Experiment(t, np.sin(t), np.sin(t))
    with pytest.raises(ValueError, match="needs equally spaced samples.*'cubic'"):
        ti.simulate(first_order(), {"a": 1.0, "b": 1.0}, [0.0], data, interpolation="bandlimited")
    ti.simulate(first_order(), {"a": 1.0, "b": 1.0}, [0.0], data, interpolation="cubic")
    with pytest.raises(ValueError, match="did you mean 'bandlimited'"):
        ti.Problem(first_order(), data, p0={"a": 1.0, "b": 1.0}, interpolation="bandlimted")
    with pytest.raises(ValueError, match="did you mean 'bandlimited'"):
        ti.Problem(first_order(), data, p0={"a": 1.0, "b": 1.0}, interpolation="bl")


def test_a_record_that_is_not_whole_periods_is_warned_of():
    t = np.arange(100) * TS
    with pytest.warns(RuntimeWarning, match="does not look periodic"):
        Discretisation.of(interpolation="periodic").inputs(first_order(), t, t[:, None])


MODEL_FILE = """
rhs = {"x": "-a*x + b*u"}
output = {"y": "x"}
inputs = ["u"]
p0 = {"a": 2.5, "b": 2.2}
x0 = {"x": 0.1}
free_x0 = ["x"]
"""


def test_the_cli_flag_and_the_model_file_key(tmp_path):
    """``interpolation = "periodic"`` in a model file is fitted with (fit.json says so),
    ``--interpolation`` overrides it, and simulate scores with the fit.json's."""
    from tensorid.cli import main

    P = 200
    u, *_ = tones(P, range(1, 60), seed=7)
    t = np.arange(P) * TS
    y = ti.simulate(first_order(), {"a": 3.0, "b": 2.0}, [0.1], ti.Experiment(t, u(t)),
                    interpolation="periodic").y[:, 0]  # fmt: skip
    csv = tmp_path / "rec.csv"
    np.savetxt(csv, np.column_stack([t, u(t), y]), delimiter=",", header="t,u,y", comments="")
    model = tmp_path / "m.py"
    model.write_text(MODEL_FILE + 'interpolation = "periodic"\n')
    runs = {}
    for name, extra in (("file", []), ("flag", ["--interpolation", "bandlimited"])):
        out = tmp_path / name
        args = ["fit", str(model), str(csv), "--out", str(out), "--no-progress", *extra]
        assert main(args) == 0
        runs[name] = json.loads((out / "fit.json").read_text())
    assert runs["file"]["integration"]["interpolation"] == "periodic"
    assert runs["flag"]["integration"]["interpolation"] == "bandlimited"
    # noise-free, whole periods: the file's setting recovers the truth to rounding
    assert abs(runs["file"]["params"]["a"] - 3.0) < 1e-6
    fit_json = str(tmp_path / "file" / "fit.json")
    args = ["simulate", str(model), str(csv), "--params", fit_json, "--out", str(tmp_path / "s")]
    assert main(args) == 0


def test_the_command_line_offers_every_interpolation():
    """The choices are spelled out in app/options.py (so that --help need not import
    JAX): they must be the engine's."""
    import argparse

    from tensorid.app.options import integration_options
    from tensorid.engine.schemes.discretisation import INTERPOLATIONS

    p = argparse.ArgumentParser()
    integration_options(p)
    assert p._option_string_actions["--interpolation"].choices == list(INTERPOLATIONS)
