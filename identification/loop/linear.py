"""The loop's linear engine: the linear part of ``DiscretePlant`` as parallel 2nd-order filters.

``plant.discretize(h)`` (:class:`identification.model.discrete.DiscretePlant`, THE
discretisation: exact ZOH with fractional delay) has a block-diagonal ``Phi`` (rigid body, each
mode) apart from the amplifier-lag column.  Each 2-state block is therefore exactly a 2nd-order
filter (:func:`identification.model.discrete.block_tf`) of the delayed command (``Gamma_new`` /
``Gamma_old``), of the lag state and of the undelayed force channel.  Running those filters with
``scipy.signal.lfilter`` is ~100x faster than stepping ``DiscretePlant`` and exactly equal for
the linear part (``tests/test_residual.py`` checks it against ``DiscretePlant.step``).

The engine runs at the drive's sub-step ``h = dt / L`` (``L`` held currents per log sample, the
columns ``current_sub1_a .. current_subL_a`` of a multirate log; ``L = 1`` otherwise) and
returns the position at the log's sample instants.

Units: current and current-equivalent force [A], position [track], time [s].
"""
from __future__ import annotations

import json

import numpy as np
from scipy.signal import lfilter, lfilter_zi

from identification.model.discrete import block_tf
from identification.model.effects import AmplifierLag
from identification.model.plant import ModalPlant

__all__ = ["LinearModel", "linear_key"]


_PAD = 3   #: history columns kept before each row (the numerators have at most 4 taps)


def _pad(x: np.ndarray, h: np.ndarray) -> np.ndarray:
    """Rows of ``x`` preceded by ``_PAD`` copies of their held value ``h``."""
    return np.concatenate([np.repeat(h[:, None], _PAD, axis=1), x], axis=1)


def _fir(b: np.ndarray, xp: np.ndarray) -> np.ndarray:
    """Rows of a padded ``xp`` (:func:`_pad`) filtered by the FIR ``b`` (powers of z^-1)."""
    W = xp.shape[1] - _PAD
    out = b[0] * xp[:, _PAD:] if b[0] else np.zeros((xp.shape[0], W))
    for j in range(1, len(b)):
        if b[j]:
            out += b[j] * xp[:, _PAD - j:_PAD - j + W]
    return out


def _fir0(b: np.ndarray, x: np.ndarray) -> np.ndarray:
    """Rows of ``x`` filtered by the FIR ``b`` with nothing before them (an empty delay line)."""
    out = b[0] * x
    for j in range(1, len(b)):
        if b[j]:
            out[:, j:] += b[j] * x[:, :-j]
    return out


def _layout(windows, n: int, L: int, m: int, restart: bool) -> dict:
    """Index arrays that lay the runs (seeks) and windows of a log out as rows of 2-D arrays, so
    that each filter runs once over all of them (cached on ``windows``)."""
    key = (n, L, m, restart)
    cache = getattr(windows, "_layouts", None) if windows is not None else None
    if cache is not None and key in cache:
        return cache[key]
    spans = windows.spans() if (windows is not None and restart) else [(0, n)]
    A = np.array([L * a for a, _ in spans]); B = np.array([L * b for _, b in spans])
    j = np.arange(int((B - A).max()))
    idx = np.minimum(A[:, None] + j[None, :], (B - 1)[:, None])          # padded with the last value
    valid = (A[:, None] + j[None, :]) < B[:, None]
    lay = {"A": A, "idx": idx, "valid": valid, "flat": idx[valid],
           "hist": np.where(A > 0, A - 1, 0), "in_delay": j[None, :] < m,
           "idx_delayed": np.maximum(idx - m, A[:, None])}
    if windows is not None:
        wins = windows.bounds
        row = np.searchsorted(A, [L * a for a, _ in wins], side="right") - 1   # run of each window
        off = np.array([L * a for a, _ in wins]) - A[row]
        lens = np.array([L * (b - a) for a, b in wins])
        k = np.arange(int(lens.max()) + 4)
        wvalid = (k[None, :] >= 4) & ((k[None, :] - 4) < lens[:, None])
        target = L * np.array([a for a, _ in wins])[:, None] + k[None, :] - 4
        lay.update(row=row[:, None],
                   wcol=np.minimum(off[:, None] + k[None, :], (B - A)[row][:, None] + 3),   # columns of the padded run
                   wvalid=wvalid, target=target[wvalid])
        if cache is not None:
            cache[key] = lay
    return lay


