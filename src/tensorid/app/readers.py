"""The data file formats, each read into named columns (:class:`_Columns`) that
:mod:`tensorid.app.datafiles` turns into experiments.

CSV (also ``.txt``): a header line, then one row per sample. The delimiter is read
from the header (comma, semicolon, tab, or runs of spaces); with a semicolon, tab or
spaces a decimal comma (``1,5``) reads as a decimal point. UTF-8 with or without a
byte-order mark, and UTF-16, are read. MATLAB ``.mat`` (v4 to v7 through SciPy, v7.3
through h5py) and NumPy ``.npz`` files hold variables named like the columns.

A file that cannot be read gets one line (a ValueError) that names the file, what is
wrong and where, and how to fix it.
"""

from __future__ import annotations

import codecs
import csv
import zipfile
import zlib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np


@dataclass
class _Columns:
    """What a reader found: name -> 1-D array, or a line saying why that name cannot
    be used (raised only if the model needs it)."""

    values: dict[str, np.ndarray | str]
    what: str  # "column", "variable" or "array": what the file calls a signal
    lines: list[int] | None = None  # the file line of each sample (text files)
    note: str = ""  # said when columns are missing (how the header was split)
    constants: dict[str, float] = field(default_factory=dict)  # "pulses=0" in a map
    text: dict[str, list[str]] = field(default_factory=dict)  # a text column's cells (ids)

    def has(self, name: str) -> bool:
        return name in self.values or name in self.constants


class Said(str):
    """Why a column cannot be used, as a whole line naming its file and unit."""


_NOT_NUMBERS = {"U": "text", "S": "text", "O": "objects (a cell array?)", "V": "records"}


def _real(path: Path, what: str, name: str, v: np.ndarray | str) -> np.ndarray:
    """A signal as real floats; complex values with an imaginary part are refused."""
    if isinstance(v, str):
        raise ValueError(v if isinstance(v, Said) else f"{path}: {v}")
    if v.dtype.kind == "c":
        if np.any(v.imag != 0):
            raise ValueError(
                f"{path}: {what} {name!r} holds complex values; tensorid fits real "
                f"signals: split into real and imaginary {what}s"
            )
        v = v.real
    if v.dtype.kind not in "biuf":
        raise ValueError(
            f"{path}: {what} {name!r} holds {_NOT_NUMBERS.get(v.dtype.kind, v.dtype)}, "
            "not numbers; save it as a numeric vector"
        )
    return v.astype(float)


def _reason(e: BaseException) -> str:
    """An exception as a short phrase on one line."""
    text = " ".join(str(e).split())
    text = text if len(text) <= 120 else text[:117] + "..."
    return f"{type(e).__name__}: {text}" if text else type(e).__name__


# -- CSV -------------------------------------------------------------------------------
_BOMS = (  # UTF-32 first: its little-endian mark starts with UTF-16's
    (codecs.BOM_UTF32_LE, "utf-32", "UTF-32"),
    (codecs.BOM_UTF32_BE, "utf-32", "UTF-32"),
    (codecs.BOM_UTF8, "utf-8-sig", "UTF-8"),
    (codecs.BOM_UTF16_LE, "utf-16", "UTF-16"),
    (codecs.BOM_UTF16_BE, "utf-16", "UTF-16"),
)
_DELIMITERS = {",": "comma", ";": "semicolon", "\t": "tab"}


def _encoding(path: Path, raw: bytes) -> tuple[str, str]:
    """(codec, name) of a text file: from its byte-order mark, else UTF-16 when every
    other byte is zero, else UTF-8."""
    for bom, codec, name in _BOMS:
        if raw.startswith(bom):
            return codec, name
    head = raw[:4096]
    if b"\0" not in head:
        return "utf-8", "UTF-8"
    even, odd = head[0::2], head[1::2]
    if odd.count(0) > len(odd) // 2 and even.count(0) < len(even) // 10:
        return "utf-16-le", "UTF-16"
    if even.count(0) > len(even) // 2 and odd.count(0) < len(odd) // 10:
        return "utf-16-be", "UTF-16"
    raise ValueError(
        f"{path} holds NUL bytes, so it is not a text file (an Excel workbook?); "
        "export the data as CSV text (UTF-8)"
    )


