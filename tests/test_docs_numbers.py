"""The numbers the docs state are the ones their code prints (issue 41's newcomer
found a tutorial that said 7 iterations where it printed 5), and the commands written
in the examples' headers are the ones the docs run."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def _python_blocks(page: str) -> list[str]:
    return re.findall(r"```python\n(.*?)```", (ROOT / page).read_text(), flags=re.S)


def test_the_tutorial_s_fit_prints_the_numbers_it_states(capsys):
    text = " ".join((ROOT / "docs/tutorial.md").read_text().split())
    said = re.search(
        r"Newton converges in (\d+) iterations to a training cost of ([\d.]+) and a "
        r"validation GOF of ([\d.]+)",
        text,
    )
    assert said, "the tutorial's sentence moved: update this test with it"
    ns: dict = {}
    for block in _python_blocks("docs/tutorial.md")[:3]:  # model, data, the fit
        exec(compile(block, "docs/tutorial.md", "exec"), ns)
    res = ns["res"]
    assert res.nit == int(said[1])
    assert f"{res.cost:.4g}" == said[2]
    printed = capsys.readouterr().out.strip().splitlines()[-1]
    assert f"{float(printed):.4f}" == said[3]


@pytest.mark.parametrize(
    "script, page",
    [("examples/emps/open_loop.py", "docs/emps.md"), ("examples/emps/stribeck.py", "docs/emps.md")],
)
def test_an_example_s_header_command_is_the_docs_own(script, page):
    header = [ln[1:].strip() for ln in (ROOT / script).read_text().splitlines() if ln[:1] == "#"]
    command = " ".join(header).split("tensorid fit ", 1)[1].split(" (")[0]
    command = "tensorid fit " + command.replace("\\ ", "")
    docs = [" ".join(b.replace("\\\n", " ").split()) for b in
            re.findall(r"```bash\n(.*?)```", (ROOT / page).read_text(), flags=re.S)]  # fmt: skip
    assert " ".join(command.split()) in docs
    assert "../shared" not in (ROOT / script).read_text()


@pytest.mark.slow
def test_the_multi_start_example_prints_the_line_the_docs_show(tmp_path, capsys, monkeypatch):
    """docs/your-own-model.md's multi-start example, run as written (about 30 s)."""
    import shlex

    from tensorid import cli

    text = (ROOT / "docs/your-own-model.md").read_text()
    command = re.search(r"\(`(tensorid fit\s+examples/silverbox/.*?)`\):", text, flags=re.S)
    shown = re.search(r"```text\n(auto: converged.*?best of 4 starts.*?)\n```", text, re.S)
    assert command and shown
    args = shlex.split(" ".join(command[1].split()))[1:]
    monkeypatch.chdir(ROOT)
    capsys.readouterr()
    assert cli.main([*args, "--no-progress", "--out", str(tmp_path / "fit")]) == 0
    captured = capsys.readouterr()
    printed = [ln for ln in (captured.out + captured.err).splitlines() if "best of 4" in ln]
    # the starts' total iterations and evaluations are rounding's (a start's last steps
    # at its optimum: one more or fewer on another processor); the rest digit for digit
    totals = re.compile(r"all starts: (\d+) iterations, (\d+) cost evaluations")
    masked = [totals.sub("all starts: _", ln) for ln in (*printed, shown[1])]
    assert len(printed) == 1 and masked[0] == masked[1]
    for a, b in zip(totals.findall(printed[0])[0], totals.findall(shown[1])[0], strict=True):
        assert abs(int(a) - int(b)) <= 3, (printed[0], shown[1])


