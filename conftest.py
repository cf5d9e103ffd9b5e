"""pytest configuration: one BLAS thread (small dense linear algebra is slower multithreaded
on 2 cores, and parallel workers would oversubscribe)."""
import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")
