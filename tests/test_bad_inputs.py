"""The bad-input panel: every case of tests/bad_inputs.txt (one a line, grouped by
kind) must end in a clear one-line error that names the file or argument (exit
status 2 from the command line), a valid result, or a warning: never a traceback, a
hang, or NaN. To add a case, add a line there, and here a file maker if it needs a
new file."""

from __future__ import annotations

import io
import shlex
import signal
import struct
import warnings
import zipfile
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

import tensorid as ti
from tensorid import cli

PANEL = Path(__file__).with_name("bad_inputs.txt")

# -- the files the cases use ------------------------------------------------------------
FIRST = """rhs = {"x": "-a*x + b*u"}
output = {"y": "x"}
inputs = ["u"]
params = ["a", "b"]
p0 = {"a": 1.0, "b": 1.0}
x0 = {"x": 0.0}
"""
TWO_OUT = """rhs = {"x": "-a*x + b*u"}
output = {"y": "x", "z": "x*1e8"}
inputs = ["u"]
params = ["a", "b"]
p0 = {"a": 1.0, "b": 1.0}
"""


def _edit(text: str, old: str, new: str) -> str:
    assert old in text, old
    return text.replace(old, new)


def _record(n: int = 200, ts: float = 0.05) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """t, u, y of the first-order model x' = -2x + 3u (x0 = 0), sampled at ts."""
    t = np.arange(n) * ts
    u = np.sin(0.7 * t) + 0.5 * np.sign(np.sin(0.19 * t))
    exp = ti.Experiment(t, u)
    model = ti.Model(
        rhs=lambda x, p, u: -p[0] * x + p[1] * u[0], states=["x"], params=["a", "b"],
        inputs=["u"], output=lambda x, p: x, outputs=["y"],
    )  # fmt: skip
    y = ti.simulate(model, {"a": 2.0, "b": 3.0}, [0.0], exp).y[:, 0]
    return t, u, y


def _csv(sep: str = ",", header=("t", "u", "y"), n: int = 200, fmt="{:.10g}") -> str:
    t, u, y = _record(n)
    rows = [sep.join(header)] + [
        sep.join(fmt.format(v) for v in r) for r in zip(t, u, y, strict=True)
    ]
    return "\n".join(rows) + "\n"


def _cells(line: str) -> list[str]:
    return line.split(",")


def _npz(path: Path, **arrays) -> None:
    np.savez(path, **arrays)


def _written(text: str | bytes) -> Callable[[Path], None]:
    def make(path: Path) -> None:
        if isinstance(text, bytes):
            path.write_bytes(text)
        else:
            path.write_text(text)

    return make


def _two_out_csv(path: Path) -> None:
    t, u, y = _record()
    z = 1e8 * y
    path.write_text(
        "t,u,y,z\n" + "".join(f"{a},{b},{c},{d}\n" for a, b, c, d in zip(t, u, y, z, strict=True))
    )


def _npz_maker(**kw) -> Callable[[Path], None]:
    return lambda path: _npz(path, **kw)


def _npz_record(path: Path) -> None:
    t, u, y = _record()
    _npz(path, t=t, u=u, y=y)


def _truncated_npz(path: Path) -> None:
    buf = io.BytesIO()
    t, u, y = _record()
    np.savez(buf, t=t, u=u, y=y)
    path.write_bytes(buf.getvalue()[:300])


def _complex_npz(path: Path) -> None:
    t, u, y = _record()
    _npz(path, t=t, u=u, y=y + 1j * y)


def _object_npz(path: Path) -> None:
    t, u, y = _record()
    with zipfile.ZipFile(path, "w") as z:
        for name, arr in (("t", t), ("u", u)):
            b = io.BytesIO()
            np.save(b, arr)
            z.writestr(f"{name}.npy", b.getvalue())
        b = io.BytesIO()
        np.save(b, np.array([{"a": 1}] * 3, dtype=object), allow_pickle=True)
        z.writestr("y.npy", b.getvalue())


def _mat(path: Path, complex_: bool = False) -> None:
    import scipy.io

    t, u, y = _record()
    scipy.io.savemat(path, {"t": t, "u": u[:, None], "y": (y + 1j * y) if complex_ else y[None]})


