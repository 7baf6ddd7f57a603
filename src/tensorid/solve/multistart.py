"""Multi-start: many fits from spread-out initial guesses, run through any
concurrent.futures executor (a local process pool by default, a Dask distributed
cluster via ``client.get_executor()``), ranked by cost, the best refined.

Problems are sent as cloudpickle bytes, so models written as lambdas, in scripts,
notebooks or model files reach the workers; each worker compiles a problem once
and reuses it for every start it receives. What a worker does with its starts is a
task passed in by the caller (fit's, in starts.py: it returns a FitResult per
start), so this module knows nothing of the fitting methods.
"""

from __future__ import annotations

import hashlib
import os
import signal
import threading
import time
from collections.abc import Callable
from concurrent.futures import Executor, ProcessPoolExecutor
from contextlib import contextmanager
from multiprocessing import get_context
from typing import Any

import numpy as np

from .._state import state
from ..engine.schemes.status import Status

SAMPLINGS = ("lhs", "uniform")
SAME_COST = 1e-9  # relative: starts whose costs agree this closely reached one minimum


def ranked_starts(runs: list[dict]) -> list[dict]:
    """The starts best first: by cost, those that failed to a finite cost last; the
    starts at the best cost (within SAME_COST) by fewest iterations, so a tie goes
    to the start that got there fastest."""
    ranked = sorted(runs, key=lambda r: (not np.isfinite(r["cost"]), r["cost"]))
    if not ranked or not np.isfinite(ranked[0]["cost"]):
        return ranked
    top = [r for r in ranked if at_best(r["cost"], ranked[0]["cost"])]
    return sorted(top, key=lambda r: r["nit"]) + ranked[len(top) :]


def at_best(cost: float, best: float) -> bool:
    """Whether ``cost`` is the best cost to within SAME_COST (relative)."""
    return bool(np.isfinite(cost) and cost <= best + SAME_COST * abs(best))


def draw_starts(
    theta0: np.ndarray,
    lower: np.ndarray,
    upper: np.ndarray,
    n: int,
    *,
    spread: float | None = None,
    sampling: str = "lhs",
    seed: int = 0,
) -> np.ndarray:
    """n starts (the first is theta0 itself), every entry inside its bounds.

    With ``spread``: within ±spread (relative) of theta0; for a positive entry whose
    bounds span a decade or more (upper ≥ 10 lower > 0), within a factor 1 + spread
    of theta0, log-uniformly. Without (None, the default): entries with both bounds
    finite across the whole box (log-uniformly where it spans a decade or more), the
    others within ±0.2 of theta0. ``sampling``: "lhs" (Latin hypercube, in the
    uniform or logarithmic coordinate) or "uniform"."""
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
    lo, hi, logs = _ranges(theta0, lower, upper, spread)
    safe = np.where(logs, lo, 1.0), np.where(logs, hi, 1.0)
    llo, lhi = np.log(safe[0]), np.log(safe[1])
    pts = np.where(logs, np.exp(llo + unit * (lhi - llo)), lo + unit * (hi - lo))
    return np.vstack([theta0[None, :], np.clip(pts, lower, upper)])


def _ranges(theta0, lower, upper, spread) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(lo, hi, logs): where each entry's starts are drawn (the box, or ±spread of
    theta0 within the bounds) and which are drawn log-uniformly (factor 1 + spread):
    those whose bounds span decades, where a uniform draw would land nearly every
    start in the top decade."""
    boxed = np.isfinite(lower) & np.isfinite(upper)
    logs = np.isfinite(upper) & (lower > 0) & (upper >= 10 * lower)
    s = 0.2 if spread is None else float(spread)
    lo = np.where(logs, theta0 / (1 + s), theta0 - s * np.abs(theta0))
    hi = np.where(logs, theta0 * (1 + s), theta0 + s * np.abs(theta0))
    if spread is None:
        lo, hi = np.where(boxed, lower, lo), np.where(boxed, upper, hi)
    return np.maximum(lo, lower), np.minimum(hi, upper), logs


def process_pool(workers: int) -> ProcessPoolExecutor:
    """A local pool of fresh ("spawn") processes, each with one XLA thread: the
    problems are small, so the cores are better spent on separate starts. Spawn,
    not fork, because forking a process that has started JAX's threads is unsafe."""
    import jax

    # the parent's cache folder, or None where it turned the cache off
    on = jax.config.values.get("jax_enable_compilation_cache")
    cache = jax.config.values.get("jax_compilation_cache_dir") if on else None
    return ProcessPoolExecutor(
        workers, mp_context=get_context("spawn"), initializer=_worker_init, initargs=(cache,)
    )


