"""Compiled programs kept across processes as XLA executables, beside the traced
programs of :mod:`.programs`, so that a later process loads what XLA compiled
instead of lowering the traced program again and looking it up in JAX's
compilation cache.

A traced program read back from disk still costs its first call 10-40 ms of
lowering and 12-40 ms of the compilation cache's lookup (hashing the lowered module,
reading, loading); loading the executable itself takes 14-40 ms, with the same
numbers bit for bit (2-core machine, the six programs of the bundled Silverbox
example's command-line fit: 0.90 → 0.77 s for the command after its imports).

An executable is more particular than a traced program: it is compiled for this
machine's processor and XLA's flags. Its file is named by the traced program's key
(which holds the model, the sweep, the shapes, the package's sources and JAX's
version and settings) and a digest of what the executable depends on beyond it: the
processor (its model and feature flags), ``XLA_FLAGS``, the backend's platform
version and device kind, and JAX's settings that reach XLA's compile options (such
as ``jax_disable_most_optimizations``). A cache folder shared by machines of
different processors keeps one executable per kind.

An executable is only written when this process compiled it: one that JAX's
compilation cache handed back serializes incompletely (jaxlib 0.10.2: its call fails,
"Function ... not found", when the result is read), and JAX's switch to keep its cache
out of one compilation does not reach a cache the process has opened. So where JAX's
cache answers (a hit, counted through jax.monitoring), nothing is kept. A program is
compiled under a name made of its key (``programs._named``), which JAX's cache keys
too, so an earlier version of tensorid whose traced program was the same does not
answer for it: the new version compiles it once and keeps it. What is written is
read back and run once in a second thread, while the process goes on with what it
compiled: a file that does not work is removed there (and a later process whose
first call of a read executable fails removes it too, and compiles). Whatever else
goes wrong (a file that cannot be read or written), the plain jit runs as before;
this only saves time.
"""

from __future__ import annotations

import atexit
import hashlib
import os
import pickle
import platform
import threading
import time
from pathlib import Path

import jax

from ..._state import state

SUFFIX = ".xla"


def _processor() -> str:
    """The processor's model and feature flags (Linux: /proc/cpuinfo's first entry),
    else what the platform module says."""
    try:
        with open("/proc/cpuinfo", encoding="utf-8", errors="replace") as f:
            text = f.read(1 << 16)
        first = text.split("\n\n", 1)[0]
        keep = ("vendor_id", "cpu family", "model", "model name", "flags", "Features")
        return "\n".join(line for line in first.splitlines() if line.split(":")[0].strip() in keep)
    except OSError:
        return f"{platform.machine()} {platform.processor()}"


# JAX's settings that reach XLA's compile options (JAX's own cache keys them), not the
# traced program: an executable compiled under one is not what another would compile
_COMPILE_SETTINGS = (
    "jax_disable_most_optimizations",
    "jax_exec_time_optimization_effort",
    "jax_memory_fitting_effort",
    "jax_optimization_level",
    "jax_memory_fitting_level",
    "jax_compiler_enable_remat_pass",
    "jax_xla_profile_version",
    "jax_use_shardy_partitioner",
)


def _setting(name: str):
    value = getattr(jax.config, name, None)  # on this thread (context managers)
    return jax.config.values.get(name) if value is None else value


def machine_digest() -> str:
    """Of what an executable depends on beyond its traced program: the processor,
    XLA_FLAGS, the backend and its devices' kind (once per process) and JAX's
    compile settings (as they hold now)."""
    if state.machine is None:
        try:
            device = jax.devices()[0]
            version = f"{device.client.platform_version} {device.device_kind}"
        except Exception:  # noqa: BLE001 - only part of the digest
            version = ""
        state.machine = f"{_processor()}\n{os.environ.get('XLA_FLAGS', '')}\n{version}"
    settings = repr([_setting(name) for name in _COMPILE_SETTINGS])
    return hashlib.sha256(f"{state.machine}\n{settings}".encode()).hexdigest()[:12]


