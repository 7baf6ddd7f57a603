"""Figures, Markdown tables and JSON output shared by the study and fit reports."""

from __future__ import annotations

import io
import json
import math
from pathlib import Path

import numpy as np


def _plt():
    import matplotlib

    matplotlib.use("Agg")  # files only: works on machines with no display
    import matplotlib.pyplot as plt

    return plt


def compare_plot(
    path: Path,
    t: np.ndarray,
    y_meas: np.ndarray,
    y_sim: np.ndarray,
    *,
    title: str,
    ylabel: str = "y",
    xlabel: str = "t [s]",
    labels: tuple[str, str] = ("measured", "model"),
) -> Path:
    """Measured against simulated output, with the residual below (one output)."""
    plt = _plt()
    fig, (ax, axr) = plt.subplots(
        2, 1, figsize=(9, 5.5), sharex=True, gridspec_kw={"height_ratios": [3, 1]}
    )
    ax.plot(t, y_meas, color="0.2", lw=1.0, label=labels[0])
    ax.plot(t, y_sim, color="tab:red", lw=0.9, ls="--", label=labels[1])
    ax.set_ylabel(ylabel)
    ax.set_title(title, fontsize=10)
    ax.legend(loc="upper right", fontsize=8)
    ax.grid(alpha=0.3)
    axr.plot(t, y_meas - y_sim, color="tab:blue", lw=0.8)
    axr.set_ylabel("residual")
    axr.set_xlabel(xlabel)
    axr.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


def bar_plot(
    path: Path, groups: list[str], series: dict[str, list[float]], *, title: str, ylabel: str
) -> Path:
    plt = _plt()
    fig, ax = plt.subplots(figsize=(9, 4))
    width = 0.8 / max(len(series), 1)
    x = np.arange(len(groups))
    for i, (name, vals) in enumerate(series.items()):
        ax.bar(x + (i - (len(series) - 1) / 2) * width, vals, width, label=name)
    ax.set_xticks(x, groups, fontsize=8)
    ax.set_ylabel(ylabel)
    ax.set_title(title, fontsize=10)
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3, axis="y")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


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


def write_json(path: Path, data) -> Path:
    path.write_text(json.dumps(_jsonable(data), indent=2) + "\n")
    return path


# -- reports of a fit -------------------------------------------------------------------
def _squeeze_name(s: str) -> str:
    return "".join(c if c.isalnum() or c in "-_" else "_" for c in s)


def summary_table(res) -> str:
    """The estimates of a FitResult as a plain-text table."""
    from rich.console import Console
    from rich.table import Table

    u = res.uncertainty() if np.isfinite(res.cost) else None
    tab = Table(
        title=f"{res.problem.model.name}: {res.method}, "
        f"{'converged' if res.success else 'NOT converged'} in {res.nit} "
        f"iterations, cost {res.cost:.6g}"
    )
    for col in ("unknown", "estimate", "std. error", "95 % interval"):
        tab.add_column(col, justify="right" if col != "unknown" else "left")
    for k, name in enumerate(res.problem.theta_names):
        se = u.stderr[k] if u else np.nan
        ci = f"[{u.ci95[k, 0]:.6g}, {u.ci95[k, 1]:.6g}]" if u else "–"
        tab.add_row(name, f"{res.theta[k]:.6g}", f"{se:.3g}", ci)
    console = Console(width=100, record=True, file=io.StringIO())
    console.print(tab)
    for w in res.warnings:
        console.print(f"warning: {w}")
    return console.export_text()


def _convergence_plot(path: Path, history: list[dict], title: str) -> Path:
    plt = _plt()
    it = [h["iteration"] for h in history]
    fig, (a1, a2) = plt.subplots(1, 2, figsize=(9, 3.5))
    a1.semilogy(it, [h["cost"] for h in history], "o-", ms=3)
    a1.set_xlabel("iteration")
    a1.set_ylabel("cost J")
    a2.semilogy(it, [max(h["grad_norm"], 1e-300) for h in history], "o-", ms=3, color="tab:orange")
    a2.set_xlabel("iteration")
    a2.set_ylabel("gradient norm (scaled)")
    for a in (a1, a2):
        a.grid(alpha=0.3)
    fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


def fit_figures(res, out=None, validation=None) -> list[Path]:
    """Measured against simulated per experiment and output, residuals, and the
    convergence history; written to the folder ``out`` (default: current folder)."""
    out = Path(out or ".")
    out.mkdir(parents=True, exist_ok=True)
    from .metrics import gof

    files = []
    sets = [("train", e, s) for e, s in zip(res.problem.experiments, res.simulate(), strict=True)]
    for e, s in validation or []:
        sets.append(("validation", e, s))
    model = res.problem.model
    for kind, e, s in sets:
        for j, name in enumerate(model.outputs):
            g = gof(e.y[:, j], s.y[:, j])
            files.append(
                compare_plot(
                    out / f"{kind}_{_squeeze_name(e.name or 'data')}_{_squeeze_name(name)}.png",
                    e.t,
                    e.y[:, j],
                    s.y[:, j],
                    ylabel=name,
                    title=f"{kind}: {e.name or 'data'}, output {name}: GOF {g:.4f}",
                )
            )
    if res.history:
        files.append(
            _convergence_plot(
                out / "convergence.png",
                res.history,
                f"{res.method}: cost and gradient norm per iteration",
            )
        )
    return files
