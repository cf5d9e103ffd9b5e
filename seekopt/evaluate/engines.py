"""Where sweep cells run: in process, on a local process pool, or on a Dask cluster.

Every engine has the same small interface, so the driving loop (:func:`seekopt.evaluate.sweep.run_sweep`)
submits work lazily -- each of the engine's :attr:`Engine.lanes` workers at most :attr:`Engine.depth`
payloads deep (the next one waits on the worker while it computes), each claimed just before it is
submitted -- and saves each result as soon as it arrives; an engine failure of one payload never
stops the others:

``submit(payload, lane) -> handle`` (to worker ``lane`` where the engine can choose),
``wait(handles, timeout) -> [(handle, result, exception), ...]`` (the finished ones, at least one
unless the timeout expires), ``close()`` (also a context manager).

* :class:`SerialEngine` -- one after the other, in this process;
* :class:`PoolEngine` -- a :class:`WorkerPool` of processes (:func:`make_pool`), one
  :class:`concurrent.futures.ProcessPoolExecutor` of one process per worker so a payload goes to
  the worker of its lane (or any other executor, whichever worker is free); processes, not
  threads, because Ipopt with MUMPS is not thread-safe;
* :class:`DaskEngine` -- ``dask.distributed``: ``"local"`` starts a loopback
  :class:`~dask.distributed.LocalCluster` (one thread per worker process), or a scheduler address
  ``tcp://HOST:PORT`` / ``tls://HOST:PORT``, or an existing client; a lane is a worker (the task
  is restricted to it, loosely: it runs elsewhere if that worker is gone).

Worker processes of :func:`make_pool` (set up by :func:`_worker_init`):

* **one BLAS thread each** -- seekopt sets ``OMP_NUM_THREADS``, ``OPENBLAS_NUM_THREADS``,
  ``MKL_NUM_THREADS`` to 1 and limits an already loaded BLAS with threadpoolctl
  (:func:`seekopt.design.blas.limit_blas`, the limiter the designer uses too): the design's
  matrices are small, and several workers with several BLAS threads each oversubscribe the
  cores (Dask's nanny does the same for its workers; :func:`worker_held` applies it on any
  other Dask worker);
* **they die with their parent** -- on Linux ``prctl(PR_SET_PDEATHSIG, SIGKILL)`` (when the pool
  is made from the main thread, whose exit is the process's), and everywhere a watchdog thread
  that exits the worker when its parent process is gone; so SIGKILL, SIGTERM or SIGINT of the
  sweep never leaves workers (or the multiprocessing resource tracker, which exits when they do)
  computing for nobody;
* they ignore Ctrl-C: the driving process handles it (saves what is done, stops the workers).

What a worker builds (a designer, see :class:`seekopt.evaluate.sweep.CellRunner`) it keeps with
:func:`worker_held`, on the worker itself, not in a module-level cache.
"""
from __future__ import annotations

import os
import sys
import threading
import time
import uuid

from seekopt.design.blas import limit_blas

__all__ = ["EngineError", "Engine", "SerialEngine", "PoolEngine", "DaskEngine", "make_engine", "make_pool",
           "WorkerPool", "worker_held", "one_blas_thread", "limit_blas", "one_line"]

_PR_SET_PDEATHSIG = 1


class EngineError(ValueError):
    """An engine cannot start (no cluster, bad address); one line."""


def one_line(exc: BaseException) -> str:
    """``"<Type>: <message>"`` on one line, at most 300 characters (errors saved and printed)."""
    text = " ".join(str(exc).split())
    return f"{type(exc).__name__}: {text}"[:300]


# ------------------------------------------------------------------ worker set-up
def one_blas_thread() -> None:
    """Limit this (worker) process to one BLAS/OpenMP thread (:func:`seekopt.design.blas.limit_blas`, the one
    limiter; re-exported here)."""
    limit_blas(1)


