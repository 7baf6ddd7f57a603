"""Every bad input gets a clear error that names the problem, before any compilation."""

from __future__ import annotations

import math

import jax.numpy as jnp
import numpy as np
import pytest
from conftest import SILVERBOX_P, silverbox_model

import tensorid as ti

T = np.arange(20) * 0.01
U = np.sin(T)
Y = np.cos(T)


_model = silverbox_model


def _problem(**kw):
    args = dict(p0=SILVERBOX_P, x0=[0.0, 0.0])
    args.update(kw)
    return ti.Problem(silverbox_model(), ti.Experiment(T, U, Y), **args)


# -- data ----------------------------------------------------------------------------
@pytest.mark.parametrize(
    "field,bad,match",
    [
        ("y", np.where(np.arange(20) == 7, np.nan, Y), "y contains NaN .* sample 7"),
        ("u", np.where(np.arange(20) == 3, np.inf, U), "u contains inf .* sample 3"),
        ("t", np.where(np.arange(20) == 5, np.nan, T), "t contains NaN"),
    ],
)
def test_non_finite_data(field, bad, match):
    kw = {"t": T, "u": U, "y": Y, field: bad}
    with pytest.raises(ValueError, match=match):
        ti.Experiment(**kw)


@pytest.mark.parametrize(
    "t,match",
    [
        (np.r_[T[:5], T[4], T[6:]], "strictly increasing, but it repeats at sample 5"),
        (np.r_[T[:5], T[3], T[6:]], "strictly increasing, but it goes backwards at sample 5"),
    ],
)
def test_time_not_strictly_increasing(t, match):
    with pytest.raises(ValueError, match=match):
        ti.Experiment(t, U, Y)


def test_lengths_disagree():
    with pytest.raises(ValueError, match="u has 19 samples but t has 20"):
        ti.Experiment(T, U[:-1], Y)
    with pytest.raises(ValueError, match="y has 21 samples but t has 20"):
        ti.Experiment(T, U, np.r_[Y, 0.0])
    with pytest.raises(ValueError, match="transposed"):
        ti.Experiment(T, np.stack([U, U]), Y)


def test_empty_or_tiny_data():
    with pytest.raises(ValueError, match="at least 2 samples"):
        ti.Experiment(np.array([]), np.array([]), np.array([]))


def test_data_channels_disagree_with_model():
    with pytest.raises(ValueError, match="2 input column.* model has 1 inputs"):
        ti.Problem(silverbox_model(), ti.Experiment(T, np.stack([U, U], 1), Y), p0=SILVERBOX_P)
    with pytest.raises(ValueError, match="2 output column.* model has 1 outputs"):
        ti.Problem(silverbox_model(), ti.Experiment(T, U, np.stack([Y, Y], 1)), p0=SILVERBOX_P)
    with pytest.raises(ValueError, match="no measured outputs"):
        ti.Problem(silverbox_model(), ti.Experiment(T, U), p0=SILVERBOX_P)


# -- model ---------------------------------------------------------------------------
def test_rhs_wrong_shape():
    with pytest.raises(ValueError, match=r"rhs returned shape \(3,\) but the model has 2 states"):
        _model(rhs=lambda x, p, u: jnp.zeros(3))
    with pytest.raises(ValueError, match=r"rhs returned shape \(2, 1\)"):
        _model(rhs=lambda x, p, u: jnp.zeros((2, 1)))


def test_output_wrong_shape():
    with pytest.raises(ValueError, match=r"output returned shape \(2,\) but the model has 1 "):
        _model(output=lambda x, p: x)


def test_scalar_output_is_accepted_for_one_output():
    m = _model(output=lambda x, p: x[0])
    assert m.h(jnp.array([1.0, 2.0]), jnp.zeros(4)).shape == (1,)


def test_rhs_wrong_dtype():
    with pytest.raises(TypeError, match="rhs returned dtype"):
        _model(rhs=lambda x, p, u: jnp.array([1, 2]))


def test_rhs_that_jax_cannot_trace():
    def rhs(x, p, u):
        if x[0] > 0:  # Python control flow on a traced value
            return x
        return -x

    with pytest.raises(TypeError, match="cannot be traced by JAX.*jnp.where"):
        _model(rhs=rhs)
    with pytest.raises(TypeError, match="cannot be traced by JAX.*instead of numpy or math"):
        _model(rhs=lambda x, p, u: jnp.stack([math.sin(x[0]), x[1]]))


