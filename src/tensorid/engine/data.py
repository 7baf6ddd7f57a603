"""Measured input/output records (one experiment each), checked on construction."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


def _as_2d(name: str, a, P: int | None) -> np.ndarray:
    arr = np.asarray(a, dtype=float)
    if arr.ndim == 1:
        arr = arr[:, None]
    elif arr.ndim == 0:
        raise ValueError(f"{name} must be an array of samples, got a scalar")
    elif arr.ndim != 2:
        raise ValueError(f"{name} must have shape (P,) or (P, channels), got {arr.shape}")
    if P is not None and arr.shape[0] != P:
        hint = ""
        if arr.shape[1] == P:
            hint = f"; it looks transposed: pass {name}.T"
        raise ValueError(f"{name} has {arr.shape[0]} samples but t has {P}{hint}")
    return arr


def _check_finite(name: str, arr: np.ndarray) -> None:
    bad = ~np.isfinite(arr)
    if bad.any():
        rows = np.unique(np.nonzero(bad)[0])
        kind = "NaN" if np.isnan(arr[bad]).any() else "inf"
        raise ValueError(
            f"{name} contains {kind} at {bad.sum()} place(s), first at sample "
            f"{rows[0]}; remove or interpolate those samples before fitting"
        )


@dataclass(frozen=True, eq=False)
class Experiment:
    """One measured record.

    Parameters
    ----------
    t : (P,) sample times, strictly increasing (seconds or any unit the model uses).
    u : (P, U) or (P,) inputs at the sample times; None for an autonomous model.
    y : (P, S) or (P,) measured outputs; may be None for simulation only.
    name : label used in reports and parameter names.
    """

    t: np.ndarray
    u: np.ndarray = None  # type: ignore[assignment]  # None becomes (P, 0)
    y: np.ndarray | None = None
    name: str = ""

    def __post_init__(self) -> None:
        t = np.asarray(self.t, dtype=float)
        if t.ndim != 1:
            raise ValueError(f"t must be one-dimensional (P,), got shape {t.shape}")
        if t.size < 2:
            raise ValueError(f"an experiment needs at least 2 samples, got {t.size}")
        _check_finite("t", t)
        dt = np.diff(t)
        if (dt <= 0).any():
            i = int(np.argmax(dt <= 0))
            what = "repeats" if dt[i] == 0 else "goes backwards"
            raise ValueError(
                f"t must be strictly increasing, but it {what} at sample {i + 1} "
                f"(t[{i}] = {t[i]}, t[{i + 1}] = {t[i + 1]}); sort the record "
                "and drop duplicate times"
            )
        P = t.size
        u = np.zeros((P, 0)) if self.u is None else _as_2d("u", self.u, P)
        _check_finite("u", u)
        y = None if self.y is None else _as_2d("y", self.y, P)
        if y is not None:
            _check_finite("y", y)
        object.__setattr__(self, "t", t)
        object.__setattr__(self, "u", u)
        object.__setattr__(self, "y", y)

    @property
    def measured(self) -> np.ndarray:
        """y, for code that needs measurements; a clear error when there are none."""
        if self.y is None:
            raise ValueError(f"experiment {self.name!r} has no measured outputs y")
        return self.y

    @property
    def P(self) -> int:
        """Number of samples."""
        return self.t.size

    def window(self, start: int, stop: int, name: str | None = None) -> Experiment:
        """Samples [start:stop] as a new experiment (Python slice semantics)."""
        kept = len(range(*slice(start, stop).indices(self.P)))
        if kept < 2:
            raise ValueError(
                f"samples {start}:{stop} of experiment {self.name!r} keep {kept} sample(s), "
                f"but a window needs at least 2; the record has {self.P} samples, so "
                f"choose 0 <= start < stop <= {self.P}"
            )
        return Experiment(
            self.t[start:stop],
            self.u[start:stop],
            None if self.y is None else self.y[start:stop],
            name=self.name if name is None else name,
        )

    def __repr__(self) -> str:
        S = 0 if self.y is None else self.y.shape[1]
        return (
            f"Experiment({self.name!r}, P={self.P}, U={self.u.shape[1]}, S={S}, "
            f"t=[{self.t[0]:g} .. {self.t[-1]:g}])"
        )
