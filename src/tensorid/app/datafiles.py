"""Data files: one experiment per file, or files joined side by side.

The formats (CSV, MATLAB .mat, NumPy .npz) are read into named columns by
:mod:`tensorid.app.readers`; here those columns become an Experiment under the model's
names. Time is a column or variable ``t``, or the sampling time ``ts``; every other
column named after a model input or output is that signal.

A bad file gets one line (a ValueError) that names the file, what is wrong and where,
and how to fix it.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np

from ..engine.modelling.data import Experiment
from ..engine.modelling.model import Model
from . import event_table
from .readers import _TS, _Columns, _read, _real, input_is_output
from .records import (
    as_text,
    check_covariates,
    has_id_column,
    increasing,
    no_samples,
    not_several_units,
    split_units,
)
from .timebase import DataNote, _time  # noqa: F401  (DataNote: here for cli.py and users)

# -- experiments -----------------------------------------------------------------------


def _signals(p: Path, cols: _Columns, names: list[str]) -> dict[str, np.ndarray]:
    """The named signals as real arrays of one length, all finite."""
    data = {n: _real(p, cols.what, n, cols.values[n]) for n in names}
    sizes = {n: a.size for n, a in data.items()}
    if len(set(sizes.values())) > 1:
        raise ValueError(
            f"{p}: the {cols.what}s differ in length ({sizes}); every signal needs one "
            "value per sample"
        )
    for name, a in data.items():
        bad = ~np.isfinite(a)
        if bad.any():
            i = int(np.argmax(bad))
            row = f" (line {cols.lines[i]} of the file)" if cols.lines else ""
            raise ValueError(
                f"{p}: column {name!r} has {int(bad.sum())} missing or non-finite "
                f"value(s) (empty, NaN or inf), first at sample {i}{row}; remove or "
                "fill those samples"
            )
    return data


def _window(p: Path, e: Experiment, samples: tuple[int, int]) -> Experiment:
    """Samples start:stop of the record, refused unless they lie inside it."""
    start, stop = (int(s) for s in samples)
    P = e.P
    if min(start, stop) < 0 or stop > P or stop - start < 2:
        why = (
            "a negative index"
            if min(start, stop) < 0
            else "past the end"
            if stop > P
            else "START is not below STOP"
            if start >= stop
            else "only one sample"
        )
        raise ValueError(
            f"{p} has {P} samples, so samples {start}:{stop} are out of range ({why}); "
            f"choose START:STOP with 0 <= START < STOP <= {P}, at least 2 samples"
        )
    return e.window(start, stop)


def _constant(source) -> float | None:
    """The number a column map gives instead of a column name ("pulses=0": an input
    the record lacks, held at 0), or None."""
    if isinstance(source, bool):
        return None
    if isinstance(source, int | float):
        return float(source)
    try:
        return float(str(source))
    except ValueError:
        return None


def _mapped(p, cols: _Columns, columns: dict | None, model: Model, strict=True) -> _Columns:
    """The file's signals under the model's names: ``columns`` maps a model input,
    output or "t" to the file's column (variable, array) name, or an input to a
    number: a constant signal the record lacks (the file's own column of that name,
    should it have one, wins). An output mapped to a number is refused: it is a
    measurement."""
    if not columns:
        return cols
    known = ["t", *model.inputs, *model.outputs]
    values = dict(cols.values)
    constants, text = dict(cols.constants), dict(cols.text)
    for name, source in columns.items():
        if name not in known:
            raise ValueError(
                f"columns: {name!r} is not one of the model's inputs, outputs or 't' {known}"
            )
        value = None if str(source) in cols.values else _constant(source)
        if value is not None and name in model.outputs:
            raise ValueError(
                f"columns: {name}={source}: a number holds an input constant, but {name!r} "
                "is an output, which is measured: map it to the file's column, or leave it "
                "out to simulate without scores"
            )
        if value is not None and name != "t":
            if not np.isfinite(value):
                raise ValueError(f"columns: {name}={source} is not a finite number")
            constants[name] = value
            values.pop(name, None)
            continue
        if source not in cols.values:
            if not strict:  # one of several files: another may hold it
                continue
            raise ValueError(
                f"{p}: columns maps {name!r} to {source!r}, which the file does not have; "
                f"it has {sorted(cols.values)}"
            )
        values[name] = cols.values[source]
        if source in cols.text:  # a text column's cells go with it ("." in an event table)
            text[name] = cols.text[source]
    input_is_output(p, columns, model, constants)
    return _Columns(values, cols.what, cols.lines, cols.note, constants, text)


def _joined(paths: list[Path], parts: list[_Columns]) -> _Columns:
    """Several files' columns side by side (inputs in one, outputs in another): one
    name in two files is refused, except a time column that agrees."""
    values: dict = {}
    for p, cols in zip(paths, parts, strict=True):
        for name, v in cols.values.items():
            if name == "t" and name in values and np.size(v) != np.size(values[name]):
                raise ValueError(
                    f"the joined files {[str(q) for q in paths]} have different lengths "
                    f"({np.size(values[name])} and {np.size(v)} samples in {p}); join records of "
                    "the same length"
                )
            same = (
                name in values
                and isinstance(v, np.ndarray)
                and np.array_equal(np.ravel(v), np.ravel(values[name]))
            )
            if name in values and name in ("t", *_TS) and not same:
                first = next(q for q, c in zip(paths, parts, strict=True) if name in c.values)
                raise ValueError(
                    f"{p}: its time column {name!r} differs from {first}'s (joined files are "
                    "samples of one record, side by side): give files of the same times, or "
                    "keep the time in one of them"
                )
            if name in values and name not in ("t", *_TS):
                raise ValueError(
                    f"{p}: column {name!r} is in more than one of the joined files "
                    f"{[str(q) for q in paths]}; keep it in one"
                )
            values[name] = v
    lines = parts[0].lines if all(c.lines == parts[0].lines for c in parts) else None
    return _Columns(values, parts[0].what, lines, "")


def _lacking(p, cols: _Columns, model: Model, need: list[str], ts) -> None:
    """One line when the file lacks a signal the model needs; an input may be held
    at a constant instead (NAME=0 in the column map)."""
    missing = [n for n in need if not cols.has(n)]
    if not missing:
        return
    # the same name in other capitals (MATLAB exports U, Y): read by name, exactly
    # (all of them at once: t, inputs and outputs, not one per try)
    names = (["t"] if ts is None else []) + list(model.inputs) + list(model.outputs)
    absent = [n for n in names if not cols.has(n)]
    cased = {n: c for n in absent for c in cols.values if str(c).lower() == n.lower()}
    inputs = [n for n in missing if n in model.inputs and n not in cased]
    hint = (
        f"; an input the record lacks can be held constant: --columns "
        f"{','.join(f'{n}=0' for n in inputs)} (columns={{{inputs[0]!r}: 0}} in Python)"
        if inputs
        else ""
    )
    if cased:
        pairs = ",".join(f"{n}={c}" for n, c in cased.items())
        hint = f"; names are read as written, capitals too: --columns {pairs}{hint}"
    raise ValueError(
        f"{p} lacks columns {missing}; expected {(['t'] if ts is None else []) + need} "
        f"(the model's inputs {list(model.inputs)} and outputs {list(model.outputs)}), "
        f"found {sorted(cols.values)}{cols.note}{hint}"
    )


def _experiment(p, cols: _Columns, model: Model, ts, samples, require_outputs: bool):
    """The Experiment of one file (or of files joined, ``p`` naming them all)."""
    need = list(model.inputs) + list(model.outputs)
    has_outputs = all(cols.has(n) for n in model.outputs)
    if not require_outputs and not has_outputs:
        need = list(model.inputs)
        _some_outputs(p, cols, model)
    _lacking(p, cols, model, need, ts)
    use_t = "t" in cols.values and ts is None
    read = [n for n in need if n not in cols.constants]
    data = _signals(p, cols, (["t"] if use_t else []) + read)
    if not data:  # no signal read (autonomous, or held constant): any array sets P
        arrays = [v for v in cols.values.values() if isinstance(v, np.ndarray) and v.size > 1]
        data = {"": arrays[0]} if arrays else {"": np.zeros(0)}
    P = next(iter(data.values())).size
    data.update({n: np.full(P, c) for n, c in cols.constants.items()})
    t = _time(p, cols, ts, P, data)
    u = np.stack([data[n] for n in model.inputs], axis=1) if model.U else np.zeros((P, 0))
    y = np.stack([data[n] for n in model.outputs], axis=1) if has_outputs else None
    try:
        e = Experiment(t, u, y, name=_stem(p))
    except ValueError as err:  # time not increasing, too short: name the file
        raise ValueError(f"{p}: {err}") from None
    return e if samples is None else _window(p, e, samples)


def _some_outputs(p, cols: _Columns, model: Model) -> None:
    """A DataNote where a file read without outputs (for simulation) holds some of
    them: a record is scored only with every output, and the ones it has were left
    unused without a word."""
    have = [n for n in model.outputs if cols.has(n)]
    if not have:
        return
    import warnings

    lacks = [n for n in model.outputs if n not in have]
    warnings.warn(
        f"{p} has the output(s) {have} but lacks {lacks}: simulated without scores and "
        "without estimating initial states (give every output's column to score it)",
        DataNote,
        stacklevel=3,
    )


def _stem(p) -> str:
    return "+".join(Path(q).stem for q in str(p).split("+"))


def _needed(cols: _Columns, model: Model, require_outputs: bool) -> list[str]:
    """The model's signals this file lacks."""
    need = list(model.inputs) + ([] if not require_outputs else list(model.outputs))
    return [n for n in need if not cols.has(n)]


