"""Traced programs kept across processes (engine/programs.py): a second process reads
them instead of tracing, gets the same numbers bit for bit, and a program is never
reused for a model, layout or setting it was not traced for."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import tensorid as ti
from tensorid.engine import programs
from tensorid.engine.compiling import pruning

# one process: build a problem from text equations, count how often the sweeps' Python
# runs (a trace), print (J, g, H) to full precision
SCRIPT = r"""
import json, sys
import numpy as np
import tensorid as ti
from tensorid.engine.sweeping.sweeps import Sweeps

traced = []
for name in ("_second_order", "_first_order", "_simulate"):
    fn = getattr(Sweeps, name)
    def counting(self, *a, _fn=fn, _name=name, **k):
        traced.append(_name)
        return _fn(self, *a, **k)
    setattr(Sweeps, name, counting)

k = float(sys.argv[1])
model = ti.model_from_equations(
    {"x": "v", "v": f"-{k}*x - c*v + u"}, {"y": "x"}, ["u"], ["c"]
)
t = np.arange(200) * 0.05
u = np.sin(t)
y = ti.simulate(model, {"c": 0.3}, [0.1, 0.0], ti.Experiment(t, u)).y
prob = ti.Problem(model, ti.Experiment(t, u, y + 0.01), p0={"c": 0.5}, x0=[0.1, 0.0],
                  free_x0=["v"])
J, g, H = prob.cost_grad_hess(prob.theta0)
sim = prob.simulate(prob.theta0)[0].y
print(json.dumps({"traced": traced, "J": J.hex(), "g": [v.hex() for v in g],
                  "H": [v.hex() for v in H.ravel()], "sim": [v.hex() for v in sim.ravel()]}))
"""


def _run(cache: Path, k: float = 2.0, script: str = SCRIPT, **env) -> dict:
    """``script``'s JSON line, run in a process of its own on the cache ``cache``."""
    environ = dict(os.environ, TENSORID_CACHE_DIR=str(cache), TENSORID_PROGRAMS="1", **env)
    out = subprocess.run(
        [sys.executable, "-c", script, str(k)],
        capture_output=True,
        text=True,
        env=environ,
        check=True,
        timeout=600,  # (a hang fails)
    )
    return json.loads(out.stdout.strip().splitlines()[-1])


@pytest.fixture(scope="module")
def cache(tmp_path_factory):
    return tmp_path_factory.mktemp("cache") / "jax"


def test_a_second_process_reads_the_programs_and_gets_the_same_numbers(cache):
    first = _run(cache)
    assert "_second_order" in first["traced"] and "_simulate" in first["traced"]
    kept = list((cache / "programs").glob("*.jaxexport"))
    assert len(kept) >= 2
    # everything under the one folder (issue 51: TENSORID_CACHE_DIR=X also wrote X-programs)
    assert sorted(p.name for p in cache.parent.iterdir()) == [cache.name]
    second = _run(cache)
    assert second["traced"] == []  # nothing traced: every program was read
    for key in ("J", "g", "H", "sim"):
        assert second[key] == first[key]
    # and the numbers are those of a process that keeps nothing
    plain = _run(cache.parent / "off", TENSORID_CACHE="0")
    assert plain["traced"] and not (cache.parent / "off" / "programs").exists()
    for key in ("J", "g", "H", "sim"):
        assert plain[key] == first[key]


@pytest.mark.slow  # fresh processes; the default run keeps the bit-for-bit check
def test_another_model_is_traced_afresh_not_read(cache):
    _run(cache)
    other = _run(cache, k=3.0)  # the same names and shapes, another constant in F
    assert "_second_order" in other["traced"]
    plain = _run(cache.parent / "off2", k=3.0, TENSORID_CACHE="0")
    assert other["J"] == plain["J"] and other["H"] == plain["H"]


@pytest.mark.slow  # fresh processes; the default run keeps the bit-for-bit check
def test_a_damaged_program_file_is_traced_again(cache):
    _run(cache)
    folder = cache / "programs"
    for f in (*folder.glob("*.jaxexport"), *folder.glob("*.xla")):
        f.write_bytes(b"not a program")
    again = _run(cache)
    assert "_second_order" in again["traced"]
    plain = _run(cache.parent / "off3", TENSORID_CACHE="0")
    assert again["J"] == plain["J"] and again["H"] == plain["H"]


