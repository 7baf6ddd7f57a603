"""Multi-start: many fits from spread-out initial guesses, run through any
concurrent.futures executor (a local process pool by default, a Dask distributed
cluster via ``client.get_executor()``), ranked by cost, the best refined.

Problems are sent as cloudpickle bytes, so models written as lambdas, in scripts,
notebooks or model files reach the workers; each worker compiles a problem once
and reuses it for every start it receives. What a worker does with its starts is a
task passed in by the caller (fit's, in methods.py), so this module knows nothing
of the fitting methods.
"""

from __future__ import annotations

import hashlib
import os
from collections.abc import Callable
from concurrent.futures import Executor, ProcessPoolExecutor
from multiprocessing import get_context
from typing import Any

import numpy as np

SAMPLINGS = ("lhs", "uniform")


def draw_starts(
    theta0: np.ndarray,
    lower: np.ndarray,
    upper: np.ndarray,
    n: int,
    *,
    spread: float = 0.2,
    sampling: str = "lhs",
    seed: int = 0,
) -> np.ndarray:
    """n starts (the first is theta0 itself). Entries with finite bounds on both sides
    are drawn within the bounds; the others within ±spread of theta0 (relative), kept
    inside any one-sided bound. ``sampling``: "lhs" (Latin hypercube) or "uniform"."""
    if sampling not in SAMPLINGS:
        raise ValueError(f"sampling must be one of {SAMPLINGS}, got {sampling!r}")
    if n < 1:
        raise ValueError(f"starts must be at least 1, got {n}")
    K = theta0.size
    rng = np.random.default_rng(seed)
    m = n - 1
    if sampling == "lhs":
        unit = (
            rng.permuted(np.tile(np.arange(m), (K, 1)), axis=1).T + rng.uniform(size=(m, K))
        ) / max(m, 1)
    else:
        unit = rng.uniform(size=(m, K))
    boxed = np.isfinite(lower) & np.isfinite(upper)
    lo = np.where(boxed, lower, theta0 - spread * np.abs(theta0))
    hi = np.where(boxed, upper, theta0 + spread * np.abs(theta0))
    pts = np.clip(lo + unit * (hi - lo), lower, upper)
    return np.vstack([theta0[None, :], pts])


def process_pool(workers: int) -> ProcessPoolExecutor:
    """A local pool of fresh ("spawn") processes, each with one XLA thread: the
    problems are small, so the cores are better spent on separate starts. Spawn,
    not fork, because forking a process that has started JAX's threads is unsafe."""
    os.environ.setdefault(
        "XLA_FLAGS", "--xla_cpu_multi_thread_eigen=false intra_op_parallelism_threads=1"
    )
    import jax

    cache = jax.config.values.get("jax_compilation_cache_dir")  # shared with the parent
    return ProcessPoolExecutor(
        workers, mp_context=get_context("spawn"), initializer=_worker_init, initargs=(cache,)
    )


def _worker_init(cache: str | None) -> None:
    if cache:
        from .._config import enable_compilation_cache

        enable_compilation_cache(cache)


_WORKER_PROBLEMS: dict[str, Any] = {}


def _run_payload(payload: tuple) -> list[dict]:
    """Worker side: ``task(problem, thetas)`` for one chunk of starts."""
    import cloudpickle

    blob, task, thetas = payload
    key = hashlib.sha1(blob).hexdigest()
    if key not in _WORKER_PROBLEMS:
        _WORKER_PROBLEMS.clear()
        _WORKER_PROBLEMS[key] = cloudpickle.loads(blob)
    return task(_WORKER_PROBLEMS[key], thetas)


def run_starts(
    problem,
    task: Callable[[Any, list], list[dict]],
    thetas: np.ndarray,
    executor: Executor | None = None,
    workers: int | None = None,
    batch: int = 1,
) -> list[dict]:
    """``task(problem, chunk)`` for chunks of up to ``batch`` rows of ``thetas``, on
    ``executor``, a local process pool of ``workers``, or here for one worker; the
    task returns one dict per start. Results come back in the order of the starts.
    ``task`` must be picklable (a module-level function or a partial of one)."""
    import cloudpickle

    blob = cloudpickle.dumps(problem)
    chunks = [thetas[i : i + batch].tolist() for i in range(0, len(thetas), batch)]
    payloads = [(blob, task, chunk) for chunk in chunks]
    workers = workers or os.cpu_count() or 1
    if executor is not None:
        done = list(executor.map(_run_payload, payloads))
    elif workers == 1 or len(payloads) == 1:  # here: no copy, the compiled sweeps are reused
        done = [task(problem, chunk) for chunk in chunks]
    else:
        with process_pool(min(workers, len(payloads))) as pool:
            done = list(pool.map(_run_payload, payloads))
    return [r for rs in done for r in rs]
