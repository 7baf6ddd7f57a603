"""What a fit or a study writes: Markdown tables, JSON, fit.json and report.md, and
the study's bar plots. Reports read results; results know nothing of reports."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from ..analysis.display import coloured_residuals_line
from ..analysis.figures import new_figure, save_png
from ..analysis.summary import (
    criteria_text,
    headline,
    interval,
    interval_note,
    interval_text,
    metric_notes,
    metric_rows,
    noise_intensities,
    noise_text,
    plural,
    score_notes,
    significant,
    stderr_text,
)
from ..analysis.validation import Score, training_scores
from ..engine.modelling.checks import step
from ..solve.starts import fit_counts
from .fleet_report import fleet_json, fleet_lines
from .output import write_text
from .provenance import markdown as provenance_lines


def md_table(header: list[str], rows: list[list]) -> str:
    def fmt(v):
        if isinstance(v, float):
            if math.isnan(v):
                return "–"
            return f"{v:.6g}"
        return str(v)

    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(fmt(v) for v in row) + " |" for row in rows]
    return "\n".join(lines)


def _jsonable(obj):
    if isinstance(obj, dict):
        return {str(k): _jsonable(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [_jsonable(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return _jsonable(obj.tolist())
    if isinstance(obj, np.generic):
        obj = obj.item()
    if isinstance(obj, float) and not math.isfinite(obj):
        return None  # JSON has no inf/NaN; null says "not available"
    return obj


def json_text(data) -> str:
    """JSON (inf and NaN as null)."""
    return json.dumps(_jsonable(data), indent=2) + "\n"


def write_json(path: Path, data) -> Path:
    """JSON (inf and NaN as null), written atomically."""
    return write_text(path, json_text(data))


def bar_plot(
    path: Path, groups: list[str], series: dict[str, list[float]], *, title: str, ylabel: str
) -> Path:
    fig = new_figure(figsize=(9, 4))
    ax = fig.subplots()
    width = 0.8 / max(len(series), 1)
    x = np.arange(len(groups))
    for i, (name, vals) in enumerate(series.items()):
        ax.bar(x + (i - (len(series) - 1) / 2) * width, vals, width, label=name)
    ax.set_xticks(x, groups, fontsize=8)
    ax.set_ylabel(ylabel)
    ax.set_title(title, fontsize=10)
    # beside the axes, not over them: inside, it covered the bars of the first groups
    ax.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0)
    ax.grid(alpha=0.3, axis="y")
    fig.tight_layout()
    return save_png(fig, path)


# -- a fit ------------------------------------------------------------------------------
def _metrics(scores: list[Score], metric: str) -> dict:
    """{record: {output: value}}, keyed as fit.json always has been (record name or
    its index)."""
    return {s.experiment.name or str(i): getattr(s, metric) for i, s in enumerate(scores)}


def _validation_x0(validation) -> dict:
    """Each validation record's initial state, and how its fit ended (null: none
    fitted)."""
    names = [s.experiment.name or str(i) for i, s in enumerate(validation)]
    return {
        "validation_x0": {n: s.x0.tolist() for n, s in zip(names, validation, strict=True)},
        "validation_x0_status": {n: s.x0_fit for n, s in zip(names, validation, strict=True)},
    }


def _profile_json(profiles: dict | None) -> dict:
    if not profiles:
        return {}
    return {
        "ci95_profile": {n: list(p.interval) for n, p in profiles.items()},
        "profile_ends": {n: dict(p.ends) for n, p in profiles.items()},
        # how each profile's re-optimisations ended: {status: count}
        "profile_corrections": {n: dict(p.corrections) for n, p in profiles.items()},
        "profile_level": next(iter(profiles.values())).level,
    }


def _error_bars(res, u, names: list[str], residual) -> dict:
    """fit.json's error bars: the exact Hessian's, the Gauss-Newton form's, the
    Newey-West form's where the residuals are not white or the loss is robust (null
    where they passed whiteness: it would only repeat stderr), and the information."""
    d = u.as_dicts()
    gn = res.uncertainty("gauss-newton").stderr.tolist()
    d["stderr_gauss_newton"] = dict(zip(names, gn, strict=True))
    coloured = residual is not None and residual.not_shown_white
    loss = res.problem.loss
    wanted = coloured or loss.robust
    robust = res.uncertainty("robust") if wanted else None
    d["stderr_robust"] = dict(zip(names, robust.stderr.tolist(), strict=True)) if robust else None
    d["robust_lags"] = robust.lags if robust else None
    d["information"] = res.information().as_dict()
    return d


def fit_json(
    res,
    validation: list[Score],
    profiles: dict | None = None,
    influence=None,
    residual=None,
    missing: str | None = None,
) -> dict:
    """Everything fit.json holds (a contract: keys are added, never renamed). With
    ``missing`` (why: an interrupt after the fit), only what needs no further
    computation: no error bars, metrics or criteria, and ``statistics_missing`` says why."""
    u = res.uncertainty() if res.has_uncertainty and not missing else None
    names = res.problem.theta_names
    train = [] if missing else training_scores(res)
    d = {
        "params": res.params,
        "free": names,
        "free_x0": list(res.problem.free_x0),
        "estimates": dict(zip(names, res.theta.tolist(), strict=True)),
        "x0": np.asarray(res.x0).tolist(),
        "cost": res.cost,
        "success": res.success,
        "status": str(res.status),
        "message": res.message,
        **fit_counts(res),  # iterations, function_evaluations and their totals over starts
        "hessian_vector_products": res.nhev,
        "method": res.method,
        "integration": res.problem.discretisation.as_dict(),
        "hessian_path": res.problem.hessian,
        "loss": res.problem.loss.name,
        "predictor": res.problem.predictor.name,
        "noise_intensities": noise_intensities(res, u),
        "loss_scale": res.problem.loss_scale,
        "weights": dict(zip(res.problem.model.outputs, res.problem.weights.tolist(), strict=True)),
        "priors": {names[i]: list(ms) for i, ms in res.problem.priors.items()},
        "prior_noise_variance": res.problem.noise_variance if res.problem.priors else None,
        "prior_noise_check": res.noise_check.as_dict() if res.noise_check else None,
        "prior_moves": None if missing else res.prior_moves(),  # (a computation)
        # each constraint: expr, c (kept >= 0), value, active, multiplier (λ >= 0, ∇J = Σ λ∇c)
        "constraints": res.constraints.items if res.constraints else [],
        "constraints_fit": _constraints_fit(res),
        "seconds": res.seconds,
        "compile_seconds": res.compile_seconds,
        "segments": res.problem.segments,
        "shooting": res.shooting,
        "hybrid": res.hybrid,
        "warnings": res.convergence_warnings if missing else res.warnings,
        "notes": res.notes,
        "residual_variance": u.sigma2 if u else None,
        "correlation_names": names,
        "history": res.history,
        "starts": res.starts,
        "sample_time": step(res.problem.experiments[0]),  # a discrete-time model's step
        "init_window": validation[0].init_window if validation else None,
        "horizon": validation[0].horizon if validation else None,
        **_validation_x0(validation),
    }
    for metric in ("gof", "rmse", "nrmse"):
        d[metric] = {"train": _metrics(train, metric), "validation": _metrics(validation, metric)}
    # why a gof is null where no simulation blew up: an output constant in its record
    d["gof_notes"] = [n.removeprefix("note: ") for n in metric_notes(train + list(validation))]
    if u:
        d.update(_error_bars(res, u, names, residual))
    d.update(_profile_json(profiles) | fleet_json(res))  # fleet_json: issue 42's keys
    if missing:
        d["statistics_missing"] = missing
    elif np.isfinite(res.cost):
        c = res.criteria()
        d.update({k: v for k, v in c.items() if k in ("aic", "aicc", "bic")})
        d["criteria_not_available"] = c["not_available"]
    d.update(_verdicts(res, residual))
    if influence is not None:
        d["influential_samples"] = {
            n: [list(row) for row in influence.most_influential(n, 10)] for n in influence.names
        }
    return d


def _verdicts(res, residual) -> dict:
    """The residual tests and the model-error check (made after the fit where the
    residuals are not white; null otherwise)."""
    check = res.cached_model_check()
    d = {"model_check": check.as_dict() if check is not None else None,
         # (fit.json's "seconds" is the fit's own; the check's fits come after it)
         "model_check_seconds": check.seconds if check is not None else None}  # fmt: skip
    return d | ({"residual_tests": residual.as_dict()} if residual is not None else {})


def _profile_lines(profiles: dict | None, data: dict) -> list[str]:
    if not profiles:
        return []
    level = next(iter(profiles.values())).level
    rows = []
    for n, p in profiles.items():
        wald = data.get("ci95", {}).get(n)
        ends = ", ".join(f"{s}: {e}" for s, e in p.ends.items() if e != "crossed")
        rows.append([n, interval(*wald) if wald else "–", interval(*p.interval), ends or "–"])
    return [
        "",
        f"## Profile likelihood ({level:.0%})",
        "",
        "Likelihood-ratio intervals from the profile of each unknown (the others "
        "re-optimised), beside the Wald intervals from the standard errors.",
        "",
        md_table(["unknown", "Wald 95 %", f"profile {level:.0%}", "not crossed"], rows),
        *(
            f"\n{p.name}: {note.removeprefix('note: ')}"
            for p in profiles.values()
            for note in p.notes
        ),
    ]


def _constraints_fit(res) -> dict | None:
    """fit.json's constraints_fit: converged, outer_iterations, restricted_stderr,
    second_order (None without constraints)."""
    if not res.constraints:
        return None
    out = res.constraints.as_dict()
    del out["constraints"]
    return out


def _constraint_lines(res) -> list[str]:
    """report.md's constraints: each one's value, activity and multiplier, and what
    the error bars mean beside them."""
    if not res.constraints:
        return []
    rep = res.constraints
    rows = [[f"`{d['expr']}`", f"{d['value']:.6g}", "yes" if d["active"] else "no",
             f"{d['multiplier']:.6g}"] for d in rep.items]  # fmt: skip
    header = ["constraint", "value of c (>= 0)", "active", "multiplier λ"]
    return [
        "## Constraints",
        "",
        f"Kept by an augmented Lagrangian ({plural(rep.outer, 'outer iteration')}); "
        "λ >= 0 with ∇J = Σ λ ∇c at the solution: the rise of the optimal cost per unit "
        "the margin c >= 0 is tightened, 0 for a constraint that does not bind.",
        "",
        md_table(header, rows),
        "",
        *[part for line in rep.lines() for part in (f"{line[0].upper()}{line[1:]}.", "")],
    ]


def _prior_lines(res) -> list[str]:
    """report.md's priors: each with where the data alone put its unknown and how far
    the prior moved it, and the noise level that weighed them."""
    moves = res.prior_moves()
    if not moves:
        return []
    priors = {res.problem.theta_names[i]: ms for i, ms in res.problem.priors.items()}
    rows = []
    for m in moves:
        se, n = m["data_stderr"], m["standard_errors"]
        mean, sd = priors.get(m["unknown"], (math.nan, math.nan))
        rows.append(
            [
                m["unknown"],
                f"{mean:.6g} ± {sd:.2g}" if m["prior"] else "–",
                significant(m["estimate"], se),
                "–" if m["data_only"] is None else significant(m["data_only"], se),
                stderr_text(se),
                "–" if n is None else f"{n:.2f}" + (" (moved)" if m["moved"] else ""),
            ]
        )
    header = [
        "unknown",
        "prior",
        "estimate",
        "data alone",
        "its std. error",
        "moved by (std. errors)",
    ]
    nc, weighed = res.noise_check, f"σ² = {res.problem.noise_variance:.3g}"
    if nc is not None and nc.source == "given":
        weighed += f" (given as noise=; residual variance at the fit {nc.residual:.3g})"
    elif nc is not None:
        weighed += (
            f" (from the outputs' second differences, {nc.first:.3g}, re-estimated from the "
            f"residuals in {plural(nc.refits, 'refit')}; residual variance at the fit "
            f"{nc.residual:.3g})"
        )
    return [
        "## Priors",
        "",
        (
            "The priors are weighed as they are: the cost is −2 log L, to which each adds "
            "((θ − mean)/sd)²."
            if res.problem.loss.likelihood
            else f"The priors are weighed by the noise variance {weighed}."
        )
        + " 'Data alone' is where the data without the priors put each unknown, with its "
        "standard error from the data alone.",
        "",
        md_table(header, rows),
        "",
    ]


def fit_report(
    res,
    data: dict,
    scores: list[Score],
    figures: list[Path],
    profiles: dict | None = None,
    residual=None,
) -> str:
    """report.md of a fit."""
    u = res.uncertainty() if res.has_uncertainty else None
    rows = []
    for n in res.problem.theta_names:
        se = data.get("stderr", {}).get(n, math.nan)
        ci = data.get("ci95", {}).get(n)
        ci_text = interval_text(u, n, ci) if ci else "–"
        note = interval_note(u, n) if u else ""
        rows.append([n, significant(data["estimates"][n], se), stderr_text(se), ci_text, note])
    prov = data.get("provenance")
    title = f"`{prov['model']['path']}`" if prov else res.problem.model.name
    lines = [
        f"# Fit of {title}",
        "",
        headline(res) + f"; {res.seconds:.2f} s.",
        "",
        md_table(["unknown", "estimate", "std. error", "95 % interval", "note"], rows),
        "",
        *fleet_lines(data),  # a fleet's population and units tables (issue 42)
    ]
    if data.get("noise_intensities"):
        lines += ["## Noise model", "", f"Predictor: {data['predictor']} (prediction error). "
                  + noise_text(data["noise_intensities"], res.problem.model.discrete) + ".",
                  ""]  # fmt: skip
    if data["warnings"]:
        lines += ["## Warnings", ""] + [f"- {w}" for w in data["warnings"]] + [""]
    if data["notes"] and res.success:
        lines += ["## Notes", ""] + [f"- {n}" for n in data["notes"]] + [""]
    lines += _constraint_lines(res)
    lines += _prior_lines(res)
    if "information" in data:
        lines += ["## Observed and expected information", "", data["information"]["text"] + ".", ""]
    header, metric_table = metric_rows(scores)
    lines += ["## Goodness of fit", "", md_table(header, metric_table)]
    lines += [f"\n{n.removeprefix('note: ')}" for n in score_notes(scores)]
    if res.starts:
        lines += [
            "",
            f"## {len(res.starts)} starts, best first",
            "",
            md_table(
                ["start", "cost", "status", "iterations"],
                [[s["start"], s["cost"], s.get("status", ""), s["nit"]] for s in res.starts[:20]],
            ),
        ]
    if residual is not None:
        lines += [
            "",
            f"## Residual analysis ({residual.level:.0%}, lags up to {residual.max_lag})",
            "",
        ]
        lines += [f"- {line}" for line in residual.lines()]
        check = res.cached_model_check()
        if check is not None:
            lines += ["", f"Model-error check ({check.how}): {check.line()}."]
        if res.has_uncertainty and residual.not_shown_white:
            lines += ["", coloured_residuals_line(res, residual, check) + "."]
    if "aic" in data:
        lines += ["", criteria_text(data) + "."]
    lines += _profile_lines(profiles, data)
    lines += ["", "## Figures", ""] + [f"![{f.stem}]({f.name})" for f in figures]
    if data.get("overrides"):
        lines += ["", "Overridden on the command line: " + json.dumps(data["overrides"]) + "."]
    lines += [""] + provenance_lines(prov) if prov else []
    return "\n".join(lines) + "\n"
