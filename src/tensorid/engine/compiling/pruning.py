"""The caps on what compiling leaves on disk: the kept programs and executables of
:mod:`.programs` (other versions' files unused for a month go; beyond a size cap, the
least recently used), the half-written files of killed processes, and JAX's own
compilation cache beside them. Once per process, at the first program written."""

from __future__ import annotations

import time
from pathlib import Path

import jax

from ..._state import state

STALE_DAYS = 30
MAX_BYTES = 512 * 2**20  # the folder's cap: beyond it the least recently used go
COMPILED_MAX_BYTES = 2**30  # the same for JAX's compiled code beside it


def prune(where: Path | None, current: str) -> None:
    """Once per process: remove the programs of other versions of tensorid unused for
    STALE_DAYS days, so that the folder does not grow with every upgrade, and then,
    while the folder holds more than MAX_BYTES, the least recently used programs
    (reading one marks it used) down to three quarters of that: every new record
    length or model is a new program, and nothing else would ever remove them. Also
    the half-written files of processes killed while writing (an hour old), and JAX's
    compilation cache gets the same cap (:func:`_prune_compiled`). ``where`` None: no
    program is kept in this process, only the compiled code is pruned."""
    if state.pruned:
        return
    state.pruned = True
    if where is not None:
        _prune_programs(where, current)
    _prune_own_compiled()


def _prune_programs(where: Path, current: str) -> None:
    old = time.time() - STALE_DAYS * 86400
    kept = []
    for path in (*where.glob("*.jaxexport"), *where.glob("*.xla")):
        try:
            st = path.stat()
            if not path.name.startswith(current) and st.st_mtime < old:
                path.unlink()
            else:
                kept.append((st.st_mtime, st.st_size, path))
        except OSError:
            pass
    _keep_under(kept, MAX_BYTES)
    for path in where.glob(".*.part"):  # a killed writer's: a live one's is seconds old
        try:
            if path.stat().st_mtime < time.time() - 3600:
                path.unlink()
        except OSError:
            pass


def _prune_own_compiled() -> None:
    """:func:`_prune_compiled` on the cache folder tensorid chose, if it is on."""
    from ... import _config

    settings = jax.config.values
    if settings.get("jax_enable_compilation_cache") and (
        settings.get("jax_compilation_cache_dir") == _config.own_cache
    ):
        _prune_compiled(_config.own_cache, settings.get("jax_compilation_cache_max_size", -1))


def _prune_compiled(folder: str | None, jax_cap: int) -> None:
    """JAX's compilation cache in ``folder``, which grows with every program it
    compiles (16,000 files and 310 MB on a developer's machine): kept to
    COMPILED_MAX_BYTES, the least recently used first. JAX reads its files itself,
    so "used" is the later of a file's access and modification times (at the day's
    resolution of a relatime mount). Left to JAX where the user gave it a cap of its
    own (``jax_cap``, its jax_compilation_cache_max_size, is not -1)."""
    if not folder or jax_cap != -1:
        return
    entries = []
    for path in Path(folder).glob("*-cache"):
        try:
            st = path.stat()
        except OSError:
            continue
        entries.append((max(st.st_atime, st.st_mtime), st.st_size, path))
    _keep_under(entries, COMPILED_MAX_BYTES)


def _keep_under(entries: list, cap: int) -> None:
    """Where the files of ``entries`` ((last used, size, path) each) hold more than
    ``cap`` bytes, remove the least recently used down to three quarters of it (not
    just under it: a folder at its cap would prune at every write)."""
    total = sum(size for _, size, _ in entries)
    if total <= cap:
        return
    for _, size, path in sorted(entries, key=lambda k: k[0]):
        if total <= 0.75 * cap:
            break
        try:
            path.unlink()
        except FileNotFoundError:  # another process pruning too: gone all the same
            pass
        except OSError:
            continue
        total -= size
