"""The end of ``tensorid fit`` for a fleet's population fit: the console's table,
fit.json (the population keys of app/fleet_report.py with the run's settings and
provenance), report.md, observations.csv (one row per observation: PRED, IPRED,
IWRES, CWRES, NPDE, ...) and the figures (every unit's data and fits, observed against
predicted, the visual predictive check, the residuals), and what the command line
asked for beside the fit: --profile (typical values, ω, shared parameters),
--validate (held-out units, their η by empirical Bayes) and --data-sensitivity (which
unit moves the estimates). Those run after the estimates are printed; Ctrl-C or a
failure in them keeps the fit."""

from __future__ import annotations

import csv
import sys
from functools import partial
from pathlib import Path
from types import SimpleNamespace

import numpy as np

from .._config import __version__
from ..analysis.figures import draw, profile_figure
from ..population.figures import figure_jobs
from ..population.influence import influence_lines, unit_influence
from ..population.profiles import names_of
from ..population.validation import held_out, held_out_lines
from .after_fit import printed_profiles
from .fleet_report import fleet_json, fleet_lines
from .keeping import _save_now, _tidy, drawn_here, write_folder
from .provenance import markdown as provenance_lines
from .reports import _profile_json


def population_json(res, recorded: dict) -> dict:
    """fit.json of a population fit (a contract: keys added, never renamed)."""
    ended = getattr(res.objective_function, "problem", None) or res.problem  # as it ended
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
        "starts": res.starts,  # several starts: each one's objective and ending, best first
        # what compare/simulate --ipred rebuild the fit from (its units' η̂ on a new unit):
        # the integration as the fit ended (substeps it raised), Ω's structure and the
        # parameters each unit has its own value of without a distribution
        "integration": ended.discretisation.as_dict(),
        "omega_structure": ended.omega,
        "individual": list(ended.individual),
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
    lines += _analyses_lines(data)
    lines += [f"![{p.stem}]({p.name})" for p in figures] + [""]
    prov = data.get("provenance")
    return "\n".join(lines + (provenance_lines(prov) if prov else []))


def analyses(res, args, held) -> tuple[dict, list[str], bool]:
    """What the command line asked for beside the fit: ({"profiles", "held_out",
    "unit_influence"} where asked, notes, whether Ctrl-C stopped them). Each prints its
    lines as it ends; a failing one is a note, the fit is kept either way."""
    out: dict = {}
    notes: list[str] = []
    asked = args is not None and (args.profile is not None or args.data_sensitivity)
    if not res.success or not np.isfinite(res.objective):  # (no optimum to start from)
        if asked or held is not None:
            notes.append(f"no profiles, held-out units or unit influence: the fit {res.message}")
        return out, notes, False
    jobs = [("profiles", args is not None and args.profile is not None, _profiles),
            ("held_out", held is not None, lambda r, a: _held(r, held)),
            ("unit_influence", bool(getattr(args, "data_sensitivity", False)), _units)]  # fmt: skip
    for key, wanted, run in jobs:
        if not wanted:
            continue
        try:
            out[key] = run(res, args)
        except KeyboardInterrupt:
            notes.append(f"interrupted during the {key.replace('_', ' ')}; the fit is kept")
            return out, notes, True
        except (ValueError, np.linalg.LinAlgError) as e:
            notes.append(f"no {key.replace('_', ' ')}: {e}")
    return out, notes, False


def _profiles(res, args) -> dict:
    """--profile's names that the fit still has (a random effect that collapsed to 0 was
    made shared: its ω is gone, said in a note, and the others are profiled)."""
    known = names_of(res)
    gone = [n for n in args.profile or [] if n not in known]
    if gone:
        print(f"tensorid: note: no profile of {', '.join(gone)}: the fit has no such "
              f"estimate (a random effect that collapsed to 0 was made shared)")  # fmt: skip
    asked = [n for n in args.profile or [] if n in known]
    if args.profile and not asked:
        return {}
    return printed_profiles(res, SimpleNamespace(profile=asked, profile_level=args.profile_level))


def _held(res, problem) -> list[dict]:
    scores = held_out(res, problem)
    for line in held_out_lines(scores, res.problem.model.outputs):
        print(line)
    return scores


def _units(res, args) -> list[dict]:
    influence = unit_influence(res)
    for line in influence_lines(influence):
        print(line)
    return influence


def _analyses_json(extras: dict) -> dict:
    """fit.json's keys of the analyses: profiles as a single fit's (ci95_profile, ...),
    ``held_out`` and ``unit_influence``."""
    d = _profile_json(extras.get("profiles"))
    for key in ("held_out", "unit_influence"):
        if key in extras:
            d[key] = extras[key]
    return d


def _profile_figures(res, profiles: dict | None) -> list:
    """(stem, builder) of each profile's figure: −2 log L's rise against the value,
    beside the Wald parabola of its standard error on that scale."""
    if not profiles:
        return []
    known = names_of(res)
    out = []
    for name, p in profiles.items():
        i, log = known[name]
        se = float(np.sqrt(res.cov[i, i])) * (p.estimate if log else 1.0)
        out.append((f"profile_{name}", partial(_one_profile, p, se)))
    return out


def _one_profile(p, se, res):
    return profile_figure(p, 1.0, se)


