"""Property-based tests (hypothesis): the data loaders on random and corrupted
files, and the transition tensors on random linear systems, where states and
sensitivities have a closed form through the matrix exponential."""

from __future__ import annotations

import functools
import tempfile
from pathlib import Path

import numpy as np
import pytest
import scipy.io
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays
from scipy.linalg import expm

import tensorid as ti

SETTINGS = settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])

# -- loaders -------------------------------------------------------------------------
LOADER_MODEL = ti.Model(
    rhs=lambda x, p, u: -p[0] * x + u[0] - u[1],
    output=lambda x, p: x,
    states=["x"],
    params=["k"],
    inputs=["u1", "u2"],
    outputs=["y"],
)
finite = st.floats(-1e12, 1e12, allow_nan=False, allow_infinity=False, width=64)


@st.composite
def records(draw):
    P = draw(st.integers(2, 30))
    steps = draw(arrays(float, P - 1, elements=st.floats(1e-6, 1e3)))
    t = np.concatenate([[draw(st.floats(-1e3, 1e3))], np.zeros(P - 1)])
    t[1:] = t[0] + np.cumsum(steps)
    cols = {"t": t}
    for name in ("u1", "u2", "y", "extra"):
        cols[name] = draw(arrays(float, P, elements=finite))
    order = draw(st.permutations(list(cols)))
    if np.any(np.diff(t) <= 0):  # float rounding of large offsets can merge two times
        t[:] = np.arange(P, dtype=float)
    return {k: cols[k] for k in order}


def _write(folder: Path, cols: dict, fmt: str) -> Path:
    path = folder / f"data.{fmt}"
    if fmt == "csv":
        names = list(cols)
        rows = [",".join(names)] + [
            ",".join(repr(float(cols[n][i])) for n in names) for i in range(len(cols["t"]))
        ]
        path.write_text("\n".join(rows) + "\n")
    elif fmt == "npz":
        np.savez(path, **cols)
    else:
        scipy.io.savemat(path, {k: v[None, :] for k, v in cols.items()})
    return path


@SETTINGS
@given(cols=records(), fmt=st.sampled_from(["csv", "npz", "mat"]))
def test_loaders_return_exactly_what_was_written(cols, fmt):
    with tempfile.TemporaryDirectory() as d:
        (e,) = ti.load_data(_write(Path(d), cols, fmt), LOADER_MODEL)
    np.testing.assert_array_equal(e.t, cols["t"])
    np.testing.assert_array_equal(e.u, np.stack([cols["u1"], cols["u2"]], axis=1))
    np.testing.assert_array_equal(e.measured[:, 0], cols["y"])


CORRUPTIONS = ["nan", "inf", "text", "empty", "time-backwards", "time-repeated", "drop-column"]


@SETTINGS
@given(cols=records(), how=st.sampled_from(CORRUPTIONS), data=st.data())
def test_any_corrupted_csv_is_refused_with_a_value_error_that_names_the_problem(cols, how, data):
    P = len(cols["t"])
    i = data.draw(st.integers(0, P - 1))
    col = data.draw(st.sampled_from(["t", "u1", "u2", "y"]))
    cells = {k: [repr(float(v)) for v in a] for k, a in cols.items()}
    if how in ("nan", "inf", "text", "empty"):
        cells[col][i] = {"nan": "nan", "inf": "-inf", "text": "1.2.3", "empty": ""}[how]
        expect = "not a number" if how == "text" else f"column {col!r} has 1 missing"
    elif how.startswith("time"):
        j = data.draw(st.integers(1, P - 1))
        cells["t"][j] = (
            cells["t"][j - 1] if how == "time-repeated" else repr(float(cols["t"][j - 1]) - 1.0)
        )
        expect = "increasing"
    else:
        del cells[col]
        expect = "lacks columns" if col != "t" else "no time column"
    text = "\n".join([",".join(cells)] + [",".join(cells[k][r] for k in cells) for r in range(P)])
    with tempfile.TemporaryDirectory() as d:
        path = Path(d) / "bad.csv"
        path.write_text(text + "\n")
        with pytest.raises(ValueError) as info:
            ti.load_data(path, LOADER_MODEL)
    assert expect in str(info.value), (how, col, str(info.value))


# -- random linear systems against the matrix exponential ----------------------------
T_GRID = np.linspace(0.0, 2.0, 21)


