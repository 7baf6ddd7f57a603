"""How long JAX spent compiling: tracing, lowering and XLA compilation, as JAX itself
reports them (jax.monitoring), so that a fit can state its compile time apart from
its run time."""

from __future__ import annotations

import threading
from contextlib import contextmanager

import jax

_EVENTS = "/jax/core/compile/"
_local = threading.local()
_registered = False
_lock = threading.Lock()


def _listener(event: str, duration: float, **_) -> None:
    if event.startswith(_EVENTS):
        for clock in getattr(_local, "clocks", ()):
            clock[0] += duration


@contextmanager
def compile_clock():
    """Within the block, ``clock[0]`` accumulates the seconds JAX spends compiling on
    this thread (nested clocks each see every compilation)."""
    global _registered
    with _lock:  # registered twice, every compilation would count twice
        if not _registered:
            jax.monitoring.register_event_duration_secs_listener(_listener)
            _registered = True
    clock = [0.0]
    _local.clocks = (*getattr(_local, "clocks", ()), clock)
    try:
        yield clock
    finally:
        _local.clocks = tuple(c for c in _local.clocks if c is not clock)
