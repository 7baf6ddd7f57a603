"""JAX configuration shared by every module.

Identification needs float64: the Silverbox cost Hessian spans ~18 orders of
magnitude before scaling, and exactness tests compare to 1e-9 relative.

Compiled sweeps are kept on disk by default (JAX's persistent compilation cache), so
that a second process fitting the same problem skips most of the compilation, which
is seconds against fits of a fraction of one. ``TENSORID_CACHE=0`` in the
environment or ``disable_compilation_cache()`` turns it off.

XLA's CPU runtime runs a loop's operations one kernel call at a time (tens of
nanoseconds each) unless the loop is small by the bytes it carries, when it compiles
the whole loop into one function; its limit, 1 KB, leaves out every sweep over a
record (it carries the record's buffers). ``import tensorid`` raises it to 16 MB where
JAX has not started yet (:func:`add_xla_flags`): the Silverbox simulation then takes
0.29 ms instead of 1.1, its (J, ∇J, ∇²J) 2.6 ms instead of 4.3 (2-core machine;
benchmarks/bench_derivatives.py). Loops with matrix products are never compiled so
(XLA keeps those for its threaded library), so large models are not slowed. An
XLA_FLAGS of the user's own with --xla_backend_extra_options, or naming a file of
flags, is left as it is.

XLA's newer CPU fusion emitters are turned off (``--xla_cpu_use_fusion_emitters=
false``, unless the user's XLA_FLAGS name it; on the jaxlib versions that know the
flag, EMITTERS_FLAG_VERSIONS): with them a first fit spends 10-25 %
longer compiling (two-tank's filter (J, ∇J, ∇²J) 2.6-2.9 s against 2.1-2.2 s, the
chain of 16 masses' adjoint 2.0-2.1 against 1.8-1.9 s) and the compiled programs run
no faster (within ±5 % on Silverbox, two-tank, its filter and the chain). The
numbers are the same to rounding (J, ∇J, ∇²J within 1.5e-16 relative, most bit for
bit: benchmarks/numbers_fingerprint.py), so a fit that ends at a threshold may fall
the other side of it (docs/robust.md, the two-tank filter).

XLA's YNNPACK library fusions are turned off as well
(``--xla_cpu_experimental_ynn_fusion_type=``, on the jaxlib versions that know it,
YNN_FLAG_VERSIONS; a user's XLA_FLAGS naming it wins). An executable read back from
disk sets its library fusions up at its first call: theophylline's outer evaluation
took 0.14 s there against 0.01 s for each later call, and a warm population fit took
2.25-2.36 s with them against 1.98-2.08 s without (5 alternating pairs, 2-core
machine). The price is its first, cold fit: 11.1-11.4 s against 11.6-11.8 s (XLA
compiles the products itself). Per call they bought nothing measurable (Silverbox's
(J, ∇J, ∇²J) 1.99 against 2.01 ms, the chain's adjoint 42.8 against 39.7 ms:
benchmarks/bench_edge.py), and single-record first fits compile no slower without
them (benchmarks/bench_first_fit.py). Other projects report wrong values from these
fusions on jaxlib 0.11 and turn them off with the same flag.
"""

import os
import re
import sys

import jax

from ._early import cores  # noqa: F401  (here for the engine, which reads _config)

__version__ = "0.1.0"


# bytes a loop may carry and still be compiled as one function (XLA's default: 1 KB)
SMALL_LOOP_BYTES = 1 << 24


def add_xla_flags(*flags: str) -> bool:
    """Append ``flags`` (``--name=value``) to $XLA_FLAGS, each unless the variable
    already names it (the user's or an earlier setting wins). XLA reads the variable
    once, when JAX starts its first backend: after that nothing changes in this
    process, and it returns False (child processes still inherit the variable). A
    variable that names a file of flags (it does not start with "-") is left alone:
    XLA would read the appended flags as part of the file's name."""
    have = os.environ.get("XLA_FLAGS", "")
    if have.strip() and not have.lstrip().startswith("-"):
        return False
    names = {f.split("=")[0].lstrip("-") for f in have.split()}
    new = [f for f in flags if f.split("=")[0].lstrip("-") not in names]
    if new:
        os.environ["XLA_FLAGS"] = " ".join([have, *new]).strip()
    try:  # JAX's own, private: where it is gone, assume JAX has not started
        from jax._src.xla_bridge import backends_are_initialized
    except ImportError:
        return True
    return not backends_are_initialized()


# jaxlib versions whose XLA knows --xla_cpu_use_fusion_emitters: XLA aborts the
# process (uncatchable) on a flag it does not know, and jaxlib 0.4.30-0.5.1 do not
# know this one; it is set only on the versions it was measured or found on
EMITTERS_FLAG_VERSIONS = ((0, 5, 3), (0, 11))
# jaxlib versions whose XLA knows --xla_cpu_experimental_ynn_fusion_type: from 0.8.1
# (its wheels' libraries name it; 0.8.0's do not), through 0.11 (where it is reported
# as the cure for miscompiled fusions). By release number: a development build of
# 0.8.1 older than the flag would abort, as would a child process with an older
# jaxlib that inherits the variable (as with the emitters flag)
YNN_FLAG_VERSIONS = ((0, 8, 1), (0, 12))
YNN_FLAG = "xla_cpu_experimental_ynn_fusion_type"


