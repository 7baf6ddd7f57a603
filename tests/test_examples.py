"""Every example script runs and prints what it promises."""

import subprocess
import sys
from pathlib import Path

import pytest

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"


@pytest.mark.parametrize(
    "script,expect",
    [
        pytest.param("silverbox_paper.py", "validation GOF 0.98", marks=pytest.mark.slow),
        ("two_tank.py", "GOF 0.789"),
        ("text_equations.py", "95 % interval"),
        pytest.param("design_two_tank.py", "| p3 | 0.022018 |", marks=pytest.mark.slow),
    ],
)
def test_example_runs(script, expect):
    out = subprocess.run(
        [sys.executable, str(EXAMPLES / script)], capture_output=True, text=True, timeout=300
    )
    assert out.returncode == 0, out.stderr[-2000:]
    assert expect in out.stdout, out.stdout[-2000:]
