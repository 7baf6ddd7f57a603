"""A fleet's per-unit work as map-reduce: the units cut into chunks, each chunk's inner
solves and its sums of O, ∇O and ∇²O computed on a worker (a local process pool, or
any concurrent.futures executor such as a Dask cluster's ``client.get_executor()``),
the sums added here. Per outer evaluation a worker receives ψ and its units' η̂ (a few
numbers per unit) and returns its η̂ and 1 + P + P² numbers; the outer step (a P × P
solve) is the serial part.

The problem travels once per worker as cloudpickle bytes (a worker keeps it, with its
compiled programs, for every later call); each chunk is a view of one Objective, so
chunks of one size share their programs. A chunk whose worker is lost (its future
fails or, with ``timeout``, does not answer) is sent again once and then computed
here: a lost worker costs time, never the fit.
"""

from __future__ import annotations

from concurrent.futures import Executor
from concurrent.futures import TimeoutError as FutureTimeout

import numpy as np

from ..solve.multistart import _run_payload, _stop_pool, process_pool
from .objective import Objective


def evaluate_chunk(obj: Objective, psi, etas, hessian: bool = True):
    """(η̂, unconverged unit names, Σ O_i, Σ ∇O_i, Σ ∇²O_i or None) of ``obj``'s units."""
    etas, ok = obj.solve_inner(psi, etas)
    if not ok:
        return etas, list(obj.unconverged) + list(obj.unfinite), np.inf, None, None
    O, g = obj.value_grad(psi, etas)
    H = obj.hessian(psi, etas) if hessian else None
    return etas, [], float(O.sum()), g.sum(0), H


def _chunk_task(problem, args):
    """Worker side: one chunk's evaluation (its Objective built once per worker)."""
    method, index, psi, etas, hessian = args
    cache = problem.__dict__.setdefault("_population_objectives", {})
    if method not in cache:
        cache[method] = Objective(problem, method)
    return evaluate_chunk(cache[method].subset(index), psi, etas, hessian)


class UnitMap:
    """Every unit's share of an outer evaluation, in ``chunks`` on ``executor`` (or a
    local pool of ``workers`` processes, kept for the fit and stopped by ``close``)."""

    def __init__(self, obj: Objective, executor: Executor | None, workers: int | None,
                 timeout: float | None = None, chunks: int | None = None):  # fmt: skip
        import cloudpickle

        self.obj, self.timeout = obj, timeout
        E = len(obj.units.names)
        n = max(1, min(E, chunks or workers or 2))
        size = -(-E // n)  # equal chunks (the last may be shorter): shared programs
        self.index = [np.arange(i, min(i + size, E)) for i in range(0, E, size)]
        self.blob = cloudpickle.dumps(obj.problem)
        self.own = executor is None
        self.pool = process_pool(min(workers or 2, len(self.index))) if self.own else executor
        self.lost = 0

    def __call__(self, psi, etas, hessian: bool = True):
        psi, etas = np.asarray(psi), np.asarray(etas)
        futures = [self._submit(idx, psi, etas, hessian) for idx in self.index]
        parts = [
            self._result(f, idx, psi, etas, hessian)
            for f, idx in zip(futures, self.index, strict=True)
        ]
        out_etas = np.concatenate([p[0] for p in parts])
        unconverged = [n for p in parts for n in p[1]]
        if unconverged or not all(np.isfinite(p[2]) for p in parts):
            self.obj.unconverged = unconverged
            return out_etas, False, np.inf, None, None
        H = sum(p[4] for p in parts) if hessian else None
        return out_etas, True, sum(p[2] for p in parts), sum(p[3] for p in parts), H

    def _submit(self, idx, psi, etas, hessian):
        args = (self.obj.method, idx, psi, etas[idx], hessian)
        return self.pool.submit(_run_payload, (self.blob, _chunk_task, args))

    def _result(self, future, idx, psi, etas, hessian):
        for attempt in range(2):
            try:
                return future.result(timeout=self.timeout)
            except KeyboardInterrupt:
                future.cancel()
                raise
            except (FutureTimeout, Exception):  # a lost worker: once more, then here
                self.lost += 1
                future.cancel()
                if attempt == 0:
                    try:
                        future = self._submit(idx, psi, etas, hessian)
                        continue
                    except Exception:
                        break
        return evaluate_chunk(self.obj.subset(idx), psi, etas[idx], hessian)

    def close(self, complete: bool = True) -> None:
        if self.own:
            _stop_pool(self.pool, complete)  # type: ignore[arg-type]
