"""The command line: ``tensorid paper | fit | simulate``. The application's commands
and the paper study each register their own subcommand here, at the top of the
package, so that no layer imports the one above it."""

from __future__ import annotations

import argparse
import sys

from .app import cli as app_cli
from .paper import command as paper_command


def build_parser() -> argparse.ArgumentParser:
    ap = app_cli.Parser(
        prog="tensorid",
        description="Grey-box system identification with exact gradients and Hessians "
        "from state/parameter transition tensors.",
    )
    sub = ap.add_subparsers(dest="command", required=True)
    paper_command.register(sub)
    app_cli.register(sub)
    return ap


def main(argv: list[str] | None = None) -> int:
    return app_cli.run(build_parser(), argv)


if __name__ == "__main__":
    sys.exit(main())
