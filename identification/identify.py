"""Identify the modal plant from a seek log: the paper's method and a robust output-error method.

``identify(log, method="robust" | "paper") -> Identification``.  Only the columns a real drive logs
are used: ``time_s``, ``current_a``, ``position_track``, ``target_track``.

``method="paper"`` (Sections 2-3 of the seed paper, in order)
    1. eq. (8): rigid-body ``b0, b1`` by LS over each seek (start to end, position relative to
       the start), pooled; ``k0 = b0 / Ts^2`` (see :mod:`identification.rigid` on ERRATA item 5).
    2. LS Prony (eqs. (4)-(7), :func:`identification.prony.ls_prony`) on the PES after settling,
       pooled over the settle windows.  As in the paper the PES is used as it is (no rigid
       prediction removed: after settling the PES is what the paper calls the modes' response).
    3. eqs. (9)-(11) (:mod:`identification.gains`): gains by LS of the settle-window PES on each
       mode's response to the measured current.

``method="robust"`` (default)
    a. pooled matrix pencil on the settle windows (automatic order, spurious-pole rejection), and
       the ZOH rigid fit with fractional delay (:func:`identification.rigid.rigid_fit`);
    b. joint output-error fit of the measured position to the measured current over whole seek
       segments (seek start to end: the seek is where the modes are excited far above the noise),
       by variable projection: ``scipy.optimize.least_squares`` over the nonlinear parameters
       (each mode's frequency and damping, the delay) with all linear parameters (``k0``,
       ``k0 bias``, ``k0 g_r``, per-segment initial position and velocity) projected out by LS at
       every evaluation.  The rigid part is the exact ZOH + delay discretisation of plant.py and
       each mode's response is run over the whole log (:func:`identification.gains.mode_response`),
       so mode states carry over from seek to seek.  The closed-loop noise (sensor noise, flutter,
       RRO) is coloured; the residual is prewhitened by an AR model estimated from the first fit's
       residual (the direct prediction-error method with an AR noise model), which makes the fit
       near-efficient and the residual near-white.  Modes missed by (a) are added by a
       matched scan of the whitened residual (one candidate mode at a time on a frequency grid),
       and modes whose gain is not significant are dropped;
    c. standard deviations from the Jacobian: Gauss-Newton covariance of the whitened problem,
       with a Newey-West (Bartlett) sandwich over the residual autocorrelation within segments
       for the colour that the AR model leaves.

Fit % on held-out seeks (both methods): seeks ``i`` with ``i % holdout_every == holdout_every - 1``
are not used in the fit.  For each, the model is simulated from the measured current (modes over
the whole log, rigid body from the seek start), the initial position and velocity of the seek
are fitted by LS over the seek (two numbers per seek), and on the settle windows ``[N, M]`` of
those seeks ``fit = 100 (1 - ||y - y_hat|| / ||y - y_bar||)`` with ``y`` the PES, ``y_hat`` the
predicted PES and ``y_bar`` the mean of ``y`` over those windows.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np
from scipy import signal
from scipy.optimize import least_squares

from .gains import mode_regressors, modal_gains
from .logs import LogError, SeekLog, segment_seeks
from .plant import ModalPlant, Mode
from .prony import fit_amplitudes, ls_prony, matrix_pencil, modal_to_z, z_to_modal
from .rigid import SegmentProjector, bias_response, eq8_fit, rigid_fit, zoh_rigid_response

__all__ = ["Identification", "identify", "heldout_fit", "VarPro"]


@dataclass
class Identification:
    """What :func:`identify` found.

    Attributes
    ----------
    plant : ModalPlant
        The identified plant; ``plant.std`` holds ``k0``, ``bias_a``, ``delay_s`` standard
        deviations and each mode's ``std`` its ``freq_hz``, ``zeta``, ``gain`` ones.
    method : str
        ``"robust"`` or ``"paper"``.
    poles_per_order : dict
        Pole sets seen on the way: ``{label: [(freq_hz, zeta), ...]}`` (pencil, Prony order,
        after each refinement stage).
    fit_percent : float
        Held-out fit % on settle windows (see the module notes); nan without held-out seeks.
    fit_percent_rigid : float
        The same for the identified rigid body alone (modes removed).
    residual_rms : float
        RMS of the fit residual [track] (robust: output error on the fit segments, before
        whitening; paper: eq. (10) residual on the settle windows).
    timing : dict
        Seconds per stage.
    diagnostics : dict
        Anything else (rejected poles, significance, AR order, inflation factor, ...).
    """
    plant: ModalPlant
    method: str
    poles_per_order: dict = field(default_factory=dict)
    fit_percent: float = float("nan")
    fit_percent_rigid: float = float("nan")
    residual_rms: float = float("nan")
    timing: dict = field(default_factory=dict)
    diagnostics: dict = field(default_factory=dict)


# ------------------------------------------------------------------------------- the OE problem
class VarPro:
    """Output-error fit of position to current over seek segments, linear parameters projected out.

    Columns (full log length, one per linear parameter): the unit-``k0`` ZOH rigid response with
    the delay (restarting at each segment start), the unit-force bias response ``t^2/2`` and each
    unit mode's response.  Each column and the data are (optionally) filtered by the whitening
    FIR ``ar`` = ``[1, a_1 .. a_p]``, restricted to the fit rows (each segment minus its first
    ``p`` samples, where the filter would mix segments) and projected orthogonally to the
    per-segment ``[1, t]`` (initial position and velocity; an affine signal stays affine under
    the FIR filter, so the nuisance space is unchanged).

    Nonlinear parameters ``x = [ln f_1..ln f_R, ln zeta_1..ln zeta_R, delay/dt]``.
    """

    def __init__(self, log: SeekLog, segments, ar=None):
        self.u = np.asarray(log.current_a, dtype=float)
        self.y = np.asarray(log.position_track, dtype=float)
        self.dt = log.dt
        self.n = len(self.u)
        self.ar = None if ar is None else np.asarray(ar, dtype=float)
        p = 0 if self.ar is None else len(self.ar) - 1
        self.segments = [(a, b) for a, b in segments if b - a >= p + 8]
        self.starts = [a for a, _ in self.segments]
        self.proj = SegmentProjector([(a + p, b) for a, b in self.segments], offsets=[p] * len(self.segments))
        self.bias = bias_response(self.n, self.dt, self.starts)
        self.yt = self.transform(self.y)
        self.nfev = 0

    def transform(self, cols):
        cols = np.asarray(cols, dtype=float)
        if self.ar is not None:
            cols = signal.lfilter(self.ar, [1.0], cols, axis=0)
        return self.proj.project(self.proj.take(cols))

    def raw_columns(self, freqs, zetas, delay_samples):
        d = delay_samples * self.dt
        R = zoh_rigid_response(self.u, self.dt, d, self.starts)
        M = mode_regressors(self.u, freqs, zetas, self.dt, d)
        return np.column_stack([R, self.bias, M])

    @staticmethod
    def unpack(x, R):
        return np.exp(x[:R]), np.exp(x[R:2 * R]), float(x[2 * R])

    def solve(self, x):
        """Transformed columns, linear coefficients, residual and an orthonormal column basis."""
        key = np.asarray(x, dtype=float).tobytes()
        if getattr(self, "_last", (None,))[0] == key:
            return self._last[1]
        R = (len(x) - 1) // 2
        f, z, d = self.unpack(x, R)
        X = self.transform(self.raw_columns(f, z, d))
        s = np.linalg.norm(X, axis=0)
        s[s == 0] = 1.0
        Q, Rm = np.linalg.qr(X / s)
        c = np.linalg.solve(Rm, Q.T @ self.yt) / s
        r = self.yt - X @ c
        self.nfev += 1
        self._last = (key, (X, c, r, Q))
        return X, c, r, Q

    def residual(self, x):
        return self.solve(x)[2]

    def jacobian(self, x, full=False):
        """Kaufman's variable-projection Jacobian ``-P_perp (dX/dx_k) c`` (columns by finite
        differences of the affected regressors).  ``full=True``: the Jacobian with respect to all
        parameters ``[x, c]`` of the unprojected-linear problem (for the covariance)."""
        R = (len(x) - 1) // 2
        X, c, r, Q = self.solve(x)
        f, z, d = self.unpack(x, R)
        D = np.zeros((len(r), len(x)))
        for k in range(R):
            for j, (df, dz) in enumerate(((1e-6, 0.0), (0.0, 1e-4))):
                col = mode_regressors(self.u, [f[k] * math.exp(df)], [z[k] * math.exp(dz)], self.dt, d * self.dt)
                D[:, k + j * R] = (self.transform(col)[:, 0] - X[:, 2 + k]) / (df + dz) * c[2 + k]
        h = 1e-3
        Xd = self.transform(self.raw_columns(f, z, d + h))
        D[:, 2 * R] = (Xd - X) @ c / h
        if full:
            return np.column_stack([-D, -X]), r
        return -(D - Q @ (Q.T @ D))

    def fit(self, x0, lb, ub, max_nfev=60):
        res = least_squares(self.residual, x0, jac=lambda x: self.jacobian(x), bounds=(lb, ub),
                            method="trf", x_scale="jac", max_nfev=max_nfev, xtol=1e-10, ftol=1e-10)
        return res.x

    def scan(self, x, freqs, zetas=(0.005, 0.02, 0.06)):
        """Residual-sum-of-squares reduction of adding one unit mode ``(f, zeta)`` to the model at
        ``x``: ``(P_perp v . r)^2 / ||P_perp v||^2`` for each grid point.  Returns (freq, zeta, gain)."""
        X, c, r, Q = self.solve(x)
        R = (len(x) - 1) // 2
        d = x[2 * R] * self.dt
        best = np.zeros((len(freqs), len(zetas)))
        for j, zt in enumerate(zetas):
            V = self.transform(mode_regressors(self.u, freqs, [zt] * len(freqs), self.dt, d))
            V = V - Q @ (Q.T @ V)
            best[:, j] = (V.T @ r) ** 2 / np.maximum(np.einsum("ij,ij->j", V, V), 1e-300)
        return best, r


def ar_whitener(resid_segments, order: int):
    """AR(``order``) prediction-error filter ``[1, a_1..a_p]`` by pooled LS (covariance method)
    over residual segments (each long enough)."""
    rows, rhs = [], []
    for e in resid_segments:
        if len(e) <= order + 4:
            continue
        W = np.lib.stride_tricks.sliding_window_view(e, order + 1)
        rows.append(W[:, :-1][:, ::-1])
        rhs.append(W[:, -1])
    A = np.vstack(rows)
    b = np.concatenate(rhs)
    a = np.linalg.lstsq(A, -b, rcond=None)[0]
    return np.r_[1.0, a]


# ------------------------------------------------------------------------------- covariance
def sandwich_cov(J, r, bounds, lags: int):
    """Covariance of LS estimates with serially correlated residuals (Newey-West, Bartlett weights).

    ``J`` (rows x params) and ``r`` are stacked segments with row ``bounds``; cross products are taken
    only within segments.  Returns ``(cov, cov_white)`` where ``cov_white = s^2 (J^T J)^-1`` is the
    plain Gauss-Newton covariance scaled by the residual variance.
    """
    s = np.linalg.norm(J, axis=0)
    s[s == 0] = 1.0
    Js = J / s
    B = np.linalg.pinv(Js.T @ Js)
    dof = max(len(r) - J.shape[1], 1)
    cov_white = B * float(r @ r) / dof
    G = Js * r[:, None]
    M = G.T @ G
    inseg = np.ones(len(r), dtype=bool)
    for lag in range(1, lags + 1):
        w = 1.0 - lag / (lags + 1.0)
        ok = np.ones(len(r) - lag, dtype=bool)
        for b in bounds[1:-1]:           # pairs (i, i + lag) that straddle a segment boundary
            ok[max(b - lag, 0):b] = False
        C = G[:-lag][ok].T @ G[lag:][ok]
        M += w * (C + C.T)
    del inseg
    cov = B @ M @ B * len(r) / dof
    return cov / np.outer(s, s), cov_white / np.outer(s, s)


# ------------------------------------------------------------------------------- held-out fit
def predict_segments(log: SeekLog, plant: ModalPlant, segments, steady: bool = True):
    """Predicted position on each segment ``[i0, i1)``: the plant's response to the measured current
    (modes over the whole log, rigid body and bias restarted at ``i0``) plus the initial position
    and velocity fitted by LS over the segment.  Returns a list of arrays [track]."""
    dt, u = log.dt, log.current_a
    starts = [a for a, _ in segments]
    d = plant.delay_s
    y = plant.k0 * (zoh_rigid_response(u, dt, d, starts) + plant.bias_a * bias_response(len(u), dt, starts))
    if plant.modes:
        M = mode_regressors(u, [m.freq_hz for m in plant.modes], [m.zeta for m in plant.modes], dt, d, steady)
        y = y + M @ (plant.k0 * np.array([m.gain for m in plant.modes]))
    out = []
    for a, b in segments:
        t = np.arange(b - a, dtype=float)
        V = np.column_stack([np.ones_like(t), t / max(len(t), 1)])
        e = log.position_track[a:b] - y[a:b]
        out.append(y[a:b] + V @ np.linalg.lstsq(V, e, rcond=None)[0])
    return out


def heldout_fit(log: SeekLog, plant: ModalPlant, seeks) -> float:
    """Fit % ``100 (1 - ||y - y_hat|| / ||y - mean(y)||)`` of the settle-window PES of ``seeks``.

    ``y_hat`` from :func:`predict_segments` on each seek (seek start to end, initial position and
    velocity fitted over the seek), compared on the settle windows ``[settle, end)`` only.
    """
    seeks = [s for s in seeks if s.settled and s.end - s.start >= 4]
    if not seeks:
        return float("nan")
    pred = predict_segments(log, plant, [(s.start, s.end) for s in seeks])
    y = np.concatenate([log.pes[s.settle:s.end] for s in seeks])
    yh = np.concatenate([p[s.settle - s.start:] - log.target_track[s.settle:s.end] for p, s in zip(pred, seeks)])
    return float(100.0 * (1.0 - np.linalg.norm(y - yh) / np.linalg.norm(y - y.mean())))


# ------------------------------------------------------------------------------- identify
def _split(log: SeekLog, holdout_every: int):
    seeks = segment_seeks(log)
    name = log.source or "<log>"
    if len(seeks) < 2:
        raise LogError(name, f"need at least 2 seeks to identify a plant, found {len(seeks)}")
    if holdout_every and holdout_every > 1 and len(seeks) >= 2 * holdout_every:
        held = [s for i, s in enumerate(seeks) if i % holdout_every == holdout_every - 1]
        fit = [s for i, s in enumerate(seeks) if i % holdout_every != holdout_every - 1]
    else:
        held, fit = [], seeks
    if not any(s.settled for s in fit):
        raise LogError(name, "no seek settles within the 0.1-track band: no settle window to identify modes from")
    return seeks, fit, held


def identify(log: SeekLog, method: str = "robust", **options) -> Identification:
    """Identify the modal plant (rigid body, modes, bias, delay) from a seek log.

    Parameters
    ----------
    log : SeekLog
        Seek log; only ``current_a``, ``position_track``, ``target_track`` (and the rate) are used.
    method : {"robust", "paper"}
        See the module notes.
    **options
        ``holdout_every`` (int, 5: every 5th seek is held out for the fit %; 0 uses all),
        ``freq_range`` ((lo, hi) Hz, default ``(100, 0.47 fs)``: modes looked for),
        ``max_modes`` (12), ``ar_order`` (32, robust: whitening AR order; 0 disables),
        ``t_min`` (5.0, robust: least |gain| / std kept), ``scan`` (True, robust: add missed modes),
        ``max_nfev`` (40, per refinement), ``prony_order`` (8, paper: mode pairs of LS Prony),
        ``settle_band`` (0.1 track).

    Returns
    -------
    Identification

    Raises
    ------
    LogError
        Too few seeks, no settled seek, or no usable data.
    """
    if method not in ("robust", "paper"):
        raise ValueError(f"method must be 'robust' or 'paper', got {method!r}")
    fs = log.sample_rate_hz
    opts = dict(holdout_every=5, freq_range=(100.0, 0.47 * fs), max_modes=12, ar_order=32, t_min=5.0,
                scan=True, max_nfev=40, prony_order=8)
    unknown = set(options) - set(opts)
    if unknown:
        raise TypeError(f"identify: unknown option(s) {sorted(unknown)}")
    opts.update(options)
    t0 = time.perf_counter()
    seeks, fit_seeks, held = _split(log, opts["holdout_every"])
    timing = {"segment": time.perf_counter() - t0}
    run = _identify_paper if method == "paper" else _identify_robust
    ident = run(log, fit_seeks, opts, timing)
    t1 = time.perf_counter()
    if held:
        ident.fit_percent = heldout_fit(log, ident.plant, held)
        ident.fit_percent_rigid = heldout_fit(log, ident.plant.copy(modes=[]), held)
    timing["heldout"] = time.perf_counter() - t1
    timing["total"] = time.perf_counter() - t0
    ident.timing = timing
    ident.diagnostics.update(n_samples=log.n, n_seeks=len(seeks), n_fit_seeks=len(fit_seeks),
                             n_heldout_seeks=len(held),
                             samples_per_s=log.n / timing["total"] if timing["total"] > 0 else float("inf"))
    ident.plant.meta.update(method=method, log=log.source or "<arrays>", fit_percent=ident.fit_percent)
    return ident


def _modes_from(x, c, R):
    f, z, d = VarPro.unpack(x, R)
    return f, z, d, c[0], c[1] / c[0], c[2:] / c[0]


def _lin_t(vp: VarPro, x):
    """|c_r| / std(c_r) of the mode coefficients (white LS covariance of the whitened problem)."""
    X, c, r, Q = vp.solve(x)
    s = np.linalg.norm(X, axis=0)
    cov = np.linalg.pinv((X / s).T @ (X / s)) / np.outer(s, s) * float(r @ r) / max(len(r) - X.shape[1], 1)
    return np.abs(c[2:]) / np.sqrt(np.maximum(np.diag(cov)[2:], 1e-300))


def _drop(x, keep):
    R = (len(x) - 1) // 2
    keep = np.asarray(keep, dtype=bool)
    return np.r_[x[:R][keep], x[R:2 * R][keep], x[2 * R]]


def _identify_robust(log: SeekLog, fit_seeks, opts, timing) -> Identification:
    fs, dt = log.sample_rate_hz, log.dt
    lo, hi = opts["freq_range"]
    segs = [(s.start, s.end) for s in fit_seeks]
    ppo, diag = {}, {}
    t = time.perf_counter()
    rf = rigid_fit(log.current_a, log.position_track, segs, dt)
    timing["rigid"] = time.perf_counter() - t
    # (a) pooled matrix pencil on the settle windows
    t = time.perf_counter()
    wins = [log.pes[s.settle:s.end] for s in fit_seeks if s.settled]
    try:
        poles, pdiag = matrix_pencil(wins, fs, freq_range=(lo, hi))
        diag["pencil_order"] = pdiag.order
        diag["pencil_rejected"] = [(float(z_to_modal(z, fs)[0]), why) for z, why in pdiag.rejected]
    except ValueError as exc:          # no window long enough
        poles, diag["pencil_error"] = [], str(exc)
    ppo["pencil"] = [(p.freq_hz, p.zeta) for p in poles]
    diag["settle_modes"] = [(p.freq_hz, p.zeta, p.amplitude) for p in poles]
    cand = sorted((p for p in poles if lo <= p.freq_hz <= hi), key=lambda p: -p.energy)[:opts["max_modes"]]
    x = np.r_[np.log([p.freq_hz for p in cand]), np.log([max(p.zeta, 1e-3) for p in cand]), rf.delay_s / dt]
    timing["pencil"] = time.perf_counter() - t

    def bounds(x):
        R = (len(x) - 1) // 2
        lb = np.r_[np.full(R, math.log(0.8 * lo)), np.full(R, math.log(1e-4)), 0.0]
        ub = np.r_[np.full(R, math.log(0.499 * fs)), np.full(R, math.log(0.7)), 4.0]
        return lb, ub

    def refine(vp, x):
        if len(x) == 1:
            lb, ub = bounds(x)
            r = least_squares(vp.residual, x, bounds=(lb, ub), method="trf", max_nfev=opts["max_nfev"])
            return r.x
        return vp.fit(np.clip(x, *[b + e for b, e in zip(bounds(x), (1e-9, -1e-9))]), *bounds(x),
                      max_nfev=opts["max_nfev"])

    def whitener(x):
        if not opts["ar_order"]:
            return None
        _, _, r, _ = vp0.solve(x)
        b = vp0.proj.bounds
        return ar_whitener([r[b[i]:b[i + 1]] for i in range(len(b) - 1)], int(opts["ar_order"]))

    def prune(vp, x):
        """Drop the least significant mode while any is below t_min, and near-duplicates."""
        while (len(x) - 1) // 2 > 0:
            R = (len(x) - 1) // 2
            tv = _lin_t(vp, x)
            f = np.exp(x[:R])
            worst = int(np.argmin(tv))
            for i in range(R):          # two modes within 1.5 %: keep the more significant
                for j in range(i + 1, R):
                    if abs(f[i] / f[j] - 1) < 0.015:
                        worst = i if tv[i] < tv[j] else j
                        tv[worst] = -1.0
            if tv[worst] >= opts["t_min"]:
                return x
            x = refine(vp, _drop(x, np.arange(R) != worst))
        return x

    # (b) output error, then prewhitened, with the scan for missed modes
    t = time.perf_counter()
    vp0 = VarPro(log, segs)
    if len(x) > 1:
        x = refine(vp0, x)
    ppo["OE (white)"] = list(zip(*VarPro.unpack(x, (len(x) - 1) // 2)[:2]))
    vp = VarPro(log, segs, whitener(x))
    x = prune(vp, refine(vp, x) if len(x) > 1 else x)
    timing["refine"] = time.perf_counter() - t
    t = time.perf_counter()
    grid = np.exp(np.arange(math.log(lo), math.log(hi), math.log(1.015)))
    added = []
    while opts["scan"] and (len(x) - 1) // 2 < opts["max_modes"]:
        stat, r = vp.scan(x, grid)
        sig2 = float(r @ r) / max(len(r) - (len(x) - 1) // 2 - 2, 1)
        k = np.unravel_index(int(np.argmax(stat)), stat.shape)
        if stat[k] / sig2 < opts["t_min"] ** 2 * 2:
            break
        fz = (float(grid[k[0]]), (0.005, 0.02, 0.06)[k[1]])
        added.append(fz + (float(stat[k] / sig2),))
        R = (len(x) - 1) // 2
        x = np.r_[x[:R], math.log(fz[0]), x[R:2 * R], math.log(fz[1]), x[2 * R]]
        x = prune(vp, refine(vp, x))
    diag["scan_added"] = added
    timing["scan"] = time.perf_counter() - t
    # final: AR model from the final OE residual, refit, prune, covariance
    t = time.perf_counter()
    vp = VarPro(log, segs, whitener(x))
    if len(x) > 1:
        x = prune(vp, refine(vp, x))
    R = (len(x) - 1) // 2
    ppo["final"] = list(zip(*VarPro.unpack(x, R)[:2]))
    J, r = vp.jacobian(x, full=True)
    cov, cov_white = sandwich_cov(J, r, vp.proj.bounds, lags=max(int(opts["ar_order"]), 16))
    X, c, r, _ = vp.solve(x)
    f, z, d, k0, bias, g = _modes_from(x, c, R)
    sd = np.sqrt(np.abs(np.diag(cov)))
    nx = len(x)
    cc = cov[nx:, nx:]                                      # covariance of c = [k0, k0 bias, k0 g]

    def ratio_std(i):                                       # std of c_i / c_0
        gv = np.zeros(len(c)); gv[0] = -c[i] / c[0] ** 2; gv[i] = 1.0 / c[0]
        return float(np.sqrt(max(gv @ cc @ gv, 0.0)))
    modes = [Mode(float(f[i]), float(z[i]), float(g[i]),
                  {"freq_hz": float(f[i] * sd[i]), "zeta": float(z[i] * sd[R + i]), "gain": ratio_std(2 + i)})
             for i in np.argsort(f)]
    plant = ModalPlant(k0=float(k0), modes=modes, bias_a=float(bias), delay_s=float(d * dt), sample_rate_hz=fs,
                       track_pitch_nm=log.track_pitch_nm,
                       std={"k0": float(sd[nx]), "bias_a": ratio_std(1), "delay_s": float(sd[2 * R] * dt)})
    r_oe = vp0.solve(x)[2]
    infl = np.sqrt(np.diag(cov) / np.maximum(np.diag(cov_white), 1e-300))
    diag.update(ar_order=int(opts["ar_order"]), std_inflation_median=float(np.median(infl)),
                std_inflation_max=float(np.max(infl)), whitened_residual_rms=float(np.sqrt(np.mean(r ** 2))),
                t_stat=[float(v) for v in np.abs(c[2:]) / np.maximum(np.sqrt(np.diag(cc)[2:]), 1e-300)],
                rigid_init={"k0": rf.k0, "bias_a": rf.bias_a, "delay_s": rf.delay_s},
                n_fit_rows=int(vp.proj.n_rows), nfev=vp.nfev + vp0.nfev)
    timing["final"] = time.perf_counter() - t
    return Identification(plant, "robust", ppo, residual_rms=float(np.sqrt(np.mean(r_oe ** 2))), diagnostics=diag)


def _identify_paper(log: SeekLog, fit_seeks, opts, timing) -> Identification:
    fs, dt = log.sample_rate_hz, log.dt
    lo, hi = opts["freq_range"]
    t = time.perf_counter()
    e8 = eq8_fit(log.current_a, log.position_track, [(s.start, s.end) for s in fit_seeks], dt)   # eq. (8)
    timing["rigid"] = time.perf_counter() - t
    t = time.perf_counter()
    windows = [(s.settle, s.end) for s in fit_seeks if s.settled]
    pes = log.pes
    wins = [pes[a:b] for a, b in windows]
    ppo = {}
    n_max = int(opts["prony_order"])
    roots = None
    for n in range(1, n_max + 1):                            # eqs. (4)-(7) at each order
        try:
            roots = ls_prony(wins, n, fs)
        except ValueError:
            break
        up = roots[(roots.imag > 1e-12) & (np.abs(roots) < 1)]
        ppo[f"prony n={n}"] = sorted(zip(*[v.tolist() for v in z_to_modal(up, fs)]))
    if roots is None:
        raise LogError(log.source or "<log>", "settle windows too short for LS Prony")
    up = roots[(roots.imag > 1e-12) & (np.abs(roots) < 1)]
    f, z = z_to_modal(up, fs)
    keep = (f >= lo) & (f <= hi) & (z < 0.5)
    f, z = f[keep], z[keep]
    timing["prony"] = time.perf_counter() - t
    t = time.perf_counter()
    Y = mode_regressors(log.current_a, f, z, dt, 0.0)        # eq. (9), the paper has no delay
    gf = modal_gains(pes, Y, windows)                         # eqs. (10)-(11)
    timing["gains"] = time.perf_counter() - t
    g = gf.coef / e8.k0
    rss_dof = e8.residual_rms ** 2 * e8.n_samples / max(e8.n_samples - 2, 1)
    cov8 = np.linalg.inv(e8.U) * rss_dof
    modes = [Mode(float(fi), float(zi), float(gi), {"gain": float(si / e8.k0)})
             for fi, zi, gi, si in sorted(zip(f, z, g, gf.std))]
    plant = ModalPlant(k0=e8.k0, modes=modes, bias_a=e8.bias_a, delay_s=0.0, sample_rate_hz=fs,
                       track_pitch_nm=log.track_pitch_nm, std={"k0": float(np.sqrt(cov8[0, 0]) / dt ** 2)})
    amps = []
    for w in wins:
        if len(w) > 2 * len(f) + 2 and len(f):
            amps.append(2 * np.abs(fit_amplitudes(w, modal_to_z(f, z, fs), fs)))
    amp = np.mean(amps, axis=0) if amps else np.full(len(f), np.nan)
    diag = {"eq8": {"b0": e8.b0, "b1": e8.b1, "residual_rms": e8.residual_rms},
            "settle_modes": [(float(a), float(b), float(c)) for a, b, c in zip(f, z, amp)],
            "prony_order": n_max}
    return Identification(plant, "paper", ppo, residual_rms=gf.residual_rms, diagnostics=diag)
