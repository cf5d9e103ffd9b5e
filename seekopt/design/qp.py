"""The condensed dense seek-design QP: closed-loop convolution maps (:class:`LoopMaps`) and the
QP of one seek-size class (:class:`SeekQP`).

The 2DOF loop ``u = u_ff + C (r - y)`` around the linear part of a plant is linear and
time-invariant at the servo rate, so the head position and the sub-step currents are
convolutions of ``u_ff`` and ``r`` with the loop's impulse responses.  Those come from the
one simulator (:func:`seekopt.drive.simulator.closed_loop_responses`); :class:`LoopMaps` turns them
into Toeplitz rows on demand::

    y(k)      = sum_j h_yu(k-j) u_ff(j) + sum_j h_yr(k-j) r(j)
    i(k, l)   = sum_j h_iu(k-j, l) u_ff(j) + sum_j h_ir(k-j, l) r(j) + i_hold

(``l`` the ``L`` current sub-steps of sample ``k``; ``i_hold = -bias_a``).

The QP's pieces: its rows as an operator (:mod:`seekopt.design.qp_rows`), the samples that carry them
(:mod:`seekopt.design.qp_samples`, re-exported here), its objective (:mod:`seekopt.design.qp_objective`).
The QP solvers (casadi.conic plugins, Ipopt, the fallback chain) are in :mod:`seekopt.design.solvers`.
"""
from __future__ import annotations

import time

import numpy as np

from seekopt.design.loop_maps import LoopMaps, toeplitz_rows
from seekopt.design.profiles import rigid_endpoint_matrix
from seekopt.design.qp_objective import seek_objective
from seekopt.design.qp_rows import SeekRows, assemble_blocks, block_parts
from seekopt.design.qp_samples import pes_row_samples, set_row_samples
# solver names re-exported for callers of the former combined module
from seekopt.design.modal_residual import (dtft, hf_guard_matrix, mode_residual_phasors,  # noqa: F401
                                            mode_residual_rows, mode_residuals)
from seekopt.design.solvers import (QP_PLUGINS, ConicQP, IpoptQP, QPSolution, constraint_violation, dm,  # noqa: F401
                                     make_qp_solver, violation_of)

__all__ = ["LoopMaps", "toeplitz_rows", "hf_guard_matrix", "mode_residual_phasors", "mode_residual_rows", "mode_residuals", "dtft", "pes_row_samples", "set_row_samples", "SeekQP"]


