"""The fit command's figures drawn in a second process (app/renderer.py): the same
PNG bytes as drawn in this process, and nothing lost or left behind when that
process fails or the command ends early."""

from __future__ import annotations

import os
import signal
import time

import numpy as np
import pytest

from tensorid import _early
from tensorid.analysis import figures
from tensorid.app import renderer as renderer_module
from tensorid.app.renderer import Renderer

T = np.linspace(0.0, 2.0, 400)
JOBS = [
    (
        "train_a_y",
        "compare",
        dict(t=T, y_meas=np.sin(5 * T), y_sim=np.sin(5 * T) * 0.98, ylabel="y", title="a"),
    ),
    (
        "convergence",
        "convergence",
        dict(
            history=[{"iteration": i, "cost": 10.0**-i, "grad_norm": 2.0**-i} for i in range(6)],
            title="newton: cost and gradient norm per iteration",
        ),
    ),
    (
        "residual_tests",
        "residual",
        dict(
            bound=0.1,
            panels=[
                dict(
                    what="whiteness of y",
                    passed=False,
                    lags=np.arange(1, 11),
                    values=np.linspace(0.3, 0.0, 10),
                    feedback=None,
                ),
                dict(
                    what="y against input u",
                    passed=True,
                    lags=np.arange(0, 11),
                    values=np.linspace(0.05, 0.0, 11),
                    feedback=np.linspace(0.02, 0.0, 10),
                ),
            ],
        ),
    ),
    (  # a population fit's kinds (analysis/fleet_figures.py, loaded by path there too)
        "units",
        "units",
        dict(
            units=[
                dict(
                    name=str(i),
                    t=T,
                    t_seen=T[::40],
                    y_seen=np.exp(-T[::40] * i),
                    own=np.exp(-T * i),
                    typical=np.exp(-T),
                )
                for i in (1, 2, 3)
            ],
            output="cp",
            more="",
        ),
    ),  # fmt: skip
    (
        "residuals",
        "population_residuals",
        dict(
            columns={
                k: np.sin(np.arange(30.0) * (j + 1))
                for j, k in enumerate(("TIME", "PRED", "IPRED", "CWRES", "IWRES", "NPDE"))
            },
            output="cp",
        ),
    ),  # fmt: skip
]


def _here(tmp_path, stem, kind, arguments) -> bytes:
    path = tmp_path / f"{stem}.here.png"
    figures.save_png(figures.draw(kind, arguments), path)
    return path.read_bytes()


@pytest.mark.parametrize(
    "processes, forks",
    [
        (1, 0),
        (2, 0),
        pytest.param(1, 2, marks=pytest.mark.skipif(not hasattr(os, "fork"), reason="fork")),
    ],
)
def test_the_renderer_draws_the_same_pngs_as_this_process(tmp_path, monkeypatch, processes, forks):
    out = tmp_path / "o"
    out.mkdir()
    expected = {stem: _here(tmp_path, stem, kind, a) for stem, kind, a in JOBS}
    r = Renderer(processes=processes, forks=forks)
    assert len(r._procs) == processes
    try:
        assert r.submit(out, JOBS) == [stem for stem, _, _ in JOBS]

        def not_here(*a, **k):  # so that a file can only come from the renderer
            raise AssertionError("drawn in this process")

        monkeypatch.setattr(figures, "draw", not_here)
        paths = [r.collect(stem) for stem, _, _ in JOBS]
    finally:
        r.close()
    assert [p.name for p in paths] == [f"{stem}.png" for stem, _, _ in JOBS]
    for stem, _, _ in JOBS:
        assert (out / f"{stem}.png").read_bytes() == expected[stem], stem
    assert not list(out.glob(".*.part"))


