"""Where results are written, so that nothing a user computed is lost to a bad
destination or a failing write.

The destination is checked before any work (``check_destination``); every file is
written to a temporary name beside its target and renamed into place, so a full disk
or an interrupt leaves either the old file or the new one, never a truncated one. A
run holds its folder with a lock file (``claimed``), and a rerun removes what the
earlier run wrote and it did not (``replace_outputs``, from a manifest), so a folder
never holds a mix of two runs' results.
"""

from __future__ import annotations

import os
import tempfile
from collections.abc import Callable, Iterator
from contextlib import contextmanager
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


LOCK = ".tensorid.lock"
MANIFEST = ".tensorid-files"
# what a fit wrote before folders had a manifest (tensorid 0.1.0 and older)
_LEGACY = ("fit.json", "report.md", "convergence.png", "train_*.png", "validation_*.png")


def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # someone else's process: alive
        return True
    return True


@contextmanager
def claimed(folder, what: str = "--out") -> Iterator[Path]:
    """Hold ``folder`` for this run: it is created, and a lock file in it keeps a
    second run from writing into it at the same time (one clear line instead of two
    runs overwriting each other's files). A lock left by a run that died is taken
    over; the lock is removed when the run ends, however it ends."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    lock = folder / LOCK
    for _ in range(2):
        try:
            fd = os.open(lock, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o644)
            break
        except FileExistsError:
            try:
                pid = int(lock.read_text().strip() or 0)
            except (OSError, ValueError):
                pid = 0
            if pid and pid != os.getpid() and _pid_alive(pid):
                raise ValueError(
                    f"{what} {folder} is being written by another tensorid run (process "
                    f"{pid}); wait for it to finish or choose another folder"
                ) from None
            lock.unlink(missing_ok=True)  # its run died: take the folder over
    else:
        raise ValueError(f"{what} {folder}: could not take its lock file {lock}; remove it")
    with os.fdopen(fd, "w") as f:
        f.write(f"{os.getpid()}\n")
    try:
        yield folder
    finally:
        lock.unlink(missing_ok=True)


def previous_outputs(folder: Path) -> set[Path]:
    """The files an earlier run wrote into ``folder`` (from its manifest; for a folder
    written before manifests, the file names a fit has always used)."""
    manifest = folder / MANIFEST
    if manifest.is_file():
        names = [n for n in manifest.read_text().splitlines() if n and "/" not in n]
        return {folder / n for n in names if n not in (".", "..")}
    return {p for pattern in _LEGACY for p in folder.glob(pattern)}


def replace_outputs(folder: Path, old: set[Path], written: list[Path]) -> list[Path]:
    """After a run wrote ``written``: remove what the earlier run wrote and this one
    did not (a rerun never leaves a mix of old and new results), then record this
    run's files in the manifest. Returns the files removed."""
    removed = []
    for p in sorted(old - set(written)):
        if p.is_file():
            p.unlink()
            removed.append(p)
    write_text(folder / MANIFEST, "".join(f"{p.name}\n" for p in written))
    return removed