def _decode(path: Path, raw: bytes) -> str:
    codec, name = _encoding(path, raw)
    try:
        return raw.decode(codec)
    except UnicodeDecodeError as e:
        line = raw[: e.start].decode(codec, errors="replace").count("\n") + 1
        raise ValueError(
            f"{path}: byte 0x{raw[e.start]:02x} at offset {e.start} (line {line}) is not "
            f"valid {name} text ({e.reason}); save the file as UTF-8 (in Excel: 'CSV UTF-8')"
        ) from None


def _delimiter(header: str) -> str | None:
    """The delimiter that splits the header line into the most fields (',', ';' or
    tab); None for columns separated by spaces; ',' for a single column."""
    fields = {d: len(next(csv.reader([header], delimiter=d))) for d in _DELIMITERS}
    best = max(fields, key=lambda d: fields[d])
    if fields[best] > 1 or len(header.split()) < 2:
        return best
    return None


def _rows(lines: list[str], delimiter: str | None) -> list[tuple[int, list[str]]]:
    """(line number, cells) of every line that is not blank."""
    if delimiter is None:
        return [(i + 1, line.split()) for i, line in enumerate(lines) if line.strip()]
    reader = csv.reader(lines, delimiter=delimiter)
    return [(reader.line_num, r) for r in reader if r and any(c.strip() for c in r)]


def _number(cell: str, decimal_comma: bool) -> float | complex:
    s = cell.strip()
    if not s:
        return np.nan
    if decimal_comma:
        s = s.replace(",", ".")
    try:
        return float(s)
    except ValueError:
        if not any(ch.isdigit() for ch in s):
            raise
        return complex(s.replace(" ", "").replace("i", "j"))  # 1+2j, or MATLAB's 1+2i


def _column(name: str, cells: list[str], lines: list[int], decimal_comma: bool) -> np.ndarray | str:
    """The numbers of one column (complex if any cell is), or why it has none."""
    try:
        return np.array([float(c) if c.strip() else np.nan for c in cells])
    except ValueError:
        pass
    out = []
    for cell, line in zip(cells, lines, strict=True):
        try:
            out.append(_number(cell, decimal_comma))
        except ValueError:
            return (
                f"column {name!r} holds a value that is not a number, {cell.strip()!r} "
                f"on line {line}; fix or remove that value"
            )
    return np.array(out)


def _uncommented(lines: list[str]) -> list[str]:
    """``lines`` with the comment lines (#) before the header blanked (they were read
    as the header: "found ['#', 'export', 'lab']"), and numpy.savetxt's header, "# t,u,y"
    above the numbers, read as the header; line numbers are kept."""
    out = list(lines)
    lead = []
    for i, line in enumerate(lines):
        if not line.strip():
            continue
        if not line.lstrip().startswith("#"):
            break
        lead.append(i)
        out[i] = ""
    else:
        return out  # nothing but comments: told as a file without data rows
    first = next(line for line in out if line.strip())
    cells = first.replace(";", ",").replace("\t", ",").replace(" ", ",").split(",")
    try:
        [float(c) for c in cells if c.strip()]
    except ValueError:
        return out  # a header of names follows the comments
    if lead:  # numbers right below the comments: the last of them names the columns
        out[lead[-1]] = lines[lead[-1]].lstrip()[1:]
    return out


def _no_units_row(path: Path, row: tuple[int, list[str]]) -> None:
    """One line for a first row below the header without a digit in it: a row of
    units (s, V, m) or a second header, which was told as one bad value of column t."""
    cells = [c.strip() for c in row[1] if c.strip()]
    if not cells or any(ch.isdigit() for c in cells for ch in c):
        return  # numbers (perhaps split wrongly: told by the columns' checks)
    shown = ", ".join(cells[:6]) + (", ..." if len(cells) > 6 else "")
    raise ValueError(
        f"{path}: line {row[0]}, below the header, holds no number ({shown}): a row of "
        "units or a second header; delete it (the data start on the next line)"
    )


