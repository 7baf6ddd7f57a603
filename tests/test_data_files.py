"""Odd and bad data files: a valid-but-odd file reads the same numbers as a plain CSV;
a bad one gets one line that names the file, the problem and the fix."""

from __future__ import annotations

import sys
import warnings

import jax.numpy as jnp
import numpy as np
import pytest
import scipy.io

import tensorid as ti
from tensorid import cli

P = 50
T = np.arange(P) * 0.1
U = np.round(np.sin(T), 6)
Y = np.round(np.cos(T), 6)

MODEL = ti.Model(
    rhs=lambda x, p, u: -p[0] * x + u[0],
    output=lambda x, p: x,
    states=["x"],
    params=["k"],
    inputs=["u"],
    outputs=["y"],
)

MODEL_FILE = """
import tensorid
model = tensorid.Model(rhs=lambda x, p, u: -p[0] * x + u[0], output=lambda x, p: x,
                       states=["x"], params=["k"], inputs=["u"], outputs=["y"])
p0 = {"k": 1.0}
"""


def _text(sep=",", decimal="."):
    rows = [sep.join(["t", "u", "y"])]
    for r in zip(T, U, Y, strict=True):
        rows.append(sep.join(repr(float(v)).replace(".", decimal) for v in r))
    return "\n".join(rows) + "\n"


def _same_as_plain(path, **kw):
    (e,) = ti.load_data(path, MODEL, **kw)
    np.testing.assert_array_equal(e.t, T)
    np.testing.assert_array_equal(e.u[:, 0], U)
    np.testing.assert_array_equal(e.measured[:, 0], Y)


def _error(path, **kw) -> str:
    with pytest.raises(ValueError) as info:
        ti.load_data(path, MODEL, **kw)
    message = str(info.value)
    assert "\n" not in message and str(path) in message, message
    return message


def test_a_plain_csv_reads_the_numbers(tmp_path):
    (tmp_path / "d.csv").write_text(_text())
    _same_as_plain(tmp_path / "d.csv")


# -- MATLAB v7.3 (HDF5) ----------------------------------------------------------------
def _write_v73(path, variables: dict):
    """A .mat file the way MATLAB 7.3 writes it: a 512-byte text header, HDF5 after
    it, each variable a root dataset stored transposed, with a MATLAB_class."""
    h5py = pytest.importorskip("h5py")
    with h5py.File(path, "w", userblock_size=512) as f:
        for name, value in variables.items():
            a = np.asarray(value)
            if a.dtype.kind == "c":
                rec = np.empty(a.shape, dtype=[("real", "<f8"), ("imag", "<f8")])
                rec["real"], rec["imag"] = a.real, a.imag
                a, cls = rec, "double"
            elif a.dtype.kind == "U":  # MATLAB char: UTF-16 code units
                a, cls = np.array([[ord(c)] for c in str(a)], dtype=np.uint16), "char"
            else:
                a, cls = np.atleast_2d(a).T, "double"  # a P x 1 column
            d = f.create_dataset(name, data=a.T)
            d.attrs["MATLAB_class"] = np.bytes_(cls)
        refs = f.create_group("#refs#")
        refs.create_dataset("a", data=np.zeros(2))
        f.create_group("meta").attrs["MATLAB_class"] = np.bytes_("struct")
    header = b"MATLAB 7.3 MAT-file, Platform: GLNXA64, Created on: Mon Jan 1 2024 HDF5 schema"
    with open(path, "r+b") as f:
        f.write(header.ljust(116) + b"\0" * 8 + b"\x00\x02IM")


def test_mat_v73_reads_through_h5py(tmp_path):
    path = tmp_path / "d73.mat"
    _write_v73(path, {"t": T, "u": U, "y": Y, "label": "run one"})
    _same_as_plain(path)


def test_mat_v73_without_h5py_says_how_to_get_it(tmp_path, monkeypatch):
    path = tmp_path / "d73.mat"
    _write_v73(path, {"t": T, "u": U, "y": Y})
    monkeypatch.setitem(sys.modules, "h5py", None)  # import h5py now fails
    message = _error(path)
    assert "v7.3" in message and "pip install h5py" in message and "'-v7'" in message


