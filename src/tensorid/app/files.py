"""Model files and data files.

A model file is Python. It defines ``model = tensorid.Model(...)`` or, for text
equations, ``rhs = {state: "expr"}`` with optional ``output``, ``inputs`` and
``params``; and it may define ``p0`` (dict), ``x0`` (dict state -> value),
``free_x0`` (list), ``fixed`` (list) and ``bounds`` (dict name -> (lo, hi)).

Data files are CSV (a time column ``t``, or a sampling time given as ``ts``, plus
columns named after the model's inputs and outputs), MATLAB .mat or NumPy .npz
(variables with those names). Each file is one experiment.
"""

from __future__ import annotations

import csv
import importlib.util
import sys
import traceback
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..engine.data import Experiment
from ..engine.equations import model_from_equations
from ..engine.model import Model


@dataclass
class ModelSpec:
    """What a model file defines: the model and the problem settings."""

    model: Model
    p0: dict | None = None
    x0: dict | None = None
    free_x0: list = field(default_factory=list)
    fixed: list = field(default_factory=list)
    bounds: dict = field(default_factory=dict)
    path: Path | None = None

    def x0_array(self) -> np.ndarray:
        """x0 of the model file as an array (N,), states it does not name at 0."""
        x0 = dict.fromkeys(self.model.states, 0.0)
        for k, v in (self.x0 or {}).items():
            if k not in x0:
                raise ValueError(
                    f"{self.path}: x0 names unknown state {k!r}; states are "
                    f"{list(self.model.states)}"
                )
            x0[k] = float(v)
        return np.array([x0[s] for s in self.model.states])


def _user_frames(exc: BaseException, path: Path) -> str:
    """The lines of the user's own file in a traceback."""
    frames = [
        f
        for f in traceback.extract_tb(exc.__traceback__)
        if Path(f.filename).resolve() == path.resolve()
    ]
    return "".join(f"  {path.name}, line {f.lineno}: {f.line}\n" for f in frames)