def test_a_second_process_loads_the_executables(tmp_path):
    """The executables beside the traced programs (engine/executables.py): kept by the
    first process, loaded by the next, which then neither traces nor lowers. (A cache
    folder of its own: where JAX's cache already holds a program, none is kept.)"""
    cache = tmp_path / "jax"
    first = _run(cache)
    folder = cache / "programs"
    kept = sorted(folder.glob("*.xla"))
    assert len(kept) == len(list(folder.glob("*.jaxexport"))) >= 2
    for f in folder.glob("*.jaxexport"):  # not needed where the executable is there
        f.write_bytes(b"not a program")
    second = _run(cache)
    assert second["traced"] == []
    for key in ("J", "g", "H", "sim"):
        assert second[key] == first[key]


def test_an_executable_whose_call_fails_is_removed_and_jit_runs(tmp_path, monkeypatch):
    """A kept executable that loads but fails at its first call (a file from a build
    whose serialization was incomplete): its file goes, the plain jit answers."""
    import jax

    from tensorid.engine import executables

    kept = tmp_path / f"k-{executables.machine_digest()}.xla"
    kept.write_bytes(b"stand-in")

    def broken(*args):
        raise RuntimeError("Function slice_fusion not found")

    monkeypatch.setattr(programs, "folder", lambda: tmp_path)
    monkeypatch.setattr(programs, "_key", lambda *a: "k")
    monkeypatch.setattr(executables, "load", lambda path: broken if path == kept else None)
    prog = programs.Program(jax.jit(lambda x: 2 * x), None, "e")
    out = prog(np.arange(3.0))
    assert np.array_equal(out, [0.0, 2.0, 4.0]) and not kept.exists()
    assert np.array_equal(prog(np.arange(3.0)), [0.0, 2.0, 4.0])  # jit from then on


def test_the_key_sees_the_model_its_constants_and_the_layout():
    def model(scale):
        table = np.array([1.0, scale])

        def rhs(x, p, u):
            return -p[0] * x * table[1] + u[0]

        return ti.Model(rhs=rhs, states=["x"], params=["a"], inputs=["u"])

    a, b, c = model(2.0), model(2.0), model(2.5)
    assert programs.model_digest(a) == programs.model_digest(b)
    assert programs.model_digest(a) != programs.model_digest(c)  # a closed-over array
    t = np.arange(20) * 0.1
    data = ti.Experiment(t, np.ones(20), np.ones(20))
    p1 = ti.Problem(a, data, p0={"a": 1.0}, x0=[0.0])
    p2 = ti.Problem(a, data, p0={"a": 1.0}, x0=[0.0], free_x0=["x"])
    p3 = ti.Problem(a, data, p0={"a": 1.0}, x0=[0.0], scheme="heun")
    leaves = [np.zeros(3)]
    keys = {programs._key(p._sweeps, "e", leaves, "tree") for p in (p1, p2, p3)}
    assert len(keys) == 3


def test_a_model_with_its_own_derivative_rule_is_not_kept():
    import jax

    @jax.custom_jvp
    def soft(x):
        return x

    @soft.defjvp
    def _(primals, tangents):
        return soft(primals[0]), 2.0 * tangents[0]

    m = ti.Model(rhs=lambda x, p, u: -p[0] * soft(x), states=["x"], params=["a"])
    assert programs.model_digest(m) is None


def test_constants_of_a_jitted_helper_are_in_the_key():
    import jax

    def model(scale):
        table = np.array([scale])

        @jax.jit
        def gain(x):
            return x * table[0]

        return ti.Model(rhs=lambda x, p, u: -p[0] * gain(x), states=["x"], params=["k"])

    assert programs.model_digest(model(1.0)) == programs.model_digest(model(1.0))
    assert programs.model_digest(model(1.0)) != programs.model_digest(model(2.0))


