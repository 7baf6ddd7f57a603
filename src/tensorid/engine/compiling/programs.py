"""Compiled sweeps kept across processes as traced programs (``jax.export``), so that
a second process skips tracing and lowering them, not only XLA's compilation.

JAX's persistent compilation cache (``_config.py``) keeps what XLA compiled, but each
new process still traces the sweeps' Python (nested forward-mode derivatives of the
model through the integrator) and lowers them before it can look the result up:
0.05-0.3 s per program, several programs per command-line fit, where the fit itself
takes hundredths of a second. Here each program, once traced, is also written to
disk as an exported StableHLO module; a later process reads it back (about a
millisecond) and hands it to XLA, whose own cache then answers. Beside it the
executable XLA compiled from it is kept too (:mod:`.executables`), which a later
process on the same kind of machine loads without lowering anything.

A program is only reused when it would be traced exactly the same. Its key is a
digest of everything the trace depends on:

- the model's F and C as JAX itself sees them (their jaxprs at the model's shapes,
  with the values of any arrays they close over) and its shapes and names;
- the sweep structure: which initial states and parameters are free, the
  discretisation (the scheme's tableau, substeps, tolerances), the loss, the
  predictor, and which entry point (batched or not);
- the arguments' shapes and dtypes;
- this package's source code, the versions of JAX and jaxlib, the backend and the
  numerical settings of JAX (64-bit, matmul precision, promotion rules).

A model whose jaxpr holds a custom derivative or batching rule, a callback or any
other function-valued parameter is not kept (a rule is not part of the printed
jaxpr, so a changed rule could not be told apart), nor a scheme, loss or predictor
that is not one of tensorid's own (a user's scheme object is traced but only its
``repr`` would be keyed), nor anything once a source file of tensorid changed after
it was imported (the running code is then not the code on disk), nor anything when
the compilation cache is off (``TENSORID_CACHE=0``). Each file carries a digest of
its contents, checked when it is read. Whatever goes
wrong here (no ``flatbuffers``, a file that cannot be read or written, a program
JAX cannot export), the sweep is traced and compiled as before: this only saves
time, it never changes a number.
"""

from __future__ import annotations

import hashlib
import os
import tempfile
import threading
from collections import OrderedDict
from concurrent.futures import Future
from pathlib import Path

import jax
import numpy as np

from ..._state import state
from . import executables
from .compilation import announced, describe
from .pruning import prune as _prune

_NOT_KEPT = ("custom_jvp", "custom_vjp", "custom_vmap", "callback", "debug", "<function", "0x")
_SETTINGS = (
    "jax_enable_x64",
    "jax_default_matmul_precision",
    "jax_numpy_dtype_promotion",
    "jax_numpy_rank_promotion",
)


def _sources() -> dict[Path, tuple[int, int]]:
    """(mtime, size) of each source file of tensorid (regular files, no editor's
    dotfiles)."""
    root = Path(__file__).resolve().parents[2]  # tensorid/, above engine/compiling/
    out = {}
    for path in sorted(root.rglob("*.py")):
        if path.name.startswith(".") or not path.is_file():
            continue
        st = path.stat()
        out[path] = (st.st_mtime_ns, st.st_size)
    return out


try:  # what this process imported: a program is only kept while the disk still has it
    _IMPORTED: dict[Path, tuple[int, int]] | None = _sources()
except OSError:
    _IMPORTED = None


def folder() -> Path | None:
    """Where programs are kept: in JAX's compilation cache folder, as ``programs``
    (everything under the one folder TENSORID_CACHE_DIR names), or None when that
    cache is off or TENSORID_PROGRAMS is 0
    (the compiled code is then still cached; a first process pays 10-20 % more
    compile time for writing its programs, which the test suite, compiling hundreds
    once each, does without)."""
    if os.environ.get("TENSORID_PROGRAMS", "1").strip().lower() in ("0", "false", "no", "off"):
        return None
    if not jax.config.values.get("jax_enable_compilation_cache", False):
        return None
    cache = jax.config.values.get("jax_compilation_cache_dir")
    if not cache:
        return None
    return Path(cache) / "programs"


