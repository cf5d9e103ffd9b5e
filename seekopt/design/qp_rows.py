"""The constraint rows of a seek QP (:class:`seekopt.design.qp.SeekQP`) as an operator: explicit rows plus
*derived* rows that are a signed sum of an explicit row and one of a few shared rows, never stored.

The blind-band rows (:mod:`seekopt.design.blind_pes`) are ``e_i(k) +- d_f(k)``: a band plant's PES row
plus or minus the PES a hypothetical mode at ``f`` adds, for every band plant ``i``, grid frequency ``f``
and sign -- 10 derived rows per band row with 5 grid points.  Stored whole they were 54 000 of a robust
structure's 66 000 rows (``(66 000, 208)``: 110 MB per matrix; each seek length's ``A(K)``, its ``|A|``
and every full product read it all).  Here each is the pair (explicit row ``p``, shared row ``d``,
sign ``s``)::

    A[m_b + j] = A[p_j] + s_j D[d_j]          (m_b explicit rows first, derived rows after)

with ``A = A0 + |K| A1`` and ``D = D0 + |K| D1`` (the seek QP's ``K``-scaling); the products are formed
from the explicit rows' and the shared rows' products (the same sums, in the same order, as the stored
rows gave).  Units: the seek QP's scaled rows (bands, ``Imax``).
"""
from __future__ import annotations

import numpy as np

__all__ = ["SeekRows", "block_parts", "assemble_blocks"]


def _as_slice(idx: np.ndarray):
    """``idx`` as a slice when it is a run of consecutive indices (a view, not a gather), else ``idx``."""
    if idx.size and np.all(np.diff(idx) == 1):
        return slice(int(idx[0]), int(idx[-1]) + 1)
    return idx


