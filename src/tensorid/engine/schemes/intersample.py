"""The input between samples for the smooth interpolations: "cubic", "bandlimited" and
"periodic" (``linear`` and ``zoh`` need nothing more than the two end samples of an
interval, see ``discretisation.input_at``).

Each of them is a fixed linear combination of the samples, computed once per record
before anything compiles (``track``): on sample interval h the input is a polynomial in
the fraction s ∈ [0, 1] of the interval, stored as its Chebyshev coefficients, one row
per sample (P, Q, U; the last row, past the record, is never integrated over). The march
evaluates row h at any stage fraction s by Clenshaw's recurrence (``chebyshev_at``),
which adaptive schemes need (their s is not known in advance). The input does not depend
on θ, so every derivative stays exact; and since the rows belong to samples, a
multiple-shooting segment or a k-step window slices them as it slices the samples,
each interval keeping the whole record as its context.

- "cubic": the not-a-knot cubic spline through the samples (C², any sample grid;
  it reproduces a cubic polynomial exactly); Q = 4.
- "bandlimited": the samples convolved with a Kaiser-windowed sinc of ``TAPS`` samples
  each side (β = ``BETA``), for any record of a band-limited input that is not a whole
  number of periods. Past each end the record is continued by its point reflection
  through the end sample (u₋ₖ = 2u₀ − uₖ), which continues the value and the slope: the
  first and last ``TAPS`` intervals see a jump in the second derivative, not in the
  value or slope. Equal sample intervals are required.
- "periodic": the trigonometric interpolant, the trigonometric polynomial of degree
  < P/2 through the P samples (for even P the Nyquist term is a cosine), evaluated by
  FFT: exact for a record that holds whole periods of a periodic input (a multisine),
  also at its ends. Equal sample intervals are required.

The polynomial of "bandlimited" and "periodic" on an interval has ``NODES`` Chebyshev
coefficients: a signal below the Nyquist frequency is entire with |u⁽ⁿ⁾| ≤ πⁿ max|u|
per sample, so the truncation error, ≈ 2 (π/4)ᴺᴼᴰᴱˢ/NODES! ≈ 2e-15 of the signal's
size, is at rounding level: the polynomial is the interpolant to rounding.
"""

from __future__ import annotations

import warnings

import jax
import numpy as np

SMOOTH = ("cubic", "bandlimited", "periodic")
TAPS = 32  # the windowed sinc's half-width in samples
BETA = 16.0  # its Kaiser window's shape (stopband ≈ 140 dB)
NODES = 16  # Chebyshev coefficients per interval (bandlimited, periodic)
# equal sample intervals to this relative tolerance (a t column written with six digits)
SPACING_RTOL = 1e-4


def chebyshev_at(c: jax.Array, s) -> jax.Array:
    """Σ_k c_k T_k(2s − 1) for coefficients c (Q, U) at fraction s: the input there."""
    x = 2.0 * s - 1.0
    b1 = b2 = 0.0 * c[0]
    for k in range(c.shape[0] - 1, 0, -1):
        b1, b2 = 2.0 * x * b1 - b2 + c[k], b1
    return x * b1 - b2 + c[0]


def _nodes(Q: int) -> tuple[np.ndarray, np.ndarray]:
    """(fractions s_q of the Q Chebyshev points of the first kind on [0, 1], the matrix
    A with coefficients = values @ A)."""
    q = np.arange(Q) + 0.5
    x = np.cos(np.pi * q / Q)
    A = (2.0 / Q) * np.cos(np.pi * np.outer(q, np.arange(Q)) / Q)
    A[:, 0] /= 2
    return (1.0 + x) / 2.0, A


def kernel(x: np.ndarray) -> np.ndarray:
    """The Kaiser-windowed sinc at offsets x (samples), zero for |x| ≥ TAPS."""
    inside = np.clip(1.0 - (x / TAPS) ** 2, 0.0, None)
    window = np.i0(BETA * np.sqrt(inside)) / np.i0(BETA)
    return np.where(np.abs(x) < TAPS, np.sinc(x) * window, 0.0)


def equal_spacing(t: np.ndarray, kind: str) -> float:
    """The sample interval of t, or one line saying the intervals are not equal."""
    dt = np.diff(t)
    if dt.size == 0:
        return 1.0
    step = float(np.median(dt))
    if np.max(np.abs(dt - step)) > SPACING_RTOL * step:
        raise ValueError(
            f"interpolation={kind!r} needs equally spaced samples, but the sample "
            f"intervals range from {dt.min():.6g} to {dt.max():.6g}: give "
            "interpolation='cubic' (any grid) or resample the record"
        )
    return step


def _values_bandlimited(u: np.ndarray, s: np.ndarray) -> np.ndarray:
    """u(h + s_q) (P, Q, U) by the windowed sinc, the record point-reflected past its
    ends."""
    P = u.shape[0]
    pad = TAPS + 1
    idx = np.arange(1, pad + 1)
    left = 2.0 * u[0] - u[np.minimum(idx, P - 1)][::-1]
    right = 2.0 * u[-1] - u[np.maximum(P - 1 - idx, 0)]
    ext = np.concatenate([left, u, right])  # sample h is ext[h + pad]
    d = np.arange(-TAPS + 1, TAPS + 1)  # taps h + d
    W = kernel(s[:, None] - d[None, :])  # (Q, 2 TAPS)
    start = pad - TAPS + 1
    span = ext[start : start + P + 2 * TAPS - 1]
    windows = np.lib.stride_tricks.sliding_window_view(span, 2 * TAPS, axis=0)  # (P, U, 2 TAPS)
    return np.einsum("qd,hud->hqu", W, windows)