def _die_with_parent(parent_pid: int, pdeathsig: bool) -> None:
    """Exit this (worker) process when ``parent_pid`` is gone: the kernel's parent-death signal
    (Linux) and a watchdog thread that polls the parent pid (any POSIX system)."""
    if pdeathsig and sys.platform.startswith("linux"):
        try:
            import ctypes
            import signal
            libc = ctypes.CDLL(None, use_errno=True)
            libc.prctl(_PR_SET_PDEATHSIG, int(signal.SIGKILL), 0, 0, 0)
        except (OSError, AttributeError):
            pass
    if os.getppid() != parent_pid:       # the parent died before the signal was armed
        os._exit(1)

    def watch():
        while True:
            time.sleep(0.5)
            if os.getppid() != parent_pid:
                os._exit(1)
    threading.Thread(target=watch, name="seekopt-parent-watchdog", daemon=True).start()


def _worker_init(parent_pid: int | None = None, pdeathsig: bool = True) -> None:
    """Pool worker set-up: ignore Ctrl-C, one BLAS thread, die with the parent (module notes)."""
    import signal
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    one_blas_thread()
    if parent_pid is not None and os.name == "posix":
        _die_with_parent(parent_pid, pdeathsig)


def make_pool(workers: int | None = None) -> "WorkerPool":
    """A pool of ``workers`` processes that have one BLAS thread and die with this process (module notes).

    ``spawn`` start method (no fork of a threaded parent; a script that uses it needs the
    ``if __name__ == "__main__":`` guard).  Its workers keep what they built
    (:func:`worker_held`) between calls, so a pool reused across sweeps stays warm; a sweep sends
    each worker its own cells (:meth:`WorkerPool.submit_to`).
    """
    return WorkerPool(workers or os.cpu_count() or 1)


class WorkerPool:
    """``workers`` worker processes, each behind its own one-process
    :class:`~concurrent.futures.ProcessPoolExecutor`, so work can go to a chosen worker
    (:meth:`submit_to`: a sweep keeps one TPI's neighbouring lengths on the worker whose designer
    is warm for them); :meth:`submit` (the executor interface) goes to the worker with the least
    work queued.  ``shutdown(wait, cancel_futures=)`` as an executor's; :meth:`terminate` stops the
    workers at once."""

    def __init__(self, workers: int):
        import multiprocessing as mp
        from concurrent.futures import ProcessPoolExecutor
        main = threading.current_thread() is threading.main_thread()
        ctx = mp.get_context("spawn")
        self._max_workers = int(workers)
        self._lanes = [ProcessPoolExecutor(max_workers=1, mp_context=ctx, initializer=_worker_init,
                                           initargs=(os.getpid(), main)) for _ in range(self._max_workers)]
        self._queued = [0] * self._max_workers
        self._lock = threading.Lock()

    @property
    def workers(self) -> int:
        return self._max_workers

    def submit_to(self, lane: int, fn, /, *args, **kwargs):
        """``fn(*args, **kwargs)`` on worker ``lane`` (0 ... workers - 1); a future."""
        with self._lock:
            self._queued[lane] += 1
        fut = self._lanes[lane].submit(fn, *args, **kwargs)
        fut.add_done_callback(lambda f: self._done(lane))
        return fut

    def _done(self, lane: int) -> None:
        with self._lock:
            self._queued[lane] -= 1

    def submit(self, fn, /, *args, **kwargs):
        """``fn(*args, **kwargs)`` on the worker with the least work queued; a future."""
        with self._lock:
            lane = min(range(self._max_workers), key=self._queued.__getitem__)
        return self.submit_to(lane, fn, *args, **kwargs)

    def processes(self) -> list:
        return [p for ex in self._lanes for p in (getattr(ex, "_processes", None) or {}).values()]

    def shutdown(self, wait: bool = True, *, cancel_futures: bool = False) -> None:
        """Shut every worker down (all told first, then waited for: ``wait`` joins the workers)."""
        managers = [getattr(ex, "_executor_manager_thread", None) for ex in self._lanes]
        for ex in self._lanes:
            ex.shutdown(wait=False, cancel_futures=cancel_futures)
        if wait:
            for t in managers:
                if t is not None:
                    t.join()

    def terminate(self) -> None:
        """Stop now: cancel the queued work and terminate the workers (an interrupted sweep)."""
        procs = self.processes()
        self.shutdown(wait=False, cancel_futures=True)
        for p in procs:
            if p.is_alive():
                p.terminate()
        for p in procs:
            p.join(5)

    def __enter__(self):
        return self

    def __exit__(self, typ, exc, tb):
        self.shutdown(wait=True, cancel_futures=typ is not None)


