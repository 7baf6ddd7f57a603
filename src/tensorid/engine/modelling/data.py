"""Measured input/output records (one experiment each), checked on construction."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .events import Events, merge


def _real(name: str, a, where: str = "") -> np.ndarray:
    """``a`` as floats, or one line naming ``name``: complex values (NumPy drops the
    imaginary part with a bare warning) and text (a bare conversion error) refused."""
    try:
        arr = np.asarray(a)
    except ValueError:  # ragged
        arr = np.asarray(a, dtype=object)
    if arr.dtype.kind == "c":
        raise ValueError(
            f"{where}{name} is complex ({arr.dtype}); tensorid fits real signals: pass its "
            f"real part (np.real({name})) or its magnitude (np.abs({name}))"
        )
    try:
        return np.asarray(arr, dtype=float)
    except (TypeError, ValueError):
        bad = next((v for v in arr.ravel() if not _number(v)), None)
        raise ValueError(
            f"{where}{name} holds values that are not numbers (e.g. {str(bad)!r:.40}); convert "
            "them to numbers first"
        ) from None


def _number(v) -> bool:
    try:
        float(v)
    except (TypeError, ValueError):
        return False
    return True


def _as_2d(name: str, a, P: int | None) -> np.ndarray:
    arr = _real(name, a)
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


def _init_window(n, P: int, what: str = "init_window") -> int:
    """An initialisation window of at least 2 samples (the initial state is estimated
    on them) that leaves at least 2 of P to score."""
    try:
        ok = not isinstance(n, bool) and float(n).is_integer() and 2 <= n <= P - 2
    except (TypeError, ValueError):
        ok = False
    if not ok:
        raise ValueError(
            f"{what} must be a whole number of samples from 2 to {P - 2} (the record "
            f"has {P}, and at least 2 are scored), got {n!r}"
        )
    return int(n)


def _columns(name: str, a, keep, record: str) -> np.ndarray:
    """``a`` as (P, channels), only the columns ``keep`` (an index or indices) where given."""
    arr = _real({"input": "u", "output": "y"}[name], a, f"benchmark record {record!r}: ")
    if arr.ndim == 1:
        arr = arr[:, None]
    if arr.ndim != 2 or arr.shape[0] < 2:
        raise ValueError(
            f"benchmark record {record!r}: {name} has shape {arr.shape}; expected (P,) or "
            "(P, channels) with P >= 2 samples"
        )
    if keep is None:
        return arr
    cols = np.atleast_1d(np.asarray(keep))
    if cols.dtype.kind not in "iu" or ((cols < 0) | (cols >= arr.shape[1])).any():
        raise ValueError(
            f"benchmark record {record!r}: {name}s={keep!r} must be column indices from 0 "
            f"to {arr.shape[1] - 1} ({name} has {arr.shape[1]} column(s))"
        )
    if len(set(cols.tolist())) < cols.size:  # a column twice would count twice
        raise ValueError(
            f"benchmark record {record!r}: {name}s={keep!r} names a column twice; give each once"
        )
    return arr[:, cols]


def _benchmark_fields(record, inputs, outputs, Ts, name) -> tuple:
    """(u, y, sampling period, init window, name) of a benchmark record, checked."""
    missing = [a for a in ("u", "y") if getattr(record, a, None) is None]
    if missing:
        raise ValueError(
            f"a benchmark record needs attributes u and y (nonlinear_benchmarks' "
            f"Input_output_data); this {type(record).__name__} lacks {', '.join(missing)}"
        )
    label = str(name if name is not None else getattr(record, "name", "") or "benchmark")
    u = _columns("input", record.u, inputs, label)
    y = _columns("output", record.y, outputs, label)
    if u.shape[0] != y.shape[0]:
        raise ValueError(
            f"benchmark record {label!r}: u has {u.shape[0]} samples but y has {y.shape[0]}"
        )
    given = getattr(record, "sampling_time", None) if Ts is None else Ts
    try:  # the package writes a discrete-time record's sampling_time as None or text
        ts = float(given) if given is not None else np.nan
    except (TypeError, ValueError):
        ts = np.nan
    if not (np.isfinite(ts) and ts > 0):
        if Ts is not None:
            what = f"got Ts={Ts!r}"
        elif isinstance(given, (int, float)):
            what = f"has sampling_time={given!r}"
        else:
            what = "has no sampling_time"
        raise ValueError(
            f"benchmark record {label!r} {what}; give Ts= the sampling period (a positive "
            "number; 1.0 for a discrete-time model whose equations do not use time)"
        )
    window = getattr(record, "state_initialization_window_length", None)
    if window is not None:
        what = f"benchmark record {label!r}: its state_initialization_window_length"
        window = _init_window(window, y.shape[0], what)
    return u, y, ts, window, label


def _observed(observed, y, P: int) -> np.ndarray | None:
    """The (P, S) observation mask, checked; where y is given, its NaN entries are
    unobserved too (a missing value in a record with gaps)."""
    if observed is None:
        return None
    if y is None:
        raise ValueError("observed is given but y is not: it marks which samples of y count")
    seen = np.asarray(observed)
    if seen.ndim == 1:
        seen = np.broadcast_to(seen[:, None], (seen.shape[0], y.shape[1]))
    if seen.shape != y.shape:
        raise ValueError(f"observed has shape {seen.shape}; y has {y.shape}: give one per y")
    seen = seen.astype(bool) & np.isfinite(y)
    if not seen.any():
        raise ValueError("observed marks no sample as measured: a record needs one at least")
    return seen


def _check_finite(name: str, arr: np.ndarray) -> None:
    bad = ~np.isfinite(arr)
    if bad.any():
        rows = np.unique(np.nonzero(bad)[0])
        kind = "NaN" if np.isnan(arr[bad]).any() else "inf"
        raise ValueError(
            f"{name} contains {kind} at {bad.sum()} place(s), first at sample "
            f"{rows[0]}; "
            + ("mark them not measured (observed=, False there: they are left out) or "
               "remove them" if name == "y" else "remove or interpolate those samples")
            + " before fitting"
        )  # fmt: skip


@dataclass(frozen=True, eq=False)
class Experiment:
    """One measured record.

    Arguments:
        t: (P,) sample times, strictly increasing (seconds or any unit the model uses).
        u: (P, U) or (P,) inputs at the sample times; None for an autonomous model.
        y: (P, S) or (P,) measured outputs; may be None for simulation only.
        name: label used in reports and parameter names.
        init_window: the record's own initialisation window (a benchmark test record's
            ``state_initialization_window_length``, see :meth:`from_benchmark`): the first
            samples, spent estimating the initial state, that a score leaves out.
            ``FitResult.validate`` uses it where no ``init_window`` is given. None: none.
        events: doses, infusions, resets or impulses at scheduled times
            (:class:`tensorid.Events`). Their times join the sample grid (rows that
            carry only an event are not observed; the inputs there are interpolated),
            and an event after the last sample is left out (``late_events`` counts it).
        observed: (P, S) booleans, False where a sample of an output was not measured
            (its y is ignored and may be NaN): a row with no observation, or outputs
            measured at different times. None: every sample observed.
        censored: (P, S) booleans, True where a sample was below its quantification
            limit, which its y holds (Beal's M3: a population fit by Laplace counts the
            probability of lying below it); such a sample is not ``observed``.
    """

    t: np.ndarray
    u: np.ndarray = None  # type: ignore[assignment]  # None becomes (P, 0)
    y: np.ndarray | None = None
    name: str = ""
    init_window: int | None = None
    events: Events | None = None
    observed: np.ndarray | None = None
    censored: np.ndarray | None = None
    late_events: int = field(default=0, init=False, repr=False)
    # True at the record's own rows, False at those its events added (None: all own);
    # passed on by window() and dataclasses.replace, whose events add no rows again
    _own: np.ndarray | None = field(default=None, repr=False)

    def __post_init__(self) -> None:
        t = np.asarray(self.t, dtype=float)
        if t.ndim != 1:
            raise ValueError(f"t must be one-dimensional (P,), got shape {t.shape}")
        if t.size < (2 if self.events is None else 1):
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
        seen = _observed(self.observed, y, P)
        cens = None if self.censored is None else np.asarray(self.censored, dtype=bool)
        if cens is not None:
            if y is None or cens.shape != y.shape:
                raise ValueError("censored marks samples of y: give it y's shape (P, S)")
            seen = ~cens if seen is None else seen & ~cens
        if y is not None:
            kept = seen if cens is None else seen | cens
            y = np.where(kept, y, 0.0) if kept is not None else y
            _check_finite("y", y)
        if self.events is not None:
            if not isinstance(self.events, Events):
                raise TypeError(
                    f"events must be a tensorid.Events, got {type(self.events).__name__}; "
                    "build them with ti.Events.doses(...), .resets(...) or .impulses(...)"
                )
            grid = t
            t, u, y, seen, events, late = merge(t, u, y, seen, self.events)
            own = np.zeros(t.size, dtype=bool)
            own[np.searchsorted(t, grid)] = True if self._own is None else self._own
            object.__setattr__(self, "_own", None if own.all() else own)
            if cens is not None:  # the new rows are not censored samples either
                wide = np.zeros((t.size, cens.shape[1]), dtype=bool)
                wide[np.searchsorted(t, grid)] = cens
                cens = wide
            object.__setattr__(self, "events", events)
            object.__setattr__(self, "late_events", late)
            if t.size < 2:
                raise ValueError(
                    "an experiment needs at least 2 samples; with its events it has "
                    f"{t.size} (give the first dose's time, or a sample before the last)"
                )
        if seen is not None and seen.all():
            seen = None
        object.__setattr__(self, "observed", seen)
        object.__setattr__(self, "censored", cens if cens is not None and cens.any() else None)
        object.__setattr__(self, "t", t)
        object.__setattr__(self, "u", u)
        object.__setattr__(self, "y", y)
        if self.init_window is not None:
            object.__setattr__(self, "init_window", _init_window(self.init_window, P))

    @classmethod
    def from_benchmark(cls, record, inputs=None, outputs=None, *, Ts=None, name=None):
        """A record of the nonlinear-benchmarks package (its loaders'
        ``Input_output_data``, or any object with ``u``, ``y``, ``sampling_time`` and
        ``state_initialization_window_length``) as an Experiment, its time axis
        ``k · sampling_time`` from 0 and its initialisation window kept as
        ``init_window`` (None where the record has none, as training records).

        inputs, outputs : the columns of ``u`` and ``y`` to keep, in the model's order
            (an index or a list of indices); None keeps them all.
        Ts : the sampling period, for a record that has none (a discrete-time record);
            given, it replaces the record's ``sampling_time``.
        name : the Experiment's name; default the record's ``name``.
        A list or tuple of records gives a list of Experiments."""
        if isinstance(record, (list, tuple)):
            return [cls.from_benchmark(r, inputs, outputs, Ts=Ts, name=name) for r in record]
        u, y, ts, window, label = _benchmark_fields(record, inputs, outputs, Ts, name)
        try:
            return cls(np.arange(y.shape[0]) * ts, u, y, label, window)
        except ValueError as e:  # the record's own words: u or y holds NaN, ...
            raise ValueError(f"benchmark record {label!r}: {e}") from None

    @property
    def mask(self) -> np.ndarray | None:
        """(P, S) 1.0 where a sample of an output was measured, 0.0 where not; None
        where every one was (a record without gaps)."""
        return None if self.observed is None else self.observed.astype(float)

    @property
    def observations(self) -> int:
        """How many numbers were measured (samples × outputs, less the gaps)."""
        if self.y is None:
            return 0
        seen = int(self.y.size if self.observed is None else self.observed.sum())
        return seen + (0 if self.censored is None else int(self.censored.sum()))

    @property
    def measured(self) -> np.ndarray:
        """y, for code that needs measurements; a clear error when there are none."""
        if self.y is None:
            raise ValueError(f"experiment {self.name!r} has no measured outputs y")
        return self.y

    @property
    def seen(self) -> np.ndarray:
        """(P, S) booleans, True where a sample of an output was measured: ``observed``,
        or every sample of a record without gaps."""
        return np.ones(self.measured.shape, dtype=bool) if self.observed is None else self.observed

    @property
    def seen_rows(self) -> np.ndarray:
        """(P,) booleans, True where some output was measured (not a gap of every
        output, nor a row holding only a dose): the samples that count as samples."""
        return np.any(self.seen, axis=1)

    @property
    def measured_with_gaps(self) -> np.ndarray:
        """y (P, S) with NaN where a sample of an output was not measured."""
        return np.where(self.seen, self.measured, np.nan)

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
        events = self.events
        if events is not None:  # the window's own: from its first sample on
            t0 = self.t[start:stop][0]
            events = events.take(np.flatnonzero(events.time >= t0))
        return Experiment(
            self.t[start:stop],
            self.u[start:stop],
            None if self.y is None else self.y[start:stop],
            name=self.name if name is None else name,
            events=events,
            observed=None if self.observed is None else self.observed[start:stop],
            censored=None if self.censored is None else self.censored[start:stop],
            _own=None if self._own is None else self._own[start:stop],
        )

    def inputs_held(self, interpolation: str) -> np.ndarray:
        """u as ``interpolation`` reads it: held ("zoh") from each of the record's own
        rows over the rows its events added (a dose between two samples changes no
        input there; their interpolated value is linear interpolation's)."""
        if interpolation != "zoh" or self._own is None:
            return self.u
        last_own = np.maximum.accumulate(np.where(self._own, np.arange(self.P), 0))
        return self.u[last_own]

    def __repr__(self) -> str:
        S = 0 if self.y is None else self.y.shape[1]
        return (
            f"Experiment({self.name!r}, P={self.P}, U={self.u.shape[1]}, S={S}, "
            f"t=[{self.t[0]:g} .. {self.t[-1]:g}]"
            + ("" if self.init_window is None else f", init_window={self.init_window}")
            + ")"
        )