class SeekRows:
    """Rows ``A(K)`` of a seek QP: ``m_b`` explicit rows ``A0 + |K| A1`` and derived rows
    ``A[p] + s (D0 + |K| D1)[d]`` (module docstring).

    Parameters
    ----------
    A0, A1 : (m_b, n) ndarray
        Explicit rows (``A1``: the part scaled by ``|K|``).
    D0, D1 : (m_d, n) ndarray or None
        Shared rows of the derived rows.
    p, d : (m_v,) int ndarray
        Explicit row and shared row of each derived row.
    s : (m_v,) ndarray
        Sign of the shared row in each derived row (+-1).
    """

    def __init__(self, A0, A1, D0=None, D1=None, p=None, d=None, s=None):
        A0, A1 = np.asarray(A0, dtype=float), np.asarray(A1, dtype=float)
        n = A0.shape[1]
        self._setup(n, (np.arange(n), A0), (np.arange(n), A1), D0, D1, p, d, s)

    @classmethod
    def from_parts(cls, n: int, part0, part1, D0=None, D1=None, p=None, d=None, s=None) -> "SeekRows":
        """The rows from each part's entries on its columns only: ``part0 = (cols, P)`` with ``A0[:, cols] = P``
        (``A0`` zero elsewhere), ``part1`` likewise for ``A1`` -- the full ``(m_b, n)`` arrays are never
        written (:attr:`A0`, :attr:`A1` build them when asked)."""
        self = cls.__new__(cls)
        self._setup(int(n), part0, part1, D0, D1, p, d, s)
        return self

    def _setup(self, n, part0, part1, D0, D1, p, d, s):
        (cols0, Q0), (cols1, Q1) = part0, part1
        self.m_b, self.n = Q0.shape[0], n
        z = np.zeros(0, dtype=int)
        self.p = z if p is None else np.asarray(p, dtype=int)
        self.d = z if d is None else np.asarray(d, dtype=int)
        self.s = np.zeros(0) if s is None else np.asarray(s, dtype=float)
        self.D0 = np.zeros((0, self.n)) if D0 is None else D0
        self.D1 = np.zeros((0, self.n)) if D1 is None else D1
        self.m = self.m_b + self.p.size
        # the columns each part lives on (A0: feedforward and epigraph, A1: reference): products read
        # only those, and A(K) is never formed (a robust structure's explicit rows are 20 MB per part)
        nz0, nz1 = np.any(Q0 != 0, axis=0), np.any(Q1 != 0, axis=0)
        self._c0, self._c1 = np.asarray(cols0, dtype=int)[nz0], np.asarray(cols1, dtype=int)[nz1]
        # column-major, as a column selection gives (BLAS's products on it: the same sums as always)
        self._P0 = Q0 if nz0.all() and Q0.flags.f_contiguous else np.asfortranarray(Q0[:, nz0])
        self._P1 = Q1 if nz1.all() and Q1.flags.f_contiguous else np.asfortranarray(Q1[:, nz1])
        self._full = None
        # parts on disjoint columns (the seek QP's): an entry of A(K) is one part's, or zero
        self._disjoint = not np.intersect1d(self._c0, self._c1).size
        self._at0, self._at1 = np.full(self.n, -1), np.full(self.n, -1)    # column -> its place in a part
        self._at0[self._c0] = np.arange(self._c0.size)
        self._at1[self._c1] = np.arange(self._c1.size)
        self._aK = 0.0
        self._Dk = self.D0
        self._abs = None
        self._cols_key, self._cols_map = None, None     # _col_map of the last columns
        self._dcols = None                              # the shared rows at |K| on the last columns

    @property
    def A0(self) -> np.ndarray:
        """The explicit rows' ``|K|``-free part, ``(m_b, n)`` (written out on first use)."""
        return self._explicit()[0]

    @property
    def A1(self) -> np.ndarray:
        """The explicit rows' part scaled by ``|K|``, ``(m_b, n)`` (written out on first use)."""
        return self._explicit()[1]

    def _explicit(self):
        if self._full is None:
            A0, A1 = np.zeros((self.m_b, self.n)), np.zeros((self.m_b, self.n))
            A0[:, self._c0] = self._P0
            A1[:, self._c1] = self._P1
            self._full = (A0, A1)
        return self._full

    def at(self, aK: float) -> "SeekRows":
        """Fix ``|K|`` (kept until the next call with another ``|K|``)."""
        aK = float(aK)
        if self._aK != aK:
            self._aK = aK
            self._Dk = self.D0 + aK * self.D1
            self._dcols = None
        return self

    def _base(self, x: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
        t = self._P1 @ x[self._c1]
        t *= self._aK
        return np.add(self._P0 @ x[self._c0], t, out=out)

    def explicit_matvec(self, x: np.ndarray) -> np.ndarray:
        """``A x`` over the ``m_b`` explicit rows."""
        return self._base(x)

    def matvec(self, x: np.ndarray) -> np.ndarray:
        """``A x`` over all ``m`` rows."""
        if not self.p.size:
            return self._base(x)
        out = np.empty(self.m)
        b, v = out[:self.m_b], out[self.m_b:]
        self._base(x, out=b)
        np.multiply(self.s, (self._Dk @ x)[self.d], out=v)
        v += b[self.p]          # = b[p] + s (D x)[d], the same sum (addition commutes)
        return out

    def abs_matvec(self, ax: np.ndarray) -> np.ndarray:
        """``|A| ax`` for ``ax >= 0``, each row's ``|A0 + |K| A1|`` taken as ``|A0| + |K| |A1|`` (exact where
        the parts have no column in common, as in the seek QP) and a derived row's ``|A[p] + s D[d]|`` as
        ``|A[p]| + |D[d]|``: the size of the terms its product sums (the cancellation level of a re-check)."""
        if self._abs is None:
            self._abs = (np.abs(self._P0), np.abs(self._P1), np.abs(self.D0), np.abs(self.D1))
        a0, a1, d0, d1 = self._abs
        b = a0 @ ax[self._c0] + self._aK * (a1 @ ax[self._c1])
        if not self.p.size:
            return b
        return np.concatenate([b, b[self.p] + (d0 @ ax + self._aK * (d1 @ ax))[self.d]])

    def _rows(self, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
        """Explicit rows ``rows`` (< ``m_b``) of ``A0 + |K| A1`` on columns ``cols`` (from the parts' own
        columns: whole rows of contiguous arrays, then the columns).  Parts on disjoint columns: each part's
        columns among ``cols`` picked from its rows (the same numbers: ``|K| A1`` is the one product, no sum)."""
        if self._disjoint:
            j0, i0, j1, i1 = self._col_map(cols)
            out = np.zeros((rows.size, cols.size))
            out[:, j0] = self._P0[rows, i0] if isinstance(i0, slice) else self._P0[rows][:, i0]
            out[:, j1] = self._aK * (self._P1[rows, i1] if isinstance(i1, slice) else self._P1[rows][:, i1])
            return out
        out = np.zeros((rows.size, self.n))
        out[:, self._c0] = self._P0[rows]
        out[:, self._c1] += self._aK * self._P1[rows]
        return out[:, cols]

    def _col_map(self, cols: np.ndarray):
        """``(j0, i0, j1, i1)``: the places ``j`` in ``cols`` of the columns of part 0 / 1 and their places ``i``
        in the part (the last ``cols``' kept: a working set's rounds share them)."""
        if self._cols_key is None or not np.array_equal(self._cols_key, cols):
            a0, a1 = self._at0[cols], self._at1[cols]
            j0, j1 = np.flatnonzero(a0 >= 0), np.flatnonzero(a1 >= 0)
            self._cols_key = cols.copy()
            self._cols_map = tuple(_as_slice(v) for v in (j0, a0[j0], j1, a1[j1]))
            self._dcols = None
        return self._cols_map

    def _shared_cols(self, cols: np.ndarray) -> np.ndarray:
        """The shared rows ``D0 + |K| D1`` on columns ``cols`` (kept for the last ``|K|`` and columns)."""
        if self._dcols is None or not np.array_equal(self._dcols[0], cols):
            self._dcols = (cols.copy(), self._Dk[:, cols])
        return self._dcols[1]

    def take(self, rows: np.ndarray, cols: np.ndarray | None = None) -> np.ndarray:
        """The rows ``rows`` (and columns ``cols``) as an explicit array: a derived row is its explicit row's
        entries plus its signed shared row's (gathered with the explicit rows, then added)."""
        rows = np.asarray(rows, dtype=int)
        cols = np.arange(self.n) if cols is None else np.asarray(cols, dtype=int)
        der = np.flatnonzero(rows >= self.m_b)
        if not der.size:
            return self._rows(rows, cols)
        j = rows[der] - self.m_b
        src = rows.copy()
        src[der] = self.p[j]
        out = self._rows(src, cols)
        add = self.s[j, None] * self._shared_cols(cols)[self.d[j]]
        if der[0] == rows.size - der.size:       # derived rows last (sorted rows): one slice
            out[der[0]:] += add
        else:
            out[der] += add
        return out

    def dense(self) -> np.ndarray:
        """``A(K)`` whole (``m`` rows; for a solve on every row, rarely needed)."""
        return self.take(np.arange(self.m))

    @staticmethod
    def expand(A0, A1, D0, D1, p, d, s) -> tuple:
        """``(A0, A1)`` of every row, derived rows written out (the ``K``-independent parts)."""
        if not len(p):
            return A0, A1
        return (np.vstack([A0, A0[p] + s[:, None] * D0[d]]), np.vstack([A1, A1[p] + s[:, None] * D1[d]]))


# ---------------------------------------------------------------- row blocks of a seek QP (moved from qp.py)
def block_parts(blocks, n: int, N: int):
    """The row blocks of :func:`assemble_blocks` as :meth:`SeekRows.from_parts`' parts, ``((cols0, P0), (cols1, P1))``:
    ``a_v`` (and ``t`` on the last column) in ``P0`` on columns ``0..N-1`` (and ``n - 1``), ``a_q`` in ``P1`` on
    the reference columns ``N..`` -- the ``A0``, ``A1`` of :func:`assemble_blocks` on those columns only."""
    m = sum(v.shape[0] for v, _, _ in blocks)
    has_t = any(t is not None for _, _, t in blocks)
    nq = max([q.shape[1] for _, q, _ in blocks if q is not None], default=0)
    P0 = np.zeros((m, N + has_t), order="F")       # column-major: SeekRows keeps its parts so
    P1 = np.zeros((m, nq), order="F")
    r = 0
    for v, q, t in blocks:
        k = v.shape[0]
        P0[r:r + k, :N] = v
        if q is not None:
            P1[r:r + k, :q.shape[1]] = q
        if t is not None:
            P0[r:r + k, -1] = t
        r += k
    cols0 = np.r_[np.arange(N), n - 1] if has_t else np.arange(N)
    return (cols0, P0), (N + np.arange(nq), P1)


def assemble_blocks(blocks, n: int, N: int):
    """``(A0, A1)``: row blocks ``(a_v, a_q, t)`` placed into two ``(rows, n)`` arrays -- ``a_v`` on the
    ``N`` feedforward columns and ``t`` (a number) on the epigraph column of ``A0``, ``a_q`` on the
    reference columns ``N..`` of ``A1``: :func:`block_parts` written out at full width."""
    (c0, P0), (c1, P1) = block_parts(blocks, n, N)
    A0, A1 = np.zeros((P0.shape[0], n)), np.zeros((P1.shape[0], n))
    A0[:, c0] = P0
    A1[:, c1] = P1
    return A0, A1