def _worker_init(cache: str | None) -> None:
    # Ctrl-C in a terminal reaches the whole process group: the parent alone
    # decides (it stops the workers and keeps what finished)
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    from .._config import add_xla_flags, disable_compilation_cache, enable_compilation_cache

    # one XLA thread per worker, set in the worker (not in the parent's environment):
    # read when JAX first computes, which comes after this
    add_xla_flags("--xla_cpu_multi_thread_eigen=false")
    state.local_worker = True  # this process is one of process_pool's
    # a parent killed outright (kill -9, out of memory) cannot stop its pool: a worker
    # would wait for work forever, so it ends with its parent
    from multiprocessing import parent_process

    parent = parent_process()
    if parent is not None:
        threading.Thread(target=_end_with, args=(parent.sentinel,), daemon=True).start()

    if cache:
        enable_compilation_cache(cache)
    else:
        disable_compilation_cache()


def _end_with(sentinel) -> None:
    """End this process once ``sentinel`` (its parent's) says the parent has ended."""
    from multiprocessing.connection import wait

    wait([sentinel])
    os._exit(1)


_WORKER_PROBLEMS: dict[str, Any] = {}


def _run_payload(payload: tuple) -> list:
    """Worker side: ``task(problem, thetas)`` for one chunk of starts."""
    import cloudpickle

    blob, task, thetas = payload
    key = hashlib.sha1(blob).hexdigest()
    if key not in _WORKER_PROBLEMS:
        _WORKER_PROBLEMS.clear()
        problem = cloudpickle.loads(blob)
        # (run_starts runs any task: its "problem" may be anything, None included)
        if state.local_worker and getattr(problem, "threads", 1) is None:
            # a local pool's worker has one core: the adjoint Hessian's threads would
            # only contend (its own copy of the problem, told so explicitly; a Dask
            # worker keeps its cores, and a user's threads= is kept)
            problem = problem.with_threads(1)
        _WORKER_PROBLEMS[key] = problem
    return task(_WORKER_PROBLEMS[key], thetas)


class StartsStopped(Exception):
    """Raised by :func:`run_starts` when the starts cannot all finish: Ctrl-C
    (``status`` INTERRUPTED) or workers that stopped answering (WORKERS_LOST).
    ``runs`` holds the results of the starts that did finish, by the index of their
    start; ``total`` is the number of starts."""

    def __init__(self, status, runs, total: int, detail: str):
        super().__init__(detail)
        self.status, self.runs, self.total, self.detail = status, dict(runs), total, detail


def run_starts(
    problem,
    task: Callable[[Any, list], list],
    thetas: np.ndarray,
    executor: Executor | None = None,
    workers: int | None = None,
    batch: int = 1,
    timeout: float | None = None,
) -> list:
    """``task(problem, chunk)`` for chunks of up to ``batch`` rows of ``thetas``, on
    ``executor``, a local process pool of ``workers``, or here for one worker; the
    task returns one result per start (a start it stopped has ``status``
    INTERRUPTED). Results come back in the order of the starts.
    ``task`` must be picklable (a module-level function or a partial of one).

    When no chunk finishes for ``timeout`` seconds (lost workers), on a broken local
    pool, or on Ctrl-C, the work still running is stopped (local workers are
    terminated, not waited for) and :class:`StartsStopped` is raised with the starts
    that finished."""
    import cloudpickle

    chunks = [thetas[i : i + batch].tolist() for i in range(0, len(thetas), batch)]
    workers = workers or os.cpu_count() or 1
    if executor is None and (workers == 1 or len(chunks) == 1):
        # here: no copy, the compiled sweeps are reused
        return _run_here(problem, task, chunks, len(thetas))
    blob = cloudpickle.dumps(problem)
    payloads = [(blob, task, chunk) for chunk in chunks]
    pool = executor or process_pool(min(workers, len(payloads)))
    complete = False
    try:
        window = LOCAL_WINDOW * workers if executor is None else CLUSTER_WINDOW
        # a pool of ours is stopped whole (_stop_pool); a user's, only by cancelling
        cancel = executor is not None
        done = _collect(pool, payloads, timeout, len(thetas), batch, window, cancel)
        complete = True
    finally:
        if executor is None:
            try:
                _stop_pool(pool, complete)  # type: ignore[arg-type]
            except KeyboardInterrupt:  # while the pool shut down: every start is kept
                _stop_pool(pool, False)  # type: ignore[arg-type]
                if complete:
                    runs = _numbered(dict(enumerate(done)), batch)
                    why = "interrupted"
                    raise StartsStopped(Status.INTERRUPTED, runs, len(thetas), why) from None
                # else the StartsStopped already on its way goes on
    return [r for rs in done for r in rs]


