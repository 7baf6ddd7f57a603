"""What the command is compiling, while it compiles: a new model's first fit waits
tens of seconds for XLA, and a console that says nothing meanwhile looks hung.

The engine announces each program's first call through jax.monitoring
(``engine.compilation.BEGIN`` and ``END``); :class:`CompileWatch` listens for as long
as the command runs. On a terminal it shows one live line, updated about once a
second ("compiling the second-order sweep (J, ∇J, ∇²J) … 12 s"), from the first
second of a compilation on; in a log (any other stream) a line when a compilation
has taken ``LOG_AFTER`` seconds and one when it ends, with its seconds. A program
read from an earlier process's files takes milliseconds: it shows nothing.
"""

from __future__ import annotations

import threading
import time

import jax
from rich.console import Console
from rich.live import Live
from rich.text import Text

from ..engine.compiling.compilation import BEGIN, END

SHOW_AFTER = 1.0  # seconds before a terminal shows the live line
LOG_AFTER = 2.0  # seconds before a log is told, and the least that ends with a line


class CompileWatch:
    """Listens for the engine's compile events while it is entered. ``hosted``: a
    live display of the caller's own (the iteration table) shows :meth:`line` under
    it; otherwise, on a terminal, the watch shows it in a transient live line of its
    own."""

    def __init__(self, console: Console, log_after: float | None = None, enabled: bool = True):
        self.console, self.enabled = console, enabled
        self.log_after = LOG_AFTER if log_after is None else log_after
        self.terminal = console.is_terminal
        self.hosted = False
        self._open: dict[int, tuple[str, float, list]] = {}  # thread → (what, t0, [told])
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._live: Live | None = None
        self._thread: threading.Thread | None = None

    # -- jax.monitoring's listeners -------------------------------------------------
    def _begin(self, event: str, **kw: str | int) -> None:
        if event == BEGIN and not self._stop.is_set():
            with self._lock:
                self._open[threading.get_ident()] = (str(kw.get("what")), time.monotonic(), [])

    def _end(self, event: str, duration_secs: float, **kw: str | int) -> None:
        if event != END or self._stop.is_set():
            return
        with self._lock:
            self._open.pop(threading.get_ident(), None)
        if duration_secs >= self.log_after:
            self._print(f"compiled {kw.get('what')} in {duration_secs:.1f} s")

    # -- what is shown ----------------------------------------------------------------
    def line(self) -> Text:
        """The live line: the longest-running compilation and its seconds so far
        (empty while none has run for SHOW_AFTER)."""
        now = time.monotonic()
        with self._lock:
            running = sorted((t0, what) for what, t0, _ in self._open.values())
        if not running or now - running[0][0] < SHOW_AFTER:
            return Text("")
        t0, what = running[0]
        more = f" (and {len(running) - 1} more)" if len(running) > 1 else ""
        return Text(f"compiling {what}{more} … {now - t0:.0f} s", style="dim")

    def _print(self, text: str) -> None:
        self.console.print(text, soft_wrap=True, highlight=False, markup=False)

    def _tick(self) -> None:
        """Once a second (a quarter on a terminal): in a log, the line of each
        compilation past ``log_after`` seconds; on a terminal, the live line started
        when one is past SHOW_AFTER seconds and stopped when none runs."""
        while not self._stop.wait(0.25 if self.terminal else 0.5):
            now = time.monotonic()
            with self._lock:
                late = [(w, t) for w, t0, t in self._open.values() if now - t0 >= self.log_after]
                showing = any(now - t0 >= SHOW_AFTER for _, t0, _ in self._open.values())
            if not self.terminal:
                for what, told in late:
                    if not told:
                        told.append(True)
                        self._print(f"compiling {what} …")
            elif not self.hosted and showing and self._live is None:
                self._live = Live(
                    get_renderable=self.line, console=self.console, transient=True,
                    refresh_per_second=1,
                )  # fmt: skip
                self._live.start(refresh=True)
            elif self._live is not None and (self.hosted or not showing):
                self._live.stop()
                self._live = None

    def __enter__(self) -> CompileWatch:
        if not self.enabled:
            return self
        jax.monitoring.register_event_listener(self._begin)
        jax.monitoring.register_event_duration_secs_listener(self._end)
        self._thread = threading.Thread(target=self._tick, name="compile-watch", daemon=True)
        self._thread.start()
        return self

    def __exit__(self, *exc) -> None:
        if not self.enabled:
            return
        self._stop.set()
        if self._thread is not None:
            self._thread.join()
        if self._live is not None:
            self._live.stop()
            self._live = None
        # where this JAX cannot unregister them, they stay, told by _stop to be quiet
        for name, fn in (
            ("unregister_event_listener", self._begin),
            ("unregister_event_duration_listener", self._end),
        ):
            unregister = getattr(jax.monitoring, name, None)
            if unregister is not None:
                unregister(fn)
