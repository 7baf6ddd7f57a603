"""Clinical event tables, in NONMEM's layout (nlmixr2's and Monolix's too): one row per
observation or dose, with the columns EVID, AMT, CMT, RATE, II, ADDL, SS, MDV and DVID
recognised by name (``events={"AMT": "DOSE"}``, ``--events AMT=DOSE`` for other
names). A file with an AMT or an EVID column is read this way, each unit (``--records
ID``) as one Experiment with its events (engine/modelling/events.py):

- EVID 0: an observation (unless MDV = 1 or the output's cell is empty or "."),
  1: a dose, 2: a time with nothing observed, 3: every state reset to 0, 4: reset,
  then a dose. Without EVID, a row with AMT > 0 is a dose.
- CMT: the dose's state, by 1-based position in the model's states or by name
  (default: the first state, as NONMEM's).
- RATE > 0: a zero-order infusion of AMT at that rate (−2: for the duration the
  model states); II with ADDL: ADDL more doses every II. DVID: which output (1-based,
  or by name) an observation row measures. CENS = 1: the observation was below its
  quantification limit, which DV holds (Beal's M3, nlmixr2's and Monolix's column).

A unit's clock is its rows' own times, from its first row (a dose or an observation);
a row of a dose and one of an observation at one time: the observation comes first
(a trough). Every mistake is one line naming the file, the unit and the line.
"""

from __future__ import annotations

import warnings

import numpy as np

from ..engine.modelling.data import Experiment
from ..engine.modelling.events import Events, state_index, warn_late
from .readers import Said, _Columns
from .records import _at, as_text, check_covariates, split_units
from .timebase import DataNote

COLUMNS = ("EVID", "AMT", "CMT", "RATE", "II", "ADDL", "SS", "MDV", "DVID", "CENS")
MISSING = ("", ".", "NA", "nan", "NaN")


def mapped(p, cols: _Columns, events: dict | None) -> _Columns:
    """The file's event columns under NONMEM's names (``events`` maps a NONMEM name to
    the file's column); one line for a name that is not NONMEM's or a column the file
    lacks."""
    if not events:
        return cols
    values, text = dict(cols.values), dict(cols.text)
    for name, source in events.items():
        if name not in COLUMNS:
            raise ValueError(
                f"events: {name!r} is not an event column; give one of {list(COLUMNS)} = the "
                "file's column name (e.g. --events AMT=DOSE)"
            )
        if source not in cols.values:
            raise ValueError(
                f"{p}: events maps {name} to {source!r}, which the file does not have; it has "
                f"{sorted(cols.values)}"
            )
        values[name] = cols.values[source]
        if source in cols.text:
            text[name] = cols.text[source]
    return _Columns(values, cols.what, cols.lines, cols.note, dict(cols.constants), text)


def is_event_table(cols: _Columns) -> bool:
    """Whether the file is an event table: it has an AMT or an EVID column."""
    return "AMT" in cols.values or "EVID" in cols.values


def numbers(where: str, cols: _Columns, name: str, n: int, default=np.nan) -> np.ndarray:
    """A column as floats, its missing cells ("", ".", NA) NaN; ``default`` where the
    file lacks it; one line for a cell that is no number."""
    v = cols.values.get(name)
    if v is None:
        return np.full(n, default, dtype=float)
    if isinstance(v, str):  # read as text: "." or names among numbers
        cells = cols.text.get(name)
        if cells is None:
            raise ValueError(v if isinstance(v, Said) else f"{where}: {v}")
        out = np.empty(len(cells))
        for i, c in enumerate(cells):
            c = c.strip()
            try:
                out[i] = np.nan if c in MISSING else float(c)
            except ValueError:
                raise ValueError(
                    f"{where}: column {name!r} holds {c!r} {_at(cols, i)}, which is not a "
                    "number (a missing value is empty or '.')"
                ) from None
        return out
    return np.asarray(v, dtype=float).reshape(-1)


def _target(where, cols, i, raw, states) -> int:
    """The state a dose row's CMT names (1-based number or a state's name)."""
    cells = cols.text.get("CMT")
    cell = cells[i].strip() if cells is not None else None
    try:
        if cell is not None and cell not in MISSING and not _is_number(cell):
            return state_index(cell, states)
        if cell is not None:  # a text column ("." somewhere): this row's own cell
            raw = float(cell) if cell not in MISSING else np.nan
        if not np.isfinite(raw):
            return 0
        k = float(raw)
        if not k.is_integer() or not 1 <= k <= len(states):
            raise ValueError
        return int(k) - 1
    except ValueError:
        shown = cell if cell is not None else f"{raw:g}"
        raise ValueError(
            f"{where}: CMT {shown} {_at(cols, i)} names no state; the model has "
            f"{len(states)} states {list(states)}: CMT is 1 to {len(states)} or a state's name"
        ) from None


