"""fit.json kept whatever happens: written where it can be (else to a fallback file,
else to the console), and saved at once on Ctrl-C, during the fit (the best point so
far) or after it (the estimates), with the earlier run's files removed so that two
runs never mix."""

from __future__ import annotations

import sys
from collections.abc import Iterator
from contextlib import contextmanager
from functools import partial
from pathlib import Path

import numpy as np

from ..analysis.display import summary_table
from ..analysis.figures import save_png
from .output import replace_outputs, write_atomic, write_kept, write_text
from .reports import fit_json, json_text


def _keep(out: Path, data: dict, kept: dict) -> list[str]:
    """fit.json into ``out`` or, where that fails, into a fallback file; its path goes
    to kept["fit.json"]. Where nothing can be written the JSON goes to the console.
    Returns the failures, one line each, naming the file and where the result went."""
    text = json_text(data)
    try:
        where, why = write_kept(out / "fit.json", text)
    except OSError as e:
        print(text)  # the last place left: the console
        return [f"{e}; fit.json is printed above"]
    kept["fit.json"] = where
    return [f"{why}; the results are in {where}"] if why else []


def _save_after_interrupt(res, out: Path, old: set[Path], kept: dict, extras=None) -> int:
    """Ctrl-C while the statistics, the console or the files of a finished fit were
    being made: a complete fit.json already written stays; otherwise the estimates
    go to fit.json without the statistics (no further computation), with ``extras``
    (provenance, overrides) as a complete one has them. Exit status 130."""
    if kept.get("fit.json"):
        _tidy(out, old, kept, [])
        print(f"tensorid: interrupted; {kept['fit.json']} was written", file=sys.stderr)
        return 130
    why = "interrupted after the fit, before its statistics were written: run it again for them"
    for name, value in res.params.items():  # the estimates on the console first
        print(f"{name} = {value!r}")
    where = _save_now(out, old, lambda: {**fit_json(res, [], missing=why), **(extras or {})})
    print(f"tensorid: interrupted after the fit; the estimates are in {where}", file=sys.stderr)
    return 130


def _save_now(out: Path, old: set[Path], data) -> Path | str:
    """fit.json from ``data()`` at once (under _no_interrupt), the failures printed.
    Returns where it went ("the console" where nowhere else)."""
    kept: dict = {}
    _tidy(out, old, kept, _keep(out, data(), kept))
    return kept.get("fit.json", "the console")


def _tidy(out: Path, old: set[Path], kept: dict, failures: list[str]) -> None:
    """After an interrupt: with fit.json in ``out``, the earlier run's files removed
    (no mix of two runs); the failures printed."""
    if kept.get("fit.json") == out / "fit.json":
        _replace_quietly(out, old, [kept["fit.json"]], failures)
    for f in failures:
        print(f"tensorid: error: {f}", file=sys.stderr)


@contextmanager
def _no_interrupt() -> Iterator[None]:
    """SIGINT ignored inside (main thread only: elsewhere signals are not ours)."""
    import signal
    import threading

    if threading.current_thread() is not threading.main_thread():
        yield
        return
    before = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, before)


def _replace_quietly(out: Path, old: set[Path], written: list[Path], failures: list):
    """replace_outputs, a failure appended to ``failures`` instead of raised."""
    try:
        replace_outputs(out, old, written)
    except OSError as e:
        failures.append(f"could not remove the earlier results in {out}: {e.strerror or e}")


def _save_interrupted(res, out: Path, old: set[Path], extras=None) -> int:
    """Ctrl-C: the best point so far goes to fit.json (status "interrupted") at once,
    with ``extras`` (provenance, overrides); no figures or report (the user is
    waiting); older results are removed, not mixed in. Exit status 130, as for any
    interrupted command."""
    if not np.isfinite(res.cost):  # nothing worth more than what the folder holds
        print(
            f"tensorid: interrupted before any start finished; {out} is as it was", file=sys.stderr
        )
        return 130
    print(summary_table(res, []))
    where = _save_now(out, old, lambda: {**fit_json(res, []), **(extras or {})})
    print(
        f"tensorid: interrupted; the best point so far (cost {res.cost:.6g}) is in {where}",
        file=sys.stderr,
    )
    return 130


def write_folder(out: Path, old: set[Path], data: dict, kept: dict, figures, report,
                 tables: tuple | list = ()) -> tuple[list[Path], list[str]]:  # fmt: skip
    """The one writer of a fit's folder, a single record's fit's and a fleet's alike:
    fit.json first (the estimates are what matters: kept elsewhere, or printed, where
    the folder cannot be written; its path goes to kept["fit.json"]), then ``tables``
    ((file name, writer of a path)), ``figures`` ((stem, maker that writes it and returns
    its path)) in the report's order, and report.md (``report(figures written)``), each
    atomically; what an earlier run wrote and this one did not is removed. A table or
    figure that fails is one line of the failures, not the end of the others;
    ``figures`` may be a function returning them, called once fit.json is written and
    before the tables (a fleet's figures compute their arrays and hand them to the
    renderer). Returns (the figures written, the failures)."""
    failures = _keep(out, data, kept)
    if kept.get("fit.json") != out / "fit.json":
        return [], failures  # the folder cannot be written: the rest would fail as well
    written: list[Path] = [kept["fit.json"]]
    # the figures' makers before the tables: a fleet's compute their arrays and hand
    # them to the renderer, which then draws while the tables are written
    figures = figures() if callable(figures) else figures
    for name, write in tables:
        try:
            written.append(write_atomic(out / name, write))
        except Exception as e:  # a table is not worth the fit: say so, go on
            failures.append(f"could not write {out / name}: {_reason(e)}")
    made: list[Path] = []
    for stem, make in figures:
        try:
            made.append(make())
        except OSError as e:
            failures.append(f"could not write {out / (stem + '.png')}: {e.strerror or e}")
        except Exception as e:  # a figure is not worth the report: say so, go on
            failures.append(f"could not draw {stem}.png: {e}")
    try:
        written.append(write_text(out / "report.md", report(made)))
    except OSError as e:
        failures.append(f"could not write {out / 'report.md'}: {e.strerror or e}")
    _replace_quietly(out, old, written + made, failures)
    return made, failures


def drawn_here(path: Path, build):
    """A figure maker for write_folder: ``build()`` drawn in this process when its turn
    comes (after fit.json), written atomically to ``path``."""
    return lambda: write_atomic(path, partial(save_png, build()))


def _reason(e: Exception) -> str:
    return (e.strerror if isinstance(e, OSError) else None) or str(e)