@pytest.mark.parametrize("how", ["cannot start", "dies"])
def test_figures_are_drawn_here_when_the_renderer_fails(tmp_path, monkeypatch, how):
    out = tmp_path / "o"
    out.mkdir()
    if how == "cannot start":
        monkeypatch.setattr("tensorid._early._SERVE", "raise SystemExit(1)")
    r = Renderer()
    try:
        r.submit(out, JOBS[:2])
        if how == "dies":
            r._procs[0].kill()
        paths = [r.collect(stem) for stem, _, _ in JOBS[:2]]
    finally:
        r.close()
    for (stem, kind, a), path in zip(JOBS[:2], paths, strict=True):
        assert path.read_bytes() == _here(tmp_path, stem, kind, a)
    assert not list(out.glob(".*.part"))


@pytest.mark.skipif(not hasattr(signal, "SIGCHLD") or not hasattr(os, "fork"), reason="POSIX")
def test_forks_are_waited_for_where_the_command_ignores_sigchld(tmp_path, monkeypatch):
    # an ignored SIGCHLD, inherited, let the kernel reap the forks: waitpid failed, the
    # reaper thread died and the command waited the full WAIT for each figure
    monkeypatch.setattr(renderer_module, "WAIT", 20.0)
    out = tmp_path / "o"
    out.mkdir()
    before = signal.signal(signal.SIGCHLD, signal.SIG_IGN)
    try:
        r = Renderer(forks=2)
    finally:
        signal.signal(signal.SIGCHLD, before)
    try:
        r.submit(out, JOBS)

        def not_here(*a, **k):
            raise AssertionError("drawn in this process")

        monkeypatch.setattr(figures, "draw", not_here)
        started = time.monotonic()
        for stem, _, _ in JOBS:
            r.collect(stem)
        assert time.monotonic() - started < 15.0
    finally:
        r.close()


@pytest.mark.parametrize("forks", [0, 2])
def test_closing_ends_the_renderer_and_removes_what_was_not_collected(tmp_path, forks):
    out = tmp_path / "o"
    out.mkdir()
    r = Renderer(forks=forks)
    procs = list(r._procs)
    r.submit(out, JOBS)
    assert list(out.glob(".*.part"))  # its files, until collected
    if forks:
        time.sleep(1.0)  # forks drawing
    r.close()
    assert procs and all(proc.poll() is not None for proc in procs)
    assert not list(out.iterdir())
    # nothing of its process group still runs (a fork killed drawing included)
    assert not any(renderer_module.running(proc.pid) for proc in procs)


# -- started with the command, before NumPy and JAX (tensorid/_early.py) ------------------


@pytest.mark.parametrize(
    "argv, orig, started",
    [
        (["/usr/bin/tensorid", "fit", "m.py", "d.csv"], [], True),
        (["tensorid", "fit", "m.py", "d.csv", "--help"], [], False),
        (["tensorid", "fit", "-h"], [], False),
        (["tensorid", "simulate", "m.py", "d.csv"], [], True),
        (["tensorid", "simulate", "m.py", "d.csv", "--out", "sim.csv"], [], False),
        (["tensorid", "simulate", "m.py", "d.csv", "--out=sim.CSV"], [], False),
        (["tensorid", "compare", "m.py", "d.csv", "--params", "fit.json"], [], True),
        (["tensorid", "paper"], [], False),
        (["tensorid"], [], False),
        (["-m", "fit", "m.py"], ["python", "-m", "tensorid", "fit", "m.py"], True),
        (["-m", "fit", "m.py"], ["python", "-m", "othertool", "fit", "m.py"], False),
        (["myscript.py", "fit"], ["python", "myscript.py", "fit"], False),
        (["pytest", "fit"], [], False),
        # a worker the fit spawns is given the command's argv before it imports tensorid
        (
            ["/usr/bin/tensorid", "fit", "m.py"],
            [
                "python",
                "-c",
                "from multiprocessing.spawn import spawn_main; spawn_main()",
                "--multiprocessing-fork",
            ],
            False,
        ),
    ],
)
def test_only_the_commands_that_draw_start_early(argv, orig, started):
    assert _early.figure_command(argv, orig) is started