def _package_digest() -> str | None:
    """Of every source file of tensorid and its version, computed once per process;
    None when the files are not there (an installation without sources) or changed
    since this process imported them."""
    if _IMPORTED is None or not _IMPORTED or _sources() != _IMPORTED:
        return None
    if state.source_digest is None:
        from ... import _config

        h = hashlib.sha256(_config.__version__.encode())
        root = Path(__file__).resolve().parents[2]  # tensorid/, above engine/compiling/
        for path in _IMPORTED:
            h.update(str(path.relative_to(root)).encode())
            h.update(path.read_bytes())
        state.source_digest = h.hexdigest()
    return state.source_digest


def _jax_digest() -> str:
    """JAX's version, backend and numerical settings as they hold now (on this thread:
    context managers such as jax.default_matmul_precision included)."""
    import jaxlib.version

    settings = [getattr(jax.config, k, None) for k in _SETTINGS]
    return f"{jax.__version__} {jaxlib.version.__version__} {jax.default_backend()} {settings}"


def _consts(jaxpr, h) -> None:
    """Add the values of the arrays every (nested) jaxpr closes over to ``h``: a helper
    under jax.jit keeps its constants in its own jaxpr, which printing does not show."""
    try:  # loaded with jax; jax.extend's public names cost an import of 20 ms
        from jax._src.core import ClosedJaxpr, Jaxpr
    except ImportError:
        from jax.extend.core import ClosedJaxpr, Jaxpr

    closed = isinstance(jaxpr, ClosedJaxpr)
    for c in jaxpr.consts if closed else ():
        a = np.asarray(c)
        h.update(f"{a.dtype}{a.shape}".encode())
        h.update(a.tobytes())
    for eqn in (jaxpr.jaxpr if closed else jaxpr).eqns:
        for value in eqn.params.values():
            for v in value if isinstance(value, tuple | list) else (value,):
                if isinstance(v, ClosedJaxpr | Jaxpr):
                    _consts(v, h)


def model_digest(model) -> str | None:
    """Of the model as JAX traces it; None when it cannot be keyed safely."""
    cache = model.compiled_sweeps
    if "program digest" in cache:
        return cache["program digest"]
    digest: str | None = None
    try:
        x, p, u = (jax.ShapeDtypeStruct((n,), np.float64) for n in (model.N, model.M, model.U))
        jaxprs = [
            jax.make_jaxpr(model.f)(x, p, u),
            jax.make_jaxpr(model.h)(x, p, *([u] if model.reads_inputs else [])),
        ]
        text = "\n".join(str(j) for j in jaxprs)
        if not any(word in text for word in _NOT_KEPT):
            h = hashlib.sha256(text.encode())
            for j in jaxprs:
                _consts(j, h)
            names = (model.states, model.params, model.inputs, model.outputs)
            h.update(repr((names, model.discrete, model.input_delays)).encode())
            digest = h.hexdigest()
    except Exception:  # a model JAX cannot trace abstractly here: not kept
        digest = None
    cache["program digest"] = digest
    return digest


def _ours(obj) -> bool:
    """A scheme, loss or predictor of tensorid's own, whose repr says all it does."""
    text = repr(obj)
    return type(obj).__module__.startswith("tensorid.") and not any(
        w in text for w in (" at 0x", "array(", "...")
    )


def _key(sweeps, entry: str, leaves, treedef) -> str | None:
    parts = (sweeps.discretisation.scheme, sweeps.discretisation, sweeps.loss, sweeps.predictor)
    if not all(_ours(x) for x in parts):
        return None
    model, package = model_digest(sweeps.model), _package_digest()
    if model is None or package is None:
        return None
    structure: tuple = (
        sweeps.free_states,
        sweeps.free_params,
        sweeps.discretisation,
        sweeps.loss,
        sweeps.predictor,
        entry,
        str(treedef),
        [(tuple(a.shape), str(a.dtype), bool(getattr(a, "weak_type", False))) for a in leaves],
    )
    if sweeps.dosing is not None:  # the events' targets and amounts are in the program
        structure += (sweeps.dosing,)
    text = f"{package}\n{_jax_digest()}\n{model}\n{structure!r}"
    # named by the package's version first, so that other versions' files can be told
    return f"{package[:8]}-{hashlib.sha256(text.encode()).hexdigest()[:40]}"


