"""Events in a record: doses (a bolus, a zero-order infusion, repeated every II for
ADDL more), resets (x := value, or every state to 0) and impulses (x += amount), at
scheduled times, as clinical tables (NONMEM's EVID/AMT/CMT/RATE/II/ADDL) and
engineering logs (a tank refilled, a cell put to rest) state them.

A record with events is marched on one grid: its observation times, every event
time and every infusion's end (``Experiment`` merges them; rows that only carry an
event are not observed). At a grid time t_h the state jumps after the sample is
observed (a sample at a dose's time is its trough)::

    x⁺_d = (1 − r_hd) x⁻_d + r_hd v_hd + A_d(b_hd, p, u_h)       (the jump)
    dx_d/dt = F_d(x, p, u) + A_d(q_hd, p, u_h)   on [t_h, t_h+1)   (infusions)

for each target state d: b the bolus amounts at t_h, q the infusion rates running on
the interval, r = 1 where the state is reset to v. A_d is the dose's amount as the
model states it (``doses = {"depot": "F * amt"}``: bioavailability, dose × weight;
default the amount itself), zero where no dose is given. The march carries the jump
and the rates as inputs held over each interval (``Dosing.channels``), so every sweep
pushes the transition matrices and tensors through the jump map by the same nested
forward-mode derivatives as through F: the gradient and the Hessian stay exact
across any number of events, including amounts that depend on parameters.
"""

from __future__ import annotations

import warnings
from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np

KINDS = ("bolus", "infusion", "reset", "reset-all", "impulse", "modelled-infusion", "steady-state")
MODELLED = -2.0  # NONMEM's RATE for an infusion whose duration the model sets


class EventNote(UserWarning):
    """Something about a record's events worth a line (a dose after its last row)."""


