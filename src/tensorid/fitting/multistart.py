"""Multi-start: many fits from spread-out initial guesses, run through any
concurrent.futures executor (a local process pool by default, a Dask distributed
cluster via ``client.get_executor()``), ranked by cost, the best refined.

Starts are sent as cloudpickle bytes, so models written as lambdas, in scripts,
notebooks or model files reach the workers; each worker compiles a problem once
and reuses it for every start it receives.
"""

from __future__ import annotations

import hashlib
import os
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
        from ._config import enable_compilation_cache

        enable_compilation_cache(cache)


_WORKER_PROBLEMS: dict[str, Any] = {}


def _fit_payload(payload: tuple) -> list[dict]:
    """Worker side: one start, or several fitted in lock-step (fit_batch)."""
    import cloudpickle

    from .optimize import fit, fit_batch

    blob, method, thetas, options = payload
    key = hashlib.sha1(blob).hexdigest()
    if key not in _WORKER_PROBLEMS:
        _WORKER_PROBLEMS.clear()
        _WORKER_PROBLEMS[key] = cloudpickle.loads(blob)
    problem = _WORKER_PROBLEMS[key]
    if len(thetas) == 1:
        results = [fit(problem, method=method, theta0=np.asarray(thetas[0]), **options)]
    else:
        results = fit_batch(problem, method, np.asarray(thetas), **options)
    return [
        {
            "theta0": list(map(float, theta0)),
            "theta": res.theta.tolist(),
            "cost": float(res.cost),
            "success": res.success,
            "nit": res.nit,
            "nfev": res.nfev,
            "seconds": res.seconds,
            "message": res.message,
        }
        for theta0, res in zip(thetas, results, strict=True)
    ]


def run_starts(
    problem,
    method: str,
    thetas: np.ndarray,
    options: dict,
    executor: Executor | None = None,
    workers: int | None = None,
    batch: int = 1,
) -> list[dict]:
    """Fit from each row of ``thetas``; results in the order of the starts. With
    ``batch`` > 1 each task fits up to that many starts in lock-step (fit_batch)."""
    import cloudpickle

    blob = cloudpickle.dumps(problem)
    chunks = [thetas[i : i + batch].tolist() for i in range(0, len(thetas), batch)]
    payloads = [(blob, method, chunk, options) for chunk in chunks]
    workers = workers or os.cpu_count() or 1
    if executor is not None:
        done = list(executor.map(_fit_payload, payloads))
    elif workers == 1 or len(payloads) == 1:
        done = [_fit_payload(p) for p in payloads]
    else:
        with process_pool(min(workers, len(payloads))) as pool:
            done = list(pool.map(_fit_payload, payloads))
    return [r for rs in done for r in rs]
