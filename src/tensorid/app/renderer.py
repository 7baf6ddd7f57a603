"""The fit command's figures drawn in a second process while the first goes on with
the statistics, fit.json and the summary: the user waits for the slower of the two,
not for their sum.

The renderer is a plain Python process that imports NumPy and Matplotlib but not
tensorid or JAX (it loads ``tensorid/analysis/figures.py`` by path), so it starts in
a fraction of a second, alongside the fit. It gets (kind, arguments, file) jobs as
plain data (``tensorid.analysis.figures.figure_jobs``), draws them with the same code
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
import time
from functools import partial
from pathlib import Path

WAIT = 60.0  # seconds without a reply after which the renderer counts as hung


def serve(figures_path: str, forks: str = "0") -> None:
    """The renderer's loop: a job (key, kind, arguments, file) at a time from stdin,
    a reply (key, None or why it failed) for each on stdout; ends at end of input.
    With ``forks`` > 1, up to that many jobs are drawn at once, each in a fork."""
    import importlib.util

    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C is the command's to handle
    if hasattr(signal, "SIGCHLD"):  # inherited as ignored, the forks could not be waited for
        signal.signal(signal.SIGCHLD, signal.SIG_DFL)
    spec = importlib.util.spec_from_file_location("_tensorid_figures", figures_path)
    assert spec is not None and spec.loader is not None  # a .py file by path
    figures = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(figures)
    figures.new_figure()  # Matplotlib imported while the command still fits
    # what the imports made lives as long as the process: set aside, so that no
    # collection here or in a fork walks it (the collector was paused meanwhile)
    import gc

    gc.freeze()
    gc.enable()
    jobs: queue.Queue = queue.Queue()

    def read() -> None:  # at once, so that the command never blocks on a full pipe
        while True:
            try:
                jobs.put(pickle.load(sys.stdin.buffer))
            except Exception:  # end of input, or a job it cannot read: it ends, and
                jobs.put(None)  # the command draws what is left itself
                return

    threading.Thread(target=read, daemon=True).start()
    draw_all(figures, jobs, int(forks))


def draw_all(figures, jobs: queue.Queue, forks: int) -> None:
    """Draw the jobs as they come, replying for each. With ``forks`` > 1, each job is
    drawn in a fork of this process, that many at once: a copy with Matplotlib
    imported and warm starts in milliseconds, where a second renderer would import it
    again (4 figures after a fit: the command 1.86 s against 2.04 s drawn in turn,
    medians of 5 on 2 cores). A job whose fork fails is reported failed (the command
    then draws it itself, and sees its error); where no fork can be made, the
    renderer draws it."""
    out = threading.Lock()

    def reply(key, why) -> None:
        with out:
            pickle.dump((key, why), sys.stdout.buffer)
            sys.stdout.buffer.flush()

    def one(job) -> str | None:
        _, kind, arguments, file = job
        try:
            figures.save_png(figures.draw(kind, arguments), Path(file))
            return None
        except Exception as e:  # reported; the command then draws it itself
            return f"{type(e).__name__}: {e}"

    if forks <= 1 or not hasattr(os, "fork"):
        while (job := jobs.get()) is not None:
            reply(job[0], one(job))
        return
    slots = threading.Semaphore(forks)
    waiting: list[threading.Thread] = []

    def reap(pid: int, key: str) -> None:
        try:
            _, status = os.waitpid(pid, 0)
            code = os.waitstatus_to_exitcode(status)
        except ChildProcessError:  # reaped by someone else: its file says nothing sure
            code = -1
        slots.release()
        reply(key, None if code == 0 else f"the figure's process ended with {code}")

    while (job := jobs.get()) is not None:
        slots.acquire()
        try:
            pid = os.fork()
        except OSError:  # no process to spare: drawn here
            slots.release()
            reply(job[0], one(job))
            continue
        if pid == 0:  # the copy: draws one figure and ends, without Python's exit
            code = 1
            try:
                # not holding the command's pipes open: the renderer's end is seen at once
                null = os.open(os.devnull, os.O_RDWR)
                os.dup2(null, 0)
                os.dup2(null, 1)
                code = 0 if one(job) is None else 1
            finally:
                os._exit(code)
        t = threading.Thread(target=reap, args=(pid, job[0]), daemon=True)
        t.start()
        waiting.append(t)
    for t in waiting:
        t.join()


def _gone(group: int, wait: float = 1.0) -> None:
    """Wait (up to ``wait`` s) until no process of the killed group ``group`` still
    runs: a fork dies a moment after its signal, and one still saving could
    otherwise write a file again after the command removed it."""
    deadline = time.monotonic() + wait
    while time.monotonic() < deadline and running(group):
        time.sleep(0.01)


def running(group: int) -> bool:
    """Whether a process of ``group`` still runs (zombies aside: a killed fork's
    parent is gone, and whoever adopts it may reap it late)."""
    try:
        os.killpg(group, 0)
    except (AttributeError, OSError):  # empty (or no process groups here)
        return False
    proc = Path("/proc")
    if not proc.is_dir():
        return True
    for stat in proc.glob("[0-9]*/stat"):
        try:  # "pid (name) state ppid pgrp ...", the name in parentheses
            fields = stat.read_text().rsplit(")", 1)[1].split()
        except (OSError, IndexError):  # ended meanwhile
            continue
        if int(fields[2]) == group and fields[0] != "Z":
            return True
    return False


def _end(proc: subprocess.Popen) -> None:
    """Close a renderer's input, at whose end it ends (not waited for)."""
    try:
        if proc.stdin is not None:
            proc.stdin.close()
    except OSError:
        pass