def _mat73(path: Path) -> None:
    h5py = pytest.importorskip("h5py")
    t, u, y = _record()
    with h5py.File(path, "w", userblock_size=512) as f:
        for name, v in (("t", t), ("u", u), ("y", y)):
            d = f.create_dataset(name, data=v[None, :])  # MATLAB stores arrays transposed
            d.attrs["MATLAB_class"] = np.bytes_("double")
    with open(path, "r+b") as f:
        f.write(b"MATLAB 7.3 MAT-file, Platform: GLNXA64, Created on: Mon Nov 23 2026".ljust(116))
        f.write(struct.pack("<8sHH", b"\0" * 8, 0x0200, 0x4D49))


MAKERS: dict[str, Callable[[Path], None]] = {
    # model files
    "first.py": _written(FIRST),
    "two_out.py": _written(TWO_OUT),
    "two_out_auto.py": _written(TWO_OUT + 'weights = "auto"\n'),
    "weights_bad.py": _written(FIRST + 'weights = "equal"\n'),
    "missing_state.py": _written(_edit(FIRST, '{"x": "-a*x + b*u"}', '{"x": "-a*v + b*u"}')),
    "output_typo.py": _written(_edit(FIRST, '{"y": "x"}', '{"y": "xx"}')),
    "output_list.py": _written(_edit(FIRST, 'output = {"y": "x"}', 'output = ["x"]')),
    "inputs_string.py": _written(_edit(FIRST, 'inputs = ["u"]', 'inputs = "u"')),
    "inputs_word.py": _written(_edit(FIRST, 'inputs = ["u"]', 'inputs = "force"')),
    "params_missing.py": _written(_edit(FIRST, 'params = ["a", "b"]', 'params = ["a"]')),
    "syntax.py": _written(FIRST + "p0 = {\n"),
    "raises.py": _written(FIRST + "raise RuntimeError('the lab is closed')\n"),
    "nothing.py": _written("a = 1\n"),
    "rhs_list.py": _written(_edit(FIRST, 'rhs = {"x": "-a*x + b*u"}', 'rhs = ["-a*x + b*u"]')),
    "unparsable.py": _written(_edit(FIRST, '"-a*x + b*u"', '"-a*x + * b*u"')),
    "no_p0.py": _written(_edit(FIRST, 'p0 = {"a": 1.0, "b": 1.0}\n', "")),
    "p0_list.py": _written(_edit(FIRST, 'p0 = {"a": 1.0, "b": 1.0}', "p0 = [1.0, 1.0]")),
    "p0_short.py": _written(_edit(FIRST, 'p0 = {"a": 1.0, "b": 1.0}', 'p0 = {"a": 1.0}')),
    "p0_unknown.py": _written(_edit(FIRST, '"b": 1.0}', '"b": 1.0, "c": 2.0}')),
    "p0_text.py": _written(_edit(FIRST, '"b": 1.0}', '"b": "one"}')),
    "p0_nan.py": _written(_edit(FIRST, '"b": 1.0}', '"b": float("nan")}')),
    "x0_unknown.py": _written(_edit(FIRST, 'x0 = {"x": 0.0}', 'x0 = {"q": 0.0}')),
    "free_unknown.py": _written(FIRST + 'free_x0 = ["q"]\n'),
    "free_string.py": _written(FIRST + 'free_x0 = "x"\n'),
    "fixed_unknown.py": _written(FIRST + 'fixed = ["c"]\n'),
    "fixed_all.py": _written(FIRST + 'fixed = ["a", "b"]\n'),
    "bounds_nan.py": _written(FIRST + 'bounds = {"a": (float("nan"), 5)}\n'),
    "bounds_swapped.py": _written(FIRST + 'bounds = {"a": (5, 0)}\n'),
    "bounds_one.py": _written(FIRST + 'bounds = {"a": 5}\n'),
    "bounds_fixed.py": _written(FIRST + 'fixed = ["a"]\nbounds = {"a": (0, 5)}\n'),
    "bounds_outside.py": _written(FIRST + 'bounds = {"a": (2, 5)}\n'),
    "bounds_open.py": _written(FIRST + 'bounds = {"a": (0, None)}\n'),
    "fixed_tuple.py": _written(FIRST + 'fixed = ("b",)\n'),
    "noise_negative.py": _written(FIRST + 'priors = {"a": (1.0, 0.5)}\nnoise = -0.1\n'),
    "noise_text.py": _written(FIRST + 'priors = {"a": (1.0, 0.5)}\nnoise = "0.1"\n'),
    "noise_alone.py": _written(FIRST + "noise = 0.1\n"),
    "noise_given.py": _written(FIRST + 'priors = {"a": (1.0, 0.5)}\nnoise = 0.01\n'),
    "interp_file.py": _written(FIRST + 'interpolation = "zoh"\n'),
    "scheme_file.py": _written(FIRST + 'scheme = "heun"\n'),
    "interp_bl.py": _written(FIRST + 'interpolation = "bl"\n'),
    "ekf_file.py": _written(FIRST + 'predictor = "ekf"\nprocess_noise = {"x": 0.1}\n'),
    "unknown_fn.py": _written(_edit(FIRST, '"-a*x + b*u"', '"-a*x + b*heaviside(u)"')),
    "if_else.py": _written(_edit(FIRST, '"-a*x + b*u"', '"-a*x if x > 0 else b*u"')),
    "predictor_caps.py": _written(FIRST + 'predictor = "Kalman"\n'),
    "noise_bounds.py": _written(FIRST + 'bounds = {"log_sigma_e_y": (-9.0, 0.0)}\n'),
    "scheme_typo.py": _written(FIRST + 'scheme = "sdrik3"\n'),
    "interp_foh.py": _written(FIRST + 'interpolation = "foh"\n'),
    "bound_typo.py": _written(FIRST + 'bound = {"a": (0.0, 5.0)}\n'),
    "endless.py": _written("while True:\n    pass\n"),
    "model_bad_rhs.py": _written(
        "import tensorid as ti\nimport jax.numpy as jnp\n"
        "model = ti.Model(rhs=lambda x, p, u: jnp.stack([x[0], x[0]]), states=['x'],\n"
        "    params=['a'], inputs=['u'], output=lambda x, p: x, outputs=['y'])\n"
        "p0 = {'a': 1.0}\n"
    ),
    "notes.txt": _written("not a model\n"),
    "delay_long.py": _written(FIRST + 'input_delays = {"u": 50.0}\n'),
    "delay_ok.py": _written(FIRST + 'input_delays = {"u": 0.2}\n'),
    "delay_negative.py": _written(FIRST + 'input_delays = {"u": -0.5}\n'),
    "priors_unknown.py": _written(FIRST + 'priors = {"c": (1.0, 0.1)}\n'),
    "priors_sd.py": _written(FIRST + 'priors = {"a": (1.0, -0.1)}\n'),
    "discrete.py": _written(_edit(FIRST, '"-a*x + b*u"', '"a*x + b*u"') + "discrete = True\n"),
    "smooth_eps.py": _written(
        "import jax.numpy as jnp\nimport tensorid as ti\n"
        "model = ti.Model(rhs=lambda x, p, u: jnp.stack([-p[0] * x[0] + p[1] * u[0]\n"
        "    - ti.coulomb_friction(x[0], 0.1, -1e-3)]), states=['x'], params=['a', 'b'],\n"
        "    inputs=['u'], output=lambda x, p: x, outputs=['y'])\n"
        "p0 = {'a': 1.0, 'b': 1.0}\n"
    ),
    # data files
    "first.csv": _written(_csv()),
    "first_val.csv": _written(_csv(n=150)),
    "uonly.csv": _written("".join(ln.rsplit(",", 1)[0] + "\n" for ln in _csv().splitlines())),
    "yonly.csv": _written("".join(f"{c[0]},{c[2]}\n" for c in map(_cells, _csv().splitlines()))),
    "yshort.csv": _written(
        "".join(f"{c[0]},{c[2]}\n" for c in map(_cells, _csv().splitlines()[:151]))
    ),
    "renamed.csv": _written(_csv(header=("t", "uEst", "yEst"))),
    "no_time.csv": _written(_csv(header=("time", "u", "y"))),
    "bom.csv": _written(("\ufeff" + _csv()).encode("utf-8")),
    "units_row.csv": _written(_csv().replace("t,u,y\n", "t,u,y\ns,V,m\n", 1)),
    "commented.csv": _written("# rig 3, 2026-11-26\n# u in V, y in m\n" + _csv()),
    "savetxt.csv": _written("# " + _csv()),  # numpy.savetxt's header="t,u,y"
    "utf16.csv": _written(_csv().encode("utf-16")),
    "semicolon.csv": _written(_csv(";")),
    "tab.csv": _written(_csv("\t")),
    "spaces.txt": _written(_csv("  ")),
    "decimal_comma.csv": _written(_csv(";").replace(".", ",")),
    "latin1.csv": _written(_csv().replace("t,u,y", "t,u,y").encode() + b"# \xe9t\xe9\n"),
    "empty.csv": _written(""),
    "header_only.csv": _written("t,u,y\n"),
    "one_row.csv": _written("t,u,y\n0,1,2\n"),
    "missing_y.csv": _written(_csv(header=("t", "u", "yy"))),
    "text_value.csv": _written(_csv().replace("\n0.05,", "\n0.05x,", 1)),
    "nan_value.csv": _written("\n".join(_csv().splitlines()[:10] + ["0.5,nan,1"])),
    "empty_cell.csv": _written("\n".join(_csv().splitlines()[:10] + ["0.5,,1"])),
    "time_back.csv": _written(_csv().replace("\n0.1,", "\n0.01,", 1)),
    "time_repeat.csv": _written(_csv().replace("\n0.1,", "\n0.05,", 1)),
    "complex.csv": _written(_csv().replace("\n0.1,", "\n0.1+2j,", 1)),
    "ragged.csv": _written(_csv() + "12,1\n"),
    "first.npz": _npz_record,
    "truncated.npz": _truncated_npz,
    "not_zip.npz": _written(b"this is not a zip file at all"),
    "complex.npz": _complex_npz,
    "object.npz": _object_npz,
    "lengths.npz": _npz_maker(t=np.arange(5.0), u=np.ones(5), y=np.ones(4)),
    "first.mat": lambda p: _mat(p),
    "complex.mat": lambda p: _mat(p, complex_=True),
    "garbage.mat": _written(bytes(range(256)) * 8),
    "v73.mat": _mat73,
    "two_out.csv": _two_out_csv,
    "sheet.xlsx": _written(b"PK\x03\x04 not really a workbook"),
    "fit.json": _written('{"params": {"a": 2.0, "b": 3.0}, "x0": [0.0]}'),
    "fit_broken.json": _written('{"params": '),
    "fit_cut.json": _written('{"params": {"a": 2.0, "b": 3.0},\n "x0": [0.0'),
    "fit_garbage.json": _written('saved 2026-11-26\n{"params": {"a": 2.0, "b": 3.0}}'),
    "fit_empty.json": _written(""),
    "compare.json": _written(
        '{"record": "first", "outputs": {}, "scored_as": "simulation", "x0": {"x": 0.0}, '
        '"x0_source": "the model file\'s x0", "params": {"a": 2.0, "b": 3.0}}'
    ),
    "fit_discrete.json": _written(
        '{"params": {"a": 0.5, "b": 1.0}, "x0": [0.0], "integration": {"scheme": "discrete"}}'
    ),
    "fit_other_states.json": _written('{"params": {"a": 2.0, "b": 3.0}, "free_x0": ["q"]}'),
    "fit_x0_dict.json": _written('{"params": {"a": 2.0, "b": 3.0}, "x0": {"x": 0.0}}'),
    "fit_binary.json": _written(b"\xff\xfe\x00{"),
    "fit_noparams.json": _written('{"x0": [0.0]}'),
}