_ADOPT = """
import os, sys
sys.argv = {argv!r}
import tensorid
from tensorid import _early
from tensorid.app import renderer
early = _early.state.renderer
print(os.environ.get("OPENBLAS_NUM_THREADS"))
print(None if early is None else early[1].pid)
if early is not None:
    r = renderer.Renderer()
    print(r._procs[0].pid if r._procs else None, len(r._procs), _early.state.renderer)
    r.close()
"""


@pytest.mark.skipif(not hasattr(os, "fork"), reason="the early start is for forking renderers")
def test_the_fit_command_s_renderer_is_started_at_import_and_taken_over(monkeypatch):
    import subprocess
    import sys

    if _early.default_forks() < 2:
        pytest.skip("one core: the renderer draws in turn, not started early")
    for name in _early._THREADS:  # (Dask's workers, started by earlier tests, set OMP's)
        monkeypatch.delenv(name, raising=False)
    code = _ADOPT.format(argv=["tensorid", "fit", "m.py", "d.csv"])
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    blas, pid, taken = out.stdout.split("\n", 2)
    assert blas == "1" and pid != "None"
    # the command's Renderer is that process (no second one), and none is left waiting
    assert taken.split() == [pid, "1", "None"]
    # not the fit command: nothing started, the user's environment as it was
    code = _ADOPT.format(argv=["tensorid", "fit", "--help"])
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.split("\n")[:2] == ["None", "None"]
    monkeypatch.setenv("OPENBLAS_NUM_THREADS", "3")  # the user's own is kept
    code = _ADOPT.format(argv=["tensorid", "fit", "m.py"])
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.split("\n")[0] == "3"
    monkeypatch.delenv("OPENBLAS_NUM_THREADS")  # OpenBLAS would read OMP's: not overridden
    monkeypatch.setenv("OMP_NUM_THREADS", "2")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.split("\n")[0] == "None"


@pytest.mark.skipif(not hasattr(os, "fork"), reason="the early start is for forking renderers")
def test_an_early_renderer_nobody_takes_ends_with_the_command():
    """A fit command that fails before it draws (bad input: one line, then out) leaves
    no renderer behind: its input ends with the command, and so does it."""
    import subprocess
    import sys

    if _early.default_forks() < 2:
        pytest.skip("one core: the renderer draws in turn, not started early")
    code = _ADOPT.format(argv=["tensorid", "fit", "m.py"]).split("if early is not")[0]
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    pid = int(out.stdout.split("\n")[1])
    deadline = time.monotonic() + 20
    while renderer_module.running(pid) and time.monotonic() < deadline:
        time.sleep(0.05)
    assert not renderer_module.running(pid)


_COLLECTOR = """
import gc, sys
sys.argv = {argv!r}
import tensorid
from tensorid import _early
print(gc.isenabled(), gc.get_freeze_count() > 0)
from tensorid import cli
cli.main(["simulate", "missing.py", "missing.csv", "--out", "x.csv"])  # refused: 2
print(gc.isenabled(), gc.get_freeze_count() > 0)
"""


@pytest.mark.parametrize(
    "argv, paused",
    [
        (["/usr/bin/tensorid", "fit", "--help"], True),  # any command, not only those drawing
        (["tensorid", "paper", "--quick"], True),
        (["-c"], False),  # the Python API: a user's process is left as it was
        (["script.py", "fit"], False),
    ],
)
def test_the_command_pauses_the_collector_while_it_imports(argv, paused):
    # each full collection during the imports walked every object imported so far
    # (0.08-0.09 s of a warm fit of the bundled example); the command's own process
    # only, and running again once the command's modules are in
    import subprocess
    import sys

    code = _COLLECTOR.format(argv=argv)
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    during, after = out.stdout.splitlines()[-2:]
    assert during == f"{not paused} False"
    assert after == f"True {paused}"
