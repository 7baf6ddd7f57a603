"""The statistics' own quantiles against scipy.special's, and the imports a fit
command no longer pays for (scipy.special and scipy.linalg: 0.1-0.15 s each)."""

from __future__ import annotations

import math
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from scipy import special

from tensorid.analysis import quantiles

ROOT = Path(__file__).resolve().parents[1]
EXAMPLE = ROOT / "examples" / "silverbox"

DOFS = [1, 2, 3, 4.5, 7, 10, 24, 33, 59, 60, 61, 100, 1017, 5000, 1e5, 1e6]
LEVELS = [1e-17, 1e-6, 0.005, 0.025, 0.05, 0.3, 0.5, 0.7, 0.9, 0.95, 0.975, 0.99, 0.995]


@pytest.mark.parametrize(
    "ours, theirs, dofs, levels",
    [
        (quantiles.chi2, lambda dof, p: 2 * special.gammaincinv(dof / 2, p), DOFS, LEVELS),
        (lambda dof, p: quantiles.chi2(dof, 1 - p), special.chdtri, DOFS, LEVELS[2:]),
        (quantiles.student_t, special.stdtrit, DOFS + [1e7, 1e9], LEVELS),
        (quantiles.f1, lambda dof, p: special.fdtri(1, dof, p), DOFS, LEVELS[2:]),
    ],
    ids=["chi2", "chi2 upper", "student t", "F(1, dof)"],
)
def test_quantiles_agree_with_scipy(ours, theirs, dofs, levels):
    # the large degrees of freedom are where log-gamma differences lose digits, and
    # the far tails where 1 − p would
    off = [
        (dof, p, ours(dof, p), theirs(dof, p))
        for dof in dofs
        for p in levels
        if not math.isclose(ours(dof, p), theirs(dof, p), rel_tol=1e-10, abs_tol=1e-300)
    ]
    assert not off


def test_normal_quantile_and_symmetry():
    for p in LEVELS[1:]:
        assert quantiles.normal(p) == pytest.approx(special.ndtri(p), rel=1e-13)
        assert quantiles.student_t(7, p) == pytest.approx(-quantiles.student_t(7, 1 - p))
    assert quantiles.student_t(3, 0.5) == 0.0


@pytest.mark.parametrize(
    "dof, p", [(0, 0.5), (-1, 0.5), (3, 0.0), (3, 1.0), (np.nan, 0.5), (np.inf, 0.5)]
)
def test_quantiles_refuse_what_has_none(dof, p):
    with pytest.raises(ValueError, match="0 < dof <= 1e12 and 0 < p < 1"):
        quantiles.chi2(dof, p)
    with pytest.raises(ValueError, match="0 < dof <= 1e12 and 0 < p < 1"):
        quantiles.student_t(dof, p)


def test_a_quantile_that_does_not_settle_is_an_error_not_a_number():
    with pytest.raises(ValueError, match="did not settle"):
        quantiles.chi2(1, 1e-100)  # about 1.6e-200


def test_a_fit_command_imports_neither_scipy_special_nor_linalg(tmp_path):
    """The README's fit, with its error bars and residual tests, in a fresh process:
    JAX's LAPACK kernels are handed over without scipy.linalg, and the quantiles
    need no scipy.special (nor scipy.stats or scipy.optimize)."""
    script = (
        "import sys\n"
        "from tensorid.cli import main\n"
        f"code = main(['fit', {str(EXAMPLE / 'model.py')!r}, {str(EXAMPLE / 'train.csv')!r},"
        f" '--validate', {str(EXAMPLE / 'validate.csv')!r}, '--no-progress',"
        f" '--out', {str(tmp_path / 'out')!r}])\n"
        "heavy = ['scipy.special', 'scipy.linalg', 'scipy.stats', 'scipy.optimize']\n"
        "print(code, [m for m in heavy if m in sys.modules])\n"
    )
    # with the program store on (the tests' default is off): only reading a kept
    # program made JAX initialise LAPACK, which imported scipy.linalg
    env = dict(os.environ, TENSORID_PROGRAMS="1", TENSORID_CACHE_DIR=str(tmp_path / "jax"))
    r = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, env=env)
    assert r.returncode == 0, r.stderr
    assert r.stdout.strip().splitlines()[-1] == "0 []"
    assert "±" in r.stdout  # the error bars and the residual tests were made
    assert (tmp_path / "out" / "residual_tests.png").exists()