def load_model(path) -> ModelSpec:
    """Import a model file and return its :class:`ModelSpec`."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"model file {path} does not exist")
    name = f"_tensorid_model_{abs(hash(path.resolve()))}"
    spec = importlib.util.spec_from_file_location(name, path)
    if spec is None or spec.loader is None:
        raise ValueError(f"{path} is not a Python file")
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    # worker processes cannot import this file by name: ship its functions by value
    import cloudpickle

    cloudpickle.register_pickle_by_value(module)
    try:
        spec.loader.exec_module(module)
    except Exception as e:
        where = _user_frames(e, path)
        raise ValueError(
            f"the model file {path} failed to run: {type(e).__name__}: {e}\n{where}".rstrip()
        ) from e
    ns = vars(module)
    if isinstance(ns.get("model"), Model):
        model = ns["model"]
    elif isinstance(ns.get("rhs"), dict):
        model = model_from_equations(
            ns["rhs"], ns.get("output"), ns.get("inputs", ()), ns.get("params"), name=path.stem
        )
    else:
        raise ValueError(
            f"{path} defines neither `model = tensorid.Model(...)` nor text "
            "equations `rhs = {state: 'expression'}`"
        )
    out = ModelSpec(model, path=path)
    for key, kind in (
        ("p0", dict),
        ("x0", dict),
        ("free_x0", list),
        ("fixed", list),
        ("bounds", dict),
    ):
        if key in ns and ns[key] is not None:
            value = ns[key]
            if isinstance(value, tuple) and kind is list:
                value = list(value)
            if not isinstance(value, kind):
                raise TypeError(
                    f"{path}: {key} must be a {kind.__name__}, got {type(value).__name__}"
                )
            setattr(out, key, value)
    return out


def _columns_csv(path: Path) -> dict[str, np.ndarray]:
    with path.open(newline="") as f:
        rows = [r for r in csv.reader(f) if r and any(c.strip() for c in r)]
    if len(rows) < 2:
        raise ValueError(f"{path} has no data rows under its header")
    header = [h.strip() for h in rows[0]]
    body = rows[1:]
    out = {}
    for j, name in enumerate(header):
        if not name:
            continue  # a trailing comma makes an empty column
        try:
            out[name] = np.array(
                [float(r[j]) if j < len(r) and r[j].strip() else np.nan for r in body]
            )
        except ValueError as e:
            raise ValueError(
                f"{path}: column {name!r} holds a value that is not a number ({e})"
            ) from None
    return out


def _columns_mat(path: Path) -> dict[str, np.ndarray]:
    import scipy.io

    d = scipy.io.loadmat(path)
    return {
        k: np.asarray(v, dtype=float).ravel()
        for k, v in d.items()
        if not k.startswith("__") and np.asarray(v).size > 1
    }


def _columns_npz(path: Path) -> dict[str, np.ndarray]:
    with np.load(path) as z:
        return {k: np.asarray(z[k], dtype=float).ravel() for k in z.files}


def load_data(
    paths,
    model: Model,
    ts: float | None = None,
    samples: tuple[int, int] | None = None,
    require_outputs: bool = True,
) -> list[Experiment]:
    """One Experiment per file, with the model's input and output columns; time from
    a column ``t`` or from the sampling time ``ts``. ``samples`` = (start, stop)
    keeps that slice of every file. Without ``require_outputs`` a file may lack the
    output columns (for simulation)."""
    if isinstance(paths, str | Path):
        paths = [paths]
    exps = []
    for p in map(Path, paths):
        if not p.is_file():
            raise FileNotFoundError(f"data file {p} does not exist")
        suffix = p.suffix.lower()
        readers = {
            ".csv": _columns_csv,
            ".txt": _columns_csv,
            ".mat": _columns_mat,
            ".npz": _columns_npz,
        }
        if suffix not in readers:
            raise ValueError(f"{p}: unknown data format {suffix!r}; use .csv, .mat or .npz")
        cols = readers[suffix](p)
        need = list(model.inputs) + list(model.outputs)
        has_outputs = all(n in cols for n in model.outputs)
        if not require_outputs and not has_outputs:
            need = list(model.inputs)
        missing = [n for n in need if n not in cols]
        if missing:
            raise ValueError(
                f"{p} lacks columns {missing}; expected "
                f"{(['t'] if ts is None else []) + need} (the model's inputs "
                f"{list(model.inputs)} and outputs {list(model.outputs)}), found "
                f"{sorted(cols)}"
            )
        for name in (["t"] if "t" in cols and ts is None else []) + need:
            bad = ~np.isfinite(cols[name])
            if bad.any():
                i = int(np.argmax(bad))
                row = f" (line {i + 2} of the file)" if suffix in (".csv", ".txt") else ""
                raise ValueError(
                    f"{p}: column {name!r} has {int(bad.sum())} missing or non-finite "
                    f"value(s) (empty, NaN or inf), first at sample {i}{row}; remove or "
                    "fill those samples"
                )
        P = next(iter(cols.values())).size if not need else cols[need[0]].size
        if "t" in cols and ts is None:
            t = cols["t"]
        elif ts is not None:
            if not ts > 0:
                raise ValueError(f"the sampling time must be positive, got {ts}")
            t = np.arange(P) * float(ts)
        else:
            raise ValueError(
                f"{p} has no time column 't'; add one or give the sampling "
                "time (--ts on the command line, ts= in Python)"
            )
        u = np.stack([cols[n] for n in model.inputs], axis=1) if model.U else np.zeros((P, 0))
        y = np.stack([cols[n] for n in model.outputs], axis=1) if has_outputs else None
        e = Experiment(t, u, y, name=p.stem)
        if samples is not None:
            e = e.window(*samples)
        exps.append(e)
    return exps