# -- the cases --------------------------------------------------------------------------
def _cases() -> list:
    out = []
    for n, line in enumerate(PANEL.read_text().splitlines(), 1):
        if not line.strip() or line.lstrip().startswith("#"):
            continue
        group, what, how, expect = (f.strip() for f in line.split(" | "))
        # a command that runs a whole fit takes seconds: those run with the slow studies
        slow = how.startswith("cli ") and not expect.startswith("error")
        marks = [pytest.mark.slow] if slow else []
        out.append(pytest.param(how, expect, id=f"{group}: {what} (line {n})", marks=marks))
    return out


def test_the_panel_is_large_and_each_case_is_new():
    lines = [c.values for c in _cases()]
    assert len(lines) >= 120
    assert len({how for how, _ in lines}) == len(lines), "a case is repeated"


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    """Every file of MAKERS, made once; its path by name."""
    folder = tmp_path_factory.mktemp("panel")
    for name, make in MAKERS.items():
        make(folder / name)
    (folder / "a_folder.csv").mkdir()
    return folder


def _api_namespace(files: Path) -> dict:
    t, u, y = _record()
    model = ti.Model(
        rhs=lambda x, p, u: -p[0] * x + p[1] * u[0], states=["x"], params=["a", "b"],
        inputs=["u"], output=lambda x, p: x, outputs=["y"], name="first",
    )  # fmt: skip
    exp = ti.Experiment(t, u, y, name="first")
    return {"ti": ti, "np": np, "model": model, "exp": exp, "t": t, "u": u, "y": y,
            "files": files, "P0": {"a": 1.0, "b": 1.0}}  # fmt: skip


