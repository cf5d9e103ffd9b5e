"""The 2DOF loop's servo sample on the full plant as CasADi symbols: the model the effect-aware NLP
(:class:`seekopt.design.nlp_problem.SeekNLP`) rolls out, and the same sample with the loop closed.

``transition``/``measure`` are the plant's one stepping engine
(:class:`identification.model.discrete.DiscretePlant`) on CasADi symbols (``casadi_ops``), ``A, B, C, D``
the controller's :meth:`~seekopt.drive.controller.Controller.lifted_ss`.
"""
from __future__ import annotations

import casadi as ca
import numpy as np

from identification.model.ops import casadi_ops
from identification.model.plant import ModalPlant

__all__ = ["closed_loop_sample", "close_sample"]


def closed_loop_sample(plant: ModalPlant, controller, ops=None) -> tuple:
    """One servo sample of the 2DOF loop on the full plant as a CasADi ``Function``.

    ``F(x, hist, xc, u, r, t, i) -> (x+, hist+, xc+, y, i_loop)``: plant state and delay line
    (:class:`DiscretePlant` at the sub-step ``1 / (L fs)``), controller state (lifted), the
    feedforward current incl. hold ``u`` [A] and the reference ``r`` [track] of the sample, its
    time ``t`` [s]; ``y`` the measured position at the start of the sample and ``i_loop`` the ``L``
    sub-step currents the loop commands, ``u + C_l x_c + D_l (r - y)``.  The plant is stepped with
    the currents ``i`` given as an input: the loop is closed by ``i = i_loop`` (an equality of the
    NLP, or :func:`close_sample` for simulation).  Returns ``(F, (nx, nh, nc), dp)``.
    """
    ops = casadi_ops() if ops is None else ops
    fs, L = float(controller.sample_rate_hz), int(controller.fast_multiple)
    dt = 1.0 / (fs * L)
    dp = plant.discretize(dt)
    A, B, C, D = (np.asarray(a, dtype=float) for a in controller.lifted_ss())
    nc = A.shape[0]
    nx, nh = dp.n, dp.m + 1
    x0, h0, xc = ca.SX.sym("x", nx), ca.SX.sym("hist", nh), ca.SX.sym("xc", nc)
    u, r, t, i = ca.SX.sym("u"), ca.SX.sym("r"), ca.SX.sym("t"), ca.SX.sym("i", L)
    y = dp.measure(x0, t, ops)
    e = r - y
    i_loop = u + ca.mtimes(ca.DM(C), xc) + ca.DM(D) * e
    xcn = ca.mtimes(ca.DM(A), xc) + ca.DM(B) * e
    x, h = x0, h0
    for j in range(L):
        x, h = dp.transition(x, h, i[j], t + j * dt, ops)
    F = ca.Function("servo_sample", [x0, h0, xc, u, r, t, i], [x, h, xcn, y, i_loop],
                    ["x", "hist", "xc", "u", "r", "t", "i"], ["x_next", "hist_next", "xc_next", "y", "i_loop"])
    return F, (nx, nh, nc), dp


def close_sample(F) -> ca.Function:
    """``F`` with the loop closed (``i = i_loop``): ``(x, hist, xc, u, r, t) -> (x+, hist+, xc+, y, i)``."""
    x, h, xc = (ca.SX.sym(n, F.size1_in(k)) for k, n in enumerate(("x", "hist", "xc")))
    u, r, t = ca.SX.sym("u"), ca.SX.sym("r"), ca.SX.sym("t")
    i = F(x, h, xc, u, r, t, ca.SX.zeros(F.size1_in(6)))[4]
    return ca.Function("closed_sample", [x, h, xc, u, r, t], list(F(x, h, xc, u, r, t, i)[:4]) + [i])