@dataclass(frozen=True, eq=False)
class Events:
    """A record's events, each at a time, for a state (index or name).

    Arguments:
        time: (n,) event times, in the record's time unit.
        state: (n,) the target state of each event, by 0-based index or by name (a
            "reset-all" event ignores it).
        amount: (n,) a bolus's or an infusion's amount, or a reset's value.
        rate: (n,) an infusion's rate (amount per time unit); 0 for a bolus.
        kind: (n,) "bolus", "infusion", "reset" (x := amount), "reset-all" (every
            state := 0, NONMEM's EVID 3), "impulse" (x += amount, of either sign) or
            "modelled-infusion" (NONMEM's RATE = −2: the amount over the duration the
            model states, ``Problem(durations={"central": "D"})``) or "steady-state"
            (NONMEM's SS = 1: every state set to the steady state of this dose, a bolus
            or, with a rate, an infusion, repeated every ``interval``; the dose itself
            is an event of its own at the same time).
        interval: (n,) a steady-state event's dosing interval (II); 0 for the others.

    Build them with :meth:`doses`, :meth:`resets` and :meth:`impulses`; ``+``
    joins two sets. Repeated doses (II, ADDL) are expanded when built.
    """

    time: np.ndarray
    state: tuple
    amount: np.ndarray
    rate: np.ndarray
    kind: tuple
    interval: np.ndarray = None  # type: ignore[assignment]  # None becomes zeros

    def __post_init__(self) -> None:
        n = len(self.state)
        set_ = object.__setattr__
        if self.interval is None:
            set_(self, "interval", np.zeros(n))
        for name in ("time", "amount", "rate", "interval"):
            a = np.asarray(getattr(self, name), dtype=float).reshape(-1)
            if a.size != n:
                raise ValueError(f"events: {name} has {a.size} entries for {n} events")
            if not np.isfinite(a).all():
                i = int(np.argmax(~np.isfinite(a)))
                raise ValueError(f"events: {name} of event {i} is not finite ({a[i]})")
            set_(self, name, a)
        bad = [k for k in self.kind if k not in KINDS]
        if bad:
            raise ValueError(f"events: kind {bad[0]!r} is not one of {KINDS}")
        modelled = np.array([k == "modelled-infusion" for k in self.kind], dtype=bool)
        neg = np.flatnonzero(
            ((self.rate < 0) & ~modelled) | ((self.amount < 0) & self._dose_mask())
        )
        if neg.size:
            i = int(neg[0])
            what = "rate" if self.rate[i] < 0 else "amount"
            raise ValueError(
                f"events: event {i} at t = {self.time[i]:g} has a negative {what} "
                f"({min(self.rate[i], self.amount[i]):g}); a dose's amount and rate are >= 0 "
                "(an impulse may take any sign: Events.impulses)"
            )
        inf = np.array([k == "infusion" for k in self.kind], dtype=bool)
        if (inf & ~(self.rate > 0)).any():
            i = int(np.argmax(inf & ~(self.rate > 0)))
            raise ValueError(f"events: the infusion at t = {self.time[i]:g} needs a rate > 0")
        set_(self, "state", tuple(self.state))
        set_(self, "kind", tuple(self.kind))

    def _dose_mask(self) -> np.ndarray:
        return np.array(
            [k in ("bolus", "infusion", "modelled-infusion") for k in self.kind], dtype=bool
        )

    # -- construction ----------------------------------------------------------------
    @classmethod
    def doses(
        cls, time, state, amount, rate=0.0, ii=0.0, addl=0, *, impulse=False, ss=False
    ) -> Events:
        """Doses: a bolus where ``rate`` is 0, else a zero-order infusion of ``amount``
        at ``rate`` (it lasts amount / rate; ``rate=-2``: for the duration the model
        states, NONMEM's RATE = −2). ``addl`` more doses follow each, every ``ii`` time
        units (NONMEM's ADDL and II: both or neither). ``ss``: each dose (not its
        repeats) at steady state, as if it had been given every ``ii`` for ever
        (NONMEM's SS = 1: the states before it are replaced)."""
        time, amount = np.atleast_1d(np.asarray(time, float)), np.atleast_1d(amount)
        n = time.size
        state = _each(state, n, "state")
        amount = np.broadcast_to(np.asarray(amount, float), (n,))
        rate = np.broadcast_to(np.asarray(rate, float), (n,))
        ii = np.broadcast_to(np.asarray(ii, float), (n,))
        addl = np.broadcast_to(np.asarray(addl, float), (n,))
        t, s, a, r = [], [], [], []
        for i in range(n):
            repeats = _repeats(ii[i], addl[i], time[i], ss)
            for k in range(repeats + 1):
                t.append(time[i] + k * ii[i])
                s.append(state[i])
                a.append(amount[i])
                r.append(rate[i])
        kinds = tuple(
            "infusion" if q > 0 else "modelled-infusion" if q == MODELLED
            else "impulse" if impulse else "bolus"
            for q in r
        )  # fmt: skip
        out = cls(np.array(t), tuple(s), np.array(a), np.array(r), kinds)
        if not ss:
            return out
        if not (ii > 0).all() or (rate < 0).any():
            raise ValueError(
                "events: a steady-state dose needs II > 0 (its dosing interval) and a bolus "
                "or an infusion at a given rate"
            )
        if ((rate > 0) & (amount / np.where(rate > 0, rate, 1.0) > ii)).any():
            raise ValueError("events: a steady-state infusion lasts longer than its II")
        steady = cls(time, state, amount, rate, ("steady-state",) * n, np.asarray(ii, float))
        return steady + out

    @classmethod
    def impulses(cls, time, state, amount) -> Events:
        """x += amount at each time (an amount of either sign)."""
        return cls.doses(time, state, amount, impulse=True)

    @classmethod
    def resets(cls, time, state, value=0.0) -> Events:
        """x := value at each time; ``state=None`` resets every state to 0."""
        time = np.atleast_1d(np.asarray(time, float))
        n = time.size
        if state is None:
            return cls(time, (0,) * n, np.zeros(n), np.zeros(n), ("reset-all",) * n)
        value = np.broadcast_to(np.asarray(value, float), (n,))
        return cls(time, _each(state, n, "state"), value, np.zeros(n), ("reset",) * n)

    def __add__(self, other: Events) -> Events:
        return Events(
            np.concatenate([self.time, other.time]),
            self.state + other.state,
            np.concatenate([self.amount, other.amount]),
            np.concatenate([self.rate, other.rate]),
            self.kind + other.kind,
            np.concatenate([self.interval, other.interval]),
        )

    def take(self, index) -> Events:
        """The events at ``index`` (positions), in that order."""
        return Events(
            self.time[index], tuple(self.state[i] for i in index), self.amount[index],
            self.rate[index], tuple(self.kind[i] for i in index), self.interval[index],
        )  # fmt: skip

    def __len__(self) -> int:
        return len(self.state)

    # -- on a record's grid ------------------------------------------------------------
    def ends(self) -> np.ndarray:
        """Each infusion's end time (amount / rate after its start)."""
        inf = np.array([k == "infusion" for k in self.kind], dtype=bool)
        return self.time[inf] + self.amount[inf] / self.rate[inf]

    def grid_times(self) -> np.ndarray:
        """Every time the march must step to: the events and the infusions' ends."""
        return np.concatenate([self.time, self.ends()])

    def within(self, last: float) -> tuple[Events, int]:
        """(the events up to ``last``, how many lie after it): an event after a record's
        last row changes nothing it holds."""
        keep = self.time <= last
        if keep.all():
            return self, 0
        return self.take(np.flatnonzero(keep)), int((~keep).sum())

    def targets(self, states: Sequence[str]) -> tuple[int, ...]:
        """The state indices these events act on (every state for a reset-all)."""
        if "reset-all" in self.kind:
            return tuple(range(len(states)))
        return tuple(sorted({state_index(s, states) for s in self.state}))

    def __repr__(self) -> str:
        counts = {k: self.kind.count(k) for k in KINDS if k in self.kind}
        return f"Events({', '.join(f'{v} {k}' for k, v in counts.items()) or 'none'})"