def _one_or_joined(
    spec, columns, model, ts, samples, require_outputs, records=None, covariates=None, events=None
) -> list[Experiment]:
    """The Experiment of one file, or of "a.mat+b.mat" joined side by side; with
    ``records`` (an id column), one per unit."""
    paths = [Path(q) for q in str(spec).split("+")] if not Path(spec).exists() else [Path(spec)]
    if any(not q for q in str(spec).split("+")) and len(paths) > 1:
        raise ValueError(
            f"data file {spec}: a file name is missing around '+'; join files as u.csv+y.csv"
        )
    parts = [_read(q) for q in paths]
    cols = parts[0] if len(parts) == 1 else _joined(paths, parts)
    label = paths[0] if len(paths) == 1 else "+".join(str(q) for q in paths)
    if records is not None:
        has_id_column(label, cols, records)
    cols = event_table.mapped(label, _mapped(label, cols, columns, model), events)
    if records is None:
        not_several_units(label, cols)
    if event_table.is_event_table(cols):
        if samples is not None or ts is not None:  # (they were dropped without a word)
            what = "samples (--samples, --validate-samples)" if samples is not None else "ts (--ts)"
            raise ValueError(
                f"{label} is an event table (its rows are doses and observations at their "
                f"times): {what} does not apply to it; drop it"
            )
        return event_table.records_of(
            label, cols, model, require_outputs, records, covariates, _stem(label)
        )
    if records is None:
        check_covariates(label, None, cols, covariates)
        return [_experiment(label, cols, model, ts, samples, require_outputs)]
    units = no_samples(label, split_units(label, cols, records), model, require_outputs)
    out = []
    for name, part in units:  # every unit checked before any is made
        increasing(label, name, part)
        check_covariates(label, name, part, covariates)
    for name, part in units:
        e = _experiment(as_text(label, name), part, model, ts, None, require_outputs)
        out.append(replace(e, name=name))
    return out