_HOLD_LOCK = threading.Lock()


def worker_held(factory):
    """``factory()``, built once in this worker and kept by the worker itself.

    On a Dask worker the object hangs on the :class:`distributed.Worker`, in a pool worker on its
    :func:`multiprocessing.current_process` object, so it lives exactly as long as the worker; the
    first call on a Dask worker also limits it to one BLAS thread.
    """
    holder = None
    if "distributed" in sys.modules:
        try:
            from distributed import get_worker
            holder = get_worker()
        except (ImportError, ValueError):
            holder = None
    on_dask = holder is not None
    if holder is None:
        import multiprocessing as mp
        holder = mp.current_process()
    key = f"_seekopt_held_{factory.__module__}.{factory.__qualname__}"
    with _HOLD_LOCK:
        obj = getattr(holder, key, None)
        if obj is None:
            if on_dask:
                one_blas_thread()
            obj = factory()
            setattr(holder, key, obj)
        return obj


# ------------------------------------------------------------------ engines
class Engine:
    """Common interface (see the module notes).

    ``lanes`` workers, each given up to ``depth`` payloads at once (the next one queued on the worker
    while it computes, so no worker waits for the driving process between payloads);
    ``submit(payload, lane)`` sends a payload to worker ``lane`` (0 ... lanes - 1) where the engine
    can choose (a :class:`WorkerPool`, a Dask cluster), anywhere free otherwise."""

    name = "engine"
    lanes = 1
    depth = 1

    @property
    def capacity(self) -> int:
        return self.lanes * self.depth

    def submit(self, payload, lane: int = 0):
        raise NotImplementedError

    def wait(self, handles, timeout=None) -> list:
        raise NotImplementedError

    def close(self, cancel: bool = False) -> None:
        pass

    def __enter__(self):
        return self

    def __exit__(self, typ, exc, tb):
        self.close(cancel=typ is not None)


class SerialEngine(Engine):
    """Run ``fn(payload)`` in this process, at submission."""

    name = "serial"

    def __init__(self, fn):
        self.fn = fn

    def submit(self, payload, lane: int = 0):
        done = _Done()
        try:
            done.result = self.fn(payload)
        except Exception as exc:  # noqa: BLE001 - reported per payload
            done.exc = exc
        return done

    def wait(self, handles, timeout=None) -> list:
        return [(h, h.result, h.exc) for h in handles]


class _Done:
    """A finished serial computation (hashable handle)."""

    result = None
    exc = None


