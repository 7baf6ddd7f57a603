"""``import tensorid`` asks XLA to compile each small loop (a sweep over a record) as
one function, leaves a user's own XLA settings alone, and gives its process-pool
workers one thread each on top of whatever the parent set."""

from __future__ import annotations

import json
import os
import subprocess
import sys

from tensorid import _config
from tensorid._config import SMALL_LOOP_BYTES, add_xla_flags

_OPTION = "xla_cpu_small_while_loop_byte_threshold"

# what a fresh process sees: its XLA_FLAGS, and whether the simulation's loop over the
# record was compiled as one function (XLA then calls it from the program's entry,
# where otherwise the loop itself stands)
_PROBE = """
import json, os, sys
pre = sys.argv[1] == "jax-first"
if pre:
    import jax.numpy as jnp
    jnp.ones(1).block_until_ready()  # JAX started before tensorid: too late to change
import jax, tensorid  # noqa: F401 (its import sets the flags)
from tensorid.paper.problems import silverbox_problem
prob = silverbox_problem()  # the paper's record: 1024 samples, 2 states
sw, (t, u, y) = prob._sweeps, prob._arrays[0]
x0, p = jax.numpy.asarray(prob.x0[0]), jax.numpy.asarray(prob.p0)
hlo = jax.jit(sw._simulate).lower(x0, p, t, u).compile()
entry = hlo.as_text().split("ENTRY", 1)[1].split(chr(10) + "}", 1)[0]
# a product and a sum, which XLA hands to YNNPACK where its fusions are on
dot = jax.jit(lambda a: jax.numpy.sum(jax.numpy.tanh(a @ a), axis=0))
library = "__ynn_fusion" in dot.lower(jax.numpy.ones((64, 64))).compile().as_text()
print(json.dumps({"flags": os.environ.get("XLA_FLAGS", ""), "ynn": library,
                  "one_function": " while(" not in entry and "xla_cpu_small_call" in entry}))
"""


def _probe(order: str, flags: str | None) -> dict:
    env = {k: v for k, v in os.environ.items() if k != "XLA_FLAGS"}
    env["JAX_PLATFORMS"] = "cpu"  # the option and the probe are XLA's CPU compiler's
    if flags is not None:
        env["XLA_FLAGS"] = flags
    out = subprocess.run(
        [sys.executable, "-c", _PROBE, order], env=env, capture_output=True, text=True
    )
    assert out.returncode == 0, out.stderr[-2000:]
    return json.loads(out.stdout.strip().splitlines()[-1])


def test_a_sweep_over_a_record_compiles_as_one_function():
    got = _probe("tensorid-first", None)
    assert f"{_OPTION}={SMALL_LOOP_BYTES}" in got["flags"]
    emitters = "--xla_cpu_use_fusion_emitters=false" in got["flags"]  # compiles sooner
    low, high = _config.EMITTERS_FLAG_VERSIONS
    assert emitters == (low <= _config._jaxlib_version() < high)
    assert got["one_function"]
    low, high = _config.YNN_FLAG_VERSIONS
    if low <= _config._jaxlib_version() < high:  # no library fusions in what it compiles
        assert f"--{_config.YNN_FLAG}=" in got["flags"] and not got["ynn"]


def test_the_users_own_library_fusions_are_kept():
    low, high = _config.YNN_FLAG_VERSIONS
    if not low <= _config._jaxlib_version() < high:
        return
    mine = f"--{_config.YNN_FLAG}=dot,reduce"  # the user's choice: YNNPACK's products
    got = _probe("tensorid-first", mine)
    assert got["flags"].startswith(mine) and got["flags"].count(_config.YNN_FLAG) == 1


def test_the_users_own_xla_options_win():
    # the user's threshold (XLA's default) is kept: the same loop runs op by op
    mine = f"--xla_backend_extra_options={_OPTION}=1024 --xla_cpu_use_fusion_emitters=true"
    got = _probe("tensorid-first", mine)
    assert got["flags"].startswith(mine) and got["flags"].count(_OPTION) == 1
    assert "fusion_emitters=false" not in got["flags"]
    assert not got["one_function"]