def load_data(
    paths,
    model: Model,
    ts: float | None = None,
    samples: tuple[int, int] | None = None,
    require_outputs: bool = True,
    columns: dict | list[dict | None] | None = None,
    records: str | None = None,
    covariates: list[str] | None = None,
    events: dict | None = None,
) -> list[Experiment]:
    """One Experiment per file, with the model's input and output columns; time from
    a column ``t`` (time stamps within 0.1 % of a sample time of a uniform grid are
    snapped to it, with a :class:`DataNote`), from the sampling time ``ts``, or from
    the file's own ``Ts`` column or variable. ``samples`` = (start, stop) keeps that
    slice of every file. Without ``require_outputs`` a file may lack the output
    columns (for simulation).

    ``columns`` maps model names to the file's names, e.g. ``{"u": "uEst", "y":
    "yEst"}`` (CSV headers, .mat variables, .npz keys; "t" for the time column), or
    an input to a number, held constant (``{"pulses": 0}``: an input the
    record lacks). A list of maps gives each file its own, in the order of
    ``paths``; so one file holding several records (u1/y1, u2/y2) is read once per
    record, each named ``file:map``. Inputs and outputs in separate files are joined
    side by side: give ``"u.mat+y.mat"``, or (with one map for all) a list of files
    that each lack what the others hold.

    ``records`` names an id column: each file holds many units (a fleet, a cohort),
    and each unit's rows (in the file's order, their times increasing) are one
    Experiment named by its id as text ("1"), in the order the ids first appear;
    with several files, named ``file:id``. A unit with no observation is left out
    with a :class:`DataNote`; one of a single sample is refused. ``covariates`` names
    inputs that must be constant within each unit (each file, without ``records``).

    A file with an AMT or an EVID column is an event table in NONMEM's layout (doses,
    infusions, repeated doses, rows without an observation: ``app/event_table.py``);
    ``events`` maps NONMEM's column names to the file's, e.g. ``{"AMT": "DOSE"}``. Each
    record then carries its doses (``Experiment.events``), and a unit of one
    observation is kept."""
    if isinstance(paths, str | Path):
        paths = [paths]
    if records is not None and not isinstance(records, str):
        raise TypeError(
            f"records must be the name of the id column (a str such as 'ID'), got {records!r}"
        )
    if ts is not None and not 0 < ts < np.inf:
        raise ValueError(f"the sampling time ts must be positive and finite, got {ts}")
    if records is not None and (samples is not None or ts is not None):  # (ts was dropped)
        what = ("samples (--samples) cut one record", "samples")
        what = ("ts (--ts) puts one record's samples at k·ts", "ts") if samples is None else what
        raise ValueError(f"{what[0]}, and records (--records) reads many units of differing "
                         f"lengths, each with its own time stamps: drop {what[1]}")  # fmt: skip
    paths = list(paths)
    maps = _maps(columns, len(paths))
    if len(paths) > 1 and not isinstance(columns, list):
        if _complementary(paths, columns, model, require_outputs):
            paths, maps = ["+".join(str(p) for p in paths)], [columns]
    exps, each_map, each_path = [], [], []
    for p, c in zip(paths, maps, strict=True):
        some = _one_or_joined(
            p, c, model, ts, samples, require_outputs, records, covariates, events
        )
        if records is not None and len(paths) > 1:  # units of several files: file:id
            some = [replace(e, name=f"{_stem(p)}:{e.name}") for e in some]
        exps += some
        each_map += [c] * len(some)
        each_path += [p] * len(some)
    return _told_apart(exps, each_map, each_path)


