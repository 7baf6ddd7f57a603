"""A jit-compiled entry point declared on a class (the sweeps' list of entry points),
and the one way arrays are handed to compiled programs."""

from __future__ import annotations

import jax
import numpy as np

from .programs import Program


class Compiled:
    """A jit-compiled entry point of :class:`Sweeps`, compiled on first use and kept
    per instance (``batched``: vmapped over a leading axis of θ, one start per row).
    Compiled functions are per process (pickling a Sweeps drops them); their traced
    programs are kept on disk for the next process (programs.py)."""

    def __init__(self, sweep: str, batched: bool = False, axes=(0,) + (None,) * 6):
        self.sweep, self.batched, self.axes = sweep, batched, axes

    def __set_name__(self, owner, name: str) -> None:
        self.name = name

    def __get__(self, obj, owner=None):
        if obj is None:
            return self
        fn = obj.__dict__.get(self.name)
        if fn is None:
            fn = getattr(obj, self.sweep)
            if self.batched:
                fn = jax.vmap(fn, in_axes=self.axes)
            entry = f"{self.sweep} batched={self.batched} axes={self.axes}"
            fn = Program(jax.jit(fn), obj, entry)  # kept across processes where it can be
            obj.__dict__[self.name] = fn
        return fn


def on_device(a) -> jax.Array:
    """``a`` as a float JAX array for a compiled program's argument. Not jnp.asarray:
    that compiles a small program for every new shape (8-15 ms each in a fresh
    process, a dozen of them in a command-line fit); device_put compiles nothing."""
    return jax.device_put(np.asarray(a, dtype=float))


def on_host(a) -> np.ndarray:
    """``a`` as a float64 NumPy array, for a compiled program that is called often
    with small arguments (θ, x0, p): the program copies it in its own C++ call, where
    :func:`on_device` spends ~20 µs of Python on each. Same shapes and dtype as
    on_device's, so the same compiled program runs."""
    return np.ascontiguousarray(a, dtype=float)