def test_a_users_scheme_object_is_not_kept():
    from tensorid.engine.schemes.integrators import SCHEMES

    class MyRK4(type(SCHEMES["rk4"])):  # a user's scheme: only its repr would be keyed
        pass

    ours = SCHEMES["rk4"]
    mine = MyRK4(**{f: getattr(ours, f) for f in ("name", "a", "b", "c", "order")})
    m = ti.Model(rhs=lambda x, p, u: -p[0] * x, states=["x"], params=["k"])
    t = np.arange(20) * 0.1
    data = ti.Experiment(t, None, np.ones(20))
    kept = ti.Problem(m, data, p0={"k": 1.0}, x0=[1.0], scheme=ours)
    not_kept = ti.Problem(m, data, p0={"k": 1.0}, x0=[1.0], scheme=mine)
    leaves = [np.zeros(3)]
    assert programs._key(kept._sweeps, "e", leaves, "tree") is not None
    assert programs._key(not_kept._sweeps, "e", leaves, "tree") is None


def test_nothing_is_kept_once_the_source_changed_after_import(monkeypatch):
    assert programs._package_digest() is not None
    changed = {p: (mtime + 1, size) for p, (mtime, size) in programs._IMPORTED.items()}
    monkeypatch.setattr(programs, "_IMPORTED", changed)  # as if a file were edited since
    assert programs._package_digest() is None


def test_under_a_transformation_the_entry_is_plain_jit(monkeypatch):
    import jax
    import jax.numpy as jnp

    monkeypatch.setenv("TENSORID_PROGRAMS", "1")
    assert programs.folder() is not None
    m = ti.Model(rhs=lambda x, p, u: -p[0] * x, states=["x"], params=["k"])
    t = jnp.asarray(np.arange(30) * 0.1)
    u = jnp.zeros((30, 0))
    prob = ti.Problem(m, ti.Experiment(np.asarray(t), None, np.ones(30)), p0={"k": 1.0}, x0=[1.0])
    sw = prob._sweeps
    x0 = jnp.ones(1)
    sw.simulate(x0, jnp.ones(1), t, u)  # the program for these shapes, read or traced
    d = jax.jacfwd(lambda k: sw.simulate(x0, k, t, u)[1])(jnp.ones(1))
    tt = np.asarray(t)
    np.testing.assert_allclose(np.asarray(d)[:, 0, 0], -tt * np.exp(-tt), rtol=1e-4)


def test_other_versions_programs_unused_for_a_month_are_pruned(tmp_path, monkeypatch):
    import time

    folder = tmp_path / "jax-programs"
    folder.mkdir()
    old, recent, ours = (folder / f"{n}-x.jaxexport" for n in ("aaaaaaaa", "bbbbbbbb", "cccccccc"))
    for f in (old, recent, ours):
        f.write_bytes(b"x")
    month = time.time() - 31 * 86400
    os.utime(old, (month, month))
    os.utime(ours, (month, month))
    monkeypatch.setattr(programs.state, "pruned", False)
    pruning.prune(folder, "cccccccc")
    assert not old.exists() and recent.exists() and ours.exists()


def test_a_folder_over_its_cap_loses_its_least_recently_used_programs(tmp_path, monkeypatch):
    import time

    folder = tmp_path / "jax-programs"
    folder.mkdir()
    now = time.time()
    files = []
    for k in range(10):  # 10 programs of 100 bytes, used k hours ago
        f = folder / f"cccccccc-{k}.jaxexport"
        f.write_bytes(b"x" * 100)
        os.utime(f, (now - 3600 * k, now - 3600 * k))
        files.append(f)
    monkeypatch.setattr(pruning, "MAX_BYTES", 800)
    monkeypatch.setattr(programs.state, "pruned", False)
    pruning.prune(folder, "cccccccc")
    # over 800 bytes: the oldest go until 600 (three quarters) are left
    assert [f.exists() for f in files] == [True] * 6 + [False] * 4
    monkeypatch.setattr(programs.state, "pruned", False)
    pruning.prune(folder, "cccccccc")  # under the cap: nothing more goes
    assert sum(f.exists() for f in files) == 6


def test_two_processes_pruning_at_once_remove_no_more_than_one(tmp_path, monkeypatch):
    # a file that another process removed first still counts as removed: each process
    # went on deleting past the target (2 of 10 left where 6 should be)
    import time
    from pathlib import Path

    folder = tmp_path / "jax-programs"
    folder.mkdir()
    now = time.time()
    files = []
    for k in range(10):
        f = folder / f"cccccccc-{k}.jaxexport"
        f.write_bytes(b"x" * 100)
        os.utime(f, (now - 3600 * k, now - 3600 * k))
        files.append(f)
    real = Path.unlink

    def raced(self, *a, **k):  # the other process got there first
        real(self, *a, **k)
        raise FileNotFoundError(2, "No such file or directory", str(self))

    monkeypatch.setattr(Path, "unlink", raced)
    monkeypatch.setattr(pruning, "MAX_BYTES", 800)
    monkeypatch.setattr(programs.state, "pruned", False)
    pruning.prune(folder, "cccccccc")
    assert sum(f.exists() for f in files) == 6


