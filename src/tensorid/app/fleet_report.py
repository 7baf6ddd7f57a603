"""fit.json and report.md of a fleet fit (issue 42): the population estimates, the
residual standard deviation of each output and each unit's own estimates, read from
the result's ``population``, ``residual_sd`` and ``units`` where it has them. A
result without them (every fit of one shared parameter set) adds nothing.

fit.json keys (a contract, added to, never renamed):

- ``population``: {parameter: {"typical", "typical_stderr", "omega", "omega_stderr",
  "cv_percent", "shrinkage_percent"}}; the typical value and its standard error in
  the parameter's units, ω the standard deviation of η (the log of the unit's value
  over the typical one);
- ``residual_sd``: {output: standard deviation of the measurement noise} (its
  additive part; 0 where the output's error has none: proportional, exponential);
- ``residual_error``: {output: {"model": "additive" | "proportional" | "combined" |
  "exponential", and each term the model has with its SD and ``<term>_stderr``:
  "additive", "proportional", "exponential"}} (a population fit's; the models'
  formulas in tensorid/population/errors.py: σ² = additive² + (proportional ·
  prediction)², log y = log prediction + ε with SD(ε) = exponential);
- ``omega_correlation``: {"a,b": {"value", "stderr"}}: the correlation of η_a and η_b
  where Ω is full (``omega = "full"``);
- ``units``: [{"id", "params": {name: value}, "stderr": {name: value}}], in the order
  of the records.
"""

from __future__ import annotations

import math

POPULATION_KEYS = (
    "typical",
    "typical_stderr",
    "omega",
    "omega_stderr",
    "cv_percent",
    "shrinkage_percent",
)
UNITS_SHOWN = 20  # rows of report.md's units table; fit.json holds every unit


def _number(value) -> float | None:
    """A number as a float (None where absent or not finite: JSON's null)."""
    try:
        x = float(value)
    except (TypeError, ValueError):
        return None
    return x if math.isfinite(x) else None


def _numbers(values) -> dict:
    return {str(k): _number(v) for k, v in dict(values or {}).items()}


def fleet_json(res) -> dict:
    """``population``, ``residual_sd`` and ``units`` for fit.json, those the result
    has (getattr: an ordinary FitResult has none, and gets nothing)."""
    out: dict = {}
    population = getattr(res, "population", None)
    if population is not None:
        out["population"] = {
            str(name): {k: _number(dict(entry).get(k)) for k in POPULATION_KEYS}
            for name, entry in dict(population).items()
        }
    residual_sd = getattr(res, "residual_sd", None)
    if residual_sd is not None:
        out["residual_sd"] = _numbers(residual_sd)
    errors = getattr(res, "residual_error", None)
    if errors:
        out["residual_error"] = {
            str(o): {k: (v if k == "model" else _number(v)) for k, v in dict(e).items()}
            for o, e in dict(errors).items()
        }
    correlation = getattr(res, "omega_correlation", None)
    if correlation:
        out["omega_correlation"] = {str(k): _numbers(v) for k, v in dict(correlation).items()}
    units = getattr(res, "units", None)
    if units is not None:
        out["units"] = [
            {
                "id": str(u["id"]),
                "params": _numbers(u.get("params")),
                "stderr": _numbers(u.get("stderr")),
            }
            for u in units
        ]
    return out


def _text(x: float | None, digits: int = 4) -> str:
    return "–" if x is None else f"{x:.{digits}g}"


def _pm(value: float | None, se: float | None) -> str:
    """ "1.53 ± 0.21", or the value alone where it has no standard error."""
    if value is None:
        return "–"
    return _text(value, 5) + ("" if se is None else f" ± {se:.2g}")


def _row(cells: list[str]) -> str:
    return "| " + " | ".join(cells) + " |"


def _population_lines(data: dict) -> list[str]:
    pop = data.get("population")
    if not pop:
        return []
    lines = [
        "## Population",
        "",
        "Each unit's value is the typical value times exp(η), η ~ N(0, ω²) over the "
        "units; CV % is the spread of the units' values relative to the typical one; the "
        "shrinkage of η is large where the data say little of the units' own values.",
        "",
        _row(["parameter", "typical ± std. error", "ω ± std. error", "CV %", "shrinkage %"]),
        "|---|---|---|---|---|",
    ]
    for name, e in pop.items():
        cells = [
            _pm(e["typical"], e["typical_stderr"]),
            _pm(e["omega"], e["omega_stderr"]),
            _text(e["cv_percent"], 3),
            _text(e["shrinkage_percent"], 3),
        ]
        lines.append(_row([name, *cells]))
    return [*lines, ""]


def _units_lines(data: dict) -> list[str]:
    units = data.get("units")
    if not units:
        return []
    names = list(dict.fromkeys(n for u in units for n in u["params"]))
    shown = units[:UNITS_SHOWN]
    lines = [
        f"## Units ({len(units)})",
        "",
        "Each unit's own estimates (empirical Bayes for population parameters) with their "
        "standard errors.",
        "",
        _row(["unit", *names]),
        "|" + "---|" * (len(names) + 1),
    ]
    for u in shown:
        cells = [_pm(u["params"].get(n), u["stderr"].get(n)) for n in names]
        lines.append(_row([u["id"], *cells]))
    more = len(units) - len(shown)
    if more > 0:
        lines += ["", f"and {more} more unit{'s' if more > 1 else ''} in fit.json (`units`)."]
    return [*lines, ""]


def fleet_lines(data: dict) -> list[str]:
    """report.md's population table, residual standard deviations and units table,
    from fit.json's entries (none: no lines)."""
    lines = _population_lines(data)
    correlation = data.get("omega_correlation") or {}
    if correlation:
        text = ", ".join(
            f"η_{k.replace(',', ' and η_')} {_pm(v.get('value'), v.get('stderr'))}"
            for k, v in correlation.items()
        )
        lines += [f"Correlations of the random effects (Ω full): {text}.", ""]
    sd, errors = data.get("residual_sd"), data.get("residual_error")
    if errors and any(e.get("model") != "additive" for e in errors.values()):
        from ..population.errors import ERROR_MODELS, TERMS

        models = {e.get("model") for e in errors.values()}
        known = [ERROR_MODELS[k] for k in ERROR_MODELS if k in models]
        text = "; ".join(
            f"{o} ({e['model']}): "
            + ", ".join(f"{w} {_pm(e.get(w), e.get(w + '_stderr'))}" for w in TERMS if w in e)
            for o, e in errors.items()
        )
        formulas = "; ".join(m.formula for m in known if m.name != "additive") or "σ"
        lines += [f"Residual error ({formulas}): {text}.", ""]
    elif sd:
        text = ", ".join(f"{o} {_text(v)}" for o, v in sd.items())
        lines += [f"Residual standard deviation (additive, per output): {text}.", ""]
    return lines + _units_lines(data)