class PoolEngine(Engine):
    """A local process pool (``executor``, left running, or a new :func:`make_pool` of ``workers``): a
    :class:`WorkerPool` takes each payload to the worker of its lane; any other executor runs it on
    whichever worker is free."""

    name = "process"
    depth = 2

    def __init__(self, fn, workers: int | None = None, executor=None):
        self.fn, self.own = fn, executor is None
        self.ex = executor or make_pool(workers)
        self.lanes = int(getattr(self.ex, "_max_workers", None) or workers or os.cpu_count() or 1)
        self._to = getattr(self.ex, "submit_to", None)

    def submit(self, payload, lane: int = 0):
        if self._to is not None:
            return self._to(lane % self.lanes, self.fn, payload)
        return self.ex.submit(self.fn, payload)

    def wait(self, handles, timeout=None) -> list:
        from concurrent.futures import FIRST_COMPLETED, wait
        done, _ = wait(handles, timeout=timeout, return_when=FIRST_COMPLETED)
        out = []
        for f in done:
            exc = f.exception()
            out.append((f, None if exc else f.result(), exc))
        return out

    def close(self, cancel: bool = False) -> None:
        if not self.own:
            return
        if cancel:       # interrupted: stop the workers now rather than finish their cells for nobody
            self.ex.terminate()
        else:
            self.ex.shutdown(wait=True, cancel_futures=True)


class DaskEngine(Engine):
    """A Dask cluster: ``address`` ``"local"`` (a loopback LocalCluster of ``workers`` processes with one
    thread each), a scheduler ``tcp://HOST:PORT``, or an existing ``client``.  One lane per worker (the
    workers known at the start; a payload may still run elsewhere when its worker is gone).

    Raises
    ------
    EngineError
        The local cluster cannot start or the scheduler cannot be reached (within 20 s).
    """

    name = "dask"
    depth = 2

    def __init__(self, fn, address: str = "local", workers: int | None = None, client=None,
                 key=lambda p: "task"):
        from dask.distributed import Client, LocalCluster
        self.fn, self.key, self.cluster, self.own = fn, key, None, None
        if client is None:
            try:
                if address == "local":
                    self.cluster = LocalCluster(n_workers=workers or 2, threads_per_worker=1, processes=True,
                                                host="127.0.0.1", dashboard_address=None)
                    client = self.own = Client(self.cluster)
                else:
                    client = self.own = Client(address, timeout="20s")
            except (OSError, RuntimeError, TimeoutError, ValueError) as exc:
                if self.cluster is not None:
                    self.cluster.close()
                where = "cannot start a local Dask cluster" if address == "local" else f"cannot connect to {address}"
                raise EngineError(f"dask: {where} ({one_line(exc)})") from None
        self.client = client
        try:
            self.workers = sorted(client.scheduler_info()["workers"])
        except Exception:  # noqa: BLE001 - a scheduler that does not answer: submit anyway, anywhere
            self.workers = []
        self.lanes = max(1, len(self.workers) or workers or 2)

    def submit(self, payload, lane: int = 0):
        where = dict(workers=[self.workers[lane % len(self.workers)]], allow_other_workers=True) \
            if self.workers else {}
        return self.client.submit(self.fn, payload, pure=False,
                                  key=f"seekopt-{self.key(payload)}-{uuid.uuid4().hex[:8]}", **where)

    def wait(self, handles, timeout=None) -> list:
        from dask.distributed import wait
        try:
            done, _ = wait(handles, timeout=timeout, return_when="FIRST_COMPLETED")
        except TimeoutError:
            return []
        out = []
        for f in done:
            try:
                out.append((f, f.result(), None))
            except Exception as exc:  # noqa: BLE001 - reported per payload
                out.append((f, None, exc))
        return out

    def close(self, cancel: bool = False) -> None:
        if self.own is not None:
            self.own.close()
        if self.cluster is not None:
            self.cluster.close()


def make_engine(engine: str, fn, workers: int | None = None, *, client=None, executor=None,
                key=lambda p: "task") -> Engine:
    """The engine named ``engine`` (``serial``, ``process``, ``local``, ``tcp://...``) running ``fn``;
    an existing Dask ``client`` or pool ``executor`` takes precedence."""
    if client is not None:
        return DaskEngine(fn, client=client, key=key)
    if executor is not None or engine == "process":
        return PoolEngine(fn, workers, executor)
    if engine == "serial":
        return SerialEngine(fn)
    return DaskEngine(fn, engine, workers, key=key)
