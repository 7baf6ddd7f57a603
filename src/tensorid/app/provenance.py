"""Where a result came from: the model file and data files (path and SHA-256), the
columns read, the command line, the versions and the time. fit.json, compare.json
and report.md carry it, so a number can be traced back and reproduced."""

from __future__ import annotations

import datetime
import hashlib
import os
import platform
import shlex
import sys
from pathlib import Path


def sha256(path) -> str | None:
    """The file's SHA-256 (hex), or None when it cannot be read."""
    h = hashlib.sha256()
    try:
        with Path(path).open("rb") as f:
            for block in iter(lambda: f.read(1 << 20), b""):
                h.update(block)
    except OSError:
        return None
    return h.hexdigest()


def _file(path) -> dict:
    """The path as given, its SHA-256 and, since a relative path means nothing without
    the folder it was given in, the absolute path."""
    return {"path": str(path), "sha256": sha256(path), "absolute_path": _absolute(path)}


def _absolute(path) -> str:
    try:
        return str(Path(path).resolve())
    except (OSError, RuntimeError):
        return str(Path.cwd() / str(path))


def _versions() -> dict:
    import jax
    import numpy

    from .._config import __version__

    return {
        "tensorid": __version__,
        "jax": jax.__version__,
        "numpy": numpy.__version__,
        "python": platform.python_version(),
    }


def data_entries(specs: list, columns: list) -> list[dict]:
    """One entry per data file: path, SHA-256 and the column map it was read with
    (``specs`` may join files as "u.mat+y.mat": each file is listed)."""
    out = []
    for spec, cols in zip(specs, columns, strict=True):
        for part in str(spec).split("+") if not Path(spec).exists() else [spec]:
            out.append(dict(_file(part), columns=dict(cols or {})))
    return out


def provenance(
    model_path,
    data: list[dict],
    argv: list[str] | None,
    *,
    ts: float | None = None,
    roles: list[str] | None = None,
    fit=None,
    start_from=None,
) -> dict:
    """fit.json's and compare.json's "provenance": with ``ts`` (--ts), each data
    entry's time base; ``roles`` names each entry "training", "validation" or
    "scored"; ``fit``: the fit.json a compare scored (path and SHA-256);
    ``start_from``: the fit.json a fit started from (--start-from, path and SHA-256)."""
    words = ["tensorid", *(sys.argv[1:] if argv is None else argv)]
    for k, entry in enumerate(data):
        _time_base(entry, ts)
        if roles is not None:
            entry["role"] = roles[k]
    out = {
        "model": _file(model_path),
        "data": data,
        "command": shlex.join(words),
        "versions": _versions(),
        "time": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"),
        "working_directory": os.getcwd(),
    }
    out |= {"start_from": _file(start_from)} if start_from is not None else {}
    return out | ({"fit": _file(fit)} if fit is not None else {})


def _time_base(entry: dict, ts: float | None) -> None:
    """Where a data file's sample times came from ("time" in its entry): --ts, its time
    column, or its own sampling time Ts; the column map names "t" only where a column
    was read for it (it said t=t of files without one)."""
    columns = entry.get("columns", {})
    source = columns.get("t", "t")
    if ts is not None:
        entry["time"] = f"--ts {ts:g}"
    elif _has_column(entry["path"], source):
        entry["time"] = f"column {source}"
        return
    else:
        entry["time"] = "the file's sampling time Ts"
    columns.pop("t", None)


def _has_column(path, name) -> bool:
    """Whether the data file holds a signal ``name`` (read again: the loaders keep no
    note of it; a file that cannot be read is taken to hold it)."""
    from .readers import _read

    try:
        return str(name) in _read(Path(path)).values
    except (OSError, ValueError):
        return True


def markdown(prov: dict) -> list[str]:
    """report.md's provenance section."""
    lines = [
        "## Provenance",
        "",
        f"- model file: `{prov['model']['path']}` (SHA-256 `{prov['model']['sha256']}`)",
    ]
    if prov.get("fit"):
        lines.append(f"- fit scored: `{prov['fit']['path']}` (SHA-256 `{prov['fit']['sha256']}`)")
    for d in prov["data"]:
        cols = ", ".join(f"{k}={v}" for k, v in d["columns"].items())
        role = f"{d['role']} data file" if d.get("role") else "data file"
        lines.append(
            f"- {role}: `{d['path']}` (SHA-256 `{d['sha256']}`)"
            + (f", columns {cols}" if cols else "")
            + (f", time from {d['time']}" if d.get("time") else "")
            + (f", samples {d['samples'][0]}:{d['samples'][1]}" if d.get("samples") else "")
        )
    v = prov["versions"]
    lines += [
        f"- command: `{prov['command']}`",
        f"- tensorid {v['tensorid']}, JAX {v['jax']}, NumPy {v['numpy']}, "
        f"Python {v['python']}; {prov['time']}",
    ]
    if prov.get("working_directory"):
        lines.append(f"- working directory: `{prov['working_directory']}`")
    return lines


def other_model(fitted: dict, model_path) -> str:
    """A note where a fit.json was made with another model file than ``model_path`` (by
    content: another file, or this one edited since), or "": its parameters are read
    by these equations, which may not be the ones they were fitted with."""
    made = (fitted.get("provenance") or {}).get("model") or {}
    if not made.get("sha256") or made["sha256"] == sha256(model_path):
        return ""
    same = Path(str(made.get("path", ""))).resolve() == Path(model_path).resolve()
    what = "this model file before it was edited" if same else f"{made.get('path')}"
    return (
        f"tensorid: note: the fit was made with {what} (SHA-256 {made['sha256'][:12]}..., "
        f"not {model_path}'s): its parameters are read by the equations of {model_path}"
    )