def test_the_quick_study_s_time_is_said_the_same_everywhere(capsys):
    """README.md, docs/index.md and `tensorid paper --help` gave 35, 40 and 50 s."""
    from tensorid import cli
    from tensorid.paper.command import QUICK_SECONDS

    cold, warm = QUICK_SECONDS["empty cache"], QUICK_SECONDS["warm cache"]
    with pytest.raises(SystemExit):
        cli.main(["paper", "--help"])
    pages = {
        "README.md": (ROOT / "README.md").read_text(),
        "docs/index.md": (ROOT / "docs/index.md").read_text(),
        "paper --help": capsys.readouterr().out,
    }
    for where, text in pages.items():
        flat = " ".join(text.split())
        assert f"about {cold} s" in flat and f"{warm} s" in flat, where
        assert QUICK_SECONDS["measured"].split(",")[0].removeprefix("measured ") in flat, where
        said = {int(x) for x in re.findall(r"about (\d+) s\b", flat)}
        assert said <= {cold, warm, 20}, (where, said)  # 20: the README's pip install


def test_the_prediction_error_example_recovers_what_its_page_says(capsys):
    """docs/prediction-error.md's example, run as written: the estimates it states,
    each within two standard errors of the truth, and no np.float64(...) printed."""
    import numpy as np

    ns: dict = {}
    exec(compile(_python_blocks("docs/prediction-error.md")[0], "prediction-error", "exec"), ns)
    res, u95 = ns["res"], ns["u95"]
    printed = capsys.readouterr().out
    assert "np.float64" not in printed
    text = " ".join((ROOT / "docs/prediction-error.md").read_text().split())
    se = dict(zip(u95.names, u95.stderr, strict=True))
    truth = {"k": 2.0, "c": 0.3, "a": 0.5}
    for n, v in truth.items():
        assert abs(res.params[n] - v) < 2 * se[n], n
        assert f"{n} = {res.params[n]:.3g} ± {se[n]:.3g}" in text, n
    sw, sev = np.exp(res.params["log_sigma_w_v"]), np.exp(res.params["log_sigma_e_y"])
    assert f"σ_w = {sw:.3g} per √s" in text and f"σ_e = {sev:.3g}" in text


def test_the_tank_refills_example_prints_what_docs_events_shows(capsys):
    """docs/events.md's engineering record with resets, run as written."""
    import runpy

    shown = re.search(r"```text\n(FTOL.*?)\n```", (ROOT / "docs/events.md").read_text(), re.S)
    assert shown, "docs/events.md's output block of examples/tank_refills.py moved"
    runpy.run_path(str(ROOT / "examples/tank_refills.py"), run_name="__main__")
    assert capsys.readouterr().out.strip() == shown[1].strip()


def _fleet_page_runs() -> list[tuple[str, str]]:
    """(command, the text block it prints) for each theophylline command of
    docs/fleets.md whose output the page shows (a bash block, then a text block with
    one output per command, blank-line separated)."""
    page = (ROOT / "docs/fleets.md").read_text()
    runs = []
    for bash, text in re.findall(r"```bash\n(.*?)```\s*```text\n(.*?)```", page, flags=re.S):
        commands = [c.strip() for c in bash.replace("\\\n", " ").splitlines() if c.strip()]
        outputs = text.strip().split("\n\n")
        if all(c.startswith("tensorid fit examples/theophylline") for c in commands):
            assert len(commands) == len(outputs), bash
            runs += list(zip(commands, outputs, strict=True))
    return runs


# How a converged fit ended and after how many iterations are rounding's at its optimum:
# whether the last step's relative decrease falls below ftol or nothing decreases at
# all, one iteration sooner or later, differ between processors (AVX-512 or AVX2 code
# from XLA: theophylline at --substeps 40 ends after 6 or 7 iterations, with every
# printed estimate the same). The estimates and −2 log L are compared digit for digit.
ENDED = re.compile(r"converged: [^\n]*")
COUNT = re.compile(r"(\d+) iterations, [\d.]+ s")


