"""The README's Python example runs as written and does what it says."""

import re
from pathlib import Path

README = Path(__file__).resolve().parents[1] / "README.md"


def test_readme_example_runs_and_recovers_the_parameters():
    blocks = re.findall(r"```python\n(.*?)```", README.read_text(), flags=re.S)
    assert blocks
    ns: dict = {}
    exec(compile(blocks[0], "README.md", "exec"), ns)
    res, truth = ns["res"], ns["truth"]
    assert res.success
    for k, v in truth.items():
        assert abs(res.params[k] / v - 1) < 0.02, k
    assert ns["H"].shape == (5, 5)


def test_readme_gives_exactly_two_setup_commands():
    text = README.read_text()
    bash = re.findall(r"```bash\n(.*?)```", text, flags=re.S)
    setup = [b for b in bash if "pip install" in b]
    assert len(setup) == 2
    assert "tensorid paper --quick" in setup[0] and "pytest" in setup[1]


def test_readme_fit_command_runs_as_written(tmp_path, monkeypatch):
    import json
    import shlex

    from tensorid import cli

    text = README.read_text()
    cmd = next(
        b
        for b in re.findall(r"```bash\n(.*?)```", text, flags=re.S)
        if b.startswith("tensorid fit")
    )
    args = shlex.split(cmd.replace("\\\n", " "))[1:]
    monkeypatch.chdir(README.parent)
    args[args.index("--out") + 1] = str(tmp_path / "fit")
    assert cli.main(args + ["--no-progress"]) == 0
    d = json.loads((tmp_path / "fit" / "fit.json").read_text())
    assert d["success"] and d["gof"]["validation"]["validate"]["y"] > 0.97
    # the model file shown in the README is the one that ships
    shown = re.search(r"```\n(rhs = .*?)```", text, flags=re.S).group(1)
    shipped = (README.parent / "examples/silverbox/model.py").read_text()
    assert all(line in shipped for line in shown.strip().splitlines())