def _is_number(s: str) -> bool:
    try:
        float(s)
    except ValueError:
        return False
    return True


def unit_record(where: str, name: str, cols: _Columns, model, require_outputs: bool):
    """One unit's rows as an Experiment with its events (None: the unit has no
    observation and outputs are required, for the caller to leave out)."""
    t = numbers(where, cols, "t", _size(cols))
    n = t.size
    if not np.isfinite(t).all():
        i = int(np.argmax(~np.isfinite(t)))
        raise ValueError(f"{where}: the time is missing {_at(cols, i)}; every row needs one")
    back = np.flatnonzero(np.diff(t) < 0)
    if back.size:
        i = int(back[0]) + 1
        raise ValueError(
            f"{where}: the time goes backwards {_at(cols, i)} ({t[i - 1]:g} then {t[i]:g}); "
            "sort the file by id and time"
        )
    amt = numbers(where, cols, "AMT", n, 0.0)
    evid = numbers(where, cols, "EVID", n)
    evid = np.where(np.isfinite(evid), evid, np.where(np.nan_to_num(amt) > 0, 1.0, 0.0))
    mdv = numbers(where, cols, "MDV", n)
    mdv = np.where(np.isfinite(mdv), mdv, (evid != 0).astype(float))
    _plain_rows(where, cols, evid, amt, mdv)
    events = _events(where, cols, model, t, evid, amt)
    outputs = [o for o in model.outputs if o in cols.values]
    y, seen = _observations(where, cols, model, outputs, evid, mdv, n)
    cens = None
    if seen is not None and "CENS" in cols.values:  # below the limit: DV holds it
        flag = np.nan_to_num(numbers(where, cols, "CENS", n, 0.0))
        odd = np.flatnonzero(~np.isin(flag, (0, 1)))
        if odd.size:
            raise ValueError(
                f"{where}: CENS {flag[odd[0]]:g} {_at(cols, int(odd[0]))} is not supported; "
                "CENS is 0 (a measurement) or 1 (below the limit DV holds)"
            )
        cens, seen = seen & (flag == 1)[:, None], seen & ~(flag == 1)[:, None]
    if require_outputs and (y is None or not (seen.any() or (cens is not None and cens.any()))):
        return None
    grid, first = np.unique(t, return_index=True)
    u = _inputs(where, cols, model, first)
    if y is not None:
        Y, S = np.zeros((grid.size, model.S)), np.zeros((grid.size, model.S), dtype=bool)
        C = np.zeros_like(S)
        slot = np.searchsorted(grid, t)
        if cens is not None:
            for r in np.flatnonzero(cens.any(axis=1)):
                if (C[slot[r]] & cens[r]).any():
                    raise ValueError(
                        f"{where}: two censored observations at time {t[r]:g} "
                        f"({_at(cols, int(r))}); keep one row per time and output"
                    )
                Y[slot[r]] = np.where(cens[r], y[r], Y[slot[r]])
                C[slot[r]] |= cens[r]
        for r in np.flatnonzero(seen.any(axis=1)):
            twice = (S[slot[r]] | C[slot[r]]) & seen[r]
            if twice.any():
                raise ValueError(
                    f"{where}: two observations of {model.outputs[int(np.argmax(twice))]!r} at "
                    f"time {t[r]:g} ({_at(cols, int(r))}); keep one row per time and output"
                )
            Y[slot[r]] = np.where(seen[r], y[r], Y[slot[r]])
            S[slot[r]] |= seen[r]
        y, seen, cens = (Y, S, C if C.any() else None) if (S | C).any() else (None, None, None)
    if require_outputs and seen is not None:  # what follows the last observation fits nothing
        last = np.flatnonzero((seen if cens is None else seen | cens).any(axis=1))[-1]
        keep = grid <= grid[last]
        grid, u, y, seen = grid[keep], u[keep], y[keep], seen[keep]
        cens = None if cens is None else cens[keep]
    if grid.size == 1:  # (its doses after it are after its last observation)
        raise SingleRow(f"{where}: the unit holds one time: nothing to integrate")
    try:
        e = Experiment(grid, u, y, name=name, events=events, observed=seen, censored=cens)
    except ValueError as err:
        raise ValueError(f"{where}: {err}") from None
    return e


class SingleRow(ValueError):
    """A unit of one time (a fleet's file leaves it out, with a note)."""


def _size(cols: _Columns) -> int:
    sizes = [v.shape[0] for v in cols.values.values() if isinstance(v, np.ndarray) and v.ndim]
    sizes += [len(c) for c in cols.text.values()]
    return max(sizes, default=0)