def _columns_csv(path: Path) -> _Columns:
    lines = _uncommented(_decode(path, path.read_bytes()).splitlines())
    header_line = next((line for line in lines if line.strip()), "")
    delimiter = _delimiter(header_line)
    rows = _rows(lines, delimiter)
    if len(rows) < 2:
        raise ValueError(f"{path} has no data rows under its header")
    header = [h.strip().strip('"') for h in rows[0][1]]
    _no_units_row(path, rows[1])
    numbers = [n for n, _ in rows[1:]]
    values: dict[str, np.ndarray | str] = {}
    text: dict[str, list[str]] = {}
    for j, name in enumerate(header):
        if not name:
            continue  # a trailing delimiter makes an empty column
        if name in values:
            raise ValueError(f"{path}: column {name!r} appears twice in the header; rename one")
        cells = [r[j] if j < len(r) else "" for _, r in rows[1:]]
        values[name] = _column(name, cells, numbers, decimal_comma=delimiter != ",")
        if isinstance(values[name], str):  # not numbers: kept as text (an id column)
            text[name] = [c.strip().strip('"') for c in cells]
    note = ""
    if len(values) == 1:
        note = (
            f"; its header {header_line.strip()!r} is one column when read as "
            f"{_DELIMITERS.get(delimiter or ',', 'space')}-separated (no ',', ';', tab or "
            "spaces between names): separate the columns with one of those"
        )
    return _Columns(values, "column", numbers, note, text=text)


# -- MATLAB ----------------------------------------------------------------------------
_HDF5_SIGNATURE = b"\x89HDF\r\n\x1a\n"
_TS = ("Ts", "ts", "TS")  # a sampling time: one number, kept although not a signal


def _is_hdf5(path: Path) -> bool:
    """Whether the file is HDF5 (MATLAB v7.3): the signature sits at 0, 512, 1024..."""
    with path.open("rb") as f:
        for offset in (0, 512, 1024, 2048, 4096):
            f.seek(offset)
            if f.read(8) == _HDF5_SIGNATURE:
                return True
    return False


def _columns_mat(path: Path) -> _Columns:
    if _is_hdf5(path):
        return _columns_mat73(path)
    import scipy.io
    import scipy.sparse

    try:
        d = scipy.io.loadmat(path)
    # a damaged file makes SciPy raise any of a dozen unrelated types (ValueError,
    # TypeError, OSError, IndexError, KeyError, zlib.error, MatReadError, ...)
    except Exception as e:
        raise ValueError(
            f"{path} is not a readable MATLAB .mat file ({_reason(e)}); re-export it "
            "(in MATLAB: save(file, 't', 'u', 'y', '-v7')) or save the data as CSV"
        ) from None
    values: dict[str, np.ndarray | str] = {}
    for k, v in d.items():
        a = np.asarray(v.toarray() if scipy.sparse.issparse(v) else v)
        if not k.startswith("__") and (a.size > 1 or k in _TS):
            values.update(signals_of(k, a, "variable"))
    return _Columns(values, "variable")


def signals_of(name: str, a: np.ndarray, what: str) -> dict[str, np.ndarray | str]:
    """A variable as the signals it holds: a vector as itself; a matrix (two sides
    longer than 1) as one signal per row or column along its longer side, named
    ``name[0]``, ``name[1]``, ..., the matrix itself as the line that says so (it was
    read as one signal of rows end to end)."""
    a = np.asarray(a)
    if sum(d > 1 for d in a.shape) <= 1:
        return {name: a.ravel()}
    if a.ndim != 2:
        return {name: f"{what} {name!r} has the shape {a.shape}; save each signal as a vector"}
    rows = a if a.shape[1] >= a.shape[0] else a.T  # samples along the longer side
    out: dict[str, np.ndarray | str] = {f"{name}[{i}]": r for i, r in enumerate(rows)}
    out[name] = (
        f"{what} {name!r} is a {a.shape[0]}×{a.shape[1]} matrix, {rows.shape[0]} signals of "
        f"{rows.shape[1]} samples: map the one you mean, e.g. --columns NAME={name}[0] "
        f"(columns={{'NAME': '{name}[0]'}} in Python)"
    )
    return out


def _mat73_array(name: str, dataset) -> np.ndarray | str:
    """One MATLAB v7.3 variable: stored transposed; complex as a (real, imag) record."""
    cls = dataset.attrs.get("MATLAB_class", b"")
    cls = cls.decode() if isinstance(cls, bytes) else str(cls)
    if cls in ("char", "cell", "struct", "function_handle") or dataset.dtype.kind == "O":
        return (
            f"variable {name!r} is a MATLAB {cls or 'reference'} array, not numbers; "
            "save it as a numeric vector"
        )
    if dataset.attrs.get("MATLAB_empty", 0):
        return np.zeros(0)
    a = np.asarray(dataset[()])
    if a.dtype.names and {"real", "imag"} <= set(a.dtype.names):
        a = a["real"] + 1j * a["imag"]
    return a.T