def _jaxlib_version() -> tuple[int, ...]:
    """jaxlib's version as numbers (0.10.2 → (0, 10, 2)); () where it cannot be read."""
    try:  # jaxlib's own, loaded with jax: no package metadata to read at import
        from jaxlib.version import __version__ as text
    except ImportError:
        return ()
    return tuple(int(m) for m in re.findall(r"\d+", text.split("+")[0])[:3])


def _xla_flags() -> list[str]:
    loops = f"xla_cpu_small_while_loop_byte_threshold={SMALL_LOOP_BYTES}"
    flags = [f"--xla_backend_extra_options={loops}"]
    version = _jaxlib_version()
    low, high = EMITTERS_FLAG_VERSIONS
    if low <= version < high:
        flags.append("--xla_cpu_use_fusion_emitters=false")
    low, high = YNN_FLAG_VERSIONS
    if low <= version < high:
        flags.append(f"--{YNN_FLAG}=")
    return flags


add_xla_flags(*_xla_flags())
jax.config.update("jax_enable_x64", True)


def _lapack_without_scipy_linalg() -> bool:
    """Hand JAX its CPU LAPACK kernels now, from SciPy's two Cython modules alone.
    JAX takes them from ``scipy.linalg.cython_blas`` and ``cython_lapack`` at its first
    compile, and importing those runs ``scipy.linalg``'s package first: 0.1-0.16 s of
    a 1.7 s command, for a package tensorid's commands do not otherwise use. Loading
    the two extension files directly takes 8 ms. They are taken out of sys.modules
    again once JAX holds the kernels, so that a later ``import scipy.linalg`` is the
    usual one. Where anything differs (SciPy already imported, another layout, JAX's
    private call gone) nothing is done and JAX imports SciPy as it always did.
    Returns whether the kernels were handed over."""
    import importlib.machinery
    import importlib.util

    if "scipy.linalg" in sys.modules:
        return False
    loaded = []
    try:
        from jax._src.lib import lapack

        scipy = importlib.util.find_spec("scipy")
        if scipy is None or not scipy.submodule_search_locations:
            return False
        folder = os.path.join(list(scipy.submodule_search_locations)[0], "linalg")
        for name in ("cython_blas", "cython_lapack"):
            path = next(
                os.path.join(folder, name + suffix)
                for suffix in importlib.machinery.EXTENSION_SUFFIXES
                if os.path.exists(os.path.join(folder, name + suffix))
            )
            spec = importlib.util.spec_from_file_location(f"scipy.linalg.{name}", path)
            if spec is None or spec.loader is None:
                return False
            module = importlib.util.module_from_spec(spec)
            sys.modules[spec.name] = module
            loaded.append(spec.name)
            spec.loader.exec_module(module)
        lapack._lapack.initialize()
        return True
    except Exception:  # noqa: BLE001 - any surprise: JAX does it its own way later
        return False
    finally:
        for name in loaded:
            sys.modules.pop(name, None)


_lapack_without_scipy_linalg()

_OFF = ("0", "false", "no", "off")
# the compilation-cache folder tensorid chose (and keeps to a size); not one that the
# user gave JAX itself, which other programs may share
own_cache: str | None = None


def enable_compilation_cache(path=None) -> str:
    """Keep compiled sweeps on disk so that the next process skips compilation
    (JAX's persistent compilation cache). ``path`` defaults to $TENSORID_CACHE_DIR
    or ~/.cache/tensorid/jax. ``import tensorid`` already does this unless
    $TENSORID_CACHE is 0 or JAX was given a cache folder of its own; call it to choose
    another folder. tensorid keeps the folder to 1 GB, the least recently used code
    going first (a folder given to JAX itself is left as it is). Returns the folder
    used."""
    from pathlib import Path

    from jax.experimental.compilation_cache import compilation_cache

    folder = Path(
        path or os.environ.get("TENSORID_CACHE_DIR") or Path.home() / ".cache/tensorid/jax"
    )
    folder.mkdir(parents=True, exist_ok=True)
    jax.config.update("jax_enable_compilation_cache", True)
    jax.config.update("jax_compilation_cache_dir", str(folder))
    # our sweeps compile in 0.1-3 s: cache them all, not only the > 1 s default
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
    jax.config.update("jax_persistent_cache_min_entry_size_bytes", 0)
    compilation_cache.reset_cache()  # JAX reads the folder once, at the first compile
    global own_cache
    own_cache = str(folder)
    return str(folder)


def disable_compilation_cache() -> None:
    """Compile everything in this process afresh and write nothing to disk (the
    same as TENSORID_CACHE=0 in the environment before ``import tensorid``)."""
    from jax.experimental.compilation_cache import compilation_cache

    jax.config.update("jax_enable_compilation_cache", False)
    compilation_cache.reset_cache()


def default_compilation_cache() -> str | None:
    """The cache as ``import tensorid`` and the command line set it up: on, in the
    default folder, unless $TENSORID_CACHE says off or JAX already has a folder (the
    user's own choice). A folder that cannot be made only leaves the cache off: a
    read-only home must not stop a fit. Returns the folder, or None when off."""
    if os.environ.get("TENSORID_CACHE", "1").strip().lower() in _OFF:
        disable_compilation_cache()
        return None
    own = jax.config.values.get("jax_compilation_cache_dir")
    if own:
        return str(own)
    try:
        return enable_compilation_cache()
    except OSError:
        return None


default_compilation_cache()