def _numbered(chunks_done: dict[int, list], batch: int) -> dict[int, Any]:
    """The finished starts by their index among all starts."""
    ordered = sorted(chunks_done.items())
    return {c * batch + j: r for c, rs in ordered for j, r in enumerate(rs)}


def _run_here(problem, task, chunks: list, total: int) -> list:
    done: dict[int, list] = {}
    for c, chunk in enumerate(chunks):
        try:
            rs = task(problem, chunk)
        except KeyboardInterrupt:
            rs = []
        done[c] = rs
        if len(rs) < len(chunk) or any(
            getattr(r, "status", None) is Status.INTERRUPTED for r in rs
        ):
            runs = _numbered(done, len(chunks[0]))
            raise StartsStopped(Status.INTERRUPTED, runs, total, "interrupted")
    return [r for c in sorted(done) for r in done[c]]


# chunks in flight at once: a wait over every chunk of a 20,000-start run cost tens
# of ms a turn; a Dask cluster gets enough to keep a large cluster busy
LOCAL_WINDOW, CLUSTER_WINDOW = 4, 1024
STOP_WAIT = 5.0  # seconds a stopped local pool's manager thread is waited for


def _collect(
    pool: Executor,
    payloads: list,
    timeout: float | None,
    total: int,
    batch: int,
    window: int,
    cancel: bool = True,
):
    """Submit the chunks, at most ``window`` of them in flight, and gather the results
    as they come, in the order of the chunks; stop on Ctrl-C, a broken pool or
    ``timeout`` seconds without progress, cancelling the chunks not yet started where
    ``cancel`` (not for a local pool of ours: see :func:`_cancel`)."""
    from concurrent.futures import FIRST_COMPLETED, wait

    futures: dict[Any, int] = {}  # in flight: their chunk
    done: dict[int, list] = {}
    queued = iter(range(len(payloads)))

    def top_up():
        from concurrent.futures.process import BrokenProcessPool

        while len(futures) < window and (c := next(queued, None)) is not None:
            try:  # a worker that died since the last wait breaks the pool for submits too
                futures[pool.submit(_run_payload, payloads[c])] = c
            except BrokenProcessPool as e:
                raise _Lost(f"a worker process died ({e})") from None

    def finished_so_far():
        for f, c in futures.items():
            if f.done() and not f.cancelled() and f.exception() is None:
                done[c] = f.result()
        return _numbered(done, batch)

    last = time.monotonic()
    with _interrupt_as_flag() as interrupted:
        try:
            top_up()
            while futures and not interrupted.is_set():
                # short waits keep Ctrl-C prompt whatever the executor
                finished, _ = wait(futures, timeout=0.25, return_when=FIRST_COMPLETED)
                for f in finished:
                    done[futures.pop(f)] = _result(f)
                    last = time.monotonic()
                if not interrupted.is_set():  # (on a cluster, none to cancel at once)
                    top_up()
                if futures and timeout is not None and time.monotonic() - last > timeout:
                    why = f"no start finished for {timeout:g} s"
                    runs = _numbered(done, batch)
                    raise StartsStopped(Status.WORKERS_LOST, runs, total, why)
            if interrupted.is_set():
                raise KeyboardInterrupt
        except KeyboardInterrupt:
            runs = finished_so_far()
            _cancel(futures, cancel)
            raise StartsStopped(Status.INTERRUPTED, runs, total, "interrupted") from None
        except _Lost as e:
            runs = finished_so_far()
            _cancel(futures, cancel)
            raise StartsStopped(Status.WORKERS_LOST, runs, total, str(e)) from None
        except StartsStopped:
            _cancel(futures, cancel)
            raise
        results = [done[c] for c in range(len(payloads))]
    if interrupted.is_set():  # Ctrl-C after the last look, before Python's handler was back
        raise StartsStopped(Status.INTERRUPTED, _numbered(done, batch), total, "interrupted")
    return results


