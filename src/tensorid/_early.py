"""What runs before anything heavy is imported: ``tensorid/__init__.py`` imports this
module first, and it imports nothing beyond Python's own (the renderer's program it
starts by path).

On import, for the commands that draw figures (``tensorid fit``, ``simulate`` and
``compare``, the installed script or ``python -m tensorid``),
:func:`start` starts the figure renderer (``app/renderer.py``) at once, so that its
import of Matplotlib overlaps this process's imports of NumPy and JAX instead of
following them, and caps OpenBLAS at one thread: the threads OpenBLAS starts when
NumPy (and SciPy's LAPACK) load spin for a while, a quarter of a second of the core
the renderer needs, and the command's own matrices are parameter-sized. Together
they took the warm fit of the bundled example from 1.49 to 1.35 s (medians of 9
alternating runs, 2 cores; docs/benchmarks.md). A thread count the user gave
OpenBLAS (OPENBLAS_NUM_THREADS, GOTO_NUM_THREADS or OMP_NUM_THREADS) is kept. For
every ``tensorid`` command the garbage collector is paused while the command's
modules are imported (:func:`settle`). Any other use of the package (the Python
API, the tests calling ``cli.main``, the workers a command spawns) starts and
pauses nothing.
"""

from __future__ import annotations

import gc
import os
import signal
import subprocess
import sys
from pathlib import Path

from ._state import state

# the renderer's program and what it draws with, by path: neither is imported here
RENDERER = Path(__file__).resolve().parent / "app" / "renderer.py"
FIGURES = Path(__file__).resolve().parent / "analysis" / "figures.py"
_SERVE = (  # (the collector paused while Matplotlib is imported: see serve)
    "import gc; gc.disable(); import runpy, sys; "
    "runpy.run_path(sys.argv[1], run_name='__tensorid_renderer__')['serve'](*sys.argv[2:])"
)


def cores() -> int:
    """The cores this process may run on: its affinity where the system says (a
    container or ``taskset`` may allow fewer than the machine has), else the count."""
    try:
        return len(os.sched_getaffinity(0))
    except (AttributeError, OSError):  # not on Linux
        return os.cpu_count() or 1


FIGURE_COMMANDS = ("fit", "simulate", "compare")  # the commands that draw figures
_THREADS = ("OPENBLAS_NUM_THREADS", "GOTO_NUM_THREADS", "OMP_NUM_THREADS")


def the_command(argv: list[str], orig_argv: list[str]) -> bool:
    """Whether this process is the ``tensorid`` command: the installed script (argv[0]
    named tensorid) or ``python -m tensorid`` (while the package is imported to be
    run, argv[0] is "-m"); not a worker it spawned (which is given the command's
    argv before it imports tensorid)."""
    if "--multiprocessing-fork" in orig_argv:
        return False
    if argv and Path(argv[0]).stem == "tensorid":
        return True
    if not argv or argv[0] != "-m":
        return False
    pairs = zip(orig_argv, orig_argv[1:], strict=False)
    return any(a == "-m" and b == "tensorid" for a, b in pairs)


def figure_command(argv: list[str], orig_argv: list[str]) -> bool:
    """Whether this process is ``tensorid fit|simulate|compare ...`` (not asking for
    help), the command (:func:`the_command`)."""
    if len(argv) < 2 or argv[1] not in FIGURE_COMMANDS:
        return False
    if any(a in ("-h", "--help") for a in argv[2:]):
        return False
    if argv[1] == "simulate" and _out(argv).lower().endswith(".csv"):
        return False  # a table only: no figures
    return the_command(argv, orig_argv)


def default_forks() -> int:
    """Figures a renderer draws at once by default: one per core, at most 4, on Linux
    (where it can fork); elsewhere none (it draws them in turn)."""
    return min(4, cores()) if sys.platform == "linux" else 0


def start_renderer(forks: int) -> subprocess.Popen | None:
    """A renderer process (``app/renderer.py``'s ``serve``) drawing up to ``forks``
    figures at once, or None where none can start (no usable interpreter, no
    processes to spare)."""
    # its forks draw with one thread each (and a fork copies no BLAS threads)
    env = dict(os.environ, OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1")
    try:
        return subprocess.Popen(
            [sys.executable, "-P", "-c", _SERVE, str(RENDERER), str(FIGURES), str(forks)],
            env=env,
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            stderr=subprocess.DEVNULL,
            start_new_session=True,  # Ctrl-C at the terminal reaches the command only
        )
    except (OSError, ValueError, TypeError):
        return None


def _out(argv: list[str]) -> str:
    """The command line's --out value ("" if none)."""
    for i, a in enumerate(argv):
        if a == "--out" and i + 1 < len(argv):
            return argv[i + 1]
        if a.startswith("--out="):
            return a.split("=", 1)[1]
    return ""


def started() -> bool:
    """Whether :func:`start` started a renderer that no one has taken yet."""
    return state.renderer is not None


def take_renderer() -> tuple[int, subprocess.Popen] | None:
    """The renderer :func:`start` started, (forks, process), once; then None."""
    taken, state.renderer = state.renderer, None
    return taken


def settle() -> None:
    """Called by the command once its modules are imported: the garbage collector,
    paused by :func:`start` while they were, runs again, with what the imports made
    set aside for good (``gc.freeze``: modules, functions and classes live as long as
    the process, so a full collection need not walk them). Each full collection had
    walked JAX's and tensorid's objects, 20-25 ms each; with the imports' young ones,
    the collector took 0.08-0.09 s of a warm fit of the bundled example, and now
    0.01 s: the fit 1.43 -> 1.24 s with the figure process's alike (``python -m``,
    medians of 9 alternating runs, 2 cores). Only in the command's own process,
    never on a user's import of the package."""
    if state.importing:
        state.importing = False
        signal.signal(signal.SIGINT, signal.default_int_handler)
    if state.collector_paused:
        state.collector_paused = False
        gc.freeze()
        gc.enable()


def _interrupted_while_importing(signum, frame) -> None:
    """Ctrl-C before the command has started: nothing is computed yet to keep."""
    sys.stderr.write("tensorid: interrupted\n")
    os._exit(130)


def start() -> None:
    """For the ``tensorid`` command: the garbage collector paused until
    :func:`settle` (imports make few cycles, and the collections it runs meanwhile
    walk every object imported so far, again and again). For a command that draws
    figures also OpenBLAS at one thread, and the renderer started now (where it
    draws in forks; the command's Renderer takes it over, and without one it ends
    with this process, whose end ends its input)."""
    if the_command(sys.argv, getattr(sys, "orig_argv", [])):
        # Ctrl-C while NumPy and JAX load: one line, not a traceback of their imports
        # (settle hands Ctrl-C back to the command's own handling)
        signal.signal(signal.SIGINT, _interrupted_while_importing)
        state.importing = True
        # XLA's own log lines ("Very slow compile? If you want to file a bug ...") are
        # not the command's to print: the progress display says what is compiling. An
        # error still raises; a level the user set is kept
        os.environ.setdefault("TF_CPP_MIN_LOG_LEVEL", "3")
        if gc.isenabled():
            gc.disable()
            state.collector_paused = True
    if not figure_command(sys.argv, getattr(sys, "orig_argv", [])):
        return
    if not any(os.environ.get(k) for k in _THREADS):  # OpenBLAS reads them in this order
        os.environ["OPENBLAS_NUM_THREADS"] = "1"
    forks = default_forks()
    if state.renderer is None and forks > 1 and (proc := start_renderer(forks)) is not None:
        state.renderer = (forks, proc)


start()