def _each(value, n: int, what: str) -> tuple:
    """``value`` once per event: a name or index for all, or one per event."""
    if isinstance(value, str | int | np.integer):
        return (value,) * n
    out = tuple(v.item() if isinstance(v, np.generic) else v for v in value)
    if len(out) != n:
        raise ValueError(f"events: {what} has {len(out)} entries for {n} events")
    return out


def _repeats(ii: float, addl: float, t: float, ss: bool = False) -> int:
    """ADDL as a count, checked against II (both or neither; a steady-state dose has
    its II alone)."""
    if not (float(addl).is_integer() and addl >= 0):
        raise ValueError(f"events: ADDL of the dose at t = {t:g} must be a whole number >= 0")
    if addl > 0 and not ii > 0:
        raise ValueError(
            f"events: the dose at t = {t:g} has ADDL = {addl:g} but no II (the interval "
            "between its repeats): give II > 0, or ADDL = 0"
        )
    if ii > 0 and addl == 0 and not ss:
        raise ValueError(
            f"events: the dose at t = {t:g} has II = {ii:g} but no ADDL (how many more "
            "doses): give ADDL >= 1, or II = 0"
        )
    return int(addl)


def state_index(s, states: Sequence[str]) -> int:
    """A state by 0-based index or by name; one line for one the model lacks."""
    if isinstance(s, str):
        if s in states:
            return list(states).index(s)
        raise ValueError(f"events: there is no state {s!r}; the model's states are {list(states)}")
    if isinstance(s, bool) or not float(s).is_integer() or not 0 <= int(s) < len(states):
        raise ValueError(
            f"events: state {s!r} does not exist; the model has {len(states)} states "
            f"{list(states)} (0-based indices 0 to {len(states) - 1}, or names)"
        )
    return int(s)


def stopped(ev: Events, k: int, end: float) -> float:
    """Infusion k's end: its own, or the first reset of every state after its start
    (NONMEM's EVID 3 and 4 stop the infusions running)."""
    later = [r for r, kind in zip(ev.time, ev.kind, strict=True)
             if kind == "reset-all" and ev.time[k] < r < end]  # fmt: skip
    return min(later, default=end)


def merge(t, u, y, observed, events: Events):
    """The record on one grid of its rows and its events' times: (t, u, y, observed,
    events within the record, events after its last row) (``regrid``); an event
    within rounding of a row is at the row (``snapped``)."""
    events, late = snapped(events, t).within(float(t[-1]))
    extra = events.grid_times()
    return (*regrid(t, u, y, observed, extra[extra <= t[-1]]), events, late)


SNAP = 1e-9  # of the record's span: an event closer to a row is at the row


def snapped(events: Events, rows: np.ndarray) -> Events:
    """``events`` with each time within rounding of a row's moved onto it: ADDL's
    t + k·II (3 × 0.7 = 2.0999999999999996 beside a row at 2.1) had made a node of its
    own just before the row, whose observation then saw the dose (the trough rule, an
    observation before a dose at its time, did not hold)."""
    # the span's share, or a few roundings of the times themselves (epoch seconds)
    tol = max(SNAP * float(rows[-1] - rows[0]), 64 * float(np.spacing(np.max(np.abs(rows)))))
    j = np.searchsorted(rows, events.time)
    lo, hi = rows[np.clip(j - 1, 0, rows.size - 1)], rows[np.clip(j, 0, rows.size - 1)]
    near = np.where(np.abs(lo - events.time) <= np.abs(hi - events.time), lo, hi)
    moved = np.where(np.abs(near - events.time) <= tol, near, events.time)
    if np.array_equal(moved, events.time):
        return events
    return replace(events, time=moved)


def regrid(t, u, y, observed, extra):
    """(t, u, y, observed) on the union of the rows' times and ``extra``: the new times
    are not observed; the inputs there are interpolated linearly between the rows
    (held outside them)."""
    grid = np.unique(np.concatenate([t, extra]))
    if grid.size == t.size:
        return t, u, y, observed
    rows = np.searchsorted(grid, t)
    U = u.shape[1]
    u2 = np.stack([np.interp(grid, t, u[:, k]) for k in range(U)], axis=1) if U else None
    if u2 is None:
        u2 = np.zeros((grid.size, 0))
    else:
        u2[rows] = u  # the rows' own values, exactly
    y2 = None
    if y is not None:
        y2 = np.zeros((grid.size, y.shape[1]))
        y2[rows] = y
    seen = np.zeros((grid.size, y.shape[1] if y is not None else 0), dtype=bool)
    if y is not None:
        seen[rows] = np.ones_like(y, dtype=bool) if observed is None else observed
    return grid, u2, y2, seen


def warn_late(where: str, late: dict[str, int]) -> None:
    """One note for the events after their records' last rows (dropped)."""
    if late:
        shown = ", ".join(f"{k} ({v})" for k, v in list(late.items())[:5])
        more = f" and {len(late) - 5} more" if len(late) > 5 else ""
        warnings.warn(
            f"{where}: events after a record's last row change nothing it holds and are left "
            f"out: {shown}{more}",
            EventNote,
            stacklevel=3,
        )
