"""The fit command's figures drawn in a second process while the first goes on with
the statistics, fit.json and the summary: the user waits for the slower of the two,
not for their sum.

The renderer is a plain Python process that imports NumPy and Matplotlib but not
tensorid or JAX (it loads ``tensorid/fitting/figures.py`` by path), so it starts in
a fraction of a second, alongside the fit. It gets (kind, arguments, file) jobs as
plain data (``tensorid.fitting.figures.figure_jobs``), draws them with the same code
as the Python API, and writes each PNG to a temporary file in the output folder that
this process made; :meth:`Renderer.collect` renames it into place (atomically, as
every file). It ignores Ctrl-C: the command decides, and :meth:`Renderer.close`
ends it and removes what was not collected. Whatever goes wrong with it (it cannot
start, dies, or fails a figure), the figure is drawn here instead: nothing is lost,
only the time saved.

This file is also the renderer's program, so it imports nothing from tensorid at
module level.
"""

from __future__ import annotations

import os
import pickle
import queue
import signal
import subprocess
import sys
import tempfile
import threading
from pathlib import Path

_FIGURES = Path(__file__).resolve().parent.parent / "fitting" / "figures.py"
WAIT = 60.0  # seconds without a reply after which the renderer counts as hung
_SERVE = (
    "import runpy, sys; "
    "runpy.run_path(sys.argv[1], run_name='__tensorid_renderer__')['serve'](sys.argv[2])"
)


def serve(figures_path: str) -> None:
    """The renderer's loop: a job (key, kind, arguments, file) at a time from stdin,
    a reply (key, None or why it failed) for each on stdout; ends at end of input."""
    import importlib.util

    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C is the command's to handle
    spec = importlib.util.spec_from_file_location("_tensorid_figures", figures_path)
    assert spec is not None and spec.loader is not None  # a .py file by path
    figures = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(figures)
    figures.new_figure()  # Matplotlib imported while the command still fits
    jobs: queue.Queue = queue.Queue()

    def read() -> None:  # at once, so that the command never blocks on a full pipe
        while True:
            try:
                jobs.put(pickle.load(sys.stdin.buffer))
            except Exception:  # end of input, or a job it cannot read: it ends, and
                jobs.put(None)  # the command draws what is left itself
                return

    threading.Thread(target=read, daemon=True).start()
    while (job := jobs.get()) is not None:
        key, kind, arguments, file = job
        try:
            figures.save_png(figures.draw(kind, arguments), Path(file))
            why = None
        except Exception as e:  # reported; the command then draws it itself
            why = f"{type(e).__name__}: {e}"
        pickle.dump((key, why), sys.stdout.buffer)
        sys.stdout.buffer.flush()


class Renderer:
    """The command's side: ``submit`` jobs as they become known, ``collect`` them in
    the order the report lists them, ``close`` (always) at the end. With three cores
    or more (one stays the command's), two renderers take the jobs in turn: a fit's
    figures come in pairs (the training record and the convergence, then validation
    and the residual tests), and drawing them one after the other was the longest
    wait of a command-line fit. (On two cores a second renderer only competes with
    the command: 2.64 s against 2.47 s, median of 5 alternating runs at load 1.7.)"""

    def __init__(self, processes: int | None = None) -> None:
        self._procs: list[subprocess.Popen] = []
        self._pending: dict[str, tuple[str, dict, Path, Path | None]] = {}
        self._done: dict[str, str | None] = {}
        self._replies: queue.Queue = queue.Queue()
        self._turn = 0
        from .._config import cores  # here: at module level this file is the renderer's

        # the command itself keeps a core: two renderers from three cores on
        wanted = processes if processes is not None else min(2, max(1, cores() - 1))
        for _ in range(wanted):
            try:
                proc = subprocess.Popen(
                    [sys.executable, "-P", "-c", _SERVE, __file__, str(_FIGURES)],
                    stdin=subprocess.PIPE,
                    stdout=subprocess.PIPE,
                    stderr=subprocess.DEVNULL,
                    start_new_session=True,  # Ctrl-C at the terminal reaches the command only
                )
            except (OSError, ValueError, TypeError):  # no usable interpreter, no processes
                break  # then the figures are drawn by those that started, or here
            self._procs.append(proc)
            threading.Thread(target=self._read, args=(proc.stdout,), daemon=True).start()

    def _read(self, stream) -> None:
        """The renderer's replies into a queue; None when it is gone."""
        while True:
            try:
                self._replies.put(pickle.load(stream))
            except (EOFError, OSError, ValueError, pickle.UnpicklingError):
                self._replies.put(None)
                return

    def submit(self, out: Path, jobs: list) -> list[str]:
        """Hand (stem, kind, arguments) jobs to the renderer, each to be written to
        ``out``/stem.png; returns their stems."""
        for stem, kind, arguments in jobs:
            tmp = self._send(out, stem, kind, arguments)
            self._pending[stem] = (kind, arguments, out / f"{stem}.png", tmp)
        return [stem for stem, _, _ in jobs]

    def _send(self, out: Path, stem: str, kind: str, arguments: dict) -> Path | None:
        if not self._procs:
            return None
        proc = self._procs[self._turn % len(self._procs)]
        self._turn += 1
        tmp = None
        try:
            fd, name = tempfile.mkstemp(prefix=f".{stem}.png.", suffix=".part", dir=out)
            os.close(fd)
            tmp = Path(name)
            stdin = proc.stdin
            assert stdin is not None  # started with stdin=PIPE
            pickle.dump((stem, kind, arguments, name), stdin)
            stdin.flush()
            return tmp
        except Exception:  # a folder it cannot write to, a job it cannot send
            if tmp is not None:
                tmp.unlink(missing_ok=True)
            self._stop()
            return None

    def collect(self, stem: str) -> Path:
        """The figure ``stem`` in place (renamed from the renderer's file, or drawn
        here where the renderer could not); OSError naming the file if it cannot be
        written."""
        from ..fitting.figures import draw, save_png
        from .output import write_atomic

        kind, arguments, path, tmp = self._pending.pop(stem)
        if tmp is not None and self._wait(stem) is None:
            return write_atomic(path, lambda part: os.replace(tmp, part))
        if tmp is not None:
            tmp.unlink(missing_ok=True)
        return write_atomic(path, lambda part: save_png(draw(kind, arguments), part))

    def _wait(self, stem: str) -> str | None:
        """The renderer's reply for ``stem``: None when its file is written, else why
        not (also when the renderer is gone, or silent for WAIT seconds)."""
        while stem not in self._done:
            if not self._procs:
                return "the renderer is gone"
            try:
                reply = self._replies.get(timeout=WAIT)
            except queue.Empty:
                reply = None
            if reply is None:
                self._stop()
                return "the renderer is gone"
            self._done[reply[0]] = reply[1]
        return self._done.pop(stem)

    def _stop(self) -> None:
        """End every renderer: one that is gone or hung stops them all, and what is
        left is drawn here (one rule, however many there are)."""
        procs, self._procs = self._procs, []
        for proc in procs:
            proc.kill()  # first: closing its output waits for a read in progress
        for proc in procs:
            proc.wait()
            for stream in (proc.stdin, proc.stdout):
                try:
                    if stream is not None:
                        stream.close()
                except OSError:
                    pass

    def close(self) -> None:
        """End the renderer and remove the files of jobs not collected (after Ctrl-C,
        or a folder that could not be written)."""
        self._stop()
        for _, _, _, tmp in self._pending.values():
            if tmp is not None:
                tmp.unlink(missing_ok=True)
        self._pending.clear()
