"""Small QPs shared by the certificate tests (not a test module)."""
from __future__ import annotations

import numpy as np


def two_conflicting_rows(seed: int = 7, n: int = 6, spare_rows: int = 200):
    """Rows ``a`` (index 0: ``x0 + x1 >= 1.5``) and ``b`` (index ``spare_rows // 2 + 1``: ``x0 - x1 >= 1.5``) that
    together need ``x0 >= 1.5`` beyond the box ``|x| <= 1``, among ``spare_rows`` random rows ``|spare x| <= 50``
    that never bind.  Returns ``(A, lba, uba, lbx, ubx)``."""
    rng = np.random.default_rng(seed)
    lbx, ubx = -np.ones(n), np.ones(n)
    a = np.zeros(n); a[:2] = 1.0
    b = np.zeros(n); b[0], b[1] = 1.0, -1.0
    spare = rng.standard_normal((spare_rows, n))
    h = spare_rows // 2
    A = np.vstack([a, spare[:h], b, spare[h:]])
    lba = np.r_[1.5, np.full(h, -50.0), 1.5, np.full(spare_rows - h, -50.0)]
    uba = np.r_[np.inf, np.full(h, 50.0), np.inf, np.full(spare_rows - h, 50.0)]
    return A, lba, uba, lbx, ubx