ADJOINT_SCRIPT = r"""
import json
import numpy as np
import tensorid as ti
from tensorid.engine.sweeping.adjoint import SecondOrderAdjoint

traced = []
for name in ("_backward", "_stretch"):
    fn = getattr(SecondOrderAdjoint, name)
    def counting(self, *a, _fn=fn, _name=name, **k):
        traced.append(_name)
        return _fn(self, *a, **k)
    setattr(SecondOrderAdjoint, name, counting)

model = ti.model_from_equations({"x": "v", "v": "-k*x - c*v + u"}, {"y": "x"}, ["u"], ["k", "c"])
t = np.arange(300) * 0.05
u = np.sin(t)
y = ti.simulate(model, {"k": 2.0, "c": 0.3}, [0.1, 0.0], ti.Experiment(t, u)).y
prob = ti.Problem(model, ti.Experiment(t, u, y + 0.01), p0={"k": 1.5, "c": 0.5},
                  x0=[0.1, 0.0], free_x0=["v"], hessian="adjoint")
J, g, H = prob.cost_grad_hess(prob.theta0)
print(json.dumps({"traced": traced, "H": [v.hex() for v in H.ravel()], "J": J.hex()}))
"""


@pytest.mark.slow  # fresh processes; the default run keeps the bit-for-bit check
def test_the_adjoints_programs_are_read_by_a_second_process(tmp_path):
    env = dict(
        os.environ,
        TENSORID_CACHE_DIR=str(tmp_path / "jax"),
        TENSORID_THREADS="1",
        TENSORID_PROGRAMS="1",
    )

    def run(**more):
        out = subprocess.run(
            [sys.executable, "-c", ADJOINT_SCRIPT],
            capture_output=True,
            text=True,
            env=dict(env, **more),
            check=True,
        )
        return json.loads(out.stdout.strip().splitlines()[-1])

    first, second = run(), run()
    assert "_backward" in first["traced"] and "_stretch" in first["traced"]
    assert second["traced"] == []
    plain = run(TENSORID_CACHE="0")
    assert second["H"] == first["H"] == plain["H"] and second["J"] == plain["J"]


def test_jax_compiled_code_is_kept_under_its_cap_least_recently_used_first(tmp_path, monkeypatch):
    # JAX's compilation cache grew without bound (16,000 files on a developer's
    # machine); it gets the program folder's rule, "used" being the later of a file's
    # access and modification times
    import time

    now = time.time()
    files = []
    for k in range(10):  # 10 entries of 100 bytes, used k hours ago
        f = tmp_path / f"jit_J-{k:02d}-cache"
        f.write_bytes(b"x" * 100)
        os.utime(f, (now - 3600 * k, now - 3600 * k - 86400))  # read after written
        files.append(f)
    other = tmp_path / "jit_J-00-atime"  # not an entry: never removed
    other.write_bytes(b"x" * 1000)
    monkeypatch.setattr(pruning, "COMPILED_MAX_BYTES", 800)
    pruning._prune_compiled(str(tmp_path), 500)  # the user's own cap: JAX's job
    assert all(f.exists() for f in files)
    pruning._prune_compiled(str(tmp_path), -1)
    assert [f.exists() for f in files] == [True] * 6 + [False] * 4
    assert other.exists()


def test_the_first_program_written_prunes_the_compiled_code_too(tmp_path, monkeypatch):
    seen = []
    monkeypatch.setattr(pruning, "_prune_own_compiled", lambda: seen.append(True))
    monkeypatch.setattr(programs.state, "pruned", False)
    pruning.prune(tmp_path, "cccccccc")
    pruning.prune(tmp_path, "cccccccc")  # once per process
    assert len(seen) == 1