def _linear_model(N: int) -> ti.Model:
    return ti.Model(
        rhs=lambda x, p, u: p.reshape(N, N) @ x,
        output=lambda x, p: x,
        states=[f"x{i}" for i in range(N)],
        params=[f"a{i}{j}" for i in range(N) for j in range(N)],
        outputs=[f"y{i}" for i in range(N)],
    )


@functools.cache
def _linear_problem(N: int, scheme: str) -> ti.Problem:
    """One compiled problem per (N, scheme); θ = (x0, A row-major); observations fixed."""
    rng = np.random.default_rng(N)
    data = ti.Experiment(T_GRID, y=rng.standard_normal((T_GRID.size, N)))
    names = [f"x{i}" for i in range(N)]
    return ti.Problem(
        _linear_model(N),
        data,
        p0=np.zeros(N * N),
        x0=np.ones(N),
        free_x0=names,
        substeps=64,
        scheme=scheme,
        **({"rtol": 1e-12, "atol": 1e-14} if scheme == "dopri5" else {}),
    )


def _second(X, t, P, Q):
    """(1, 3) block of exp([[X, tP, 0], [0, X, tQ], [0, 0, X]]): one ordering of the
    second Fréchet derivative of e^X along tP and tQ."""
    N, Z = X.shape[0], np.zeros_like(X)
    return expm(np.block([[X, t * P, Z], [Z, X, t * Q], [Z, Z, X]]))[:N, 2 * N :]


def _exact(A: np.ndarray, x0: np.ndarray, Y: np.ndarray):
    """J, g, H by the matrix exponential: x(t) = e^{At} x0; ∂x/∂A and ∂²x/∂A² from
    block-triangular exponentials (the Fréchet derivatives of e^{At})."""
    N = A.shape[0]
    K = N + N * N
    units = [np.outer(np.eye(N)[i], np.eye(N)[j]) for i in range(N) for j in range(N)]
    J, g, H = 0.0, np.zeros(K), np.zeros((K, K))
    Z = np.zeros((N, N))
    for t, y in zip(T_GRID, Y, strict=True):
        X = A * t
        E = expm(X)
        # dE[a] = d e^{At} / dA_a
        dE = [expm(np.block([[X, t * U], [Z, X]]))[:N, N:] for U in units]
        S = np.zeros((N, K))
        S[:, :N] = E
        for a in range(N * N):
            S[:, N + a] = dE[a] @ x0
        T = np.zeros((N, K, K))
        for a in range(N * N):
            T[:, :N, N + a] = T[:, N + a, :N] = dE[a]
            for b in range(a, N * N):
                d2 = (_second(X, t, units[a], units[b]) + _second(X, t, units[b], units[a])) @ x0
                T[:, N + a, N + b] = T[:, N + b, N + a] = d2
        r = y - E @ x0
        J += r @ r
        g += -2 * S.T @ r
        H += 2 * S.T @ S - 2 * np.einsum("n,nkl->kl", r, T)
    return J, g, H


@pytest.mark.slow
@settings(max_examples=20, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    N=st.integers(1, 3),
    scheme=st.sampled_from(["rk4", "dopri5"]),
    data=st.data(),
)
def test_random_linear_systems_match_the_matrix_exponential(N, scheme, data):
    A = data.draw(arrays(float, (N, N), elements=st.floats(-1.5, 1.5)))
    x0 = data.draw(arrays(float, N, elements=st.floats(-2.0, 2.0)))
    # dopri5's step control watches the states, not their sensitivities: from x0 = 0
    # the states stay 0, the steps grow to the limit and the sensitivities of a growing
    # system come out 2e-7 off the continuous ones (A = [[1, 1], [1, 1]]), while they
    # are still the exact derivatives of the discretised cost (test_integrate.py)
    assume(scheme == "rk4" or np.abs(x0).max() > 0.1)
    prob = _linear_problem(N, scheme)
    theta = np.concatenate([x0, A.ravel()])
    J, g, H = prob.cost_grad_hess(theta)
    J_ex, g_ex, H_ex = _exact(A, x0, prob.experiments[0].measured)
    np.testing.assert_allclose(J, J_ex, rtol=1e-8)
    np.testing.assert_allclose(g, g_ex, rtol=1e-7, atol=1e-8 * np.abs(g_ex).max())
    np.testing.assert_allclose(H, H_ex, rtol=1e-7, atol=1e-8 * np.abs(H_ex).max())
    # and the states themselves
    (sim,) = prob.simulate(theta)
    ref = np.stack([expm(A * t) @ x0 for t in T_GRID])
    np.testing.assert_allclose(sim.x, ref, rtol=1e-8, atol=1e-10 * (np.abs(ref).max() + 1))
