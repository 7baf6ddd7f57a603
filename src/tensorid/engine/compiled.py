"""A jit-compiled entry point declared on a class (the sweeps' list of entry points)."""

from __future__ import annotations

import jax


class Compiled:
    """A jit-compiled entry point of :class:`Sweeps`, compiled on first use and kept
    per instance (``batched``: vmapped over a leading axis of θ, one start per row).
    Compiled functions are per process: pickling a Sweeps drops them."""

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
            fn = jax.jit(fn)
            obj.__dict__[self.name] = fn
        return fn
