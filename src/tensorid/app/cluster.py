"""`tensorid fit --scheduler`: the starts run on a Dask distributed cluster, connected
before any work and closed after; an unreachable scheduler is one line."""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager


def _connect(address: str, timeout: float):
    """A Dask client for the scheduler at ``address``, or one line saying why not."""
    import socket
    from urllib.parse import urlsplit

    fix = "check the address and that `dask scheduler` runs there"
    url = urlsplit(address if "://" in address else "tcp://" + address)
    if url.scheme == "tcp":
        try:
            host, port = url.hostname, url.port
            if not host or not port:
                raise ValueError("it has no host:port")
            # a plain connect first: distributed's own failure leaves tracebacks behind
            socket.create_connection((host, port), timeout=min(timeout, 10)).close()
        except (OSError, ValueError) as e:
            raise ValueError(f"--scheduler {address}: cannot connect ({e}); {fix}") from None
    import logging

    from distributed import Client

    # the client's own log lines ("Failed to reconnect to scheduler ...") are not the
    # command's: the fit says in its own lines what a lost scheduler or worker changes
    logging.getLogger("distributed.client").setLevel(logging.CRITICAL)
    try:
        return Client(address, timeout=min(timeout, 30), set_as_default=False)
    except (OSError, ValueError, TimeoutError) as e:
        raise ValueError(f"--scheduler {address}: cannot connect ({e}); {fix}") from None


@contextmanager
def _workers(args) -> Iterator[tuple]:
    """(executor, timeout) for the starts: a Dask cluster's with --scheduler
    (connected before any work, closed after), else none (a local pool)."""
    timeout = args.worker_timeout
    if not args.scheduler:
        yield None, timeout
        return
    timeout = 300.0 if timeout is None else timeout
    client = _connect(args.scheduler, timeout)
    try:
        yield client.get_executor(), timeout
    finally:
        client.close()
