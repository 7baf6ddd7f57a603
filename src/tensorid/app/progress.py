"""Live progress for long runs, with rich; silent when disabled."""

from __future__ import annotations

import time
from contextlib import contextmanager

from rich.console import Console
from rich.progress import (
    BarColumn,
    MofNCompleteColumn,
    Progress,
    TaskID,
    TextColumn,
    TimeElapsedColumn,
)


class _StudyProgress:
    def __init__(self, progress: Progress | None, console: Console | None):
        self.progress, self.console = progress, console
        self._task: TaskID | None = None
        self._t0 = time.perf_counter()
        self._bad = 0

    def step(self, what: str) -> None:
        if self.console:
            self.console.log(what)

    def start_robustness(self, n: int, workers: int) -> None:
        if self.progress:
            self.step(f"Robustness study: {n} fits on {workers} worker process(es)")
            self._task = self.progress.add_task("robustness", total=n, status="")

    def advance(self, result: dict) -> None:
        if self.progress and self._task is not None:
            self._bad += not result["success"]
            self.progress.update(
                self._task,
                advance=1,
                status=f"{result['dataset']} {result['method']} rk4x{result['substeps']} "
                f"(optimizer-reported failures so far: {self._bad})",
            )


@contextmanager
def study_progress(enabled: bool = True):
    if not enabled:
        yield _StudyProgress(None, None)
        return
    console = Console(stderr=True)
    columns = (
        TextColumn("[bold]{task.description}"),
        BarColumn(),
        MofNCompleteColumn(),
        TimeElapsedColumn(),
        TextColumn("{task.fields[status]}"),
    )
    with Progress(*columns, console=console, transient=False) as progress:
        yield _StudyProgress(progress, console)
