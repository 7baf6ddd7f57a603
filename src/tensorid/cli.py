"""The command line: ``tensorid paper | fit | simulate``. The application's commands
and the paper study each register their own subcommand here, at the top of the
package, so that no layer imports the one above it."""

from __future__ import annotations

import argparse
import atexit
import os
import signal
import sys
import threading
from functools import partial

from .app import cli as app_cli
from .paper import command as paper_command


def build_parser() -> argparse.ArgumentParser:
    ap = app_cli.Parser(
        prog="tensorid",
        description="Grey-box system identification with exact gradients and Hessians "
        "from state/parameter transition tensors.",
    )
    ap.add_argument("--version", action="version", version=_version())
    sub = ap.add_subparsers(dest="command", required=True)
    paper_command.register(sub)
    app_cli.register(sub)
    return ap


def _version() -> str:
    """tensorid's version, with the versions its numbers rest on."""
    import platform

    import jax
    import numpy

    from ._config import __version__

    return (
        f"tensorid {__version__} (JAX {jax.__version__}, NumPy {numpy.__version__}, "
        f"Python {platform.python_version()})"
    )


def main(argv: list[str] | None = None) -> int:
    return app_cli.run(build_parser(), argv)


def console() -> None:
    """The ``tensorid`` command: :func:`main`, then out without the interpreter's
    teardown. Freeing JAX's compiled programs and modules one by one takes 0.3-0.5 s
    after the work is done and every file is closed; what a normal exit runs first still
    runs (joining threads, the pools' and the exit handlers: logging, Dask, temporary
    folders), and the output is flushed (a failed flush exits 120, as Python does).
    Under a profiler or tracer it exits normally, so that they can write their output."""
    code = main()
    if sys.getprofile() is not None or sys.gettrace() is not None:
        sys.exit(code)
    pressed: list[int] = []
    try:  # Ctrl-C from here on lands in the exit handlers (JAX's): said as in a command
        signal.signal(signal.SIGINT, partial(_interrupted_late, pressed))
        getattr(threading, "_shutdown", lambda: None)()
        atexit._run_exitfuncs()
    except KeyboardInterrupt:  # before the handler was in place
        pressed.append(1)
    if pressed:
        print("tensorid: interrupted", file=sys.stderr)
        code = 130
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except BrokenPipeError:  # the reader went away: nothing more can be said there
            pass
        except (OSError, ValueError):
            code = code or 120
    os._exit(code)


def _interrupted_late(pressed: list[int], signum, frame) -> None:
    """Ctrl-C after the command's work, while the exit handlers run: noted (the exit
    status becomes 130, as Ctrl-C during the work gives), not raised into a handler
    (Python would print "Exception ignored in atexit callback" and its traceback); a
    second Ctrl-C leaves at once."""
    pressed.append(signum)
    if len(pressed) > 1:
        print("tensorid: interrupted", file=sys.stderr, flush=True)
        os._exit(130)


if __name__ == "__main__":
    console()