def _values_periodic(u: np.ndarray, s: np.ndarray) -> np.ndarray:
    """u(h + s_q) (P, Q, U) of the trigonometric interpolant (the last row wraps)."""
    P = u.shape[0]
    spectrum = np.fft.rfft(u, axis=0)
    k = np.arange(spectrum.shape[0])[:, None]
    return np.stack(
        [np.fft.irfft(spectrum * np.exp(2j * np.pi * k * sq / P), n=P, axis=0) for sq in s],
        axis=1,
    )


def _values_cubic(t: np.ndarray, u: np.ndarray, s: np.ndarray) -> np.ndarray:
    """u(t_h + s_q Δ_h) (P, Q, U) of the not-a-knot spline; the last row holds u_{P−1}."""
    from scipy.interpolate import CubicSpline

    P = u.shape[0]
    if P < 2:
        return np.repeat(u[:, None, :], s.size, axis=1)
    spline = CubicSpline(t, u, axis=0, bc_type="not-a-knot")
    tq = t[:-1, None] + s[None, :] * np.diff(t)[:, None]  # (P−1, Q)
    inner = spline(tq)  # (P−1, Q, U)
    last = np.repeat(u[-1:, None, :], s.size, axis=1)
    return np.concatenate([inner, last], axis=0)


def coefficients(t, u, kind: str) -> np.ndarray:
    """The record's input track (P, Q, U): row h holds the Chebyshev coefficients of the
    input on interval h as a polynomial in s = (t − t_h)/(t_{h+1} − t_h)."""
    t = np.asarray(t, dtype=float)
    u = np.asarray(u, dtype=float).reshape(t.size, -1)
    Q = 4 if kind == "cubic" else NODES
    s, A = _nodes(Q)
    if kind == "cubic":
        values = _values_cubic(t, u, s)
    else:
        equal_spacing(t, kind)
        if kind == "periodic":
            _check_periodic(u)
            values = _values_periodic(u, s)
        else:
            values = _values_bandlimited(u, s)
    return np.einsum("hqu,qk->hku", values, A)


def _check_periodic(u: np.ndarray) -> None:
    """A warning where the record's end cannot join its start: the step from the last
    sample to the first (an interval of the periodic record too) is over twice the
    largest step inside the record."""
    if u.shape[0] < 3:
        return
    inside = np.abs(np.diff(u, axis=0)).max(axis=0)
    wrap = np.abs(u[0] - u[-1])
    if np.any(wrap > 2.0 * inside):
        warnings.warn(
            "interpolation='periodic' treats the record as whole periods, but the step "
            f"from its last sample to its first ({wrap.max():.3g}) is over twice its "
            f"largest step inside ({inside.max():.3g}): the record does not look "
            "periodic; give interpolation='bandlimited' unless it holds whole periods",
            RuntimeWarning,
            stacklevel=5,
        )


def evaluate(track: np.ndarray, t: np.ndarray, tq: np.ndarray, kind: str) -> np.ndarray:
    """The input of ``track`` (P, Q, U) at times tq (n,), in NumPy (for input delays):
    before t_0, u_0 held ("periodic": the record repeated)."""
    t = np.asarray(t, dtype=float)
    P = t.size
    if P < 2:
        return np.repeat(track[:1, 0, :], tq.size, axis=0)
    tq = np.asarray(tq, dtype=float)
    if kind == "periodic":
        period = P * (t[-1] - t[0]) / (P - 1)
        tq = t[0] + np.mod(tq - t[0], period)
        step = (t[-1] - t[0]) / (P - 1)
        h = np.clip(np.floor((tq - t[0]) / step).astype(int), 0, P - 1)
        s = (tq - t[0]) / step - h
    else:
        tq = np.clip(tq, t[0], t[-1])
        h = np.clip(np.searchsorted(t, tq, side="right") - 1, 0, P - 2)
        s = (tq - t[h]) / (t[h + 1] - t[h])
    x = 2.0 * s - 1.0
    T = np.polynomial.chebyshev.chebvander(x, track.shape[1] - 1)  # (n, Q)
    return np.einsum("nq,nqu->nu", T, track[h])


def track(model, t, u, kind: str) -> np.ndarray:
    """The inputs as the march reads them for a smooth interpolation (P, Q, U): the
    track of the delayed inputs where the model delays some (the delayed samples are
    the interpolant's, so the model sees the same smooth input, shifted)."""
    out = coefficients(t, u, kind)
    if not model.input_delays:
        return out
    t = np.asarray(t, dtype=float)

    def at(tq, j):
        return evaluate(out[:, :, j : j + 1], t, tq, kind)[:, 0]

    return coefficients(t, model.delayed(t, u, kind, at=at), kind)
