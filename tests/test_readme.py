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
