"""Regenerate the figures in docs/figures from a quick paper study.

python scripts/make_doc_figures.py
"""

import shutil
import tempfile
from pathlib import Path

from tensorid import paper

DOCS = Path(__file__).resolve().parents[1] / "docs" / "figures"


def main() -> None:
    with tempfile.TemporaryDirectory() as tmp:
        paper.run(Path(tmp), starts=2, quick=True, progress=False)
        for name in (
            "silverbox_train.png",
            "silverbox_validation.png",
            "silverbox_offset_validation.png",
            "two_tank.png",
        ):
            shutil.copy(Path(tmp) / name, DOCS / name)
            print(DOCS / name)


if __name__ == "__main__":  # the study's worker processes re-import this file
    main()
