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
    assert printed == [shown[1]]


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
