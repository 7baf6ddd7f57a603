"""Reproduce the paper: Silverbox and two-tank identification, its figures, and the
robustness comparison of its Table 1, on the bundled measurements.

    tensorid paper --out DIR [--starts N] [--quick]

writes DIR/results.json, DIR/report.md and PNG figures. The parts: the accuracy
levels in :mod:`.levels`, the headline fits in :mod:`.headline`, Table 1 in
:mod:`.robustness`; this module runs them in order and writes the results.
"""

from __future__ import annotations

import os
import platform
import time
from datetime import UTC, datetime
from pathlib import Path

from .._config import __version__
from ..app.output import write_text
from ..app.progress import study_progress
from ..app.reports import write_json
from .headline import silverbox_study, two_tank_study
from .levels import (
    ACCURACY_LEVELS,
    ADAPTIVE_TOLERANCES,
    QUICK_LEVELS,
    all_levels,
    level_name,
    level_options,
)
from .report import render
from .robustness import (
    COMPARED,
    CONVERGED_RTOL,
    SEGMENTS,
    SPREAD,
    _robustness_figure,
    draw_starts,
    integration_errors,
    robustness_study,
    robustness_task,
    summarise,
)

__all__ = [
    "ACCURACY_LEVELS",
    "ADAPTIVE_TOLERANCES",
    "COMPARED",
    "CONVERGED_RTOL",
    "QUICK_LEVELS",
    "SEGMENTS",
    "SPREAD",
    "all_levels",
    "draw_starts",
    "integration_errors",
    "level_name",
    "level_options",
    "robustness_study",
    "robustness_task",
    "run",
    "silverbox_study",
    "summarise",
    "two_tank_study",
]


# -- the whole study ----------------------------------------------------------------------
def run(
    out: Path,
    *,
    starts: int = 100,
    quick: bool = False,
    workers: int | None = None,
    seed: int = 0,
    progress: bool = True,
    levels=None,
) -> dict:
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    if levels is None:
        levels = QUICK_LEVELS if quick else all_levels()
    levels = tuple(map(level_name, levels))
    for lv in levels:
        level_options(lv)  # an unknown level fails here, before any work
    workers = workers or os.cpu_count() or 1
    t_start = time.perf_counter()
    with study_progress(enabled=progress) as prog:
        prog.step("Silverbox: paper's model, paper's estimates, offset variant")
        silverbox, figs = silverbox_study(out)
        prog.step("Two-tank: paper's model and estimates")
        two_tank, figs2 = two_tank_study(out)
        figs += figs2
        n_tasks = 2 * len(levels) * len(COMPARED) * starts
        prog.start_robustness(n_tasks, workers)
        runs = robustness_study(starts, levels, workers, seed, on_done=prog.advance)
        prog.step("Integration accuracy of each level")
        errors = integration_errors(levels)
    rows = summarise(runs, levels)
    figs.append(_robustness_figure(out, rows))
    results = {
        "silverbox": silverbox,
        "two_tank": two_tank,
        "robustness": rows,
        "robustness_runs": runs,
        "meta": {
            "tensorid": __version__,
            "date": datetime.now(UTC).isoformat(),
            "machine": f"{platform.machine()}, {os.cpu_count()} cores, "
            f"{platform.python_implementation()} {platform.python_version()}",
            "starts": starts,
            "quick": quick,
            "seed": seed,
            "spread": SPREAD,
            "workers": workers,
            "accuracy_levels": {
                lv: level_options(lv).get("substeps", level_options(lv).get("atol"))
                for lv in levels
            },
            "integration_error": errors,
            "converged_rtol": CONVERGED_RTOL,
            "segments": SEGMENTS,
            "seconds": time.perf_counter() - t_start,
        },
    }
    write_json(out / "results.json", results)
    write_text(out / "report.md", render(results, [Path(f).name for f in figs]))
    return results
