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

import copy
import warnings
from concurrent.futures import CancelledError, Executor
from concurrent.futures import TimeoutError as FutureTimeout

import numpy as np

from ..solve.multistart import _run_payload, _stop_pool, process_pool
from .objective import Objective


def evaluate_chunk(obj: Objective, psi, etas, hessian: bool = True):
    """(η̂, unconverged unit names, Σ O_i, Σ ∇O_i, Σ ∇²O_i or None) of ``obj``'s units."""
    etas, ok = obj.solve_inner(psi, etas)
    if not ok:
        return etas, list(obj.unconverged) + list(obj.unfinite), np.inf, None, None
    if not hessian:  # (a profile's trial point: the smaller program)
        O, g = obj.value_grad(psi, etas)
        return etas, [], float(O.sum()), g.sum(0), None
    O, g, H, _ = obj.evaluation(psi, etas)
    return etas, [], float(O.sum()), g.sum(0), H.sum(0)


def subset(obj: Objective, index) -> Objective:
    """``obj`` over ``index``'s units alone (a worker's chunk); the same programs."""
    new = copy.copy(obj)
    new.units = obj.units.subset(index)
    new.data = tuple(a[np.asarray(index)] for a in obj.data)
    new.unconverged, new.unfinite, new._evaluated = [], [], {}
    return new


def _chunk_task(problem, args):
    """Worker side: one chunk's evaluation (its Objective built once per worker)."""
    method, index, psi, etas, hessian = args
    cache = problem.__dict__.setdefault("_population_objectives", {})
    if method not in cache:
        cache[method] = Objective(problem, method)
    return evaluate_chunk(subset(cache[method], index), psi, etas, hessian)


class UnitMap:
    """Every unit's share of an outer evaluation, in ``chunks`` on ``executor`` (or a
    local pool of ``workers`` processes, kept for the fit and stopped by ``close``).

    A chunk's worker counts as lost where its future fails, or where ``timeout``
    seconds pass without an answer: on a Dask cluster, seconds with no worker at all
    (a worker still compiling its first call is busy, not lost; Dask itself moves a
    dead worker's task to another), elsewhere seconds after the chunk's first answer
    (before it, four times as many: the first call compiles). A lost chunk is sent
    again once, then computed here, and from then on every chunk is computed here:
    the fit goes on without the cluster instead of waiting a timeout per evaluation.
    Each of these is said in one line (a warning) as it happens."""

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
        self.here = False  # the workers are given up: every chunk computed here
        self.answered: set[int] = set()  # chunks that have answered once (compiled)

    def __call__(self, psi, etas, hessian: bool = True):
        psi, etas = np.asarray(psi), np.asarray(etas)
        if self.here:
            return _summed([evaluate_chunk(self.obj, psi, etas, hessian)], self.obj, hessian)
        futures = [self._submit(idx, psi, etas, hessian) for idx in self.index]
        parts = [self._result(f, k, psi, etas, hessian) for k, f in enumerate(futures)]
        return _summed(parts, self.obj, hessian)

    def _submit(self, idx, psi, etas, hessian):
        args = (self.obj.method, idx, psi, etas[idx], hessian)
        return self.pool.submit(_run_payload, (self.blob, _chunk_task, args))

    def _result(self, future, k: int, psi, etas, hessian):
        idx = self.index[k]
        for attempt in range(2):
            if self.here and not future.done():  # the workers were given up meanwhile
                future.cancel()
                break
            try:
                part = self._wait(future, k)
                self.answered.add(k)
                return part
            except KeyboardInterrupt:
                future.cancel()
                raise
            except Exception as e:  # a lost worker: once more, then here
                self.lost += 1
                future.cancel()
                if self.here:  # given up on by another chunk meanwhile (and said so)
                    break
                why = self._why(e, k)
                if attempt == 0:
                    try:
                        future = self._submit(idx, psi, etas, hessian)
                        self._say(f"{why}: sent again")
                        continue
                    except Exception:
                        pass
                self.here = True
                self._say(f"{why}: computed here, as every chunk is from now on")
        return evaluate_chunk(subset(self.obj, idx), psi, etas[idx], hessian)

    def _wait(self, future, k: int):
        """The chunk's answer; FutureTimeout where its worker counts as lost."""
        if self.timeout is None:
            return future.result()
        client = getattr(self.pool, "_client", None)  # a Dask cluster's executor
        allowed = self.timeout * (1 if k in self.answered or client is not None else 4)
        alone = 0.0  # seconds without a worker (Dask), or without an answer
        while True:
            step = min(self.timeout, 2.0)
            try:
                return future.result(timeout=step)
            except FutureTimeout:
                pass
            alive = _workers_alive(client) if client is not None else False
            if alive is None:
                raise FutureTimeout("the scheduler cannot be reached")
            alone = 0.0 if alive else alone + step  # busy (compiling, slow), not lost
            if alone >= allowed:
                raise FutureTimeout

    def _why(self, e: Exception, k: int) -> str:
        names = [self.obj.units.names[i] for i in self.index[k]]
        what = f"units {names[0]} to {names[-1]}" if len(names) > 1 else f"unit {names[0]}"
        if isinstance(e, FutureTimeout):
            cluster = getattr(self.pool, "_client", None) is not None
            why = str(e) or (
                f"the cluster has had no worker for {self.timeout:g} s"
                if cluster
                else f"no worker answered for {self.timeout:g} s"
            )
            return f"{what}: {why}"
        if isinstance(e, CancelledError):  # by the cluster: its scheduler went away
            return f"{what}: the cluster cancelled the task (its scheduler lost?)"
        return f"{what}: a worker failed ({type(e).__name__}: {str(e)[:80]})"

    def _say(self, text: str) -> None:
        warnings.warn(f"the fleet's {text}", UserWarning, stacklevel=4)

    def close(self, complete: bool = True) -> None:
        if self.own:
            _stop_pool(self.pool, complete)  # type: ignore[arg-type]


def _summed(parts, obj: Objective, hessian: bool):
    """(η̂, ok, Σ O, Σ ∇O, Σ ∇²O) of the chunks' ``parts``."""
    out_etas = np.concatenate([p[0] for p in parts])
    unconverged = [n for p in parts for n in p[1]]
    if unconverged or not all(np.isfinite(p[2]) for p in parts):
        obj.unconverged = unconverged
        return out_etas, False, np.inf, None, None
    H = sum(p[4] for p in parts) if hessian else None
    return out_etas, True, sum(p[2] for p in parts), sum(p[3] for p in parts), H


def _workers_alive(client) -> bool | None:
    """Whether the Dask cluster has a worker; None where its scheduler is gone."""
    try:
        return bool(client.scheduler_info()["workers"])
    except Exception:
        return None