def _analyses_lines(data: dict) -> list[str]:
    """report.md's sections of the profiles, held-out units and unit influence."""
    lines: list[str] = []
    if data.get("ci95_profile"):
        level = data["profile_level"]
        lines += [f"## Profile likelihood ({level:.0%})", "",
                  "| unknown | interval | not crossed |", "|---|---|---|"]  # fmt: skip
        for n, (lo, hi) in data["ci95_profile"].items():
            ends = ", ".join(f"{s}: {e}" for s, e in data["profile_ends"][n].items()
                             if e != "crossed")  # fmt: skip
            lines.append(f"| {n} | [{_g(lo)}, {_g(hi)}] | {ends or '–'} |")
        lines.append("")
    if data.get("held_out"):
        lines += ["## Held-out units", "", "Fit % of each new unit's individual prediction "
                  "(η̂ from its data) and of the population prediction (the typical unit).",
                  "", "| unit | IPRED % | PRED % |", "|---|---|---|"]  # fmt: skip
        for s in data["held_out"]:
            lines.append(f"| {s['id']} | {_percent(s['gof'])} | {_percent(s['gof_pred'])} |")
        lines.append("")
    if data.get("unit_influence"):
        lines += ["## Units that move the estimates most", "",
                  "| unit | Cook's D | moves most | by (SE) | how |",
                  "|---|---|---|---|---|"]  # fmt: skip
        for d in data["unit_influence"][:10]:
            n = d["largest"]
            how = "refit" if d["refitted"] else "Newton step"
            lines.append(f"| {d['id']} | {_g(d['cook'])} | {n} | {_g(d['shift'][n])} | {how} |")
        lines.append("")
    return lines


def _g(v) -> str:
    return "–" if v is None else f"{v:.4g}"


def _percent(v) -> str:
    if v is None:
        return "–"
    return ", ".join(f"{100 * x:.1f}" if x is not None else "–" for x in np.atleast_1d(v))


def report_population(res, out: Path, old: set[Path], recorded: dict, args=None,
                      held=None, renderer=None, kept: dict | None = None) -> int:  # fmt: skip
    """Print, then write by the one writer (keeping.write_folder); every failing write
    is named, none loses the estimates. ``args``: the command line (its --profile,
    --data-sensitivity); ``held``: the held-out units' Problem (--validate);
    ``renderer``: the command's (app/renderer.py), which draws the figures while this
    process writes; ``kept``: where fit.json went, once written (for a Ctrl-C)."""
    kept = {} if kept is None else kept
    print(res.summary())
    extras, notes, stopped = analyses(res, args, held)
    data = _finite(population_json(res, recorded) | _analyses_json(extras))
    data["notes"] = data["notes"] + notes
    tables = []
    if res.population and np.isfinite(res.objective):  # (as its figures: an Ω, a fit)
        tables.append(("observations.csv", partial(_table_csv, res)))
    failures: list[str] = []
    figures = partial(_figures, res, out, extras.get("profiles"), renderer, failures)
    _, lost = write_folder(out, old, data, kept, figures,
                           lambda made: population_report(res, data, made), tables)  # fmt: skip
    for f in [*notes, *failures, *lost]:
        print(f"tensorid: {f}")
    if kept.get("fit.json") != out / "fit.json":
        return 1
    print(f"results in {out}/")
    if stopped:
        return 130
    return 0 if res.success and not failures and not lost else 1


def _figures(res, out: Path, profiles, renderer, failures: list[str]) -> list[tuple]:
    """(stem, maker) of the fit's figures, in the report's order; each one's arrays
    computed here and handed to the ``renderer`` at once, so that it draws while the
    next are computed and the files are written (drawn here where there is none). One
    whose arrays fail is named in ``failures``: it is not worth the report."""
    makers: list[tuple] = []
    for stem, kind, build in figure_jobs(res):
        try:
            arguments = build(res)
        except Exception as e:
            failures.append(f"could not draw {stem}.png: {e}")
            continue
        if renderer is not None:
            renderer.submit(out, [(stem, kind, arguments)])
            makers.append((stem, partial(renderer.collect, stem)))
        else:
            makers.append((stem, drawn_here(out / f"{stem}.png", partial(draw, kind, arguments))))
    for stem, build in _profile_figures(res, profiles):
        makers.append((stem, drawn_here(out / f"{stem}.png", partial(build, res))))
    return makers


def _table_csv(res, path: Path) -> None:
    """observations.csv: one row per observation (population/diagnostics.py)."""
    tab = res.table()
    with open(path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(tab)
        for row in zip(*tab.values(), strict=True):
            w.writerow(_cell(v) for v in row)


def _cell(v) -> str:
    """A table cell: text as it is, a number to 10 digits, empty where not finite."""
    if isinstance(v, str):
        return v
    return f"{v:.10g}" if np.isfinite(v) else ""


def save_interrupted(res, out: Path, old: set[Path], recorded: dict, kept: dict | None = None,
                     after: bool = False) -> int:  # fmt: skip
    """Ctrl-C during a population fit (or, ``after``, while its statistics and files were
    made): the estimates to fit.json (status "interrupted" during the fit, no error
    bars) where a complete one is not written yet, no figures (the user is waiting);
    exit 130."""
    kept = {} if kept is None else kept
    if kept.get("fit.json"):
        _tidy(out, old, kept, [])
        print(f"tensorid: interrupted; {kept['fit.json']} was written", file=sys.stderr)
        return 130
    if not after:
        print(res.summary())
    where = _save_now(out, old, lambda: _finite(population_json(res, recorded)))
    what = "the estimates" if after else "the best point so far"
    print(f"tensorid: interrupted; {what} {'are' if after else 'is'} in {where}", file=sys.stderr)
    return 130
