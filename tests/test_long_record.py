"""The whole 131,072-sample Silverbox record: (J, g, H) in one sweep whose memory
does not grow with the record length."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

SCRIPT = """
import json, resource
import numpy as np
from tensorid import benchmarks, datasets

def peak_mb():
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024

out = {}
for n in (8192, 131072):
    prob = benchmarks.silverbox_problem(offset=True, data=datasets.silverbox_snls80mV(stop=n))
    J, g, H = prob.cost_grad_hess(prob.theta0)
    out[n] = dict(J=J, finite=bool(np.isfinite(g).all() and np.isfinite(H).all()),
                  sym=float(np.abs(H - H.T).max() / np.abs(H).max()), peak=peak_mb())
print(json.dumps(out))
"""


@pytest.mark.slow
def test_whole_record_sweep_memory_does_not_grow_with_its_length():
    r = subprocess.run([sys.executable, "-c", SCRIPT], capture_output=True, text=True, check=True)
    out = json.loads(r.stdout.strip().splitlines()[-1])
    small, full = out["8192"], out["131072"]
    for o in (small, full):
        assert np.isfinite(o["J"]) and o["J"] > 0 and o["finite"] and o["sym"] < 1e-12
    assert full["J"] > 10 * small["J"]  # it did see the whole record
    # 16x the samples; one P x N x K x K array alone would add 98 MB, jax.hessian ~900 MB
    assert full["peak"] - small["peak"] < 50, out
