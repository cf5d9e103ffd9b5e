"""Numeric backends for the plant's equations: one formula, evaluated on numbers or on CasADi symbols.

Every effect hook (:mod:`identification.model.effects`) and the stepping engine
(:class:`identification.model.discrete.DiscretePlant`) write their maths once, in terms of an
``ops`` object, so that the same definition runs

* on numpy floats and arrays (simulation, loop, identification): :data:`NUMPY`;
* on CasADi ``SX`` / ``MX`` / ``DM`` (the design NLP, Ipopt): :func:`casadi_ops`.

Functions of a backend: ``sin``, ``cos``, ``tanh``, ``exp``, ``sqrt``, ``fabs``, ``fmin``,
``fmax`` (elementwise primitives of the library), and the maps that may be smoothed:

``sign(x)``
    exact ``sign``; or ``tanh(x / friction_velocity_tps)`` (used on velocities [track/s]).
``clip(x, lo, hi)``
    exact ``min(max(x, lo), hi)``; or the smooth saturation
    ``smin(smax(x, lo), hi)`` with ``smax(a, b) = (a + b + sqrt((a - b)^2 + w^2)) / 2``,
    ``smin(a, b) = (a + b - sqrt((a - b)^2 + w^2)) / 2``, ``w = saturation_width_a`` [A]
    (error ``w / 2`` at a corner, ``~ w^2 / (4 d)`` at distance ``d`` from it).
``interp(x, xp, fp)``
    piecewise-linear table on fixed, increasing knots ``xp``, constant beyond the ends
    (``numpy.interp``).  Symbolically it is the same function written as
    ``fp[0] + sum_i s_i (clip(x, xp[i], xp[i+1]) - xp[i])`` with ``s_i`` the segment slopes,
    whose ``clip`` is smoothed with ``table_width_track`` [track] (the corners are rounded
    over that width; exact when 0).
``sum(terms)``, ``const(a)``, ``mtimes(A, x)``, ``dot(a, b)``, ``vcat(items)``, ``asarray(a)``,
``push(hist, new)``
    structure helpers (numpy arrays become ``casadi.DM`` constants on CasADi; ``push``
    prepends ``new`` to a delay line: ``[new, hist[0], ..., hist[-1]]``).

Smoothing is an explicit setting (:class:`SmoothingSettings`, unit-bearing fields); the default
is exact everywhere: ``fmin``, ``fmax`` and ``sign`` are valid CasADi operations (Ipopt sees
a piecewise-smooth function; smoothing helps it when iterates sit on a corner).  The numpy
backend can be smoothed the same way (``numpy_ops(smooth)``), e.g. for a velocity estimated
from noisy positions whose sign is unknown near zero.
"""
from __future__ import annotations

from dataclasses import asdict, dataclass
from functools import reduce
import operator

import numpy as np

__all__ = ["SmoothingSettings", "Ops", "NUMPY", "numpy_ops", "casadi_ops"]


@dataclass(frozen=True)
class SmoothingSettings:
    """Widths of the smooth replacements of non-smooth maps (0 = exact).

    Parameters
    ----------
    friction_velocity_tps : float
        ``sign(v) -> tanh(v / friction_velocity_tps)`` [track/s].
    saturation_width_a : float
        Corner width ``w`` of the smooth saturation ``clip`` [A].
    table_width_track : float
        Corner width of the piecewise-linear position tables (``interp``) [track].
    """

    friction_velocity_tps: float = 0.0
    saturation_width_a: float = 0.0
    table_width_track: float = 0.0

    def __post_init__(self):
        for k, v in asdict(self).items():
            if not (v >= 0.0 and np.isfinite(v)):
                raise ValueError(f"SmoothingSettings.{k} must be finite and >= 0 (got {v!r})")

    @property
    def exact(self) -> bool:
        return not any(asdict(self).values())

    def to_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict) -> "SmoothingSettings":
        return cls(**d)


