"""Live progress for long runs: a rich progress bar on a terminal, plain complete
lines in a log (no bar, no carriage returns), nothing when disabled; and the live
table of a fit's iterations (``tensorid fit``), one plain line each in a log."""

from __future__ import annotations

import sys
import time
from contextlib import contextmanager

import numpy as np
from rich.console import Console
from rich.progress import (
    BarColumn,
    MofNCompleteColumn,
    Progress,
    TaskID,
    TextColumn,
    TimeElapsedColumn,
)
from rich.table import Table


class _StudyProgress:
    """What the paper study reports as it goes. With ``progress`` (a terminal) a
    bar; with ``log`` (any other stream) a line per step and per tenth of the fits."""

    def __init__(self, progress: Progress | None, console: Console | None, log=None):
        self.progress, self.console, self.log = progress, console, log
        self._task: TaskID | None = None
        self._t0 = time.perf_counter()
        self._bad = 0
        self._done = 0
        self._total = 0

    def _line(self, text: str) -> None:
        print(f"[{time.perf_counter() - self._t0:6.1f} s] {text}", file=self.log, flush=True)

    def step(self, what: str) -> None:
        if self.console:
            self.console.log(what)
        elif self.log:
            self._line(what)

    def start_robustness(self, n: int, workers: int) -> None:
        self._total = n
        self.step(f"Robustness study: {n} fits on {workers} worker process(es)")
        if self.progress:
            self._task = self.progress.add_task("robustness", total=n, status="")

    def advance(self, result: dict) -> None:
        self._done += 1
        self._bad += not result["success"]
        status = (
            f"{result['dataset']} {result['method']} "
            f"{result.get('accuracy') or 'rk4x' + str(result['substeps'])} "
            f"(optimizer-reported failures so far: {self._bad})"
        )
        if self.progress and self._task is not None:
            self.progress.update(self._task, advance=1, status=status)
        elif self.log and self._total:
            tenth = max(1, self._total // 10)
            if self._done % tenth == 0 or self._done == self._total:
                self._line(f"robustness: {self._done}/{self._total} fits done; last {status}")


@contextmanager
def study_progress(enabled: bool = True, stream=None):
    """Progress of the paper study on ``stream`` (default: standard error)."""
    if not enabled:
        yield _StudyProgress(None, None)
        return
    stream = sys.stderr if stream is None else stream
    console = Console(file=stream)
    if not console.is_terminal:
        yield _StudyProgress(None, None, log=stream)
        return
    columns = (
        TextColumn("[bold]{task.description}"),
        BarColumn(),
        MofNCompleteColumn(),
        TimeElapsedColumn(),
        TextColumn("{task.fields[status]}"),
    )
    with Progress(*columns, console=console, transient=False) as progress:
        yield _StudyProgress(progress, console)


def _progress_table(rows: list[dict]) -> Table:
    t = Table(title="tensorid fit", show_edge=False)
    for c in ("iter", "cost", "grad norm", "trust radius", "step"):
        t.add_column(c, justify="right")
    for h in rows[-12:]:
        t.add_row(
            str(h["iteration"]),
            f"{h['cost']:.8g}",
            f"{h['grad_norm']:.2e}",
            f"{h['radius']:.2e}",
            "accepted" if h["accepted"] else "rejected",
        )
    return t


def _log_line(console: Console):
    def show(h: dict) -> None:
        parts = [f"iteration {h['iteration']}: cost {h['cost']:.8g}"]
        for key, label in (("grad_norm", "gradient norm"), ("radius", "trust radius")):
            if np.isfinite(h[key]):  # the finite-difference baselines have neither
                parts.append(f"{label} {h[key]:.2e}")
        if h["iteration"] > 0:
            parts.append("accepted" if h["accepted"] else "rejected")
        console.print(", ".join(parts), soft_wrap=True, highlight=False)

    return show