def path_for(folder: Path, key: str) -> Path:
    """The executable's file for the traced program ``key`` on this machine."""
    return folder / f"{key}-{machine_digest()}{SUFFIX}"


def _record(seconds: float) -> None:
    """Loading counts as compiling (``FitResult.compile_seconds``): it stands in for it."""
    jax.monitoring.record_event_duration_secs("/jax/core/compile/tensorid_load", seconds)


def load(path: Path):
    """The executable kept in ``path``, loaded, or None where there is none or it does
    not match the digest written with it."""
    from jax.experimental import serialize_executable

    t0 = time.perf_counter()
    try:
        data = path.read_bytes()
    except OSError:
        return None
    digest, body = data[:32], data[32:]
    try:
        if hashlib.sha256(body).digest() != digest:
            return None
        payload, in_tree, out_tree = pickle.loads(body)
        run = serialize_executable.deserialize_and_load(payload, in_tree, out_tree)
    except Exception:  # noqa: BLE001 - damaged or from another jaxlib: compile instead
        return None
    try:
        os.utime(path)  # in use: not pruned
    except OSError:
        pass
    _record(time.perf_counter() - t0)
    return run


_hits = threading.local()  # JAX's compilation cache's hits, on this thread
_listen_lock = threading.Lock()


def _count_hit(event: str, **_) -> None:
    if event == "/jax/compilation_cache/cache_hits":
        _hits.n = getattr(_hits, "n", 0) + 1


def _listen() -> None:
    with _listen_lock:
        if not state.hit_listener:
            jax.monitoring.register_event_listener(_count_hit)
            state.hit_listener = True


def compile_and_keep(jitted, args, path: Path, write):
    """``jitted`` compiled for ``args``' shapes and written to ``path`` (with
    ``write(path, bytes)``, atomic, True where written), the copy checked in a second
    thread (on an accelerator, read back first and returned: two calls at once would
    hold its memory twice): the executable to run, or None where it cannot be kept
    (then the caller's jit runs, by JAX's compilation cache). Nothing is kept where the
    folder cannot be written (each process would compile afresh, never looking in
    JAX's cache) or where JAX's cache answered the compilation (a hit: the copy would
    be incomplete, see the module's docstring)."""
    if not os.access(path.parent, os.W_OK):
        return None
    from jax.experimental import serialize_executable

    try:
        specs = jax.tree_util.tree_map(lambda a: jax.ShapeDtypeStruct(a.shape, a.dtype), args)
        _listen()
        before = getattr(_hits, "n", 0)
        compiled = jitted.trace(*specs).lower().compile()
        if getattr(_hits, "n", 0) != before:  # handed back by JAX's cache
            return None
        body = pickle.dumps(serialize_executable.serialize(compiled))
    except Exception:  # noqa: BLE001 - cannot be kept: the traced program runs
        return None
    if not write(path, body):
        return None
    if jax.default_backend() != "cpu":
        kept = load(path)  # the copy later processes will read, run here first
        return compiled if kept is None else kept
    _check_later(path, args)
    return compiled


_checks: list[threading.Thread] = []  # kept executables being checked (settle)
_checks_lock = threading.Lock()


def _check_later(path: Path, args) -> None:
    """The file just written read back and run once, in a second thread (reading does
    not hold the GIL): where that fails, the file is removed and the next process
    compiles the program again. This process runs what it compiled meanwhile: it
    waited for the read, 0.7 s of a cold theophylline fit and 2 s of its Laplace fit.
    The checks are waited for when the process ends (:func:`settle`)."""

    def run() -> None:
        try:
            kept = load(path)
            if kept is None:
                raise ValueError("unreadable")
            jax.block_until_ready(kept(*args))
        except Exception:  # noqa: BLE001 - a copy that does not work is not left
            path.unlink(missing_ok=True)

    thread = threading.Thread(target=run, name="tensorid-check-kept", daemon=True)
    with _checks_lock:
        if not _checks:
            atexit.register(settle)
        _checks.append(thread)
    thread.start()


def settle() -> None:
    """Every kept executable's check finished (none is left half-way at exit)."""
    while _checks:
        _checks.pop().join()
