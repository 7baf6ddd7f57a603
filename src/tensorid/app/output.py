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
import re
import tempfile
import time
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
    tmp = None
    try:
        fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".part", dir=path.parent)
        os.close(fd)
        write(Path(tmp))
        # mkstemp makes the file private (0600); give it the mode a plain write would
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp, 0o666 & ~umask)
        os.replace(tmp, path)
    except BaseException as e:
        if tmp is not None:
            Path(tmp).unlink(missing_ok=True)
        if isinstance(e, OSError) and e.filename != str(path):
            # a full disk reports no file name, a failing mkstemp its temporary one:
            # the error names the file the user asked for
            raise OSError(e.errno, e.strerror or str(e), str(path)) from e
        raise
    return path


def write_text(path: Path, text: str) -> Path:
    return write_atomic(path, lambda tmp: tmp.write_text(text))


def write_kept(path: Path, text: str) -> tuple[Path, str | None]:
    """``text`` to ``path``, or, where that fails, to a fallback file (in the current
    folder, else the temporary folder, else the home folder) so that a failing
    destination does not lose a result. Returns (where it went, why not at ``path``:
    one line naming the file, or None). Raises OSError if no place could be written."""
    path = Path(path)
    try:
        return write_text(path, text), None
    except OSError as e:
        why = f"could not write {path}: {e.strerror or e}"
    name = f"tensorid-{path.stem}-{time.strftime('%Y%m%d-%H%M%S')}-{os.getpid()}{path.suffix}"
    for folder in (Path.cwd(), Path(tempfile.gettempdir()), Path.home()):
        try:
            return write_text(folder / name, text), why
        except OSError:
            continue
    raise OSError(f"{why}, nor {name} in the current, temporary or home folder")


LOCK = ".tensorid.lock"
MANIFEST = ".tensorid-files"
# compare and simulate keep their own: a fit in the same folder keeps its files
COMPARE_MANIFEST, SIMULATE_MANIFEST = ".tensorid-compare-files", ".tensorid-simulate-files"
# what a fit wrote before folders had a manifest (tensorid 0.1.0 and older)
_LEGACY = ("fit.json", "report.md", "convergence.png", "train_*.png", "validation_*.png")


@contextmanager
def claimed(folder, what: str = "--out") -> Iterator[Path]:
    """Hold ``folder`` for this run: it is created, and an exclusive lock on a file in
    it keeps a second run from writing into it at the same time (one clear line
    instead of two runs overwriting each other's files). The lock is the operating
    system's (flock), so a run that dies releases it; the file is removed when the
    run ends, however it ends."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    lock = folder / LOCK
    try:
        import fcntl
    except ImportError:  # no flock (Windows): no lock, as before
        yield folder
        return
    for _ in range(20):
        try:
            fd = os.open(lock, os.O_CREAT | os.O_RDWR, 0o644)
        except OSError as e:
            raise ValueError(
                f"{what} {folder}: cannot create its lock file {lock} ({e.strerror or e}); "
                "choose a folder you can write to"
            ) from None
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = os.read(fd, 64).decode(errors="replace").strip() or "?"
            os.close(fd)
            raise ValueError(
                f"{what} {folder} is being written by another tensorid run (process "
                f"{holder}); wait for it to finish or choose another folder"
            ) from None
        try:  # held; but the run before may have removed the file we opened
            if os.fstat(fd).st_ino == os.stat(lock).st_ino:
                break
        except FileNotFoundError:
            pass
        os.close(fd)
    else:
        raise ValueError(f"{what} {folder}: could not take its lock file {lock}; remove it")
    os.ftruncate(fd, 0)
    os.write(fd, f"{os.getpid()}\n".encode())
    _remove_leftovers(folder)
    try:
        yield folder
    finally:
        try:  # while still held: no other run holds this file
            lock.unlink(missing_ok=True)
        except OSError:
            pass  # a folder turned read-only keeps the file, but closing releases the lock
        finally:
            os.close(fd)


# a temporary file of write_atomic's or the renderer's: ".NAME.XXXXXXXX.part"
_PART = re.compile(r"^\.(.+\.(json|md|png|csv)|\.tensorid-files)\.[A-Za-z0-9_]{8}\.part$")


def _remove_leftovers(folder: Path, age: float = 600.0) -> None:
    """The temporary files of a run that was killed outright (kill -9, out of memory,
    power) while writing, ``age`` seconds old or more: a `simulate` writing into the
    folder does not hold it, and its file of the moment stays. Only names tensorid
    makes go: a file of the user's is never touched."""
    old = time.time() - age
    try:
        for path in folder.glob(".*.part"):
            if _PART.match(path.name) and path.stat().st_mtime < old:
                path.unlink(missing_ok=True)
    except OSError:  # a folder it cannot clean still takes the results
        pass


def _written_by_tensorid(path: Path) -> bool:
    """Whether ``path`` is a fit.json that tensorid wrote."""
    import json

    try:
        data = json.loads(path.read_text())
    except (OSError, ValueError):
        return False
    return isinstance(data, dict) and {"params", "estimates", "cost"} <= set(data)


def previous_outputs(folder: Path, manifest_name: str = MANIFEST) -> set[Path]:
    """The files an earlier run wrote into ``folder`` (from its manifest; for a folder
    written before manifests and holding a tensorid fit.json, the file names a fit has
    always used; otherwise none). ``manifest_name``: another command's manifest
    (compare and simulate keep their own, so that they never remove a fit's files)."""
    manifest = folder / manifest_name
    if manifest.is_file():
        names = [n for n in manifest.read_text().splitlines() if n and "/" not in n]
        return {folder / n for n in names if n not in (".", "..")}
    if manifest_name != MANIFEST or not _written_by_tensorid(folder / "fit.json"):
        return set()  # not a folder of tensorid results: nothing in it is ours
    return {p for pattern in _LEGACY for p in folder.glob(pattern)}


def replace_outputs(
    folder: Path, old: set[Path], written: list[Path], manifest_name: str = MANIFEST
) -> list[Path]:
    """After a run wrote ``written``: remove what the earlier run wrote and this one
    did not (a rerun never leaves a mix of old and new results), then record this
    run's files in the manifest. Returns the files removed."""
    removed = []
    for p in sorted(old - set(written)):
        if p.is_file():
            p.unlink()
            removed.append(p)
    write_text(folder / manifest_name, "".join(f"{p.name}\n" for p in written))
    return removed
