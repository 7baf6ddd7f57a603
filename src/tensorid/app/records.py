"""Many units in one long file (``load_data(..., records="ID")``, ``--records ID``):
the rows of each value of the id column are one unit's record, in the order the ids
first appear, named by the id as text ("1", "A-17"). Each unit keeps its own time
stamps. Columns constant within a unit (weight, dose) are its covariates; a model
input named like one reads it as a constant signal.

Also the check of the covariates a model file declares (``covariates = ["Wt"]``):
constant within each unit (each file, without ``records``). Every mistake is one line
(a ValueError) naming the file, the unit and the file's line.
"""

from __future__ import annotations

import re
import warnings

import numpy as np

from ..engine.modelling.data import Experiment
from ..engine.modelling.model import Model
from .fleets import did_you_mean
from .readers import Said, _Columns
from .timebase import DataNote


def _id_text(v) -> str:
    """An id as text: 3.0 as "3", text stripped."""
    if isinstance(v, float | np.floating) and float(v).is_integer():
        return str(int(v))
    return str(v).strip()


def has_id_column(p, cols: _Columns, column: str) -> None:
    """One line, with the nearest name, when the file (as read, before any column map)
    has no id column ``column``."""
    if column in cols.values:
        return
    names = [str(n) for n in cols.values]
    hint = did_you_mean(column, names)
    raise ValueError(
        f"{p} has no id column {column!r}{hint} for --records (records= in Python); "
        f"its {cols.what}s are {names}"
    )


def _ids(p, cols: _Columns, column: str) -> list[str]:
    """The id of every row, as text; one line for a missing id."""
    has_id_column(p, cols, column)
    raw = cols.values[column]
    if isinstance(raw, str):  # text ids: the reader kept the cells
        if column not in cols.text:
            raise ValueError(f"{p}: {raw}")
        raw = np.asarray(cols.text[column], dtype=object)
    arr = np.ravel(np.asarray(raw))
    ids = [_id_text(v) for v in arr]
    blank = [
        i for i, (v, s) in enumerate(zip(arr, ids, strict=True)) if s in ("", "nan") or v is None
    ]
    if blank:
        raise ValueError(
            f"{p}: the id column {column!r} is empty {_at(cols, blank[0])}; every row "
            "needs its unit's id"
        )
    return ids


def _at(cols: _Columns, i: int) -> str:
    """ "on line 12" (text files) or "at row 11" (0-based, others)."""
    return f"on line {cols.lines[i]}" if cols.lines else f"at row {i}"


def _part(cols: _Columns, rows: np.ndarray, size: int) -> _Columns:
    """The columns of ``rows`` only (a per-row array is cut; anything else kept)."""
    values = {
        n: v[rows] if isinstance(v, np.ndarray) and v.ndim >= 1 and v.shape[0] == size else v
        for n, v in cols.values.items()
    }
    lines = [cols.lines[i] for i in rows] if cols.lines else None
    text = {n: [cells[i] for i in rows] for n, cells in cols.text.items()}
    return _Columns(values, cols.what, lines, cols.note, dict(cols.constants), text)


def split_units(p, cols: _Columns, column: str) -> list[tuple[str, _Columns]]:
    """(id, its rows' columns) per unit, in the order the ids first appear."""
    ids = _ids(p, cols, column)
    order: dict[str, list[int]] = {}
    for i, name in enumerate(ids):
        order.setdefault(name, []).append(i)
    parts = [(name, _part(cols, np.array(rows), len(ids))) for name, rows in order.items()]
    lines = cols.lines or []
    for n, v in cols.values.items():  # a column that could not be read, at a line:
        cited = re.search(r"on line (\d+)", v) if isinstance(v, str) else None
        if cited and int(cited[1]) in lines:  # said as that line's unit's
            owner = ids[lines.index(int(cited[1]))]
            for _, part in parts:
                part.values[n] = Said(f"{as_text(p, owner)}: {v}")
    return parts


def no_samples(p, units: list[tuple[str, _Columns]], model: Model, require_outputs: bool):
    """The units without a single observation (every output missing on every row)
    are left out with a note naming them (they hold nothing to fit); read for
    simulation, they are kept, without outputs. A unit of one sample is refused: a
    record needs two."""
    empty, kept = [], []
    for name, cols in units:
        outs = [n for n in model.outputs if n in cols.values]
        if outs and all(_all_missing(cols.values[n]) for n in outs):
            if require_outputs:
                empty.append(name)
                continue
            cols = _Columns(
                {n: v for n, v in cols.values.items() if n not in outs},
                cols.what,
                cols.lines,
                cols.note,
                cols.constants,
            )
        kept.append((name, cols))
    if empty:
        warnings.warn(
            f"{p}: unit(s) {empty} have no observation (every output missing) and are left out",
            DataNote,
            stacklevel=3,
        )
    single = [(n, c) for n, c in kept if _size(c) < 2]
    if single:
        name, cols = single[0]
        where = f" ({_at(cols, 0)})" if _size(cols) else ""
        raise ValueError(
            f"{p}: unit {name!r} has a single sample{where}"
            + (f", as have {[n for n, _ in single[1:]]}" if len(single) > 1 else "")
            + "; a unit's record needs at least 2 samples: add samples or remove its rows"
        )
    if not kept:
        raise ValueError(f"{p}: no unit has an observation of {list(model.outputs)}")
    return kept


