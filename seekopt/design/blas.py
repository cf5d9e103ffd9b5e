"""BLAS thread limits for a design (:attr:`seekopt.design.problem.SolverSettings.blas_threads`).

The process's thread pools are found once with :mod:`threadpoolctl` and reused: ``threadpool_limits``
scans the loaded libraries on every call.
"""
from __future__ import annotations

import contextlib
import sys

from threadpoolctl import ThreadpoolController

__all__ = ["blas_limit"]

_POOLS: list = [None, -1]      # ThreadpoolController, len(sys.modules) when it was made


def _blas_pools() -> ThreadpoolController:
    """The process's thread pools (threadpoolctl), found once: ``threadpool_limits`` scans the loaded
    libraries (``/proc/self/maps``) on every call, 5 ms of a 20-50 ms nominal design.  Scanned again
    when modules have been imported since (a new extension may bring its own BLAS)."""
    if _POOLS[0] is None or _POOLS[1] != len(sys.modules):
        _POOLS[:] = [ThreadpoolController(), len(sys.modules)]
    return _POOLS[0]


def blas_limit(n: int | None):
    """Context manager limiting BLAS to ``n`` threads (``None`` or 0: leave the pools as they are)."""
    return _blas_pools().limit(limits=int(n), user_api="blas") if n else contextlib.nullcontext()