def test_mat_v73_char_variable_named_by_the_model_is_refused(tmp_path):
    path = tmp_path / "d73.mat"
    _write_v73(path, {"t": T, "u": "abc", "y": Y})
    assert "variable 'u' is a MATLAB char array, not numbers" in _error(path)


# -- damaged MATLAB and NumPy files ----------------------------------------------------
def test_garbage_mat_is_named_not_a_traceback(tmp_path):
    path = tmp_path / "junk.mat"
    path.write_bytes(np.random.default_rng(0).bytes(600))
    message = _error(path)
    assert "is not a readable MATLAB .mat file" in message and "re-export" in message


@pytest.mark.parametrize("compress", [False, True])
def test_truncated_mat_is_named(tmp_path, compress):
    full = tmp_path / "full.mat"
    scipy.io.savemat(full, {"t": T, "u": U, "y": Y}, do_compression=compress)
    raw = full.read_bytes()
    for cut in (0, 10, 100, len(raw) // 2, len(raw) - 8):
        path = tmp_path / f"cut{cut}.mat"
        path.write_bytes(raw[:cut])
        assert "MATLAB .mat file" in _error(path)


def test_truncated_or_foreign_npz_is_named(tmp_path):
    full = tmp_path / "full.npz"
    np.savez(full, t=T, u=U, y=Y)
    raw = full.read_bytes()
    for cut in (0, 3, 100, len(raw) // 2, len(raw) - 30):
        path = tmp_path / f"cut{cut}.npz"
        path.write_bytes(raw[:cut])
        message = _error(path)
        assert "NumPy .npz file" in message and "np.savez" in message
    (tmp_path / "text.npz").write_text("t,u,y\n0,1,2\n")
    assert "not a NumPy .npz file (not a zip archive)" in _error(tmp_path / "text.npz")
    np.save(tmp_path / "one.npy", U)
    (tmp_path / "one.npy").rename(tmp_path / "one.npz")
    assert "single .npy array" in _error(tmp_path / "one.npz")


def test_object_array_in_npz_names_the_key_and_is_not_unpickled(tmp_path):
    path = tmp_path / "obj.npz"
    np.savez(path, t=T, u=np.array([{"a": 1}] * P, dtype=object), y=Y)
    message = _error(path)
    assert "array 'u' holds Python objects" in message and "numeric arrays" in message
    # an object array the model does not use is no obstacle
    np.savez(path, t=T, u=U, y=Y, notes=np.array([None, "x"], dtype=object))
    _same_as_plain(path)


# -- complex values --------------------------------------------------------------------
COMPLEX_MESSAGE = "'u' holds complex values; tensorid fits real signals: split into real"


def test_complex_data_is_refused_in_every_format(tmp_path):
    Uc = U + 1j * T
    scipy.io.savemat(tmp_path / "c.mat", {"t": T, "u": Uc, "y": Y})
    np.savez(tmp_path / "c.npz", t=T, u=Uc, y=Y)
    _write_v73(tmp_path / "c73.mat", {"t": T, "u": Uc, "y": Y})
    cells = zip(T, Uc, Y, strict=True)
    rows = ["t,u,y"] + [f"{t:.17g},{u.real:.17g}+{u.imag:.17g}j,{y:.17g}" for t, u, y in cells]
    (tmp_path / "c.csv").write_text("\n".join(rows) + "\n")
    for name in ("c.mat", "c.npz", "c73.mat", "c.csv"):
        message = _error(tmp_path / name)
        assert COMPLEX_MESSAGE in message, message
    assert "column 'u'" in _error(tmp_path / "c.csv")


def test_complex_data_with_zero_imaginary_part_reads_as_real(tmp_path):
    np.savez(tmp_path / "c.npz", t=T, u=U + 0j, y=Y)
    _same_as_plain(tmp_path / "c.npz")


# -- text encodings --------------------------------------------------------------------
def test_utf8_bom_is_stripped(tmp_path):
    (tmp_path / "bom.csv").write_bytes(b"\xef\xbb\xbf" + _text().encode())
    _same_as_plain(tmp_path / "bom.csv")


def test_comment_lines_above_the_header_and_numpy_s_header_are_read(tmp_path):
    """'# rig 3' above the header was read as the header (found ['#', '3', 'rig']), and
    numpy.savetxt's header ('# t,u,y' above the numbers) as a column '# t': "no time
    column 't'". Comments before the header are skipped; a commented line right
    above the numbers names the columns."""
    (tmp_path / "c.csv").write_text("# rig 3\n#\n\n# u in V\n" + _text())
    _same_as_plain(tmp_path / "c.csv")
    np.savetxt(tmp_path / "s.csv", np.column_stack([T, U, Y]), delimiter=",", header="t,u,y")
    _same_as_plain(tmp_path / "s.csv")
    (tmp_path / "o.csv").write_text("# nothing here\n")
    assert "no data rows" in _error(tmp_path / "o.csv")


@pytest.mark.parametrize("encoding", ["utf-16", "utf-16-le", "utf-16-be"])
def test_utf16_is_read(tmp_path, encoding):
    (tmp_path / "wide.csv").write_bytes(_text().encode(encoding))
    _same_as_plain(tmp_path / "wide.csv")


def test_undecodable_bytes_name_file_offset_and_line(tmp_path):
    text = _text().replace("t,u,y", "t,u,y\n").encode()
    path = tmp_path / "latin.csv"
    path.write_bytes(text[:20] + b"\xb5" + text[20:])
    message = _error(path)
    line = text[:20].count(b"\n") + 1  # 4: the blank line counts
    assert f"byte 0xb5 at offset 20 (line {line})" in message
    assert "save the file as UTF-8" in message


def test_binary_file_named_csv_is_not_text(tmp_path):
    (tmp_path / "book.csv").write_bytes(b"PK\x03\x04\x00\x00\x08\x00" * 20)
    assert "not a text file" in _error(tmp_path / "book.csv")


# -- delimiters ------------------------------------------------------------------------
@pytest.mark.parametrize(
    "sep,decimal",
    [(";", "."), (";", ","), ("\t", "."), ("\t", ","), (" ", "."), ("   ", "."), (", ", ".")],
)
def test_delimiters_and_decimal_commas_are_detected(tmp_path, sep, decimal):
    (tmp_path / "d.txt").write_text(_text(sep, decimal))
    _same_as_plain(tmp_path / "d.txt")


def test_a_header_that_does_not_split_says_how_it_was_read(tmp_path):
    (tmp_path / "pipe.csv").write_text(_text("|"))
    message = _error(tmp_path / "pipe.csv")
    assert "lacks columns ['u', 'y']" in message
    assert "'t|u|y' is one column when read as comma-separated" in message


def test_a_text_cell_names_column_and_line(tmp_path):
    text = _text().splitlines()
    text[4] = text[4].replace(text[4].split(",")[1], "n/a")
    (tmp_path / "d.csv").write_text("\n".join(text) + "\n")
    message = _error(tmp_path / "d.csv")
    assert "column 'u' holds a value that is not a number, 'n/a' on line 5" in message


# -- sample ranges ---------------------------------------------------------------------
@pytest.mark.parametrize(
    "samples,why",
    [
        ((5000, 6000), "past the end"),
        ((40, 60), "past the end"),
        ((30, 20), "START is not below STOP"),
        ((-5, 10), "a negative index"),
        ((7, 8), "only one sample"),
    ],
)
def test_samples_outside_the_record_say_how_long_it_is(tmp_path, samples, why):
    (tmp_path / "d.csv").write_text(_text())
    message = _error(tmp_path / "d.csv", samples=samples)
    assert f"has {P} samples, so samples {samples[0]}:{samples[1]} are out of range" in message
    assert why in message and f"0 <= START < STOP <= {P}" in message


def test_experiment_window_states_the_record_length():
    e = ti.Experiment(T, U, Y, name="rec")
    with pytest.raises(ValueError, match=f"the record has {P} samples"):
        e.window(5000, 6000)
    assert e.window(10, 20).P == 10


# -- the command line ------------------------------------------------------------------
@pytest.mark.parametrize("name", ["junk.mat", "cut.npz", "c.csv", "ok.csv"])
def test_fit_on_a_bad_file_exits_2_with_one_line(tmp_path, capsys, name):
    (tmp_path / "model.py").write_text(MODEL_FILE)
    (tmp_path / "junk.mat").write_bytes(np.random.default_rng(1).bytes(300))
    (tmp_path / "cut.npz").write_bytes(b"PK\x03\x04" + b"\0" * 40)
    (tmp_path / "c.csv").write_text("t,u,y\n0,1+2j,0\n0.1,1,0\n")
    (tmp_path / "ok.csv").write_text(_text())
    args = ["fit", str(tmp_path / "model.py"), str(tmp_path / name), "--no-progress"]
    args += ["--out", str(tmp_path / "out")]
    if name == "ok.csv":
        args += ["--samples", "5000:6000"]
    try:
        rc = cli.main(args)
    except SystemExit as e:
        rc = e.code
    assert rc == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("tensorid:") and name in err[0], err


def test_records_of_one_name_get_names_of_their_own(tmp_path, capsys):
    """Two val.csv in two folders, or one file given twice: fit.json, the report and
    the figures are keyed by the record's name, and a repeated name crashed the fit
    command after the fit (a figure's key lost) and kept one record's scores."""
    for d in ("A", "B"):
        (tmp_path / d).mkdir()
        (tmp_path / d / "val.csv").write_text(_text())
    a, b = tmp_path / "A" / "val.csv", tmp_path / "B" / "val.csv"
    # B's own record (the same bytes under another name are refused as training data:
    # test_event_table.py), its last sample moved a little
    b.write_text(_text().rstrip("\n").rsplit(",", 1)[0] + f",{float(Y[-1]) + 1e-3!r}\n")
    assert [e.name for e in ti.load_data([a, b], MODEL)] == ["A/val", "B/val"]
    assert [e.name for e in ti.load_data([a, a, b], MODEL)] == ["A/val", "A/val#2", "B/val"]
    assert [e.name for e in ti.load_data([a, a], MODEL)] == ["val", "val#2"]
    (tmp_path / "m.py").write_text(MODEL_FILE)
    out = tmp_path / "fit"
    # a training file given twice is refused (its samples would count twice); a
    # validation file may be, and the two records keep names of their own
    argv = ["fit", str(tmp_path / "m.py"), str(a), str(a), "--out", str(out), "--no-progress"]
    assert cli.main(argv) == 2 and "given twice" in capsys.readouterr().err
    argv = ["fit", str(tmp_path / "m.py"), str(a), str(b), "--validate", str(a), str(a)]
    assert cli.main([*argv, "--out", str(out), "--no-progress"]) == 0
    import json

    fit = json.loads((out / "fit.json").read_text())
    assert set(fit["gof"]["train"]) == {"A/val", "B/val"}
    assert set(fit["gof"]["validation"]) == {"val", "val#2"}
    assert not list(out.glob(".*part"))


@pytest.mark.parametrize("kind", ["mat", "npz", "mat73"])
def test_a_matrix_variable_offers_its_rows_as_signals(tmp_path, kind):
    """The two-tank record's y is a 2×2500 matrix: read end to end as one signal it
    was 'differ in length (u 2500, y 5000)', with no way to pick a row; now the matrix
    says what it is, and y[0], y[1] are its signals (samples along the longer side)."""
    both = np.stack([Y, -Y])  # 2 x P
    path = tmp_path / f"m.{'mat' if kind.startswith('mat') else kind}"
    if kind == "mat":
        scipy.io.savemat(path, {"t": T, "u": U, "y": both})
    elif kind == "npz":
        np.savez(path, t=T, u=U, y=both.T)  # P x 2: the longer side is still the samples
    else:
        _write_v73(path, {"t": T, "u": U, "y": both})
    message = _error(path)
    assert "'y' is a " in message and "matrix, 2 signals of 50 samples" in message
    assert "y[0]" in message
    (e,) = ti.load_data(path, MODEL, columns={"y": "y[1]"})
    np.testing.assert_array_equal(e.measured[:, 0], -Y)


def test_a_record_with_some_outputs_read_for_simulation_says_they_go_unused(tmp_path):
    """Read without outputs (simulate), a file holding y but not w was simulated as if
    it had no outputs, without a word; now a DataNote names what it has and lacks."""
    from tensorid.app.datafiles import DataNote

    two = ti.Model(
        rhs=lambda x, p, u: -p[0] * x + u[0],
        output=lambda x, p: jnp.concatenate([x, 2 * x]),
        states=["x"], params=["k"], inputs=["u"], outputs=["y", "w"],
    )  # fmt: skip
    (tmp_path / "d.csv").write_text(_text())  # t, u, y: no w
    with pytest.warns(DataNote, match=r"has the output\(s\) \['y'\] but lacks \['w'\]"):
        (e,) = ti.load_data(tmp_path / "d.csv", two, require_outputs=False)
    assert e.y is None
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # a file with no output at all: nothing to say
        (tmp_path / "u.csv").write_text("t,u\n0,1\n0.1,2\n0.2,3\n")
        ti.load_data(tmp_path / "u.csv", two, require_outputs=False)


def test_a_time_column_of_another_name_is_pointed_to(tmp_path):
    """A file whose times are in 'time' (or 'Time [s]') was told only of 't', 'Ts' and
    --ts; the error names the column and the map that reads it."""
    (tmp_path / "d.csv").write_text(_text().replace("t,u,y", "Time [s],u,y", 1))
    message = _error(tmp_path / "d.csv")
    assert "no time column 't'" in message and "--columns 't=Time [s]'" in message
    assert "columns={'t': 'Time [s]'} in Python" in message
    (tmp_path / "e.csv").write_text("u,y\n1,2\n3,4\n")
    assert "--columns t=" not in _error(tmp_path / "e.csv")


def test_a_folder_given_as_a_data_file_is_called_a_folder(tmp_path):
    """A folder was reported as a data file that "does not exist"."""
    (tmp_path / "records").mkdir()
    message = _error(tmp_path / "records")
    assert "is a folder" in message and "does not exist" not in message


def test_columns_named_in_other_capitals_are_pointed_to(tmp_path):
    """A MATLAB export's T, U, Y: the error listed them as found and suggested holding
    u constant (--columns u=0); it now gives the map for all of them at once."""
    (tmp_path / "caps.csv").write_text(_text().replace("t,u,y", "T,U,Y", 1))
    message = _error(tmp_path / "caps.csv")
    assert "--columns t=T,u=U,y=Y" in message and "u=0" not in message
    _same_as_plain(tmp_path / "caps.csv", columns={"t": "T", "u": "U", "y": "Y"})


def test_a_sampling_time_given_that_differs_from_the_file_s_is_noted(tmp_path):
    """--ts (ts=) is used even where the file has a time base of its own; where the two
    differ, a DataNote says so (the file's was set aside without a word)."""
    import warnings

    from tensorid.app.datafiles import DataNote

    path = tmp_path / "d.csv"
    path.write_text(_text())
    step = float(np.median(np.diff(T)))
    with pytest.warns(DataNote, match=rf"given, {2 * step:g} s .*'t' steps by {step:.6g} s"):
        (e,) = ti.load_data(path, MODEL, ts=2 * step)
    np.testing.assert_allclose(np.diff(e.t), 2 * step)  # the one given is used
    with warnings.catch_warnings():
        warnings.simplefilter("error", DataNote)
        ti.load_data(path, MODEL, ts=step)  # the same as the file's: nothing to say
    ts_file = tmp_path / "ts.csv"
    ts_file.write_text("Ts,u,y\n0.1,1,2\n0.1,2,3\n0.1,3,4\n")
    with pytest.warns(DataNote, match="its sampling time 'Ts' is 0.1 s"):
        ti.load_data(ts_file, MODEL, ts=0.05)