class Program:
    """A sweep's compiled entry point that reads its traced program from disk where a
    previous process left it (see the module's docstring), one per argument shape."""

    def __init__(self, jitted, sweeps, entry: str) -> None:
        self.jitted, self.sweeps, self.entry = jitted, sweeps, entry
        self._runs: dict = {}
        self._lock = threading.Lock()
        self._exported: dict = {}  # (key, exported) traced ahead by trace_ahead
        self._pending: dict = {}  # being read by load_kept: Futures of (run, file)

    def __call__(self, *args):
        leaves, treedef = jax.tree_util.tree_flatten(args)
        plain = all(
            isinstance(a, jax.Array | np.ndarray) and not isinstance(a, jax.core.Tracer)
            for a in leaves
        )
        if not plain:  # under a transformation (or odd arguments): what jit does
            return self.jitted(*args)
        shapes = (treedef, tuple((a.shape, a.dtype) for a in leaves))
        run = self._runs.get(shapes)
        if run is not None:
            return run(*args)
        with self._lock:
            run = self._runs.get(shapes)
            if run is not None:  # another thread compiled it meanwhile
                return run(*args)
            with announced(describe(self.entry)):  # the console's progress line
                return self._first(args, leaves, treedef, shapes)

    def trace_ahead(self, *args) -> None:
        """Trace (export) the program for ``args`` here and now, where no process kept
        it, so that its first call, made in another thread, only compiles: XLA runs
        without the GIL, tracing holds it, and two threads tracing at once each take
        as long as both (a population fit's first outer evaluation compiled in a
        second thread, 6 s of trace beside the inner steps' own, instead of 3). Does
        nothing where it is kept, exported already, or not kept at all."""
        leaves, treedef, shapes = _shapes(args)
        with self._lock:
            if shapes in self._runs or shapes in self._exported or shapes in self._pending:
                return
            try:
                at = self._kept_at(leaves, treedef)
                if at is None or executables.path_for(*at).exists():
                    return
                where, key = at
                path = where / f"{key}.jaxexport"
                if path.exists():
                    return
                with announced(describe(self.entry)):
                    self._exported[shapes] = (key, _exported(self.jitted, args, path, where, key))
            except Exception:  # the first call traces it itself
                return

    def load_kept(self, *args) -> None:
        """Read the executable an earlier process kept for ``args``' shapes, if there is
        one, for a first call that may come meanwhile from another thread (it waits for
        this read, not for the Program's lock, which is not held while reading; the
        read executable is still tried before it is trusted, as any). Nothing is traced
        or compiled here."""
        leaves, treedef, shapes = _shapes(args)
        with self._lock:
            if shapes in self._runs or shapes in self._pending:
                return
            at = self._kept_at(leaves, treedef)
            path = None if at is None else executables.path_for(*at)
            if path is None or not path.exists():
                return
            pending = self._pending[shapes] = Future()
        run = None
        try:
            run = executables.load(path)  # (without the GIL, mostly)
        finally:  # a first call waits for this: it is always answered
            pending.set_result(None if run is None else (run, path))

    def _kept_at(self, leaves, treedef) -> tuple[Path, str] | None:
        """(the folder, the key) this program is kept under for these arguments (each
        thread's own: JAX's settings are per thread), or None where it is not kept."""
        try:
            where = folder()
            key = None if where is None else _key(self.sweeps, self.entry, leaves, treedef)
        except Exception:  # whatever keeps a key from being made: not kept
            return None
        return None if where is None or key is None else (where, key)

    def _first(self, args, leaves, treedef, shapes):
        """The first call for these shapes: compiled (or read), kept and run."""
        run, path = self._prepare(args, leaves, treedef, shapes)
        if run is self.jitted:
            self._runs[shapes] = run
            return run(*args)
        try:  # the first call runs what was read: where even that fails, jit
            out = jax.block_until_ready(run(*args))  # an executable's fails late
        except Exception:
            if path is not None:
                path.unlink(missing_ok=True)  # so that the next process traces anew
            run = self.jitted
            out = run(*args)
        self._runs[shapes] = run
        return out

    def _prepare(self, args, leaves, treedef, shapes):
        """(what runs for these shapes, and its file): the executable kept by an
        earlier process, else the exported program (read, or traced and written)
        compiled and its executable kept; or (the plain jit, None) where nothing can
        be kept."""
        at = self._kept_at(leaves, treedef)
        if at is None:  # no program is kept: the compiled code is capped all the same
            _prune(None, "")
            return self.jitted, None
        where, key = at
        kept = executables.path_for(where, key)
        pending = self._pending.pop(shapes, None)  # read by load_kept (its key: this
        # thread's settings may differ from the reading thread's, JAX's are per thread)
        if pending is not None and pending.result() is not None and pending.result()[1] == kept:
            return pending.result()
        run = executables.load(kept)
        if run is not None:  # compiled by an earlier process: neither lowered nor looked up
            return run, kept
        path = where / f"{key}.jaxexport"
        ahead, exported = self._exported.pop(shapes, (None, None))  # (traced for this key)
        exported = exported if ahead == key else _read(path)
        if exported is None:  # not there yet, or damaged: trace it now
            try:
                exported = _exported(self.jitted, args, path, where, key)
            except Exception:
                return self.jitted, None
        jitted = jax.jit(_named(exported.call, key))
        run = executables.compile_and_keep(jitted, args, kept, _write)
        if run is not None:
            return run, kept
        return jitted, path