def _maps(columns, n: int) -> list:
    """One column map per file."""
    if columns is None or isinstance(columns, dict):
        return [columns] * n
    if not isinstance(columns, list) or not all(c is None or isinstance(c, dict) for c in columns):
        raise TypeError(
            f"columns must be a dict {{model name: file column}} or a list of them, one "
            f"per file; got {columns!r}"
        )
    if len(columns) not in (1, n):
        raise ValueError(
            f"{len(columns)} column maps for {n} data files: give one map for all files, "
            "or one per file in their order"
        )
    return columns * n if len(columns) == 1 else columns


def map_text(columns: dict | None) -> str:
    """A column map as the command line writes it: "u=u1,y=z1"."""
    return ",".join(f"{k}={v}" for k, v in (columns or {}).items())


def _told_apart(exps: list[Experiment], maps: list, paths: list) -> list[Experiment]:
    """Records that would share a name get names of their own (fit.json, the report
    and the figures' files are keyed by it): read from one file with different maps,
    ``file:map``; files of one name in different folders, ``folder/file``; the same
    file twice, ``file#2`` for the second."""
    names = [e.name for e in exps]
    exps = [
        replace(e, name=f"{e.name}:{map_text(c)}") if names.count(e.name) > 1 and c else e
        for e, c in zip(exps, maps, strict=True)
    ]
    names = [e.name for e in exps]
    folders = [Path(str(p).split("+")[0]).resolve().parent.name for p in paths]
    group = {n: {d for e, d in zip(exps, folders, strict=True) if e.name == n} for n in names}
    exps = [  # in different folders: named by them too
        replace(e, name=f"{d}/{e.name}") if len(group[e.name]) > 1 and d else e
        for e, d in zip(exps, folders, strict=True)
    ]
    seen: dict[str, int] = {}
    out = []
    for e in exps:
        seen[e.name] = seen.get(e.name, 0) + 1
        out.append(e if seen[e.name] == 1 else replace(e, name=f"{e.name}#{seen[e.name]}"))
    return out


def _complementary(paths, columns, model, require_outputs) -> bool:
    """Whether files that each lack some of the model's signals hold them together
    (inputs in one file, outputs in another): then they are one experiment."""
    lacks = []
    for p in paths:
        p = Path(p)
        if not p.is_file():
            return False
        cols = _mapped(p, _read(p), columns, model, strict=False)
        lacks.append(set(_needed(cols, model, require_outputs)))
    return all(lacks) and not set.intersection(*lacks)