def test_only_the_compiled_code_folder_tensorid_chose_is_pruned(tmp_path, monkeypatch):
    # a folder the user gave JAX itself (JAX_COMPILATION_CACHE_DIR) may be shared with
    # other programs: tensorid leaves it as it is
    import jax

    from tensorid import _config

    pruned = []
    monkeypatch.setattr(pruning, "_prune_compiled", lambda folder, cap: pruned.append(folder))
    here = jax.config.values.get("jax_compilation_cache_dir")
    monkeypatch.setattr(_config, "own_cache", None)  # not ours
    pruning._prune_own_compiled()
    monkeypatch.setattr(_config, "own_cache", here)  # ours (tensorid set it)
    pruning._prune_own_compiled()
    on = jax.config.values.get("jax_enable_compilation_cache")
    assert pruned == ([here] if on and here else [])


def test_half_written_programs_of_killed_processes_are_removed(tmp_path, monkeypatch):
    import time

    stale, fresh = tmp_path / ".cccccccc-1.jaxexport.abcd1234.part", tmp_path / ".x.part"
    for f in (stale, fresh):
        f.write_bytes(b"x")
    hour = time.time() - 3700
    os.utime(stale, (hour, hour))
    monkeypatch.setattr(pruning, "_prune_compiled", lambda *a: None)
    monkeypatch.setattr(programs.state, "pruned", False)
    pruning.prune(tmp_path, "cccccccc")
    assert not stale.exists() and fresh.exists()  # a live writer's is left alone


def test_keeping_an_executable_first_leaves_jax_s_cache_on_for_the_process(tmp_path):
    """JAX decides whether its compilation cache is used at a process's first
    compilation, once: where that is an executable compiled for keeping (with the
    cache off), nothing else the process compiled was cached (a first command-line
    fit wrote no cache entry)."""
    script = (
        "import sys, numpy as np, jax, tensorid\n"
        "from pathlib import Path\n"
        "from tensorid.engine import executables, programs\n"
        "f = Path(sys.argv[1])\n"
        "(f.parent / 'jax-programs').mkdir()\n"
        "executables.compile_and_keep(jax.jit(lambda x: x + 1.0), (np.ones(3),),"
        " f.parent / 'jax-programs' / 'k-0.xla', programs._write)\n"
        "jax.jit(lambda x: 3.0 * x)(np.ones(3)).block_until_ready()\n"
        "print(len(list(f.glob('*-cache'))))\n"
    )
    cache = tmp_path / "jax"
    environ = dict(os.environ, TENSORID_CACHE_DIR=str(cache), TENSORID_PROGRAMS="1")
    out = subprocess.run(
        [sys.executable, "-c", script, str(cache)],
        capture_output=True, text=True, env=environ, check=True,
    )  # fmt: skip
    assert (tmp_path / "jax-programs" / "k-0.xla").exists()
    assert int(out.stdout.split()[-1]) >= 1  # the plain jit's entry


def test_an_executable_is_kept_apart_per_compile_setting(tmp_path):
    """JAX's settings that reach XLA's compile options but not the traced program
    (its key) name another executable: one compiled with optimizations on gave
    another process run with JAX_DISABLE_MOST_OPTIMIZATIONS=1 the optimized numbers
    (the Silverbox example's cost ...760906 against ...76092 compiled afresh)."""
    import jax

    from tensorid.engine import executables

    plain = executables.path_for(tmp_path, "k")
    for name, value in [("jax_disable_most_optimizations", True),
                        ("jax_optimization_level", "O0")]:  # fmt: skip
        before = jax.config.values[name]
        jax.config.update(name, value)
        try:
            assert executables.path_for(tmp_path, "k") != plain, name
        finally:
            jax.config.update(name, before)
        assert executables.path_for(tmp_path, "k") == plain


def test_an_executable_that_cannot_be_written_is_left_to_jax_s_cache(tmp_path):
    """Compiled with JAX's cache off, an executable that could not be written was
    run all the same: a folder that cannot be written then compiled every program
    afresh in every process, never looked up in JAX's cache (the Silverbox example's
    command: 1.3-3.1 s of compiling each time, 0.2-0.3 s before). None: the caller's
    jit runs, through JAX's cache."""
    import jax

    from tensorid.engine import executables

    def program():  # one JAX's cache has not seen (a program it has is not kept)
        c = float(np.random.default_rng().integers(1, 2**40))
        return jax.jit(lambda x: x + c), c

    args = (np.ones(3),)
    f, _ = program()
    assert executables.compile_and_keep(f, args, tmp_path / "k.xla", lambda p, b: False) is None
    gone = tmp_path / "no folder" / "k.xla"
    assert executables.compile_and_keep(program()[0], args, gone, programs._write) is None
    assert not gone.exists()
    f, c = program()
    kept = executables.compile_and_keep(f, args, tmp_path / "k.xla", programs._write)
    assert kept is not None and np.array_equal(kept(*args), np.full(3, 1.0 + c))


