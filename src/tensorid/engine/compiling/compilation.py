"""How long JAX spent compiling: tracing, lowering and XLA compilation, as JAX itself
reports them (jax.monitoring), so that a fit can state its compile time apart from
its run time."""

from __future__ import annotations

import threading
import time
from contextlib import contextmanager

import jax

from ..._state import state

_EVENTS = "/jax/core/compile/"
_local = threading.local()
_lock = threading.Lock()


def _listener(event: str, duration: float, **_) -> None:
    if event.startswith(_EVENTS):
        for clock in getattr(_local, "clocks", ()):
            clock[0] += duration


@contextmanager
def compile_clock():
    """Within the block, ``clock[0]`` accumulates the seconds JAX spends compiling on
    this thread (nested clocks each see every compilation)."""
    with _lock:  # registered twice, every compilation would count twice
        if not state.compile_listener:
            jax.monitoring.register_event_duration_secs_listener(_listener)
            state.compile_listener = True
    clock = [0.0]
    _local.clocks = (*getattr(_local, "clocks", ()), clock)
    try:
        yield clock
    finally:
        _local.clocks = tuple(c for c in _local.clocks if c is not clock)


def clocks_here() -> tuple:
    """The compile clocks running on this thread, for another thread to count into
    (:func:`counted_by`): its compilations are this block's too."""
    return tuple(getattr(_local, "clocks", ()))


@contextmanager
def counted_by(clocks: tuple):
    """Within the block, this thread's compilations count on ``clocks`` as well."""
    before = getattr(_local, "clocks", ())
    _local.clocks = (*before, *clocks)
    try:
        yield
    finally:
        _local.clocks = before


# -- what is being compiled, as it starts and ends -----------------------------------
# A compiled program's first call (programs.py) is announced through JAX's own event
# registry (jax.monitoring), so that a caller above the engine (the command line's
# progress line) can say what it waits for without the engine knowing of it. The
# events are not under "/jax/core/compile/": compile_clock does not count them twice.
BEGIN = "/tensorid/compile/begin"  # record_event(BEGIN, what=...)
END = "/tensorid/compile/end"  # record_event_duration_secs(END, seconds, what=...)

_WHAT = {
    "_simulate": "the simulation",
    "_cost": "the cost J",
    "_predictions": "the predictions",
    "_residuals": "the residuals",
    "_output_jacobian": "the output sensitivities",
    "_first_order": "the first-order sweep (J, ∇J, Gauss-Newton)",
    "_second_order": "the second-order sweep (J, ∇J, ∇²J)",
    "_second_order_both": "the second-order sweep (J, ∇J, ∇²J, Gauss-Newton)",
    "_gradient": "the gradient sweep (J, ∇J)",
    "_first_order_scores": "the first-order sweep (J, ∇J, Gauss-Newton, scores)",
    "_hessp": "the Hessian-vector product",
    "_segment": "the segments' second-order sweep",
    "_segment_gn": "the segments' first-order sweep",
    "_k_step": "the k-step-ahead predictions",
    "adjoint": "the second-order adjoint",
    # a population fit's (population/objective.py)
    "population_steps": "the units' inner Newton steps",
    "population_value_grad": "the population objective and its gradient",
    "population_evaluation": "the population objective, its gradient and Hessians",
    "population_inner_blocks": "the units' inner curvature",
    "population_predict_all": "the units' predictions",
}


def describe(entry: str) -> str:
    """A program's entry point (``"_second_order batched=False axes=..."``) in words."""
    name = entry.split(" ", 1)[0]
    what = _WHAT.get(name, name.strip("_").replace("_", " "))
    return what + (", batched" if "batched=True" in entry else "")


@contextmanager
def announced(what: str):
    """Tells jax.monitoring's listeners that ``what`` is being compiled (BEGIN) and,
    when the block ends however it ends, how many seconds that took (END)."""
    jax.monitoring.record_event(BEGIN, what=what)
    t0 = time.perf_counter()
    try:
        yield
    finally:
        jax.monitoring.record_event_duration_secs(END, time.perf_counter() - t0, what=what)
