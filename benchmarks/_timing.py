"""Shared by the benchmark scripts: median wall time after a first (compiling) call."""

from __future__ import annotations

import statistics
import time

import jax


def time_call(fn, repeats: int) -> tuple[float, float]:
    """(median run seconds, seconds of the first call, compilation included)."""
    t0 = time.perf_counter()
    jax.block_until_ready(fn())
    first = time.perf_counter() - t0
    runs = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        jax.block_until_ready(fn())
        runs.append(time.perf_counter() - t0)
    return statistics.median(runs), first
