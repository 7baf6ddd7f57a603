"""The console says what it compiles while it waits (issue 43, item 1): the engine
announces each program's first call through jax.monitoring; the command line's
CompileWatch turns that into a line."""

import io
import os
import re
import subprocess
import sys
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from rich.console import Console

from tensorid.app.compile_progress import CompileWatch
from tensorid.engine.compiling.compilation import BEGIN, END, announced, describe


def test_describe_names_the_sweeps():
    assert describe("_second_order batched=False axes=(0,)") == (
        "the second-order sweep (J, ∇J, ∇²J)"
    )
    assert describe("_first_order batched=True axes=(0,)").endswith(", batched")
    assert describe("adjoint phase 1 batched=False 4 256") == "the second-order adjoint"


def test_a_log_gets_a_line_when_a_long_compilation_starts_and_ends():
    out = io.StringIO()
    console = Console(file=out, force_terminal=False, width=200)
    with CompileWatch(console, log_after=0.2):
        with announced("the second-order sweep (J, ∇J, ∇²J)"):
            time.sleep(1.0)
        with announced("the simulation"):  # quick: nothing said
            pass
    lines = out.getvalue().splitlines()
    assert lines[0].startswith("compiling the second-order sweep (J, ∇J, ∇²J)")
    assert lines[1].startswith("compiled the second-order sweep (J, ∇J, ∇²J) in ")
    assert len(lines) == 2


def test_the_live_line_counts_seconds_and_the_watch_lets_go():
    console = Console(file=io.StringIO(), force_terminal=True, width=200)
    watch = CompileWatch(console)
    with watch:
        watch.hosted = True  # as under the iteration table: only line() shows it
        jax.monitoring.record_event(BEGIN, what="the cost J")
        time.sleep(1.2)
        assert re.fullmatch(r"compiling the cost J … \d+ s", str(watch.line()))
        jax.monitoring.record_event_duration_secs(END, 1.2, what="the cost J")
        assert str(watch.line()) == ""
    jax.monitoring.record_event(BEGIN, what="after")  # no longer listened to
    assert str(watch.line()) == ""


def test_on_a_terminal_without_a_table_the_watch_shows_its_own_line():
    out = io.StringIO()
    console = Console(file=out, force_terminal=True, width=200)
    with CompileWatch(console) as watch:
        with announced("the simulation"):
            time.sleep(2.5)
        time.sleep(0.5)  # the live line is taken down once nothing compiles
        assert watch._live is None
    assert re.search(r"compiling the simulation … \d s", out.getvalue())


def test_a_programs_first_call_is_announced_once():
    from tensorid.engine.compiling.programs import Program

    seen = []

    def listen(event, **kw):
        if event == BEGIN:
            seen.append(kw["what"])

    class NoSweeps:  # no key can be made: the plain jit runs
        pass

    program = Program(jax.jit(lambda a: jnp.sin(a) * 2), NoSweeps(), "_cost batched=False")
    jax.monitoring.register_event_listener(listen)
    try:
        a = np.arange(3.0)
        np.testing.assert_array_equal(program(a), np.sin(a) * 2)
        program(a)
    finally:
        jax.monitoring.unregister_event_listener(listen)
    assert seen == ["the cost J"]


CLI = """
import sys
import tensorid.app.compile_progress as progress
progress.LOG_AFTER = float(sys.argv[1])
from tensorid.cli import main
sys.exit(main(sys.argv[2:]))
"""


@pytest.mark.slow
def test_a_first_command_line_fit_says_what_it_compiles_and_a_second_says_nothing(tmp_path):
    example = Path(__file__).resolve().parent.parent / "examples" / "silverbox"
    env = dict(os.environ, TENSORID_CACHE_DIR=str(tmp_path / "jax"), TENSORID_PROGRAMS="1")

    def fit(log_after: str) -> list[str]:
        args = ["fit", str(example / "model.py"), str(example / "train.csv")]
        args += ["--out", str(tmp_path / "fit")]
        done = subprocess.run(
            [sys.executable, "-c", CLI, log_after, *args], capture_output=True, text=True, env=env
        )
        assert done.returncode == 0, done.stderr
        return [line for line in done.stderr.splitlines() if line.startswith("compil")]

    # an empty cache: every program is compiled (each line shown here, not only past 2 s)
    cold = fit("0.01")
    assert any(line.startswith("compiling the second-order sweep") for line in cold)
    assert any(line.startswith("compiled the first-order sweep") for line in cold)
    assert fit("2") == []  # the same fit again: read from the cache, nothing to say
