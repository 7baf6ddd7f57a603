"""Compiled sweeps kept across processes as traced programs (``jax.export``), so that
a second process skips tracing and lowering them, not only XLA's compilation.

JAX's persistent compilation cache (``_config.py``) keeps what XLA compiled, but each
new process still traces the sweeps' Python (nested forward-mode derivatives of the
model through the integrator) and lowers them before it can look the result up:
0.05-0.3 s per program, several programs per command-line fit, where the fit itself
takes hundredths of a second. Here each program, once traced, is also written to
disk as an exported StableHLO module; a later process reads it back (about a
millisecond) and hands it to XLA, whose own cache then answers.

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

A model whose jaxpr holds a custom derivative rule or a callback is not kept (a rule
is not part of the printed jaxpr, so a changed rule could not be told apart), nor is
anything when the compilation cache is off (``TENSORID_CACHE=0``). Whatever goes
wrong here (no ``flatbuffers``, a file that cannot be read or written, a program
JAX cannot export), the sweep is traced and compiled as before: this only saves
time, it never changes a number.
"""

from __future__ import annotations

import hashlib
import os
import tempfile
import threading
from pathlib import Path

import jax
import numpy as np

_NOT_KEPT = ("custom_jvp", "custom_vjp", "callback", "debug_print")
_SETTINGS = (
    "jax_enable_x64",
    "jax_default_matmul_precision",
    "jax_numpy_dtype_promotion",
    "jax_numpy_rank_promotion",
)
_source_digest: str | None = None


def folder() -> Path | None:
    """Where programs are kept: beside JAX's compilation cache (``.../jax`` →
    ``.../jax-programs``), or None when that cache is off."""
    if not jax.config.values.get("jax_enable_compilation_cache", False):
        return None
    cache = jax.config.values.get("jax_compilation_cache_dir")
    if not cache:
        return None
    return Path(cache).with_name(Path(cache).name + "-programs")


def _package_digest() -> str:
    """Of every source file of tensorid and the JAX setup (once per process)."""
    global _source_digest
    if _source_digest is None:
        import jaxlib.version

        h = hashlib.sha256()
        root = Path(__file__).resolve().parent.parent
        for path in sorted(root.rglob("*.py")):
            h.update(str(path.relative_to(root)).encode())
            h.update(path.read_bytes())
        h.update(f"{jax.__version__} {jaxlib.version.__version__} {jax.default_backend()}".encode())
        h.update(repr([jax.config.values.get(k) for k in _SETTINGS]).encode())
        _source_digest = h.hexdigest()
    return _source_digest


def model_digest(model) -> str | None:
    """Of the model as JAX traces it; None when it cannot be keyed safely."""
    cache = model.compiled_sweeps
    if "program digest" in cache:
        return cache["program digest"]
    digest: str | None = None
    try:
        x, p, u = (jax.ShapeDtypeStruct((n,), np.float64) for n in (model.N, model.M, model.U))
        jaxprs = [jax.make_jaxpr(model.f)(x, p, u), jax.make_jaxpr(model.h)(x, p)]
        text = "\n".join(str(j) for j in jaxprs)
        if not any(word in text for word in _NOT_KEPT):
            h = hashlib.sha256(text.encode())
            for c in (c for j in jaxprs for c in j.consts):
                a = np.asarray(c)
                h.update(f"{a.dtype}{a.shape}".encode())
                h.update(a.tobytes())
            names = (model.states, model.params, model.inputs, model.outputs)
            h.update(repr((names, model.discrete, model.input_delays)).encode())
            digest = h.hexdigest()
    except Exception:  # a model JAX cannot trace abstractly here: not kept
        digest = None
    cache["program digest"] = digest
    return digest


def _key(sweeps, entry: str, leaves, treedef) -> str | None:
    model = model_digest(sweeps.model)
    if model is None:
        return None
    structure = (
        sweeps.free_states,
        sweeps.free_params,
        sweeps.discretisation,
        sweeps.loss,
        sweeps.predictor,
        entry,
        str(treedef),
        [(tuple(a.shape), str(a.dtype), bool(getattr(a, "weak_type", False))) for a in leaves],
    )
    h = hashlib.sha256(f"{_package_digest()}\n{model}\n{structure!r}".encode())
    return h.hexdigest()[:40]


class Program:
    """A sweep's compiled entry point that reads its traced program from disk where a
    previous process left it (see the module's docstring), one per argument shape."""

    def __init__(self, jitted, sweeps, entry: str) -> None:
        self.jitted, self.sweeps, self.entry = jitted, sweeps, entry
        self._runs: dict = {}
        self._lock = threading.Lock()

    def __call__(self, *args):
        leaves, treedef = jax.tree_util.tree_flatten(args)
        if not all(isinstance(a, jax.Array | np.ndarray) for a in leaves):
            return self.jitted(*args)
        shapes = (str(treedef), tuple((a.shape, a.dtype) for a in leaves))
        run = self._runs.get(shapes)
        if run is not None:
            return run(*args)
        with self._lock:
            run = self._runs.get(shapes) or self._prepare(args, leaves, treedef)
            if run is self.jitted:
                self._runs[shapes] = run
                return run(*args)
            try:  # the first call lowers the read program: where even that fails, jit
                out = run(*args)
            except Exception:
                run = self.jitted
                out = run(*args)
            self._runs[shapes] = run
            return out

    def _prepare(self, args, leaves, treedef):
        """The exported program for these shapes (read, or traced and written), or the
        plain jit where it cannot be kept."""
        where = folder()
        key = None if where is None else _key(self.sweeps, self.entry, leaves, treedef)
        if key is None:
            return self.jitted
        from jax import export

        path = where / f"{key}.jaxexport"
        try:
            exported = export.deserialize(bytearray(path.read_bytes()))
        except Exception:  # not there yet, or unreadable: trace it now
            try:
                specs = jax.tree_util.tree_map(
                    lambda a: jax.ShapeDtypeStruct(a.shape, a.dtype), args
                )
                exported = export.export(self.jitted)(*specs)
                _write(path, exported.serialize())
            except Exception:
                return self.jitted
        return jax.jit(exported.call)


def _write(path: Path, data: bytes) -> None:
    """Atomically, so that a process reading it never sees half a program; a folder
    that cannot be written only means the next process traces again."""
    tmp = None
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".part")
        with os.fdopen(fd, "wb") as f:
            f.write(data)
        os.replace(tmp, path)
    except OSError:
        if tmp is not None:
            Path(tmp).unlink(missing_ok=True)