def _masked(text: str) -> list[str]:
    """The lines with the wall time masked (it is the machine's, not the fit's), and
    how a converged fit ended and its iteration count (ENDED, COUNT)."""
    lines = [ENDED.sub("converged: _", ln.rstrip()) for ln in text.strip().splitlines()]
    return [COUNT.sub("_ iterations, _ s", ln) for ln in lines]


def _iterations(text: str) -> list[int]:
    return [int(n) for n in COUNT.findall(text)]


@pytest.mark.slow  # three population fits from the command line: about 2 minutes
def test_the_fleet_page_s_theophylline_blocks_are_what_its_commands_print(tmp_path):
    """Every number of docs/fleets.md's theophylline blocks (status line, objective,
    iteration count, estimates) is what its command prints (issue 51: they drifted)."""
    import shlex
    import subprocess
    import sys

    runs = _fleet_page_runs()
    assert len(runs) == 3, "docs/fleets.md's theophylline blocks moved: update this test"
    for i, (command, shown) in enumerate(runs):
        argv = shlex.split(command)[1:]
        argv[argv.index("--out") + 1] = str(tmp_path / f"run{i}")
        done = subprocess.run([sys.executable, "-m", "tensorid", *argv, "--no-progress"],
                              cwd=ROOT, capture_output=True, text=True, timeout=600)  # fmt: skip
        assert done.returncode == 0, done.stderr
        printed = done.stdout[done.stdout.index("Population fit") :]
        printed = printed[: printed.index("results in")]
        assert _masked(printed) == _masked(shown), command
        for ran, said in zip(_iterations(printed), _iterations(shown), strict=True):
            assert abs(ran - said) <= 2, (command, ran, said)


@pytest.mark.slow  # a population fit: about 40 s cold
def test_the_fleet_page_s_default_substeps_paragraph_is_what_the_fit_does(tmp_path):
    """docs/fleets.md: without --substeps, theophylline's fit raises them from 4 to 16
    by itself, before fitting, and ends where --substeps 40 ends."""
    import subprocess
    import sys

    text = " ".join((ROOT / "docs/fleets.md").read_text().split())
    said = re.search(
        r"moves the predictions by ([\d.e+]+) residual SDs .*? raises them to (\d+) and "
        r"fits once.*? ends where `--substeps 40` ends \(−2 log L ([\d.]+), ka CV ([\d.]+) %\)",
        text,
    )
    assert said, "docs/fleets.md's substeps paragraph moved: update this test"
    argv = ["fit", "examples/theophylline/model.py", "src/tensorid/datasets/theophylline.csv",
            "--records", "ID", "--columns", "t=Time,cp=conc", "--out", str(tmp_path),
            "--no-progress"]  # fmt: skip
    done = subprocess.run([sys.executable, "-m", "tensorid", *argv], cwd=ROOT,
                          capture_output=True, text=True, timeout=600)  # fmt: skip
    assert done.returncode == 0, done.stderr
    out = done.stdout
    assert f"moved by {said[1]} residual SDs" in out
    assert f"raised from 4 to {said[2]} before the fit" in out and "fit repeated" not in out
    assert f"-2 log L = {said[3]} " in out
    ka = next(ln.split() for ln in out.splitlines() if ln.strip().startswith("ka "))
    assert ka[5] == said[4]


@pytest.mark.slow  # 200 units fitted twice: about 40 s
def test_the_fleet_page_s_oscillator_block_is_what_the_example_prints(capsys):
    """docs/fleets.md's 200 oscillators, run as written: every line but the seconds."""
    import runpy

    page = (ROOT / "docs/fleets.md").read_text()
    shown = re.search(r"```text\n(Fleet fit \(individual k\).*?)```", page, re.S)
    assert shown, "docs/fleets.md's oscillator block moved: update this test"
    runpy.run_path(str(ROOT / "examples/fleet_oscillators.py"), run_name="__main__")
    printed = [ln for ln in capsys.readouterr().out.splitlines() if "with compilation" not in ln]
    assert _masked("\n".join(printed)) == _masked(shown[1])
