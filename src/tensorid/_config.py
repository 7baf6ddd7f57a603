"""JAX configuration shared by every module.

Identification needs float64: the Silverbox cost Hessian spans ~18 orders of
magnitude before scaling, and exactness tests compare to 1e-9 relative.
"""

import jax

__version__ = "0.1.0"

jax.config.update("jax_enable_x64", True)


def enable_compilation_cache(path=None) -> str:
    """Keep compiled sweeps on disk so that the next process skips compilation
    (JAX's persistent compilation cache). ``path`` defaults to $TENSORID_CACHE_DIR
    or ~/.cache/tensorid/jax. The command-line tool turns this on; call it yourself
    in scripts. Returns the folder used."""
    import os
    from pathlib import Path

    folder = Path(
        path or os.environ.get("TENSORID_CACHE_DIR") or Path.home() / ".cache/tensorid/jax"
    )
    folder.mkdir(parents=True, exist_ok=True)
    jax.config.update("jax_compilation_cache_dir", str(folder))
    # our sweeps compile in 0.1-3 s: cache them all, not only the > 1 s default
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
    jax.config.update("jax_persistent_cache_min_entry_size_bytes", 0)
    return str(folder)
