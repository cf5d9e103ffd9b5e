"""Which worker computes which cell of a sweep: lanes of neighbouring lengths of one TPI.

A worker's designer is built for one TPI (:class:`seekopt.evaluate.sweep_cell.CellRunner`) and predicts
each design's length from the neighbouring lengths it designed before, so a sweep is fastest when
one worker (a *lane*) computes all the lengths of one TPI in turn.  :class:`LanePlan` hands out the
cells that way:

* the cells are grouped by TPI; each group's lengths are handed out longest first (the expensive
  designs early, the quick ones last, so the workers finish together);
* a lane takes the next cell of its group; when its group is empty it takes a TPI no lane has
  started; when there is none, it takes the shorter half of the lengths left in the group with the
  most cells left (one more designer built, the workers busy until the end), or the cell a lane
  gave back.

The plan decides only who computes what; a cell's numbers do not depend on it.
"""
from __future__ import annotations

from collections import deque

__all__ = ["LanePlan"]


class LanePlan:
    """Cells ``(tpi, tracks)`` handed out to ``lanes`` workers (module notes).

    Parameters
    ----------
    cells : list of (float, float)
        ``(tpi, tracks)`` pairs to compute (TPI, track).
    lanes : int
        Workers.
    """

    def __init__(self, cells, lanes: int):
        by_tpi: dict = {}
        for tpi, k in cells:
            by_tpi.setdefault(tpi, []).append(k)
        self.groups = [(tpi, deque(sorted(ks, reverse=True))) for tpi, ks in sorted(by_tpi.items())]
        self.fresh = deque(range(len(self.groups)))      # groups no lane has started
        self.current = [None] * max(int(lanes), 1)       # lane -> its group
        self.returned: deque = deque()                   # cells given back (e.g. a dead sweep's claims)
        self.splits = 0

    def __bool__(self) -> bool:
        return bool(self.returned) or any(ks for _, ks in self.groups)

    def give_back(self, tpi: float, tracks: float) -> None:
        """A cell to compute again (first out of :meth:`next`)."""
        self.returned.append((tpi, tracks))

    def next(self, lane: int):
        """The next cell ``(tpi, tracks)`` for ``lane``, or None when every cell is handed out."""
        if self.returned:
            return self.returned.popleft()
        g = self.current[lane]
        if g is None or not self.groups[g][1]:
            g = self._new_group(lane)
            if g is None:
                return None
        tpi, ks = self.groups[g]
        return tpi, ks.popleft()

    def _new_group(self, lane: int):
        if self.fresh:
            g = self.fresh.popleft()
        else:
            mine = self.current[lane]
            others = [i for i in set(self.current) if i is not None and i != mine and len(self.groups[i][1]) >= 2]
            if not others:      # nothing worth splitting: take a single cell left anywhere
                others = [i for i, (_, ks) in enumerate(self.groups) if ks]
                if not others:
                    return None
                g = others[0]
                self.current[lane] = g
                return g
            big = max(others, key=lambda i: len(self.groups[i][1]))
            tpi, ks = self.groups[big]
            half = deque(ks.pop() for _ in range(len(ks) // 2))     # the shorter lengths, longest first
            half.reverse()
            self.groups.append((tpi, half))
            g = len(self.groups) - 1
            self.splits += 1
        self.current[lane] = g
        return g