# ---------------------------------------------------------------------------- the seek QP
class SeekQP:
    """The condensed seek-design QP for seeks that settle within at most ``nmax`` samples (one size class).

    Scaled decision vector ``x = [v, q, t]`` (O(1) numbers)::

        v_k = u_ff(k) / Imax,  q_k = (r(k) - K) / |K|   (k < nmax + input_tail; pinned to 0 for k >= N + input_tail),
        t   = worst settle-band residual / band          (epigraph variant only)

    ``input_tail``: samples the feedforward and reference may go on after the settle sample ``N`` (the
    seek-settle time counts ``|PES|`` only: the inputs may keep shaping the loop while the head is
    inside the band); 0: they end at ``N``.

    With ``reference="model"`` (or ``"rigid"``) there is no ``q``: ``r = R u_ff`` with ``R`` the
    Toeplitz map of the reference model's open-loop impulse response.

    Rows (each scaled to O(1); ``K`` enters as ``A(K) = A0 + |K| A1`` plus K-linear offsets):

    * settle band, plant ``i``, sample ``k``: ``e = (y_i(k) - K) / band`` in ``[-beta, beta]``
      for ``k >= N`` (rows for ``k < N`` are free); epigraph variant: ``-t <= e <= t``;
    * total current, each sub-step of ``k < nmax + 40`` (other plants of the set: ``nmax + 8``):
      ``|i| / Imax <= gamma``;
    * unmodelled-mode guard (nominal plant): residual of modes in ``[f_lo, f_hi]`` <= ``hf_tol band``;
    * blind-band mode's PES (``bpes``, :mod:`seekopt.design.blind_pes`) added to each band plant's of
      ``bpes_plants`` (None: all), both signs, samples ``k >= N`` (minimum seek-settle designs only):
      ``|e_i(k) +- dPES_f(k) / band| <= bpes_tol`` (derived rows after all others, never stored:
      :class:`~seekopt.design.qp_rows.SeekRows`, :attr:`rows`; ``A0``, ``A1`` hold the explicit rows);
    * rigid rest-to-rest: ``M u_ff = [K, 0]`` (:func:`seekopt.design.profiles.rigid_endpoint_matrix`);
    * optional slew ``|u_ff(k) - u_ff(k-1)| <= slew / fs``.

    Objective: ``rho |D v|^2 + rho_q |D q|^2 + w_e mean_i,k>=nmax e^2 (+ w_t t^2)``
    (:func:`~seekopt.design.qp_objective.seek_objective`).
    The solver of the full QP is built on first use; :meth:`numeric` gives its data as numpy arrays
    (read by the solvers through zero-copy buffers), :meth:`data` as :class:`casadi.DM`.
    """

    def __init__(self, maps: list, nmax: int, horizon: int, imax: float, band: float, fs: float,
                 band_plants: list, solver, *, epigraph: bool = False, R=None, hf=None, slew=None,
                 rho: float = 1e-2, rho_q: float = 1e-3, w_e: float = 1.0, w_t: float = 10.0,
                 eps: float = 1e-9, current_extra: int = 40, stride: int = 1, input_tail: int = 0,
                 bpes=None, bpes_tol: float | None = None, bpes_plants=None):
        t_build = time.perf_counter()
        Ns, Hn = int(nmax), int(horizon)
        self.input_tail = int(input_tail)
        N = Ns + self.input_tail            # input samples (the rows below use N input columns)
        if N > Hn:
            raise ValueError(f"input samples {N} beyond the horizon {Hn}")
        self.N, self.nin = Ns, N
        self.horizon, self.imax, self.band, self.fs = Hn, float(imax), float(band), float(fs)
        self.free_ref = R is None
        self.epigraph = bool(epigraph)
        nq = N if self.free_ref else 0
        self.nv, self.nq, self.nt = N, nq, int(epigraph)
        n = N + nq + self.nt
        self.n = n
        ks = pes_row_samples(Ns, Hn)
        self.pes_k = ks
        ncur = min(Hn, N + current_extra)
        blocks, c0, c1 = [], [], []    # offsets: c = c0 + K c1 (band / Imax units)
        kinds = []      # (kind, plant, samples) per block of rows
        pes_at = {}     # plant -> (first row, samples) of its "pes" block

        if not self.free_ref:
            Rfull = np.asarray(R, float)[:Hn, :N]
        ks_other = set_row_samples(Ns, Hn, stride)     # thinned for the other plants (pairs of adjacent samples)
        for i, m in enumerate(maps):
            ksi = ks if i == 0 else ks_other
            Tyu, Tyr, syr = m.position_rows(ksi, N if self.free_ref else Hn)
            if self.free_ref:
                av, aq = imax * Tyu / band, Tyr / band
                off0, off1 = np.zeros(len(ksi)), (syr - 1.0) / band
            else:
                av, aq = imax * (Tyu[:, :N] + Tyr @ Rfull) / band, None
                off0, off1 = np.zeros(len(ksi)), -np.ones(len(ksi)) / band
            reps = ((-1.0, "pes_hi"), (1.0, "pes_lo")) if epigraph else ((0.0, "pes"),)
            for sgn, kind in reps:
                blocks.append((av, aq, sgn if epigraph else None)); c0.append(off0); c1.append(off1)
                if kind == "pes":
                    pes_at[i] = (sum(len(kd[2]) for kd in kinds), ksi)
                kinds.append((kind, i, np.asarray(ksi, dtype=int)))
        for i, m in enumerate(maps):   # nominal: seek + 40 samples; other plants: seek + 8 (never thinned)
            Tiu, Tir, sir = m.current_rows(ncur if i == 0 else min(Hn, N + 8), N if self.free_ref else Hn)
            if self.free_ref:
                av, aq = Tiu, Tir / imax
                off0, off1 = np.full(len(sir), m.hold_a / imax), sir / imax
            else:
                av, aq = Tiu[:, :N] + Tir @ Rfull, None
                off0, off1 = np.full(Tiu.shape[0], m.hold_a / imax), np.zeros(Tiu.shape[0])
            blocks.append((av, aq, None)); c0.append(off0); c1.append(off1)
            kinds.append(("cur", i, np.arange(av.shape[0])))
        if hf is not None:     # hf = (G, freqs): rows on the nominal plant's sub-step currents
            G = hf[0]
            m = maps[0]
            Tiu, Tir, sir = m.current_rows(Hn, N if self.free_ref else Hn)
            # the hold current -bias_a has been on since long before the seek: it leaves no residual in
            # a mode (over the finite horizon it would look like a step and bias the guard)
            if self.free_ref:
                av, aq = imax * G @ Tiu / band, G @ Tir / band
                off0, off1 = np.zeros(G.shape[0]), G @ sir / band
            else:
                av, aq = imax * G @ (Tiu[:, :N] + Tir @ Rfull) / band, None
                off0, off1 = np.zeros(G.shape[0]), np.zeros(G.shape[0])
            blocks.append((av, aq, None)); c0.append(off0); c1.append(off1)
            kinds.append(("hf", 0, np.arange(G.shape[0])))
        ncol = N if self.free_ref else Hn

        def pos_block(h_u, h_r, s_r, target):
            """``(a_v, a_q, off0, off1)`` of position rows ``(y - target K) / band`` on ``ks_other``."""
            Tu, Tr = toeplitz_rows(h_u, ks_other, ncol), toeplitz_rows(h_r, ks_other, ncol)
            z = np.zeros(len(ks_other))
            if self.free_ref:
                return imax * Tu / band, Tr / band, z, (s_r[ks_other] - target) / band
            return imax * (Tu[:, :N] + Tr @ Rfull) / band, None, z, z - target / band
        M = rigid_endpoint_matrix(N, maps[0].k0, 1.0 / fs)
        self.M = M
        # rows scaled by the bucket's reach: s_pos = k0 Ts^2 Imax N^2 / 4, s_vel = k0 Ts^2 Imax N
        self.s_pos = maps[0].k0 * imax * N * N / (4 * fs * fs)
        self.s_vel = maps[0].k0 * imax * N / (fs * fs)
        av = np.zeros((2, N)); av[0] = M[0] * imax / self.s_pos; av[1] = M[1] * imax / self.s_vel
        blocks.append((av, None, None)); c0.append(np.zeros(2)); c1.append(np.zeros(2))
        kinds.append(("rigid", 0, np.arange(2)))
        if slew is not None:
            D = np.eye(N + 1, N) - np.eye(N + 1, N, -1)
            blocks.append((D, None, None)); c0.append(np.zeros(N + 1)); c1.append(np.zeros(N + 1))
            kinds.append(("slew", 0, np.arange(N + 1)))
        explicit = block_parts(blocks, n, N)    # the explicit rows, on their columns
        # a blind-band mode's PES added to each band plant's (seekopt.design.blind_pes), both signs: derived
        # rows (a band row +- a shared row, seekopt.design.qp_rows), after the explicit rows;
        # ``bpes_plants``: only those (None: every band plant)
        bp_plants = [i for i in range(len(maps)) if i in set(band_plants)
                     and (bpes_plants is None or i in set(bpes_plants))] if bpes else []
        if bp_plants and epigraph:
            raise ValueError("blind-band PES rows need the band rows of the non-epigraph QP")
        D0 = D1 = None
        vp, vd, vs = [], [], []
        if bp_plants:
            dblocks = []
            for dy_u, dy_r in bpes:
                dv, dq, d0, d1 = pos_block(dy_u, dy_r, np.cumsum(dy_r), 0.0)
                dblocks.append((dv, dq, None, d0, d1))
            D0, D1 = assemble_blocks([b[:3] for b in dblocks], n, N)
            nk = len(ks_other)
            c0b, c1b = np.concatenate(c0), np.concatenate(c1)
            for i in bp_plants:
                r0, ksi = pes_at[i]          # the plant's band rows on ks_other's samples
                at = np.searchsorted(ksi, ks_other)
                if not np.array_equal(ksi[np.minimum(at, len(ksi) - 1)], ks_other):
                    raise ValueError("blind-band PES samples without band rows")
                prow = r0 + at
                for f, b in enumerate(dblocks):
                    for sgn in (1.0, -1.0):
                        vp.append(prow); vd.append(f * nk + np.arange(nk)); vs.append(np.full(nk, sgn))
                        c0.append(c0b[prow] + sgn * b[3]); c1.append(c1b[prow] + sgn * b[4])
                        kinds.append(("bpes", i, np.asarray(ks_other, dtype=int)))
        cat = (lambda v: np.concatenate(v)) if vp else (lambda v: None)
        self.rows = SeekRows.from_parts(n, *explicit, D0, D1, cat(vp), cat(vd), cat(vs))
        lens = [len(kd[2]) for kd in kinds]
        self.kind = np.repeat(np.array([kd[0] for kd in kinds]), lens)
        self.plant_idx = np.repeat(np.array([kd[1] for kd in kinds], dtype=int), lens)
        self.sample = np.concatenate([kd[2] for kd in kinds])
        self.c0, self.c1 = np.concatenate(c0), np.concatenate(c1)
        self.m = self.rows.m
        self.band_plants = set(band_plants)
        self.slew = slew
        # ---- objective: smoothness, reference smoothness, tail energy (k >= nmax), epigraph
        self._P0, self._P1, self._P2, self._q1, self._q2 = seek_objective(     # g = K q1 + K|K| q2
            maps, Ns, Hn, N, None if self.free_ref else Rfull, imax, band, epigraph, rho, rho_q, w_e, w_t, eps)
        self._dm_cache = None      # casadi copies of the full matrices, made on first full solve
        self._H_K, self._H = None, None          # H of the last |K| (hessian())
        self._mat_K, self._mat = None, None      # (H, A) written out, of the last |K| (matrices())
        self._make_solver, self._solver = solver, None
        self._bounds_key, self._bounds = None, None      # bounds() of the last arguments
        # row masks of bounds() (computed once)
        self._pes = np.isin(self.kind, ("pes", "pes_hi", "pes_lo")) & np.isin(self.plant_idx, list(self.band_plants))
        self._masks = {k: self.kind == k for k in ("pes_hi", "pes_lo", "cur", "hf", "bpes", "rigid", "slew")}
        self.bpes_tol = bpes_tol      # |blind-band PES| / band on the band rows' samples (None: rows free)
        self.build_time_s = time.perf_counter() - t_build

    @property
    def A0(self) -> np.ndarray:
        """The explicit rows' ``|K|``-free part ``(m_b, n)`` (:attr:`SeekRows.A0`, written out on first use)."""
        return self.rows.A0

    @property
    def A1(self) -> np.ndarray:
        """The explicit rows' part scaled by ``|K|`` (:attr:`SeekRows.A1`)."""
        return self.rows.A1

    @property
    def solver(self):
        """The full-size solver chain (built on first use: the working set rarely needs it)."""
        if self._solver is None:
            self._solver = self._make_solver(self.n, self.m)
        return self._solver

    @property
    def _dm(self) -> dict:
        if self._dm_cache is None:
            r = self.rows
            A0, A1 = SeekRows.expand(r.A0, r.A1, r.D0, r.D1, r.p, r.d, r.s)
            self._dm_cache = {k: dm(v) for k, v in (("A0", A0), ("A1", A1), ("P0", self._P0),
                                                    ("P1", self._P1), ("P2", self._P2))}
        return self._dm_cache

    # ------------------------------------------------------------------ per design
    def data(self, K: float, nseek: int, beta: float | None, gamma: float, hf_tol: float | None,
             slew_a_per_s: float | None = None, nominal_from: int | None = None):
        """Numeric QP data for a seek of ``K`` tracks in ``nseek`` samples.

        ``beta``: settle-band fraction on ``k >= nseek`` (None: band rows free); ``gamma``: current
        fraction of ``Imax``; ``hf_tol``: guard tolerance in bands; ``nominal_from``: the nominal plant's
        band rows from this sample on (at most ``nseek``; the set's other plants from ``nseek``).
        """
        aK = abs(K)
        g, lba, uba, lbx, ubx = (a.copy() for a in self.bounds(K, nseek, beta, gamma, hf_tol, slew_a_per_s,
                                                                nominal_from))     # writeable, as numeric()
        H = self._dm["P0"] + aK * self._dm["P1"] + aK * aK * self._dm["P2"]
        A = self._dm["A0"] + aK * self._dm["A1"]
        return H, g, A, lba, uba, lbx, ubx

    def hessian(self, K: float) -> np.ndarray:
        """``H`` of a seek of ``K`` tracks (the last ``K``'s is kept)."""
        aK = abs(K)
        if self._H_K != aK:
            self._H, self._H_K = self._P0 + aK * self._P1 + aK * aK * self._P2, aK
        return self._H

    def row_operator(self, K: float) -> SeekRows:
        """The rows ``A(K)`` as an operator (:class:`~seekopt.design.qp_rows.SeekRows`: products and row
        subsets without writing the derived rows out; the last ``K``'s are kept)."""
        return self.rows.at(abs(K))

    def matrices(self, K: float):
        """``(H, A)`` of a seek of ``K`` tracks as numpy arrays, every row written out (the last ``K``'s are
        kept): the QP on every row.  Solvers read them through zero-copy buffers
        (:meth:`seekopt.design.solvers.ConicQP.solve`); the working set reads :meth:`row_operator`."""
        aK = abs(K)
        if self._mat_K != aK:
            self._mat = (self.hessian(K), self.row_operator(K).dense())
            self._mat_K = aK
        return self._mat

    def numeric(self, K: float, nseek: int, beta: float | None, gamma: float, hf_tol: float | None,
                slew_a_per_s: float | None = None, nominal_from: int | None = None):
        """:meth:`data` as numpy arrays ``(H, g, A, lba, uba, lbx, ubx)`` (no casadi copies; the bounds are
        writeable copies of :meth:`bounds`' kept arrays: the ``daqp`` package reads only writeable buffers)."""
        H, A = self.matrices(K)
        g, lba, uba, lbx, ubx = (a.copy() for a in self.bounds(K, nseek, beta, gamma, hf_tol, slew_a_per_s,
                                                                nominal_from))
        return H, g, A, lba, uba, lbx, ubx

    def bounds(self, K: float, nseek: int, beta: float | None, gamma: float, hf_tol: float | None,
               slew_a_per_s: float | None = None, nominal_from: int | None = None):
        """``(g, lba, uba, lbx, ubx)`` (numpy) of :meth:`data`; the last call's arrays are kept (the designer's
        re-check and the working set ask for the same bounds of each solve) and returned read-only."""
        key = (float(K), int(nseek), beta, float(gamma), hf_tol, slew_a_per_s, nominal_from)
        if self._bounds_key == key:
            return self._bounds
        out = self._bounds_of(K, nseek, beta, gamma, hf_tol, slew_a_per_s, nominal_from)
        for a in out:
            a.flags.writeable = False
        self._bounds_key, self._bounds = key, out
        return out

    def _bounds_of(self, K, nseek, beta, gamma, hf_tol, slew_a_per_s, nominal_from):
        aK = abs(K)
        N, n = self.N, self.n
        if not 0 < nseek <= N:
            raise ValueError(f"nseek {nseek} outside 1..{N}")
        nu = nseek + self.input_tail        # input samples
        n_nom = nseek if nominal_from is None else int(nominal_from)
        if not 0 < n_nom <= nseek:
            raise ValueError(f"nominal_from {nominal_from} outside 1..{nseek}")
        g = K * self._q1 + K * aK * self._q2
        c = self.c0 + K * self.c1
        lba = np.full(self.m, -np.inf); uba = np.full(self.m, np.inf)
        mk = self._masks
        active = self._pes & (self.sample >= np.where(self.plant_idx == 0, n_nom, nseek))
        if self.epigraph:
            hi, lo = active & mk["pes_hi"], active & mk["pes_lo"]
            uba[hi] = -c[hi]; lba[lo] = -c[lo]
        elif beta is not None:
            lba[active] = -beta - c[active]; uba[active] = beta - c[active]
        if self.bpes_tol is not None and (beta is not None and not self.epigraph):
            bp = mk["bpes"] & (self.sample >= np.where(self.plant_idx == 0, n_nom, nseek))
            lba[bp] = -self.bpes_tol - c[bp]; uba[bp] = self.bpes_tol - c[bp]
        cur = mk["cur"]
        lba[cur] = -gamma - c[cur]; uba[cur] = gamma - c[cur]
        if hf_tol is not None:
            hfm = mk["hf"]
            lba[hfm] = -hf_tol - c[hfm]; uba[hfm] = hf_tol - c[hfm]
        rig = mk["rigid"]
        lba[rig] = uba[rig] = np.array([K / self.s_pos, 0.0])
        if self.slew is not None and slew_a_per_s is not None:
            sl = mk["slew"]
            lim = slew_a_per_s / (self.fs * self.imax)
            lba[sl] = -lim; uba[sl] = lim
        lbx = np.zeros(n); ubx = np.zeros(n)
        lbx[:nu], ubx[:nu] = -1.0, 1.0
        if self.nq:
            lbx[self.nin:self.nin + nu], ubx[self.nin:self.nin + nu] = -2.0, 2.0
        if self.nt:
            lbx[-1], ubx[-1] = 0.0, np.inf
        return g, lba, uba, lbx, ubx

    def violation(self, x: np.ndarray, K: float, lba, uba, lbx, ubx, A=None) -> float:
        """Largest constraint violation of ``x`` relative to the size of the terms summed in each
        row (``max(1, sum_j |a_ij x_j|)``: the cancellation level) -- re-checks a solver's answer.
        ``A``: an explicit constraint matrix to check against instead of the structure's rows at ``K``."""
        if A is not None and not isinstance(A, SeekRows):
            return constraint_violation(A, x, lba, uba, lbx, ubx)
        if not np.all(np.isfinite(x)):
            return float("inf")
        op = self.row_operator(K)
        return violation_of(op.matvec(x), op.abs_matvec(np.abs(x)), x, lba, uba, lbx, ubx)

    def unpack(self, x: np.ndarray, K: float, nseek: int):
        """``(u_ff [A], r [track, relative] or None)`` over the ``nseek + input_tail`` input samples."""
        nu = nseek + self.input_tail
        u = self.imax * x[:nu]
        r = K + abs(K) * x[self.nin:self.nin + nu] if self.nq else None
        return u, r

    def residual(self, x: np.ndarray, K: float, nseek: int, plants=None) -> float:
        """Worst ``|PES| / band`` over the band rows ``k >= nseek`` of ``plants`` (default all)."""
        mb = self.rows.m_b                 # band rows are explicit rows
        e = self.row_operator(K).explicit_matvec(x) + self.c0[:mb] + K * self.c1[:mb]
        kind, sample = self.kind[:mb], self.sample[:mb]
        sel = np.isin(kind, ("pes", "pes_hi")) & (sample >= nseek)
        if plants is not None:
            sel &= np.isin(self.plant_idx[:mb], list(plants))
        if self.epigraph:
            e = e - x[-1] * np.where(kind == "pes_hi", -1.0, 0.0)
        return float(np.max(np.abs(e[sel]))) if np.any(sel) else 0.0