def _check_one_line(text: str, expect: str) -> None:
    """One line, holding each of the " && "-separated parts of ``expect``."""
    lines = [ln for ln in text.strip().splitlines() if ln.strip()]
    assert "Traceback" not in text, text
    assert len(lines) == 1, f"expected one line, got:\n{text}"
    for part in expect.split(" && "):
        assert part.lower() in lines[0].lower(), f"{part!r} not in {lines[0]!r}"


def _run_cli(how: str, files: Path, out: Path, capsys) -> tuple[int, str, str, list[str]]:
    args = [a.replace("{out}", str(out)) for a in shlex.split(how)]
    args = [str(files / a[1:-1]) if a.startswith("{") and a.endswith("}") else a for a in args]
    args = [a.replace("{files}", str(files)) for a in args]
    if args[0] == "fit":
        args += ["--no-progress"]
    if "--out" not in args:
        args += ["--out", str(out)]
    capsys.readouterr()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            code = cli.main(args)
        except SystemExit as e:  # argparse
            code = int(e.code or 0)
    captured = capsys.readouterr()
    return code, captured.out, captured.err, [str(w.message) for w in caught]


def _run_api(how: str, ns: dict):
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        value = eval(how, ns)  # noqa: S307 - the panel's own expressions
    return value, [str(w.message) for w in caught]


