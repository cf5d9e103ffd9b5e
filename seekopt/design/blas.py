"""The one BLAS thread limiter of seekopt: per design (:func:`blas_limit`, a context manager,
:attr:`seekopt.design.problem.SolverSettings.blas_threads`) and per process (:func:`limit_blas`: sweep
workers, the command line).

The design's matrices are small: multi-threaded BLAS costs more than it gains on them (a 19 x 19
``expm`` took 1.06 ms with the default threads and 0.03 ms with one, issue 12), and several sweep
workers with several BLAS threads each oversubscribe the cores.  Both limiters act through one
:class:`threadpoolctl.ThreadpoolController`, found once and reused: ``threadpool_limits`` scans the
loaded libraries on every call (``/proc/self/maps``, 5 ms of a 20-50 ms nominal design); it is scanned
again when modules have been imported since (a new extension may bring its own BLAS).
"""
from __future__ import annotations

import contextlib
import os
import sys

__all__ = ["blas_limit", "limit_blas", "BLAS_ENV_VARS"]

#: Environment variables that set the thread count of BLAS/OpenMP libraries loaded later.
BLAS_ENV_VARS = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "VECLIB_MAXIMUM_THREADS")

_POOLS: list = [None, -1]      # ThreadpoolController, len(sys.modules) when it was made


def _blas_pools():
    """The process's thread pools (:class:`threadpoolctl.ThreadpoolController`), found once; found
    again when modules have been imported since."""
    if _POOLS[0] is None or _POOLS[1] != len(sys.modules):
        from threadpoolctl import ThreadpoolController
        _POOLS[:] = [ThreadpoolController(), len(sys.modules)]
    return _POOLS[0]


def blas_limit(n: int | None):
    """Context manager limiting the loaded BLAS libraries to ``n`` threads for its duration (``None``
    or 0: leave the pools as they are)."""
    return _blas_pools().limit(limits=int(n), user_api="blas") if n else contextlib.nullcontext()


def limit_blas(n: int = 1, *, override_env: bool = True):
    """Limit this process to ``n`` BLAS/OpenMP threads; returns the :mod:`threadpoolctl` limiter (also a
    context manager that restores the previous limits on exit), or a null context when no BLAS is loaded
    yet and the environment variables alone set ``n`` (the libraries read them when they load).

    The environment variables (:data:`BLAS_ENV_VARS`) cover libraries loaded later
    (``override_env=False`` keeps a value the user set).  numpy and scipy each bring their own
    OpenBLAS, and threadpoolctl limits only the libraries already loaded: both are loaded first, so
    the one loaded second does not escape.
    """
    for var in BLAS_ENV_VARS:
        if override_env:
            os.environ[var] = str(n)
        else:
            os.environ.setdefault(var, str(n))
    if "numpy" not in sys.modules and "scipy" not in sys.modules and all(
            os.environ[var] == str(n) for var in BLAS_ENV_VARS):
        # no BLAS loaded yet: numpy's and scipy's OpenBLAS read the variables when they load (measured:
        # both then report n threads), so nothing needs loading now -- a command that never needs
        # scipy does not import it (scipy.linalg: 0.18 s CPU), and threadpoolctl is left for later
        return contextlib.nullcontext()
    import numpy  # noqa: F401
    import scipy.linalg  # noqa: F401
    return _blas_pools().limit(limits=int(n))