def draw_files(out: Path, jobs: list) -> list[Path]:
    """The figures of (stem, kind, arguments) ``jobs`` written to ``out``/stem.png, in
    order: by the renderer the command started before its imports (tensorid._early)
    where there is one, else here (a renderer started now would take longer to import
    Matplotlib than a figure or two take to draw)."""
    from .. import _early

    if not _early.started():
        from ..analysis.figures import draw, save_png
        from .output import write_atomic

        return [
            write_atomic(out / f"{stem}.png", partial(save_png, draw(kind, a)))
            for stem, kind, a in jobs
        ]
    renderer = Renderer()
    try:
        return [renderer.collect(stem) for stem in renderer.submit(out, jobs)]
    finally:
        renderer.close()


class Renderer:
    """The command's side: ``submit`` jobs as they become known, ``collect`` them in
    the order the report lists them, ``close`` (always) at the end. A fit's figures
    come in pairs (the training record and the convergence, then validation and the
    residual tests), and drawing them one after the other was the longest wait of a
    command-line fit. On Linux one renderer draws up to ``forks`` jobs at once, each
    in a fork of itself (default: one per core, at most 4); elsewhere, with three
    cores or more (one stays the command's), two renderers take the jobs in turn (on
    two cores a second renderer, importing Matplotlib again, only competed with the
    command: 2.64 s against 2.47 s, median of 5 alternating runs at load 1.7)."""

    def __init__(self, processes: int | None = None, forks: int | None = None) -> None:
        # here: at module level this file is the renderer's, which imports no tensorid
        from .._early import cores, default_forks, start_renderer, take_renderer

        self._procs: list[subprocess.Popen] = []
        self._pending: dict[str, tuple[str, dict, Path, Path | None]] = {}
        self._done: dict[str, str | None] = {}
        self._replies: queue.Queue = queue.Queue()
        self._turn = 0
        if forks is None:
            forks = default_forks()
        # the command itself keeps a core: two renderers from three cores on
        default = 1 if forks > 1 else min(2, max(1, cores() - 1))
        wanted = processes if processes is not None else default
        early = take_renderer()  # started with the command (tensorid._early)
        for _ in range(wanted):
            proc: subprocess.Popen | None
            if early is not None and early[0] == forks:
                proc, early = early[1], None
            else:
                proc = start_renderer(forks)
            if proc is None:
                break  # then the figures are drawn by those that started, or here
            self._procs.append(proc)
            threading.Thread(target=self._read, args=(proc.stdout,), daemon=True).start()
        if early is not None:  # not the one wanted: ends at the end of its input
            _end(early[1])

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
        from ..analysis.figures import draw, save_png
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
            # first: closing its output waits for a read in progress; the whole group,
            # so that a fork still drawing goes too (each renderer leads its session)
            try:  # (its pid is still its own until it is waited for)
                if proc.returncode is None:
                    os.killpg(proc.pid, signal.SIGKILL)
            except (AttributeError, OSError):  # no process groups here, or gone
                proc.kill()
        for proc in procs:
            proc.wait()
            _gone(proc.pid)
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