@contextmanager
def _interrupt_as_flag():
    """Ctrl-C sets the flag yielded, read between waits, instead of raising where it
    lands: a KeyboardInterrupt inside ``concurrent.futures.wait`` can leave a
    future's lock held, and the pool's manager thread, blocked on that lock, then
    never lets the pool shut down (CPython 3.11: 5 of 12 interrupted runs of 20,000
    futures hung). Only on the main thread under Python's own handler; elsewhere
    Ctrl-C raises as before."""
    flag = threading.Event()
    mine = threading.current_thread() is threading.main_thread()
    if not mine or signal.getsignal(signal.SIGINT) is not signal.default_int_handler:
        yield flag
        return
    signal.signal(signal.SIGINT, lambda *_: flag.set())
    try:
        yield flag
    finally:
        signal.signal(signal.SIGINT, signal.default_int_handler)


class _Lost(Exception):
    """A worker died or its cluster dropped the task."""


def _result(future):
    """A finished chunk's results; a dead worker (a broken local pool, a task the
    cluster killed or cancelled) is _Lost, anything else the task raised is a bug
    and is raised as it is."""
    from concurrent.futures import CancelledError
    from concurrent.futures.process import BrokenProcessPool

    try:
        return future.result()
    except BrokenProcessPool as e:
        raise _Lost(f"a worker process died ({e})") from None
    except CancelledError:
        raise _Lost("the cluster cancelled a task") from None
    except Exception as e:
        if type(e).__name__ == "KilledWorker":  # Dask: the task's workers kept dying
            raise _Lost(f"the cluster lost the workers of a task ({e})") from None
        raise


def _cancel(pending, cancel: bool) -> None:
    """Cancel the chunks not yet started where ``cancel``: on a cluster or a user's
    executor, which only that stops. Not on a local pool of ours, which
    :func:`_stop_pool` shuts down with ``cancel_futures``: a future cancelled here
    stays in the pool's books, and where its manager thread then sees a terminated
    worker before the shutdown it marks every future broken, fails on the cancelled
    one (CPython 3.11: InvalidStateError, gh-107219) and dies before it unblocks the
    queue's feeder thread, which Python's exit then waits for forever (1 of 2 CI runs
    of an interrupted 20,000-start fit hung so; every run with 0.3 s between the
    two)."""
    if cancel:
        for f in pending:
            f.cancel()


def _stop_pool(pool: ProcessPoolExecutor, complete: bool) -> None:
    """Shut a local pool down; when starts are still running (Ctrl-C, a lost
    worker), without waiting for them: the workers are terminated (then killed if
    they linger), so none is left behind, and nothing the pool leaves blocked holds
    this process's exit. A second Ctrl-C meanwhile does not break off the stop,
    which is bounded (a few seconds at most)."""
    if complete:
        pool.shutdown(wait=True)
        return
    with _interrupt_as_flag():
        _terminate(pool)


def _terminate(pool: ProcessPoolExecutor) -> None:
    """Stop a local pool now (see :func:`_stop_pool`); also after a shutdown already
    began, whose attributes it then finds gone."""
    procs = list((getattr(pool, "_processes", None) or {}).values())
    calls = getattr(pool, "_call_queue", None)
    if calls is not None:  # its feeder may be stuck writing to the workers about to go:
        calls.cancel_join_thread()  # Python's exit, and the manager, would wait for it
    for p in procs:
        p.terminate()
    # (shutdown forgets them)
    manager = getattr(pool, "_executor_manager_thread", None)
    results = getattr(pool, "_result_queue", None)
    pool.shutdown(wait=False, cancel_futures=True)
    for p in procs:
        p.join(1.0)
        if p.is_alive():
            p.kill()
            p.join(1.0)
    writer = getattr(results, "_writer", None)
    if writer is not None:
        # a worker terminated halfway through sending a result leaves the pool's
        # manager thread waiting for the rest for ever, since this process holds the
        # pipe's other end too: closed, the manager reads the end of input instead
        writer.close()
    # with its workers gone the manager thread ends at once; waited for a while only.
    # One blocked for good (a future's lock left held by a KeyboardInterrupt inside
    # concurrent.futures.wait under a handler other than Python's; _interrupt_as_flag
    # keeps Python's own from doing so) still holds this process's exit, which joins
    # it: the finished starts are returned and written all the same
    if manager is not None:
        manager.join(STOP_WAIT)