def linear_key(plant: ModalPlant) -> str:
    """The linear structure of a plant, independent of ``k0`` and ``bias_a`` (a cache key)."""
    d = plant.copy(k0=1.0, bias_a=0.0, effects=[e for e in plant.effects if e.kind == "structural"]).to_dict()
    d.pop("meta", None); d.pop("std", None)
    for m in d["modes"]:
        m.pop("std", None)
    return json.dumps(d, sort_keys=True)


def _blocks(plant: ModalPlant, h: float):
    """Per-block filters of ``plant.discretize(h)`` (``plant.k0`` = 1: ``Gamma`` and the lag column of
    ``Phi`` scale with k0, ``Phi`` otherwise does not, so outputs scale exactly with k0; the
    pivot's rest force is k0-normalised in the force input)."""
    dp = plant.discretize(h)
    Phi, n = dp.Phi, dp.n
    lag = n - 1 if any(isinstance(e, AmplifierLag) for e in plant.effects) else None
    nb = (n - (1 if lag is not None else 0)) // 2
    blocks = []
    for i in range(nb):
        s = slice(2 * i, 2 * i + 2)
        P, c = Phi[s, s], dp.C[s]
        bn, a = block_tf(P, c, dp.G_new[s])
        bo, _ = block_tf(P, c, dp.G_old[s])
        bf, _ = block_tf(P, c, dp.G_f[s])
        bl = block_tf(P, c, Phi[s, lag])[0] if lag is not None else None
        blocks.append(dict(P=P, a=a, b_cmd=np.array([0.0, bn[0], bn[1] + bo[0], bo[1]]),
                           b_f=np.r_[0.0, bf], b_lag=None if bl is None else np.r_[0.0, bl],
                           zi=lfilter_zi([1.0], a) if i > 0 else None))
    lag_b = lag_a = None
    if lag is not None:
        lag_b = np.array([0.0, dp.G_new[lag], dp.G_old[lag]])
        lag_a = np.array([1.0, -Phi[lag, lag]])
        blocks[0]["zi_lag"] = lfilter_zi([1.0], lag_a)
    off = Phi.copy()
    for i in range(nb):
        off[2 * i:2 * i + 2, 2 * i:2 * i + 2] = 0
    if lag is not None:
        off[:, lag] = 0
    if np.abs(off).max() > 1e-9 * max(1.0, np.abs(Phi).max()):   # beyond expm round-off
        raise ValueError("DiscretePlant is not block diagonal: unsupported structure")
    return dp.m, lag, blocks, lag_b, lag_a