def test_after_jax_has_started_nothing_changes_in_this_process():
    got = _probe("jax-first", None)
    assert not got["one_function"]  # XLA read its flags when JAX started


def test_flags_are_added_only_where_not_named(monkeypatch):
    monkeypatch.setenv("XLA_FLAGS", "--xla_cpu_multi_thread_eigen=true --other=1")
    add_xla_flags("--xla_cpu_multi_thread_eigen=false", "--xla_new=2")
    assert os.environ["XLA_FLAGS"] == "--xla_cpu_multi_thread_eigen=true --other=1 --xla_new=2"
    monkeypatch.delenv("XLA_FLAGS")
    add_xla_flags("--a=1")
    assert os.environ["XLA_FLAGS"] == "--a=1"


def test_a_flag_file_is_left_alone(monkeypatch, tmp_path):
    # XLA_FLAGS without a leading "-" names a file of flags: anything appended would
    # become part of the file's name, and XLA would abort at the first computation
    flagfile = tmp_path / "flags"
    flagfile.write_text("--xla_cpu_multi_thread_eigen=false\n")
    monkeypatch.setenv("XLA_FLAGS", str(flagfile))
    assert add_xla_flags("--a=1") is False
    assert os.environ["XLA_FLAGS"] == str(flagfile)
    got = _probe("tensorid-first", str(flagfile))  # and a process with it computes
    assert got["flags"] == str(flagfile) and not got["one_function"]


def test_the_emitters_flag_only_where_jaxlib_knows_it(monkeypatch):
    """XLA aborts the process on a flag it does not know (jaxlib 0.4.30-0.5.1 do not
    know --xla_cpu_use_fusion_emitters), so it is only added on the versions that do."""
    for version, added in [((0, 4, 30), False), ((0, 5, 1), False), ((0, 5, 3), True),
                           ((0, 10, 2), True), ((0, 11, 0), False), ((), False)]:  # fmt: skip
        monkeypatch.setattr(_config, "_jaxlib_version", lambda v=version: v)
        flags = _config._xla_flags()
        assert ("--xla_cpu_use_fusion_emitters=false" in flags) is added, version
        assert any(str(SMALL_LOOP_BYTES) in f for f in flags)


def test_the_library_fusions_flag_only_where_jaxlib_knows_it(monkeypatch):
    """--xla_cpu_experimental_ynn_fusion_type is named in jaxlib 0.8.1's libraries and
    later, not in 0.8.0's: older versions would abort on it."""
    for version, added in [((0, 7, 2), False), ((0, 8, 0), False), ((0, 8, 1), True),
                           ((0, 10, 2), True), ((0, 11, 2), True), ((0, 12, 0), False),
                           ((), False)]:  # fmt: skip
        monkeypatch.setattr(_config, "_jaxlib_version", lambda v=version: v)
        assert (f"--{_config.YNN_FLAG}=" in _config._xla_flags()) is added, version


def test_the_command_keeps_xla_s_own_log_lines_off_the_terminal():
    """issue 51, item 9: XLA's raw "Very slow compile?" alarm reached the terminal; the
    command sets XLA's log level before JAX loads (a level the user set is kept), the
    package imported by a user's own program leaves it alone."""
    import os
    import subprocess
    import sys

    code = ("import sys; sys.argv = [{argv!r}, 'paper']; import tensorid._early, os; "
            "print(os.environ.get('TF_CPP_MIN_LOG_LEVEL'))")  # fmt: skip
    env = {k: v for k, v in os.environ.items() if k != "TF_CPP_MIN_LOG_LEVEL"}

    def level(argv, **extra):
        out = subprocess.run([sys.executable, "-c", code.format(argv=argv)], env={**env, **extra},
                             capture_output=True, text=True, check=True)  # fmt: skip
        return out.stdout.split()[-1]

    assert level("/usr/bin/tensorid") == "3"
    assert level("/usr/bin/tensorid", TF_CPP_MIN_LOG_LEVEL="0") == "0"
    assert level("analysis.py") != "3"  # (JAX itself sets 1 on import)