def _columns_mat73(path: Path) -> _Columns:
    try:
        import h5py
    except ImportError:
        raise ValueError(
            f"{path} is a MATLAB v7.3 (HDF5) file, which needs h5py: pip install h5py, "
            "or re-save it in MATLAB with save(file, ..., '-v7')"
        ) from None
    values: dict[str, np.ndarray | str] = {}
    try:
        with h5py.File(path, "r") as f:
            for name, obj in f.items():
                if name.startswith("#"):
                    continue  # "#refs#", "#subsystem#": MATLAB's own storage
                if isinstance(obj, h5py.Dataset):
                    a = _mat73_array(name, obj)
                    if isinstance(a, str):
                        values[name] = a
                    else:
                        values.update(signals_of(name, a, "variable"))
                else:  # a struct, sparse matrix or object: a group of datasets
                    kind = obj.attrs.get("MATLAB_class", b"struct")
                    kind = kind.decode() if isinstance(kind, bytes) else str(kind)
                    values[name] = (
                        f"variable {name!r} is a MATLAB {kind}, not a numeric array; "
                        "save it as a full numeric vector"
                    )
    except (OSError, RuntimeError, KeyError, ValueError, TypeError) as e:
        raise ValueError(
            f"{path} is a damaged MATLAB v7.3 (HDF5) file ({_reason(e)}); re-save it "
            "in MATLAB with save(file, ..., '-v7')"
        ) from None
    return _Columns(
        {k: v for k, v in values.items() if isinstance(v, str) or v.size > 1 or k in _TS},
        "variable",
    )


# -- NumPy -----------------------------------------------------------------------------
# what np.load and zipfile raise on a truncated or damaged archive
_NPZ_ERRORS = (
    zipfile.BadZipFile,
    zlib.error,
    EOFError,
    OSError,
    NotImplementedError,
    RuntimeError,
    ValueError,
    KeyError,
)


def _npz_member(z, key: str) -> dict[str, np.ndarray | str]:
    try:
        return signals_of(key, np.asarray(z[key]), "array")
    except ValueError as e:
        if "allow_pickle" not in str(e):
            raise
        return {
            key: f"array {key!r} holds Python objects (dtype object), which tensorid does "
            f"not unpickle; save numeric arrays, e.g. np.savez(file, {key}=np.asarray(x, float))"
        }


def _columns_npz(path: Path) -> _Columns:
    how = "re-export it with np.savez(file, t=t, u=u, y=y), one array per signal"
    with path.open("rb") as f:
        magic = f.read(6)
    if magic == b"\x93NUMPY":
        raise ValueError(f"{path} is a single .npy array, not an .npz of named arrays; {how}")
    if not magic.startswith(b"PK"):
        raise ValueError(f"{path} is not a NumPy .npz file (not a zip archive); {how}")
    try:
        with np.load(path) as z:
            return _Columns({n: v for k in z.files for n, v in _npz_member(z, k).items()}, "array")
    except _NPZ_ERRORS as e:
        raise ValueError(
            f"{path} is not a readable NumPy .npz file, truncated or damaged ({_reason(e)}); " + how
        ) from None


# -- any of them ---------------------------------------------------------------------
_READERS = {".csv": _columns_csv, ".txt": _columns_csv, ".mat": _columns_mat, ".npz": _columns_npz}


def _read(p: Path) -> _Columns:
    if p.is_dir():
        raise ValueError(f"data file {p} is a folder; give the data files in it ({p}/*.csv)")
    if not p.is_file():
        raise FileNotFoundError(f"data file {p} does not exist")
    suffix = p.suffix.lower()
    if suffix not in _READERS:
        raise ValueError(f"{p}: unknown data format {suffix!r}; use .csv, .mat or .npz")
    return _READERS[suffix](p)


def input_is_output(p, columns: dict, model, constants: dict) -> None:
    """A warning where an input reads the column an output is measured from (u=y, a
    slip of the map): the model is handed the signal it is fitted to, which it ran on
    without a word."""
    import warnings

    source = {n: str(columns.get(n, n)) for n in (*model.inputs, *model.outputs)}
    for u in model.inputs:
        same = [y for y in model.outputs if source[y] == source[u] and u not in constants]
        if same:
            warnings.warn(
                f"{p}: the input {u} and the output {same[0]} are both read from column "
                f"{source[u]!r}: the model is given the signal it is fitted to; map each "
                "to its own column",
                UserWarning,
                stacklevel=4,
            )