def test_jax_s_cache_met_before_an_executable_is_kept_does_not_break_a_fit(tmp_path):
    """Once JAX's compilation cache is in use in a process (the user's own jit ran
    first), enable_compilation_cache(False) no longer keeps it from answering: where
    it held the program (its executable file gone, pruned), the executable kept was
    the incomplete copy, whose failure ("Function ... not found") surfaced only when
    the result was read, outside the first call's check: the fit failed, and so did
    every later process, which loaded the same file."""
    script = (
        "import jax, numpy as np, tensorid as ti\n"
        "jax.jit(lambda x: x - 1.0)(np.ones(2))\n"
        "from tensorid.paper.problems import silverbox_problem\n"
        "print(ti.fit(silverbox_problem(offset=True), maxiter=3).cost.hex())\n"
    )

    def run(folder, **env):
        environ = dict(os.environ, TENSORID_CACHE_DIR=str(folder), TENSORID_PROGRAMS="1", **env)
        out = subprocess.run(
            [sys.executable, "-c", script], capture_output=True, text=True, env=environ
        )
        assert out.returncode == 0, out.stderr[-300:]
        return out.stdout.split()[-1]

    plain = run(tmp_path / "off", TENSORID_CACHE="0")
    for _ in range(2):  # the second run meets JAX's cache holding what has no .xla
        assert run(tmp_path / "jax") == plain
        for f in (tmp_path / "jax" / "programs").glob("*.xla"):
            f.unlink()  # as pruning may leave JAX's cache with the program


# a population fit in one process: count the traces of the outer objective's pieces,
# print the estimates to full precision
POPULATION = r"""
import json
import jax.numpy as jnp
import numpy as np
import tensorid as ti
from tensorid.population.objective import Objective

traced = []
for name in ("unit_value_grad", "unit_evaluation"):
    fn = getattr(Objective, name)
    def counting(self, *a, _fn=fn, _name=name, **k):
        traced.append(_name)
        return _fn(self, *a, **k)
    setattr(Objective, name, counting)

m = ti.Model(rhs=lambda x, p, u: -p[0] * x, output=lambda x, p: x / p[1], states=["x"],
             params=["k", "v"], outputs=["c"])
rng = np.random.default_rng(0)
t = np.linspace(0, 4, 9)
ys = [(5 * np.exp(-k * t))[:, None] + 0.05 * rng.standard_normal((9, 1))
      for k in rng.lognormal(0, 0.3, 6)]
units = [ti.Experiment(t, None, y, name=str(i)) for i, y in enumerate(ys)]
res = ti.fit(ti.Problem(m, units, p0={"k": 1.0, "v": 2.5}, x0=[10.0], population={"k": 0.3}))
print(json.dumps({"traced": sorted(set(traced)), "x": [v.hex() for v in res.x],
                  "H": [v.hex() for v in np.ravel(res.hess)]}))
"""


@pytest.mark.slow  # two processes each fitting a population (20-40 s the first, cold)
def test_a_population_fits_programs_are_read_by_the_next_process(tmp_path):
    """issue 50 item 1: the outer Hessian's trace alone took 10 s of a 17 s theophylline
    fit whose programs were all in JAX's cache; its programs are now kept as the
    sweeps' are, and a second process traces none of them, with the same numbers."""
    first = _run(tmp_path / "jax", script=POPULATION)
    assert first["traced"] == ["unit_evaluation", "unit_value_grad"]
    second = _run(tmp_path / "jax", script=POPULATION)
    assert second["traced"] == []  # read, not traced
    # (a kept program's numbers against a process that keeps nothing: the sweeps' test
    # above; the fingerprint script's 986 arrays are bit-identical with them kept)
    assert second["x"] == first["x"] and second["H"] == first["H"]