def _no_nan(value) -> None:
    if isinstance(value, ti.FitResult):
        assert np.isfinite(value.theta).all() and not np.isnan(value.cost)
    elif isinstance(value, ti.Simulation):
        assert not np.isnan(value.y).any() or value.status is not ti.Status.OK


@pytest.fixture
def time_limit():
    """No case may hang: each gets 60 s."""

    def expired(*_):
        raise TimeoutError("the case hung")

    old = signal.signal(signal.SIGALRM, expired)
    signal.alarm(60)
    yield
    signal.alarm(0)
    signal.signal(signal.SIGALRM, old)


@pytest.mark.parametrize("how, expect", _cases())
def test_bad_input(how, expect, files, tmp_path, capsys, time_limit, monkeypatch):
    monkeypatch.setenv("TENSORID_MODEL_TIMEOUT", "1")
    kind, _, text = expect.partition(":")
    text = text.strip()
    surface, _, how = how.partition(" ")
    if surface == "cli":
        code, out, err, caught = _run_cli(how, files, tmp_path / "out", capsys)
        assert "Traceback" not in out + err, err
        if kind == "error":
            assert code == 2, (code, out, err)
            _check_one_line(err, text)
        elif kind == "fail":
            assert code == 1, (code, out, err)
            assert all(p.lower() in err.lower() for p in text.split(" && ")), err
        else:
            assert code == 0, (code, out, err)
            if kind == "warn":
                assert any(text.lower() in w.lower() for w in caught + [err]), (caught, err)
        return
    assert surface == "api", surface
    ns = _api_namespace(files)
    if kind == "error":
        with pytest.raises((ValueError, TypeError, FileNotFoundError)) as info:
            _run_api(how, ns)
        _check_one_line(str(info.value), text)
        return
    value, caught = _run_api(how, ns)
    _no_nan(value)
    if kind == "warn":
        assert any(text.lower() in w.lower() for w in caught), caught
    elif kind == "fail":
        assert isinstance(value, ti.FitResult) and not value.success
        assert all(p.lower() in value.message.lower() for p in text.split(" && ")), value.message
