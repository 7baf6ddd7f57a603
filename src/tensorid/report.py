"""Figures, Markdown tables and JSON output shared by the study and fit reports."""

from __future__ import annotations

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
