"""Where sweep cells run: in process, on a local process pool, or on a Dask cluster.

Every engine is an iterator ``(payload, result, exception)`` over the payloads, in completion
order, so the caller saves each result as soon as it arrives and an engine failure of one
payload never stops the others.  ``fn(payload)`` must be a picklable module-level function.

* :func:`iter_serial` -- one after the other, in this process;
* :func:`iter_pool` -- a :class:`concurrent.futures.ProcessPoolExecutor` (:func:`make_pool`:
  ``spawn``, workers ignore Ctrl-C so the driving process saves what is done); processes, not
  threads, because Ipopt with MUMPS is not thread-safe;
* :func:`iter_dask` -- ``dask.distributed``: ``"local"`` starts a loopback
  :class:`~dask.distributed.LocalCluster` (one thread per worker process), or a scheduler
  address ``tcp://HOST:PORT`` / ``tls://HOST:PORT``, or an existing client.
"""
from __future__ import annotations

import os
import uuid

__all__ = ["EngineError", "iter_serial", "iter_pool", "iter_dask", "make_pool", "one_line"]


class EngineError(ValueError):
    """An engine cannot start (no cluster, bad address); one line."""


def one_line(exc: BaseException) -> str:
    """``"<Type>: <message>"`` on one line, at most 300 characters (errors saved and printed)."""
    text = " ".join(str(exc).split())
    return f"{type(exc).__name__}: {text}"[:300]


def iter_serial(fn, payloads):
    """Run ``fn`` on each payload in this process."""
    for p in payloads:
        try:
            yield p, fn(p), None
        except Exception as exc:  # noqa: BLE001 - reported per payload
            yield p, None, exc


def _worker_init() -> None:
    """Pool workers leave Ctrl-C to the driving process (which saves what is done and stops)."""
    import signal
    signal.signal(signal.SIGINT, signal.SIG_IGN)


def make_pool(workers: int | None = None):
    """A process pool (``spawn``: no fork of a threaded parent; a script that uses it needs the
    ``if __name__ == "__main__":`` guard).  Its workers keep module-level caches between calls."""
    import multiprocessing as mp
    from concurrent.futures import ProcessPoolExecutor
    return ProcessPoolExecutor(max_workers=workers or os.cpu_count() or 1, mp_context=mp.get_context("spawn"),
                               initializer=_worker_init)


def iter_pool(fn, payloads, workers: int | None = None, executor=None):
    """Run ``fn`` on a process pool (``executor``, left running, or a new one of ``workers``)."""
    from concurrent.futures import as_completed
    ex = executor or make_pool(workers)
    futs = {ex.submit(fn, p): p for p in payloads}
    try:
        for fut in as_completed(futs):
            exc = fut.exception()
            yield futs[fut], (None if exc else fut.result()), exc
    finally:
        for f in futs:
            f.cancel()
        if executor is None:
            ex.shutdown(wait=True, cancel_futures=True)


def iter_dask(fn, payloads, address: str = "local", workers: int | None = None, client=None,
              key=lambda p: "task"):
    """Run ``fn`` on a Dask cluster; ``key(payload)`` names each task (a unique suffix is added).

    Raises
    ------
    EngineError
        The local cluster cannot start or the scheduler cannot be reached (within 20 s).
    """
    from dask.distributed import Client, LocalCluster, as_completed
    cluster = own = None
    if client is None:
        try:
            if address == "local":
                cluster = LocalCluster(n_workers=workers or 2, threads_per_worker=1, processes=True,
                                       host="127.0.0.1", dashboard_address=None)
                client = own = Client(cluster)
            else:
                client = own = Client(address, timeout="20s")
        except (OSError, RuntimeError, TimeoutError, ValueError) as exc:
            if cluster is not None:
                cluster.close()
            where = "cannot start a local Dask cluster" if address == "local" else f"cannot connect to {address}"
            raise EngineError(f"dask: {where} ({one_line(exc)})") from None
    try:
        futs = {}
        for p in payloads:
            f = client.submit(fn, p, pure=False, key=f"seekopt-{key(p)}-{uuid.uuid4().hex[:8]}")
            futs[f.key] = (f, p)
        for f in as_completed([f for f, _ in futs.values()]):
            p = futs[f.key][1]
            try:
                yield p, f.result(), None
            except Exception as exc:  # noqa: BLE001 - reported per payload
                yield p, None, exc
    finally:
        if own is not None:
            own.close()
        if cluster is not None:
            cluster.close()
