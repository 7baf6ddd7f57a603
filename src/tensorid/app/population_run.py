"""The end of ``tensorid fit`` for a fleet's population fit: the console's table,
fit.json (the population keys of app/fleet_report.py with the run's settings and
provenance), report.md, observations.csv (one row per observation: PRED, IPRED,
IWRES, CWRES, NPDE, ...) and the figures (every unit's data and fits, observed against
predicted, the visual predictive check, the residuals). Validation records, profiles
and the single-system statistics do not apply to it and are not run."""

from __future__ import annotations

import csv
import json
from functools import partial
from pathlib import Path

import numpy as np

from .._config import __version__
from ..analysis.figures import save_png
from ..population.figures import drawn
from .fleet_report import fleet_json, fleet_lines
from .keeping import _replace_quietly
from .output import write_atomic, write_kept, write_text
from .provenance import markdown as provenance_lines


def population_json(res, recorded: dict) -> dict:
    """fit.json of a population fit (a contract: keys added, never renamed)."""
    d = {
        "kind": "population",
        "method": res.method,
        "status": res.status.name.lower(),
        "success": res.success,
        "message": res.message,
        "objective": res.objective,
        "objective_nlmixr": res.objective_nlmixr,
        "cost": res.objective,  # as every fit.json calls what the fit minimised
        # −2 log L + 2k and + k log N, k the estimated ψ (typical values, ω, shared, errors)
        "aic": res.criteria()["aic"],
        "bic": res.criteria()["bic"],
        # the estimates' correlations, in ψ's order (unknowns' names): null where unmeasured
        "correlation": res.correlation.tolist(),
        "correlation_names": list(res.names),
        "observations": res.observations,
        "iterations": res.nit,
        "function_evaluations": res.nfev,
        "seconds": res.seconds,
        "params": res.params,
        "shared": res.shared,
        "unknowns": dict(zip(res.names, res.x.tolist(), strict=True)),
        "model": res.problem.model.name,
        "tensorid_version": __version__,
        "notes": list(res.notes),
    }
    d.update(fleet_json(res))
    for u, entry in zip(d["units"], res.units, strict=True):
        u["eta"] = entry["eta"]
    d.update(recorded)
    return _finite(d)


def _finite(value):
    """Every number JSON can hold: a non-finite one (a failed fit's cost, an error bar
    with no curvature behind it) becomes null, so that fit.json is always written."""
    if isinstance(value, dict):
        return {k: _finite(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_finite(v) for v in value]
    if isinstance(value, float | np.floating):
        return float(value) if np.isfinite(value) else None
    return value


def population_report(res, data: dict, figures: list[Path]) -> str:
    lines = [
        "# Population fit",
        "",
        f"{len(res.units)} units, {res.observations} observations; method "
        f"{res.method.upper()}: {res.message} after {res.nit} iterations "
        f"({res.seconds:.1f} s).",
        "",
        f"−2 log L = {res.objective:.4f} (less N log 2π, as nlmixr2 and NONMEM print it: "
        f"{res.objective_nlmixr:.4f}).",
        "",
    ]
    lines += [f"**Note:** {n}" for n in res.notes] + ([""] if res.notes else [])
    lines += fleet_lines(data)
    if res.shared:
        lines += ["Shared parameters: " + ", ".join(
            f"{n} = {v['value']:.5g} ± {v['stderr']:.3g}" for n, v in res.shared.items()
        ) + ".", ""]  # fmt: skip
    lines += [f"![{p.stem}]({p.name})" for p in figures] + [""]
    prov = data.get("provenance")
    return "\n".join(lines + (provenance_lines(prov) if prov else []))


def report_population(res, out: Path, old: set[Path], recorded: dict) -> int:
    """Print, then write; every failing write is named, none loses the estimates."""
    print(res.summary())
    data = population_json(res, recorded)
    path, failure = write_kept(out / "fit.json", json.dumps(data, indent=2, allow_nan=False))
    if failure:  # the folder cannot be written: the estimates went elsewhere
        print(f"tensorid: {failure}; fit.json written to {path}")
        return 1
    failures: list[str] = []
    written, figures = [path], []
    if res.population and np.isfinite(res.objective):  # (as its figures: an Ω, a fit)
        try:
            written.append(write_atomic(out / "observations.csv", partial(_table_csv, res)))
        except Exception as e:  # the table is not worth the fit: say so, go on
            failures.append(f"could not write {out / 'observations.csv'}: {_reason(e)}")
    for stem, build in drawn(res):
        try:
            fig = build(res)
        except Exception as e:  # a figure is not worth the report: say so, go on
            failures.append(f"could not draw {stem}.png: {e}")
            continue
        try:
            figures.append(write_atomic(out / f"{stem}.png", partial(save_png, fig)))
        except OSError as e:
            failures.append(f"could not write {out / (stem + '.png')}: {e.strerror or e}")
    try:
        written.append(write_text(out / "report.md", population_report(res, data, figures)))
    except OSError as e:
        failures.append(f"could not write {out / 'report.md'}: {e.strerror or e}")
    _replace_quietly(out, old, written + figures, failures)
    for f in failures:
        print(f"tensorid: {f}")
    print(f"results in {out}/")
    return 0 if res.success and not failures else 1


def _reason(e: Exception) -> str:
    return (e.strerror if isinstance(e, OSError) else None) or str(e)


def _table_csv(res, path: Path) -> None:
    """observations.csv: one row per observation (population/diagnostics.py)."""
    tab = res.table()
    with open(path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(tab)
        for row in zip(*tab.values(), strict=True):
            w.writerow(
                v if isinstance(v, str) else ("" if not np.isfinite(v) else f"{v:.10g}")
                for v in row
            )


def _cell(v) -> str:
    """A table cell: text as it is, a number to 10 digits, empty where not finite."""
    if isinstance(v, str):
        return v
    return f"{v:.10g}" if np.isfinite(v) else ""


def save_interrupted(res, out: Path, old: set[Path], recorded: dict) -> int:
    """Ctrl-C during a population fit: the best point so far to fit.json (status
    "interrupted", no error bars), no figures (the user is waiting); exit 130."""
    print(res.summary())
    data = population_json(res, recorded)
    path, failure = write_kept(out / "fit.json", json.dumps(data, indent=2, allow_nan=False))
    failures = [failure] if failure else []
    if not failure:
        _replace_quietly(out, old, [path], failures)
    for f in failures:
        print(f"tensorid: {f}")
    print(f"tensorid: interrupted; the best point so far is in {path}")
    return 130