def _all_missing(v) -> bool:
    """Whether a column of numbers holds no finite value."""
    if not isinstance(v, np.ndarray) or v.dtype.kind not in "biuf":
        return False
    return not np.isfinite(v.astype(float)).any()


def _size(cols: _Columns) -> int:
    sizes = [v.shape[0] for v in cols.values.values() if isinstance(v, np.ndarray) and v.ndim]
    return max(sizes, default=0)


def increasing(p, name: str, cols: _Columns) -> None:
    """The unit's time stamps strictly increasing, in the file's order; else one line
    naming the unit and the line."""
    t = cols.values.get("t")
    if not isinstance(t, np.ndarray) or t.dtype.kind not in "biuf":
        return  # no time column (--ts), or not numbers: told where time is read
    dt = np.diff(t.astype(float))
    bad = np.flatnonzero(~(dt > 0) & np.isfinite(dt))
    if bad.size:
        i = int(bad[0]) + 1
        what = "repeats" if dt[i - 1] == 0 else "goes backwards"
        raise ValueError(
            f"{p}: the time of unit {name!r} {what} {_at(cols, i)} ({t[i - 1]:g} then "
            f"{t[i]:g}); a unit's rows must be in increasing time: sort the file by id "
            "and time, and drop repeated rows"
        )


def not_several_units(p, cols: _Columns) -> None:
    """A file read as one record whose time starts again where another column changes
    holds several units: one line that says to name that column with --records (it
    was explained as a covariate that varies, or time that goes backwards)."""
    t = cols.values.get("t")
    if not isinstance(t, np.ndarray) or t.dtype.kind not in "biuf" or t.size < 3:
        return
    again = np.flatnonzero(np.diff(t.astype(float)) < 0) + 1
    if not again.size or np.min(np.diff([0, *again, t.size])) < 2:
        return  # no restart, or a "unit" of one row: a time stamp out of place
    found = []  # the columns that change where time starts again, and only there
    for c, v in cols.values.items():
        cells = cols.text.get(c) or (list(v) if isinstance(v, np.ndarray) and v.ndim == 1 else None)
        if c == "t" or cells is None or len(cells) != t.size:
            continue
        changes = {i for i in range(1, t.size) if cells[i] != cells[i - 1]}
        if changes == set(again.tolist()):  # constant between the restarts: an id
            found.append(c)
    if found:  # an id's name first (ID, Subject, unit), else the first in the file
        c = next((n for n in found if n.lower() in _ID_NAMES), found[0])
        i = int(again[0])
        raise ValueError(
            f"{p}: the time starts again {_at(cols, i)} ({t[i - 1]:g} then {t[i]:g}) "
            f"where column {c!r} changes: the file holds several units; name its unit "
            f"column with --records {c} (Python: records={c!r})"
        )


_ID_NAMES = ("id", "subject", "unit", "record", "serial", "patient", "batch")


def check_covariates(p, name: str | None, cols: _Columns, covariates) -> None:
    """Every covariate constant over the unit's rows (one line naming where it
    changes); an input that is no covariate may vary in time."""
    for c in covariates or ():
        v = cols.values.get(c)
        if not isinstance(v, np.ndarray) or v.dtype.kind not in "biuf" or v.size < 2:
            continue
        v = v.astype(float)
        changed = np.flatnonzero(np.abs(v - v[0]) > 1e-12 * max(abs(v[0]), 1e-300))
        if changed.size:
            i = int(changed[0])
            unit = f"unit {name!r}" if name is not None else "the record"
            raise ValueError(
                f"{p}: the covariate {c!r} changes within {unit} ({v[0]:g} {_at(cols, 0)}, "
                f"{v[i]:g} {_at(cols, i)}); a covariate is constant per unit: fix the data, "
                "or drop it from covariates in the model file (an input may vary in time)"
            )


def as_text(p, column: str | None) -> str:
    """ "FILE, unit 'ID'" for a unit's messages, or the file alone."""
    return str(p) if column is None else f"{p}, unit {column!r}"


def one_unit(args, load) -> Experiment:
    """simulate's and compare's one record, ``load(records=...)`` (load_data): with
    ``--records``, the unit ``--unit`` names (the only one needs no name); one line for
    a unit the file lacks, or --unit without --records (before the file is read)."""
    unit, column = getattr(args, "unit", None), getattr(args, "records", None)
    if unit is not None and column is None:
        raise ValueError(f"--unit {unit} picks a unit of --records ID_COLUMN: give --records")
    exps = load(records=column)
    if column is None or (unit is None and len(exps) == 1):
        return exps[0]
    names = [e.name for e in exps]
    shown = str(names[:10])[:-1] + (", ...]" if len(names) > 10 else "]")
    if unit is None:
        raise ValueError(
            f"{args.data} holds {len(names)} units (--records {column}): name the one to "
            f"use with --unit ID, one of {shown}"
        )
    if str(unit) not in names:
        raise ValueError(
            f"--unit {unit}: {args.data} has no unit {str(unit)!r} in its column {column!r}"
            f"{did_you_mean(unit, names)}; its units are {shown}"
        )
    return exps[names.index(str(unit))]