# one Program by hand: traced ahead in one process (trace_ahead), read ahead in the next
# (load_kept), counting the traces of its function and the reads of executables
AHEAD = r"""
import json, sys
import jax
import numpy as np
import tensorid as ti
from tensorid.engine.compiling import executables, programs

model = ti.model_from_equations({"x": "-c*x"}, {"y": "x"}, [], ["c"])
prob = ti.Problem(model, ti.Experiment(np.arange(5.0), None, np.ones(5)), p0={"c": 0.5},
                  x0=[1.0])
traced, loads, exports = [], [], []
read, export = executables.load, programs._exported
executables.load = lambda path: loads.append(path) or read(path)
programs._exported = lambda *a: exports.append(1) or export(*a)

def f(x):
    traced.append(1)
    return 2.0 * x + 1.0

program = programs.Program(jax.jit(f), prob.sweeps, "test_ahead")
x = np.arange(3.0)
if sys.argv[1] == "trace":
    program.trace_ahead(x)
elif sys.argv[1] == "raise":  # a read that fails: its waiting first call is answered
    counting, executables.load = executables.load, lambda path: 1 / 0
    try:
        program.load_kept(x)
    except ZeroDivisionError:
        pass
    executables.load = counting
else:
    program.load_kept(x)
before = (len(exports), len(loads))
out = program(x)
print(json.dumps({"before": before, "exports": len(exports), "loads": len(loads),
                  "traced": len(traced), "out": [float(v) for v in out]}))
"""


def test_a_program_traced_or_read_ahead_is_not_traced_or_read_again_by_its_call(tmp_path):
    """issue 50: a fleet's biggest program is traced in the fit's thread before a second
    thread compiles it (trace_ahead), and read from disk while the substeps are checked
    (load_kept); its first call then uses what was done, instead of doing it again."""
    first = _run(tmp_path / "jax", "trace", script=AHEAD)  # (argv[1], as _run's k)
    assert first["before"] == [1, 0]  # traced (exported) ahead, nothing read
    assert first["exports"] == 1  # the call compiled that export, not a new one
    assert first["out"] == [1.0, 3.0, 5.0]
    second = _run(tmp_path / "jax", "load", script=AHEAD)
    assert second["before"] == [0, 1]  # read ahead, nothing exported
    assert second["loads"] == 1  # the call used that read
    assert second["exports"] == 0 and second["traced"] == 0
    assert second["out"] == first["out"]
    failed = _run(tmp_path / "jax", "raise", script=AHEAD)  # (it hung: the read never said)
    assert failed["loads"] == 1 and failed["out"] == first["out"]


def test_a_kept_executable_that_does_not_load_is_removed_by_its_check(tmp_path):
    """The file just written is read back and run in a second thread, while the
    process goes on with what it compiled (waiting for that read cost a cold
    theophylline fit 0.7 s): a file that does not work is removed there."""
    import jax

    from tensorid.engine import executables

    c = float(np.random.default_rng().integers(1, 2**40))  # (not in JAX's cache)
    f, args = jax.jit(lambda x: x * c), (np.ones(3),)
    broken = tmp_path / "broken.xla"
    run = executables.compile_and_keep(f, args, broken, lambda p, b: programs._write(p, b"x"))
    assert run is not None and np.array_equal(run(*args), np.full(3, c))  # its own
    executables.settle()
    assert not broken.exists()
    good = tmp_path / "good.xla"
    run = executables.compile_and_keep(jax.jit(lambda x: x - c), args, good, programs._write)
    executables.settle()
    assert good.exists() and np.array_equal(run(*args), np.full(3, 1.0 - c))


def test_a_process_keeps_the_programs_of_the_structures_it_used_last():
    """A long-lived process that fits many population models keeps the programs of
    the last ``limit`` structures only (each holds its executables and its model);
    a structure asked for again is the newest."""
    from tensorid.population import objective

    kept = programs.KeptStructures(limit=2)
    kept.programs("a")["evaluation"] = 1
    kept.programs("b")["evaluation"] = 2
    assert kept.get("a") == {"evaluation": 1}  # now a is newer than b
    kept.programs("c")
    assert len(kept) == 2 and kept.get("b") is None and kept.get("a", {}) == {"evaluation": 1}
    assert kept.programs("c") == {} and kept.get("c") is kept.programs("c")
    assert isinstance(objective._PROGRAMS, programs.KeptStructures)