def _events(where, cols, model, t, evid, amt) -> Events | None:
    """The unit's dose and reset rows as Events."""
    n = t.size
    rate = numbers(where, cols, "RATE", n, 0.0)
    ii = numbers(where, cols, "II", n, 0.0)
    addl = numbers(where, cols, "ADDL", n, 0.0)
    ss = numbers(where, cols, "SS", n, 0.0)
    cmt = numbers(where, cols, "CMT", n) if "CMT" not in cols.text else np.full(n, np.nan)
    out: Events | None = None
    for i in np.flatnonzero(evid > 0):
        part = None
        if evid[i] in (3, 4):
            part = Events.resets(t[i], None)
        if evid[i] in (1, 4):
            # repeats past the unit's last row change nothing it holds: one of them is
            # kept (for the note that they are left out), not ADDL = 1e8 of them
            ii_i = float(np.nan_to_num(ii[i]))
            more = np.floor((t[-1] - t[i]) / ii_i + 1e-9) + 1 if ii_i > 0 else np.inf
            dose = _dose(where, cols, i, model, t[i], amt[i], rate[i], ii[i],
                         min(addl[i], more), ss[i], cmt[i])  # fmt: skip
            part = dose if part is None else part + dose
        if part is not None:
            out = part if out is None else out + part
    return out


def _dose(where, cols, i, model, t, amt, rate, ii, addl, ss, cmt) -> Events:
    line = _at(cols, i)
    if not (np.isfinite(amt) and amt > 0):
        raise ValueError(
            f"{where}: the dose {line} has AMT {amt:g}; a dose's amount is a number > 0 "
            "(EVID 2 marks a row with neither a dose nor an observation)"
        )
    if np.nan_to_num(ss) not in (0, 1):
        raise ValueError(
            f"{where}: SS {ss:g} {line}: only SS 1 (the dose at steady state, the states "
            "before it replaced) is supported; SS 2 adds a steady state to the states, "
            "which is right for linear models only: give the doses before it (ADDL with II)"
        )
    rate = float(np.nan_to_num(rate))
    if rate < 0 and rate != -2:
        raise ValueError(
            f"{where}: RATE {rate:g} {line}: a rate the model sets (RATE -1) is not "
            "supported yet, nor is a negative rate; give RATE > 0 (an infusion), 0 (a "
            "bolus) or -2 (the duration the model file's durations state)"
        )
    target = _target(where, cols, i, cmt, list(model.states))
    try:
        ii, addl = float(np.nan_to_num(ii)), np.nan_to_num(addl)
        return Events.doses(t, target, amt, rate, ii, addl, ss=np.nan_to_num(ss) == 1)
    except ValueError as err:
        raise ValueError(f"{where}, {line}: {str(err).removeprefix('events: ')}") from None


def _plain_rows(where, cols, evid, amt, mdv) -> None:
    """One line for an EVID not understood, and for a cell that would be dropped
    without a word: MDV other than 0 or 1, an amount on a row that doses nothing (EVID
    0 or 2)."""
    bad = np.flatnonzero(~np.isin(evid, (0, 1, 2, 3, 4)))
    if bad.size:
        i = int(bad[0])
        raise ValueError(
            f"{where}: EVID {evid[i]:g} {_at(cols, i)} is not understood; EVID is 0 (an "
            "observation), 1 (a dose), 2 (nothing observed), 3 (a reset) or 4 (a reset and a "
            "dose)"
        )
    odd = np.flatnonzero(~np.isin(mdv, (0, 1)))
    if odd.size:
        raise ValueError(
            f"{where}: MDV {mdv[odd[0]]:g} {_at(cols, int(odd[0]))} is not understood; MDV "
            "is 0 (the row observes its output) or 1 (it does not)"
        )
    lost = np.flatnonzero(np.isin(evid, (0, 2)) & (np.nan_to_num(amt) != 0))
    if lost.size:
        i = int(lost[0])
        raise ValueError(
            f"{where}: the row {_at(cols, i)} has AMT {amt[i]:g} and EVID {evid[i]:g}, which "
            "doses nothing; give EVID 1 for a dose, or an empty AMT (or 0)"
        )


