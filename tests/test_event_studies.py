"""Event records fitted from NONMEM-style tables by the command line alone, beside R's
nlme on the same model and data (benchmarks/bench_events.py prints the tables of
docs/events.md; these tests hold the fit to nlme's numbers, as nlme printed them)."""

from __future__ import annotations

import json
import math
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

# Rscript benchmarks/peers/phenobarbital_nlme.R (nlme 3.1, method = "ML"): the log
# typical values with their standard errors, ω, σ and −2 log L
NLME = {"log_cl": (-5.093242, 0.080075), "log_v": (0.342534, 0.061600),
        "omega": (0.44021, 0.45044), "sigma": 2.79274, "m2ll": 1010.8315}  # fmt: skip


@pytest.mark.slow
def test_phenobarbital_from_its_nonmem_table_agrees_with_nlme(tmp_path):
    out = tmp_path / "fit"
    r = subprocess.run(
        [sys.executable, "-m", "tensorid", "fit", str(ROOT / "examples/phenobarbital/model.py"),
         str(ROOT / "src/tensorid/datasets/phenobarbital.csv"), "--records", "ID",
         "--columns", "t=TIME,conc=DV", "--no-progress", "--out", str(out)],
        capture_output=True, text=True, timeout=600,
    )  # fmt: skip
    assert r.returncode == 0, r.stderr[-3000:]
    fit = json.loads((out / "fit.json").read_text())
    assert fit["success"] and fit["observations"] == 155 and len(fit["units"]) == 59
    assert fit["cost"] == fit["objective"]
    for name in ("cl", "v"):
        value, se = NLME[f"log_{name}"]
        ours = math.log(fit["population"][name]["typical"])
        assert abs(ours - value) < 0.6 * se, (name, ours, value)
    for name, w in zip(("cl", "v"), NLME["omega"], strict=True):
        assert fit["population"][name]["omega"] == pytest.approx(w, rel=0.03)
    assert fit["residual_sd"]["conc"] == pytest.approx(NLME["sigma"], rel=0.01)
    # FOCEI's optimum of its own objective lies at or below nlme's approximation's
    assert NLME["m2ll"] - 1.0 < fit["objective"] < NLME["m2ll"]
    # docs/events.md shows this fit's numbers
    page = (ROOT / "docs/events.md").read_text()
    row = re.search(r"\| log cl \| ([-\d.]+) \|", page)
    assert row and float(row[1]) == pytest.approx(
        math.log(fit["population"]["cl"]["typical"]), abs=1e-4
    )