class Ops:
    """A backend: library primitives plus the (optionally smoothed) maps the effects use.

    Parameters
    ----------
    name : str
        ``"numpy"`` or ``"casadi"``.
    lib : dict
        Primitives ``sin, cos, tanh, exp, sqrt, fabs, fmin, fmax, sign, const, mtimes, dot, vcat,
        asarray, push``, optionally ``clip`` (the exact saturation).
    smooth : SmoothingSettings
    """

    def __init__(self, name: str, lib: dict, smooth: SmoothingSettings | None = None):
        self.name = name
        self.smooth = smooth or SmoothingSettings()
        for k, f in lib.items():
            setattr(self, {"sign": "_sign", "clip": "_clip_exact"}.get(k, k), f)
        if self.smooth.friction_velocity_tps <= 0:
            self.sign = self._sign                  # exact: the library's own
        if self.smooth.saturation_width_a <= 0 and "clip" in lib:
            self.clip = self._clip_exact

    def __repr__(self) -> str:
        return f"Ops({self.name!r}, {self.smooth})"

    # ------------------------------------------------------------------ smoothable maps
    def sign(self, x):
        """``sign(x)``, or ``tanh(x / friction_velocity_tps)`` when smoothed."""
        v = self.smooth.friction_velocity_tps
        return self.tanh(x / v) if v > 0 else self._sign(x)

    def _smax(self, a, b, w):
        return self.fmax(a, b) if w <= 0 else 0.5 * (a + b + self.sqrt((a - b) ** 2 + w * w))

    def _smin(self, a, b, w):
        return self.fmin(a, b) if w <= 0 else 0.5 * (a + b - self.sqrt((a - b) ** 2 + w * w))

    def _clip(self, x, lo, hi, w):
        return self._smin(self._smax(x, lo, w), hi, w)

    def clip(self, x, lo, hi):
        """Saturation ``min(max(x, lo), hi)`` (smooth with ``saturation_width_a``)."""
        return self._clip(x, lo, hi, self.smooth.saturation_width_a)

    def interp(self, x, xp, fp):
        """Piecewise-linear table ``fp`` at increasing knots ``xp``, constant beyond the ends."""
        w = self.smooth.table_width_track
        if w <= 0 and self.name == "numpy":
            return np.interp(x, xp, fp)
        xp = np.asarray(xp, dtype=float)
        fp = np.asarray(fp, dtype=float)
        out = float(fp[0]) + 0.0 * x
        for i in range(len(xp) - 1):
            s = float((fp[i + 1] - fp[i]) / (xp[i + 1] - xp[i]))
            out = out + s * (self._clip(x, float(xp[i]), float(xp[i + 1]), w) - float(xp[i]))
        return out

    @staticmethod
    def sum(terms):
        """Sum of an iterable of terms (numbers, arrays or symbols)."""
        return reduce(operator.add, terms)


def _np_vcat(items):
    return np.concatenate([np.atleast_1d(a) for a in items])


def _np_push(hist, new):
    out = np.empty(hist.shape[0] + 1)
    out[0] = new
    out[1:] = hist
    return out


def _np_clip(x, lo, hi):
    if isinstance(x, float):                      # scalar fast path (the stepping engine)
        return min(max(x, lo), hi)
    return np.minimum(np.maximum(x, lo), hi)


def _np_asarray(a):
    return a if isinstance(a, (float, np.ndarray)) else np.asarray(a, dtype=float)


_NUMPY_LIB = dict(sin=np.sin, cos=np.cos, tanh=np.tanh, exp=np.exp, sqrt=np.sqrt, fabs=np.abs,
                  fmin=np.minimum, fmax=np.maximum, sign=np.sign,
                  const=lambda a: np.asarray(a, dtype=float), mtimes=np.dot, dot=np.dot,
                  vcat=_np_vcat, push=_np_push, clip=_np_clip,
                  asarray=_np_asarray)


def numpy_ops(smooth: SmoothingSettings | None = None) -> Ops:
    """The numpy backend (exact by default)."""
    return Ops("numpy", _NUMPY_LIB, smooth)


#: The exact numpy backend: the default ``ops`` of every hook.
NUMPY = numpy_ops()


def casadi_ops(smooth: SmoothingSettings | None = None) -> Ops:
    """The CasADi backend (``SX``, ``MX`` and ``DM`` alike); casadi is imported here only.

    Parameters
    ----------
    smooth : SmoothingSettings, optional
        Smoothing of ``sign``, ``clip`` and ``interp`` for Ipopt (default exact).
    """
    import casadi as ca

    def asarray(a):
        return a if isinstance(a, (ca.SX, ca.MX, ca.DM)) else ca.DM(np.asarray(a, dtype=float))

    lib = dict(sin=ca.sin, cos=ca.cos, tanh=ca.tanh, exp=ca.exp, sqrt=ca.sqrt, fabs=ca.fabs,
               fmin=ca.fmin, fmax=ca.fmax, sign=ca.sign, const=lambda a: ca.DM(np.asarray(a, dtype=float)),
               mtimes=ca.mtimes, dot=lambda a, b: ca.dot(asarray(a), asarray(b)),
               vcat=lambda items: ca.vertcat(*items), asarray=asarray,
               push=lambda hist, new: ca.vertcat(new, hist), clip=lambda x, lo, hi: ca.fmin(ca.fmax(x, lo), hi))
    return Ops("casadi", lib, smooth)