class KeptStructures:
    """Programs kept in this process per structure (a population objective's model,
    discretisation, random effects, method, …): those of the ``limit`` structures used
    last. A structure's programs hold its compiled executables and its model, tens of
    MB; a process that fits many models (a notebook, a worker, a scan over model
    variants) would otherwise keep every one it ever compiled. A structure pushed out
    and asked for again reads its programs from disk (or traces them) anew."""

    def __init__(self, limit: int = 8):
        self.limit = limit
        self._kept: OrderedDict = OrderedDict()
        self._lock = threading.Lock()

    def programs(self, key) -> dict:
        """The programs kept under ``key`` (an empty dict to fill where none are),
        now the last used; the oldest structure beyond ``limit`` is let go."""
        with self._lock:
            kept = self._kept.setdefault(key, {})
            self._kept.move_to_end(key)
            while len(self._kept) > self.limit:
                self._kept.popitem(last=False)
            return kept

    def get(self, key, default=None):
        """The programs kept under ``key`` (now the last used), or ``default``."""
        with self._lock:
            if key not in self._kept:
                return default
            self._kept.move_to_end(key)
            return self._kept[key]

    def __len__(self) -> int:
        return len(self._kept)


def _shapes(args) -> tuple:
    """(leaves, treedef, the shapes a program is compiled for) of ``args``."""
    leaves, treedef = jax.tree_util.tree_flatten(args)
    return leaves, treedef, (treedef, tuple((a.shape, a.dtype) for a in leaves))


def _named(call, key: str):
    """``call`` under a name made of the program's key. JAX's compilation cache keys a
    module by its name as well as its contents, so another version of tensorid whose
    traced program is the same compiles it anew, and keeps the executable, instead of
    being handed JAX's cached copy, which cannot be kept (:mod:`.executables`): every
    later process of that version would have rebuilt it from JAX's cache (1.5 s of a
    warm theophylline fit's 3.2 s). The first fit after an upgrade compiles, once."""

    def named(*args):
        return call(*args)

    named.__name__ = named.__qualname__ = "kept_" + key.replace("-", "_")
    return named


def _exported(jitted, args, path: Path, where: Path, key: str):
    """``jitted`` traced and exported at ``args``' shapes, and written to ``path``."""
    from jax import export

    specs = jax.tree_util.tree_map(lambda a: jax.ShapeDtypeStruct(a.shape, a.dtype), args)
    exported = export.export(jitted)(*specs)
    _write(path, exported.serialize())
    _prune(where, key[:8])
    return exported


def _read(path: Path):
    """The exported program in ``path``, or None where it is missing or its contents
    do not match the digest written with them."""
    from jax import export

    try:
        data = path.read_bytes()
        digest, payload = data[:32], data[32:]
        if hashlib.sha256(payload).digest() != digest:
            return None
        exported = export.deserialize(bytearray(payload))
    except Exception:
        return None
    try:
        os.utime(path)  # in use: not pruned
    except OSError:
        pass
    return exported


def _write(path: Path, data: bytes | bytearray) -> bool:
    """Atomically and with a digest of the contents, so that a process reading it never
    uses half a program; a folder that cannot be written only means the next process
    traces again. Whether it was written."""
    tmp = None
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".part")
        with os.fdopen(fd, "wb") as f:
            f.write(hashlib.sha256(data).digest() + data)
        os.replace(tmp, path)
        tmp = None
    except OSError:
        return False
    finally:  # also after Ctrl-C: no half-written file is left behind
        if tmp is not None:
            Path(tmp).unlink(missing_ok=True)
    return True
