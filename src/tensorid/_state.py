"""The run-wide state of one process, in one object (``state``), so that no module
keeps its own globals to reassign (``global`` statements live only in _config.py).
Nothing here imports NumPy or JAX: _early.py reads it before they are imported.

Each attribute is set once per process (or taken once) by the module named beside it.
"""

from __future__ import annotations

from typing import Any


class State:
    """What this process has set up, once."""

    def __init__(self) -> None:
        # _early.py: the figure process started before the imports, (forks, process),
        # until the command's Renderer takes it; and the garbage collector paused
        self.renderer: tuple[int, Any] | None = None
        self.collector_paused = False
        self.importing = False  # Ctrl-C said in one line until the command starts
        # engine/compiling/compilation.py: its compile-time listener registered with JAX
        self.compile_listener = False
        # engine/compiling/executables.py: the processor, XLA_FLAGS and devices, as digested;
        # the compilation cache's hit listener registered
        self.machine: str | None = None
        self.hit_listener = False
        # engine/compiling/programs.py: the package source's digest; the folder pruned
        self.source_digest: str | None = None
        self.pruned = False
        # solve/multistart.py: this process is a worker of process_pool
        self.local_worker = False


state = State()