def _observations(where, cols, model, outputs, evid, mdv, n):
    """(y (n, S) with NaN where not measured, observed (n, S)) of the rows; (None,
    None) where the file has no output column."""
    if not outputs:
        return None, None
    y = np.full((n, model.S), np.nan)
    for name in outputs:
        y[:, model.outputs.index(name)] = numbers(where, cols, name, n)
    row = (evid == 0) & (mdv == 0)
    inf = np.flatnonzero((row[:, None] & np.isinf(y)).any(axis=1))
    if inf.size:
        raise ValueError(
            f"{where}: an observation {_at(cols, int(inf[0]))} is infinite; an observation "
            "is a finite number (a missing one is empty or '.', or MDV 1)"
        )
    seen = row[:, None] & np.isfinite(y)
    which = np.zeros((n, model.S), dtype=bool)  # the output each row's DVID names
    if "DVID" in cols.values:  # one output: the rows of another DVID are not its
        dvid = numbers(where, cols, "DVID", n) if "DVID" not in cols.text else None
        for i in np.flatnonzero(row):
            k = _output(where, cols, i, None if dvid is None else dvid[i], model)
            which[i, k] = True
        seen &= which
    missing = [o for o in model.outputs if o not in outputs]
    if missing:  # an output the file lacks is never observed
        lost = which[:, [model.outputs.index(o) for o in missing]].any(axis=1)
        if lost.any():  # rows whose DVID names it: said, not dropped silently
            warnings.warn(  # (the file's, not each unit's: said once)
                f"{where.split(', unit ')[0]}: the observation rows whose DVID names "
                f"{missing} are not read: no column is mapped to them (--columns "
                f"{missing[0]}=DV; columns= in Python)", DataNote, stacklevel=2
            )  # fmt: skip
        seen[:, [model.outputs.index(o) for o in missing]] = False
    return y, seen


def _output(where, cols, i, raw, model) -> int:
    """The output a row's DVID names (1-based number or name)."""
    cell = cols.text["DVID"][i].strip() if "DVID" in cols.text else None
    if cell is not None and cell in model.outputs:
        return list(model.outputs).index(cell)
    try:
        k = float(cell if cell is not None else raw)  # type: ignore[arg-type]
        if k.is_integer() and 1 <= k <= model.S:
            return int(k) - 1
    except (TypeError, ValueError):
        pass
    raise ValueError(
        f"{where}: DVID {cell if cell is not None else raw} {_at(cols, i)} names no output; "
        f"the model's outputs are {list(model.outputs)}: DVID is 1 to {model.S} or a name"
    )


def _inputs(where, cols, model, first) -> np.ndarray:
    """The inputs at each distinct time (its first row's values)."""
    if not model.U:
        return np.zeros((first.size, 0))
    cols_u = []
    for name in model.inputs:
        if name in cols.constants:
            cols_u.append(np.full(first.size, cols.constants[name]))
            continue
        if name not in cols.values:
            raise ValueError(
                f"{where} lacks the input column {name!r}; found {sorted(cols.values)} (an "
                f"input the file lacks can be held constant: --columns {name}=0)"
            )
        v = numbers(where, cols, name, _size(cols))
        bad = np.flatnonzero(~np.isfinite(v[first]))
        if bad.size:
            i = int(first[bad[0]])
            raise ValueError(
                f"{where}: the input {name!r} is missing {_at(cols, i)}; every row needs it "
                "(a covariate: its unit's value)"
            )
        cols_u.append(v[first])
    return np.stack(cols_u, axis=1)


def records_of(label, cols, model, require_outputs, records, covariates, stem: str) -> list:
    """The records of an event table: one per unit (``stem``: the name of the file's
    one record without ``records``), each with its doses and its rows without an
    observation; the units without any observation, or of one time, left out with a
    note, the events after a unit's last row with one note for all, and
    each unit's notes said once for the file."""

    if "t" not in cols.values:
        raise ValueError(
            f"{label}: an event table needs its time column: map it with --columns t=TIME "
            f"(columns={{'t': 'TIME'}}); found {sorted(cols.values)}"
        )
    units = [(stem, cols)] if records is None else split_units(label, cols, records)
    for name, part in units:  # every unit checked before any is made
        check_covariates(label, None if records is None else name, part, covariates)
    out, empty, late, single = [], [], {}, []
    notes: dict[str, type[Warning]] = {}  # the units' notes, each said once for the file
    for name, part in units:
        where = str(label) if records is None else as_text(label, name)
        try:
            with warnings.catch_warnings(record=True) as said:  # the file's notes: once
                warnings.simplefilter("always")
                e = unit_record(where, name, part, model, require_outputs)
        except SingleRow:
            if records is None:  # the file's one record: nothing else to fit
                raise
            single.append(name)
            continue
        finally:
            notes.update({str(w.message): w.category for w in said})
        if e is None:
            empty.append(name)
            continue
        if e.late_events:
            late[name] = e.late_events
        out.append(e)
    if empty:
        warnings.warn(
            f"{label}: unit(s) {empty} have no observation and are left out", DataNote, stacklevel=3
        )
    for text, category in notes.items():
        warnings.warn(text, category, stacklevel=3)
    if single:
        warnings.warn(
            f"{label}: unit(s) {single} hold one time (one row, or a baseline at its dose's "
            "time; nothing to integrate) and are left out", DataNote, stacklevel=3
        )  # fmt: skip
    warn_late(str(label), late)
    if not out:
        raise ValueError(f"{label}: no unit has an observation of {list(model.outputs)}")
    return out
