"""Where results are written, so that nothing a user computed is lost to a bad
destination or a failing write.

The destination is checked before any work (``check_destination``); every file is
written to a temporary name beside its target and renamed into place, so a full disk
or an interrupt leaves either the old file or the new one, never a truncated one.
"""

from __future__ import annotations

import os
import tempfile
from collections.abc import Callable
from pathlib import Path


def check_destination(folder, what: str = "--out") -> Path:
    """A folder that can be created or written to; a one-line ValueError that names it
    and says what to do otherwise (raised before any work is done)."""
    folder = Path(folder)
    if folder.exists() and not folder.is_dir():
        raise ValueError(f"{what} {folder} is a file, not a folder; give a folder name")
    parent = folder
    while not parent.exists():
        parent = parent.parent
    if not parent.is_dir():
        raise ValueError(f"{what} {folder} lies under {parent}, which is a file; choose another")
    if not os.access(parent, os.W_OK | os.X_OK):
        raise ValueError(
            f"{what} {folder}: {parent} is not writable; choose a folder you can write to"
        )
    return folder


def write_atomic(path: Path, write: Callable[[Path], object]) -> Path:
    """``write(tmp)`` to a temporary file beside ``path``, then rename it into place;
    the temporary file is removed if the write fails."""
    path = Path(path)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".part", dir=path.parent)
    os.close(fd)
    try:
        write(Path(tmp))
        # mkstemp makes the file private (0600); give it the mode a plain write would
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp, 0o666 & ~umask)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return path


def write_text(path: Path, text: str) -> Path:
    return write_atomic(path, lambda tmp: tmp.write_text(text))