class LinearModel:
    """The linear part of ``plant.discretize(dt / substeps)`` as parallel 2-state blocks + lfilter.

    Parameters
    ----------
    plant : ModalPlant
        Only its linear part (rigid body, modes, delay, structural effects) is used.
    dt : float
        Log sample period [s].
    substeps : int
        Held currents per sample ``L`` (the engine runs at ``dt / L``).
    cache : dict, optional
        Holds the k0-normalised filters per linear structure (the caller keeps it, e.g. the
        fit data :class:`identification.loop.fit_engine.Data`).
    """

    def __init__(self, plant: ModalPlant, dt: float, substeps: int = 1, cache: dict | None = None):
        self.plant, self.dt, self.L = plant, float(dt), int(substeps)
        key = (linear_key(plant), self.dt, self.L)
        built = None if cache is None else cache.get(key)
        if built is None:
            built = _blocks(plant.copy(k0=1.0), self.dt / self.L)
            if cache is not None:
                cache[key] = built
        self.m, self.lag, blocks, self.lag_b, self.lag_a = built
        k0 = float(plant.k0)    # every response is proportional to k0 (see _blocks)
        self.blocks = [dict(b, b_cmd=b["b_cmd"] * k0, b_f=b["b_f"] * k0,
                            b_lag=None if b["b_lag"] is None else b["b_lag"] * k0) for b in blocks]
        self._zi_lag = blocks[0].get("zi_lag")
        self._basis = None

    def free_basis(self, length: int) -> np.ndarray:
        """``(length, 2)`` rigid-block output at the samples from unit initial position / velocity
        (the anchors' regressors; a prefix of the longest one computed)."""
        if self._basis is None or len(self._basis) < length:
            P = np.linalg.matrix_power(self.blocks[0]["P"], self.L)
            out = np.empty((max(length, 256), 2))
            x = np.eye(2)
            for k in range(len(out)):
                out[k] = x[0]
                x = P @ x
            self._basis = out
        return self._basis[:length]

    def _fine(self, x, n: int) -> np.ndarray:
        """``(n,)`` per sample (held) or ``(n, L)`` per sub-step -> ``(n L,)`` sub-step sequence."""
        x = np.asarray(x, float)
        if x.ndim == 1:
            return np.repeat(x, self.L) if self.L > 1 else x
        if x.shape != (n, self.L):
            raise ValueError(f"input of shape {x.shape}: expected ({n},) or ({n}, {self.L})")
        return x.reshape(-1)

    def response(self, cmd, force=None, windows=None, split: bool = False, with_rigid: bool = True,
                 restart: bool = True, hist_cmd=None, per_block: bool = False):
        """Output [track] of the linear part at each log sample (before that sample's input).

        Parameters
        ----------
        cmd : array, ``(n,)`` or ``(n, L)``
            Command current entering the delay line [A], per sample (held over its sub-steps)
            or per sub-step.
        force : array or None, same shapes
            Undelayed current-equivalent force [A].
        windows : Windows or None
            If given, the rigid block is filtered per window from an arbitrary state at the
            window start (its free response is the anchor nuisance; numerically clean);
            samples outside the windows are then meaningless.  Otherwise the rigid block
            starts at rest at sample 0.
        split : bool
            Return ``(rigid, flexible)`` separately.
        with_rigid : bool
            Compute the rigid block (False: flexible blocks only).
        restart : bool
            With ``windows``: the flexible blocks, the amplifier and the delay line restart at
            each run of contiguous windows (one seek) in steady state for the input of the
            sub-step before it (``DiscretePlant.reset`` with the previous current held, the
            force of the first sample), as the reference simulation does; False: they run
            through the whole log from steady state at the first inputs.
        hist_cmd : array, optional
            The command held before each run [A] (default: the sub-step before it).
        per_block : bool
            With ``split``: the flexible part as ``(n, blocks)``, one column per mode (in
            ``ModalPlant.all_modes`` order).
        """
        n = len(cmd)
        L = self.L
        c = self._fine(cmd, n)
        f = None if force is None else self._fine(force, n)
        lay = _layout(windows, n, L, self.m, restart)
        A, idx, valid = lay["A"], lay["idx"], lay["valid"]
        hc = c[lay["hist"]] if hist_cmd is None else np.asarray(hist_cmd, float)   # input held before each run
        w = np.where(lay["in_delay"], hc[:, None], c[lay["idx_delayed"]])
        fr = None if f is None else f[idx]
        hf = None if f is None else f[A]
        xl = None
        wp = _pad(w, hc)
        if self.lag is not None:   # lag state, steady at the history
            v = _fir(self.lag_b, wp)
            xl = lfilter([1.0], self.lag_a, v, axis=1, zi=self._zi_lag[None, :] * (self.lag_b.sum() * hc)[:, None])[0]
        xlp = None if xl is None else _pad(xl, hc)
        frp = None if fr is None else _pad(fr, hf)
        per_window = windows is not None
        if per_window:
            row, wcol, wvalid, target = lay["row"], lay["wcol"], lay["wvalid"], lay["target"]
        rigid = np.zeros(len(c))
        flex = np.zeros((len(c), len(self.blocks) - 1)) if per_block else np.zeros(len(c))
        for i, bl in enumerate(self.blocks):
            if i == 0 and not with_rigid:
                continue
            terms = [(bl["b_cmd"], wp, hc)]
            if xl is not None:
                terms.append((bl["b_lag"], xlp, hc))
            if fr is not None:
                terms.append((bl["b_f"], frp, hf))
            v = _fir(terms[0][0], terms[0][1])                      # the numerators, exactly
            for b, xp, _ in terms[1:]:
                v += _fir(b, xp)
            if i > 0:                                                # in steady state before each run
                v_ss = sum(b.sum() * h for b, _, h in terms)
                y = lfilter([1.0], bl["a"], v, axis=1, zi=bl["zi"][None, :] * v_ss[:, None])[0]
                if per_block:
                    flex[lay["flat"], i - 1] += y[valid]
                else:
                    flex[lay["flat"]] += y[valid]
            elif not per_window:   # the rigid block from rest with an empty delay line (history left to anchors)
                raw = [w] + ([xl] if xl is not None else []) + ([fr] if fr is not None else [])
                v0 = sum(_fir0(b, x) for (b, _, _), x in zip(terms, raw))
                rigid[lay["flat"]] += lfilter([1.0], bl["a"], v0, axis=1)[valid]
            else:   # per window from rest 4 sub-steps before it (any state at its start is an anchor)
                vp = np.concatenate([np.zeros((len(v), 4)), v], axis=1)
                vp[:, :4] = v[:, :1]
                y = lfilter([1.0], bl["a"], vp[row, wcol], axis=1)
                rigid[target] += y[wvalid]
        rigid, flex = rigid[::L], flex[::L]
        return (rigid, flex) if split else rigid + flex
