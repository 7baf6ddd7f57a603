"""A record's time base as the data files give it: a column ``t``, a sampling time
``Ts`` in the file, or the one given (``--ts``, ``ts=``); time stamps within clock
jitter of a uniform grid are snapped to it, with a note (:class:`DataNote`)."""

from __future__ import annotations

import shlex
import warnings

import numpy as np

from .readers import _TS, _Columns, _real

JITTER = 1e-3  # of a sample time: time stamps this close to a uniform grid lie on it


class DataNote(UserWarning):
    """Something done to a record while reading it that its user should know of (time
    stamps snapped to a uniform grid); the command line prints it as one line."""


def _sampling_time(p, cols: _Columns) -> float | None:
    """The file's own sampling time: a column or variable ``Ts`` or ``ts`` (one value,
    or the same value on every row), or None."""
    name = next((n for n in _TS if n in cols.values), None)
    if name is None:
        return None
    v = _real(p, cols.what, name, cols.values[name])
    v = v[np.isfinite(v)]
    if v.size == 0 or not (v > 0).all() or np.ptp(v) > 1e-12 * v[0]:
        raise ValueError(
            f"{p}: {cols.what} {name!r} should hold the sampling time (one positive "
            "value); fix it, or give the sampling time with --ts"
        )
    return float(v[0])


def _on_grid(p, t: np.ndarray) -> np.ndarray:
    """``t``, or the uniform grid fitted to it (least squares) when no sample is further
    than JITTER sample times from it (clock jitter), with a DataNote saying by how much."""
    if t.size < 3:
        return t
    k = np.arange(t.size)
    Ts, t0 = np.polynomial.polynomial.polyfit(k, t, 1)[::-1]
    grid = t0 + k * Ts
    off = float(np.abs(t - grid).max())
    # below this the stamps are uniform to the rounding of their own digits (which near
    # t = 2 is a few 1e-16 s, far above 1e-9 of a microsecond's sample time)
    rounding = max(1e-9 * Ts, 64 * np.finfo(float).eps * float(np.abs(t).max()))
    if not rounding < off <= JITTER * Ts:  # uniform to rounding, or truly uneven
        return t
    grid, Ts = _plainest(t, grid, Ts, t0, k)
    off = float(np.abs(t - grid).max())
    warnings.warn(
        f"{p}: the time stamps lie within {off:.2g} s ({off / Ts:.1e} sample times, "
        f"tolerance {JITTER:g}) of a uniform grid of {Ts:.8g} s; snapped to it",
        DataNote,
        stacklevel=2,
    )
    return grid


def _plainest(t, grid, Ts: float, t0: float, k) -> tuple[np.ndarray, float]:
    """(grid, Ts): the uniform grid of the fewest digits within JITTER sample times of
    every stamp (0, 0.1, 0.2, ... rather than the least-squares 2.1e-07 + k·0.10000001),
    or the least-squares one where none is."""
    for digits in range(1, 16):
        places = digits - 1 - int(np.floor(np.log10(Ts)))
        step, start = round(Ts, places), round(t0, places)
        plain = np.round(start + k * step, max(places, 0) + 6)  # (k·step's last digits)
        if step > 0 and float(np.abs(t - plain).max()) <= JITTER * Ts:
            return plain, step
    return grid, Ts


def _time(p, cols: _Columns, ts, P: int, data: dict) -> np.ndarray:
    """The sample times: from --ts (ts=), else the column ``t``, else the file's own
    sampling time (``Ts``); one line naming the ways out when there is none."""
    if ts is None and "t" in data:
        return _on_grid(p, data["t"])
    if ts is not None:
        _given(p, cols, ts)
    ts = _sampling_time(p, cols) if ts is None else ts
    if ts is None:
        named = [
            n for n in cols.values if str(n).lower() == "t" or str(n).lower().startswith("time")
        ]
        hint = (
            f"; if {named[0]!r} holds the times: --columns {shlex.quote(f't={named[0]}')} "
            f"(columns={{'t': {named[0]!r}}} in Python)"
            if named
            else ""
        )
        raise ValueError(
            f"{p} has no time column 't' and no sampling time 'Ts'; add one or give the "
            f"sampling time (--ts on the command line, ts= in Python){hint}"
        )
    return np.arange(P) * float(ts)


def _given(p, cols: _Columns, ts: float) -> None:
    """A DataNote where the sampling time given (--ts, ts=), which is used, differs from
    the file's own time base (its column ``t``, or its ``Ts``): a user who forgot that
    the file has one learns that it was set aside."""
    column = cols.values.get("t")
    own: float | None
    try:
        if isinstance(column, np.ndarray) and column.size > 1:
            t = _real(p, cols.what, "t", column)
            own, what = float(np.median(np.diff(t))), f"its {cols.what} 't' steps by"
        else:
            own, what = _sampling_time(p, cols), "its sampling time 'Ts' is"
    except ValueError:  # a time base it could not use: nothing to compare
        return
    if own is None or not np.isfinite(own) or abs(own - ts) <= 1e-6 * ts:
        return
    warnings.warn(
        f"{p}: the sampling time given, {ts:g} s (--ts, ts= in Python), is used, though "
        f"{what} {own:.6g} s; leave it out to use the file's",
        DataNote,
        stacklevel=3,
    )