def test_rhs_with_a_bug_shows_the_error():
    with pytest.raises(TypeError, match="rhs failed when called with x of shape.*NameError"):
        _model(rhs=lambda x, p, u: jnp.stack([x[1], undefined_name]))  # noqa: F821


def test_index_past_the_end_is_caught_although_jax_would_clamp_it():
    with pytest.raises(ValueError, match=r"rhs indexes past the end.*4 params \['m', 'd'"):
        _model(rhs=lambda x, p, u: jnp.stack([x[1], p[7] * x[0]]))
    with pytest.raises(ValueError, match="output indexes past the end"):
        _model(output=lambda x, p: x[2:3] + x[5])


def test_names():
    with pytest.raises(ValueError, match="both as a state and as a parameter"):
        _model(params=["m", "d", "a", "y"])
    with pytest.raises(ValueError, match="repeated names"):
        _model(states=["y", "y"])
    with pytest.raises(TypeError, match="list of names"):
        _model(inputs="u")


# -- problem -------------------------------------------------------------------------
def test_unknown_names():
    with pytest.raises(ValueError, match=r"free_x0 names unknown states \['w'\]"):
        _problem(free_x0=["w"])
    with pytest.raises(ValueError, match=r"fixed names unknown params \['k'\]"):
        _problem(fixed=["k"])
    with pytest.raises(ValueError, match=r"bounds names unknown params or states \['k'\]"):
        _problem(bounds={"k": (0, 1)})
    with pytest.raises(ValueError, match=r"p0 names unknown entries \['k'\]"):
        _problem(p0=dict(SILVERBOX_P, k=1.0))
    with pytest.raises(ValueError, match=r"p0 is missing values for \['b'\]"):
        _problem(p0={k: v for k, v in SILVERBOX_P.items() if k != "b"})
    with pytest.raises(ValueError, match="weights names unknown outputs"):
        _problem(weights={"z": 1.0})


def test_p0_outside_bounds():
    with pytest.raises(ValueError, match=r"p0\['a'\] = 0.9675 is outside its bounds \(0, 0.5\)"):
        _problem(bounds={"a": (0, 0.5)})
    with pytest.raises(ValueError, match=r"x0\['v'\] = 0 is outside its bounds"):
        _problem(free_x0=["v"], bounds={"v": (1, 2)})


def test_bounds_lo_above_hi():
    with pytest.raises(ValueError, match=r"bounds\['a'\] = \(2.0, 1.0\) has lo > hi"):
        _problem(bounds={"a": (2, 1)})
    with pytest.raises(ValueError, match="must be a pair"):
        _problem(bounds={"a": 1.0})


def test_bounds_on_fixed_or_non_free_entries():
    with pytest.raises(ValueError, match="which is fixed"):
        _problem(fixed=["a"], bounds={"a": (0, 2)})
    with pytest.raises(ValueError, match="not in free_x0"):
        _problem(bounds={"v": (0, 2)})


def test_shapes_of_p0_and_x0():
    with pytest.raises(ValueError, match=r"p0 has 3 values but there are 4"):
        _problem(p0=[1.0, 2.0, 3.0])
    with pytest.raises(ValueError, match=r"x0 has 3 values but there are 2"):
        _problem(x0=[0.0, 0.0, 0.0])
    with pytest.raises(ValueError, match="p0 is required"):
        _problem(p0=None)
    with pytest.raises(ValueError, match="non-finite"):
        _problem(p0=dict(SILVERBOX_P, a=np.nan))


def test_nothing_to_estimate_and_bad_settings():
    with pytest.raises(ValueError, match="nothing to estimate"):
        _problem(fixed=["m", "d", "a", "b"])
    with pytest.raises(ValueError, match="substeps must be a positive integer"):
        _problem(substeps=0)
    with pytest.raises(ValueError, match="interpolation must be one of"):
        _problem(interpolation="quintic")
    with pytest.raises(ValueError, match="unknown integration scheme"):
        _problem(scheme="rk45")


def test_theta_of_wrong_length():
    with pytest.raises(ValueError, match="theta must have 4 entries"):
        _problem().cost_grad_hess([1.0, 2.0])
