"""THE discretisation of a :class:`~identification.model.plant.ModalPlant` and the one stepping engine.

Zero-order hold on the command over each step ``dt`` with a fractional input delay
``tau = (m + f) dt`` handled exactly (modified z-transform)::

    x[k+1] = Phi x[k] + Gamma_old c[k-m-1] + Gamma_new c[k-m] + Gamma_f f[k]
    Gamma_new = int_0^{(1-f)dt} e^{A s} ds B,   Gamma_old = int_0^{dt} e^{A s} ds B - Gamma_new
    y[k] = C x[k] + d_out(t_k)

``c[k] = input_map(u[k], p[k])`` is the command after the ``input`` effects (saturation,
torque-constant variation), entering the delay line; ``f[k] = bias_a + pivot rest force +
sum force(p[k], v[k])`` the undelayed force channel; ``d_out`` the ``output`` effects (run-out).
Nonlinear effects are evaluated from the state at the start of each step and held over it.
``A`` is block diagonal (rigid body, each mode; the amplifier-lag state feeds every block),
so the matrices are computed block by block (:func:`zoh` on each block) and ``Phi`` is
exactly block structured.

A multirate drive's sub-step hold is the same discretisation at ``dt = Ts / L``
(:func:`substep_hold`: the current ``(n, L)`` held over ``Ts / L`` each, the output sampled
at the servo instants ``k L``).

The engine is a pure transition on numbers or CasADi symbols
(:meth:`DiscretePlant.transition`, :meth:`DiscretePlant.measure`, backend ``ops`` of
:mod:`identification.model.ops`); :meth:`DiscretePlant.reset`, :meth:`~DiscretePlant.output`
and :meth:`~DiscretePlant.step` are a stateful wrapper around them, and
:meth:`DiscretePlant.linear_response` is the vectorised fast path of the same maths for the
linear part (:mod:`identification.model.linear`).
"""
from __future__ import annotations

import math

import numpy as np
from scipy.linalg import expm

from identification.model.effects import AmplifierLag, PivotSpringDamper
from identification.model.linear import block_responses, block_tf  # noqa: F401  (block_tf re-exported)
from identification.model.ops import NUMPY, casadi_ops

__all__ = ["DiscretePlant", "block_tf", "zoh", "substep_hold"]


class DiscretePlant:
    """A :class:`ModalPlant` discretised at ``dt`` (ZOH, fractional delay) that steps itself.

    State (numbers: 1-D numpy arrays; symbols: CasADi column vectors)

    ``x`` : (n,)
        Continuous-time states at the step's start, ordered as
        :meth:`ModalPlant.state_space`: rigid position [track] and velocity [track/s], each
        mode's deflection [track] and rate [track/s], then (with ``amplifier_lag``) the
        delivered current [A].
    ``hist`` : (m + 1,)
        Delay line of past commands (after the ``input`` effects) [A]:
        ``hist[i] = c[k-1-i]``, ``i = 0..m`` (``hist[0]`` the previous step's command).

    Usage::

        dp = plant.discretize(dt); dp.reset(position=0.0)
        for k in range(n): y[k] = dp.output(); dp.step(u[k])

    or, purely (numbers or symbols)::

        x, hist = dp.rest_state(0.0)
        for k in range(n):
            y[k] = dp.measure(x, t0 + k * dt)
            x, hist = dp.transition(x, hist, u[k], t0 + k * dt)

    Attributes
    ----------
    Phi : (n, n) ndarray
    G_new, G_old, G_f : (n,) ndarray
        Command (split by the fractional delay) and force input columns.
    C : (n,) ndarray
        Output row (rigid position plus every mode's deflection).
    m : int
        Whole samples of input delay; ``frac`` the fraction ``f`` of a sample.
    force0 : float
        Constant undelayed force [A]: ``bias_a`` plus the pivot's rest-offset force.
    """

    def __init__(self, plant: ModalPlant, dt: float):
        self.plant, self.dt = plant, float(dt)
        A, B, Bf, C = plant.state_space()
        self.A, self.B, self.Bf, self.C = A, B, Bf, C
        self.n = n = A.shape[0]
        tau = plant.total_delay_s / self.dt
        self.m = int(math.floor(tau + 1e-9))
        self.frac = max(tau - self.m, 0.0)
        self.lag = n - 1 if any(isinstance(e, AmplifierLag) for e in plant.effects) else None
        self.blocks = [slice(i, i + 2) for i in range(0, n - (self.lag is not None), 2)]
        self.Phi, G = _zoh_blocks(A, np.column_stack([B, Bf]), self.dt, self.blocks, self.lag)
        _, G_new = _zoh_blocks(A, B[:, None], (1.0 - self.frac) * self.dt, self.blocks, self.lag)
        self.G_new = G_new[:, 0]
        self.G_old = G[:, 0] - self.G_new
        self.G_f = G[:, 1]
        self._inputs = [e for e in plant.effects if e.kind == "input"]
        self._forces = [e for e in plant.effects if e.kind == "force"]
        self._outputs = [e for e in plant.effects if e.kind == "output"]
        self._pivot = next((e for e in plant.effects if isinstance(e, PivotSpringDamper)), None)
        self.force0 = float(plant.bias_a) + (self._pivot.rest_force_a(plant.k0) if self._pivot else 0.0)
        self._consts: dict = {}
        self.x = np.zeros(n)
        self.hist = np.zeros(self.m + 1)
        self.k = 0
        self.t0 = 0.0

    # ------------------------------------------------------------- the maps
    def command(self, u, position, ops=NUMPY):
        """Command [A] entering the delay line: ``u`` through the ``input`` effects in order.

        (On numbers the hooks are called without ``ops``, so that an effect written for numbers
        only, ``input_map(u, position)``, still steps.)"""
        for e in self._inputs:
            u = e.input_map(u, position) if ops is NUMPY else e.input_map(u, position, ops)
        return u

    def net_force(self, position, velocity, ops=NUMPY):
        """Undelayed current-equivalent force [A]: ``force0`` + the ``force`` effects."""
        f = self.force0
        for e in self._forces:
            f = f + (e.force(position, velocity) if ops is NUMPY else e.force(position, velocity, ops))
        return f

    def _c(self, ops):
        c = self._consts.get(ops.name)
        if c is None:
            c = self._consts[ops.name] = tuple(ops.const(a) for a in (
                self.Phi, np.column_stack([self.G_new, self.G_old]), self.G_f, self.G_f * self.force0, self.C))
        return c

    def transition(self, x, hist, u, t, ops=NUMPY):
        """One step ``dt``: ``(x[k], hist[k]) -> (x[k+1], hist[k+1])``, pure.

        Parameters
        ----------
        x, hist
            State at the step's start (see the class docstring).
        u
            Current commanded over the step [A] (before the ``input`` effects).
        t
            Time at the step's start [s] (for time-dependent effects; none of the library's
            input/force effects uses it yet).
        ops
            Backend (:data:`~identification.model.ops.NUMPY`, ``casadi_ops(...)``).

        Returns
        -------
        (x_next, hist_next)
            Same types as ``x``, ``hist`` (numpy 1-D arrays; CasADi ``(n, 1)``, ``(m + 1, 1)``).
            ``hist_next = [c[k], hist[0], ..., hist[m-1]]``; ``x_next = Phi x + Gamma_new c[k-m]
            + Gamma_old c[k-m-1] + Gamma_f f(x)`` with ``c[k-m] = hist_next[m]``,
            ``c[k-m-1] = hist[m]``.
        """
        Phi, G_d, G_f, Gf0, _ = self._consts.get(ops.name) or self._c(ops)
        cmd = self.command(u, x[0], ops) if self._inputs else u
        line = ops.push(hist, cmd)            # [c[k], c[k-1], ..., c[k-m-1]]
        m = self.m
        # Gamma_new c[k-m] + Gamma_old c[k-m-1]
        x_next = ops.mtimes(Phi, x) + ops.mtimes(G_d, line[m:m + 2])
        if self._forces:
            x_next = x_next + G_f * self.net_force(x[0], x[1], ops)
        else:
            x_next = x_next + Gf0                 # Gamma_f force0
        return x_next, line[0:m + 1]

    def measure(self, x, t, ops=NUMPY):
        """Measured head position [track] in state ``x`` at time ``t`` [s]:
        ``C x`` plus the ``output`` effects (run-out)."""
        y = ops.dot((self._consts.get(ops.name) or self._c(ops))[4], x)
        for e in self._outputs:
            y = y + (e.output(t) if ops is NUMPY else e.output(t, ops))
        return y

    def rest_state(self, position: float = 0.0, velocity: float = 0.0, current: float | None = None):
        """``(x, hist)`` at rest at ``position`` [track] (numbers).

        Modes deflected statically by the net input, delay line (and amplifier) filled with
        the command of ``current`` [A] (default: the holding current against the force at
        ``(position, velocity)`` and the pivot spring; input maps ignored for that estimate).
        """
        p = self.plant
        f = float(self.net_force(position, velocity))
        if current is None:
            need = (2 * math.pi * self._pivot.freq_hz) ** 2 * position / p.k0 if self._pivot else 0.0
            current = need - f
        cmd = float(self.command(float(current), position))
        net = cmd + f
        x = np.zeros(self.n)
        x[0], x[1] = position, velocity
        for i, md in enumerate(p.all_modes()):
            x[2 + 2 * i] = p.k0 * md.gain * net / md.omega ** 2
        if self.lag is not None:
            x[self.lag] = cmd
        return x, np.full(self.m + 1, cmd)

    # ------------------------------------------------------ stateful wrapper
    def reset(self, position: float = 0.0, velocity: float = 0.0, current: float | None = None,
              t0: float = 0.0) -> None:
        """Start at :meth:`rest_state`; the step counter at 0, time ``t0`` [s]."""
        self.x, self.hist = self.rest_state(position, velocity, current)
        self.k = 0
        self.t0 = t0

    @property
    def time(self) -> float:
        return self.t0 + self.k * self.dt

    def output(self) -> float:
        """Head position [track] now (before this step's input): :meth:`measure`."""
        return float(self.measure(self.x, self.t0 + self.k * self.dt))

    def step(self, u: float) -> None:
        """Advance one ``dt`` with command current ``u`` [A] held over the step: :meth:`transition`."""
        self.x, self.hist = self.transition(self.x, self.hist, u, self.t0 + self.k * self.dt)
        self.k += 1

    # ---------------------------------------------------------- symbolic
    def casadi_functions(self, smooth=None, sym: str = "SX"):
        """``(F, Y)`` CasADi Functions of the engine: ``F(x, hist, u, t) -> (x_next, hist_next)``
        and ``Y(x, t) -> y`` (``smooth``: :class:`~identification.model.ops.SmoothingSettings`).
        Build once; ``F.mapaccum`` / ``F.fold`` give whole trajectories."""
        import casadi as ca
        ops = casadi_ops(smooth)
        S = getattr(ca, sym)
        x, h, u, t = S.sym("x", self.n), S.sym("hist", self.m + 1), S.sym("u"), S.sym("t")
        xn, hn = self.transition(x, h, u, t, ops)
        F = ca.Function("transition", [x, h, u, t], [xn, hn], ["x", "hist", "u", "t"], ["x_next", "hist_next"])
        Y = ca.Function("measure", [x, t], [self.measure(x, t, ops)], ["x", "t"], ["y"])
        return F, Y

    # ------------------------------------------------------ linear fast path
    def augmented_ss(self):
        """Linear discrete system (command -> position) with the delay line as states.

        State ``[x, c(k-1), ..., c(k-m-1)]`` (i.e. ``[x, hist]``); exact for the linear part of
        the plant (the force channel and the effects left out)."""
        n, m = self.n, self.m
        N = n + m + 1
        A = np.zeros((N, N)); B = np.zeros((N, 1)); C = np.zeros((1, N))
        A[:n, :n] = self.Phi
        A[:n, n + m] += self.G_old
        if m == 0:
            B[:n, 0] += self.G_new
        else:
            A[:n, n + m - 1] += self.G_new
        B[n, 0] = 1.0
        for i in range(1, m + 1):
            A[n + i, n + i - 1] = 1.0
        C[0, :n] = self.C
        return A, B, C, np.zeros((1, 1))

    def linear_response(self, u, force=None, x0=None, hist0=None, t0: float = 0.0,
                        outputs: bool = True, split: bool = False):
        """Vectorised :meth:`output` sequence of the linear part (equal to stepping to rounding).

        ``y[k] = measure(x[k], t0 + k dt)`` for ``x[k+1] = Phi x + Gamma_new c[k-m] +
        Gamma_old c[k-m-1] + Gamma_f (force0 + force[k])`` with ``c = u`` (the ``input`` effects
        and the state-dependent ``force`` effects are not applied: equal to :meth:`step` for a
        plant without them; pass their values in ``u`` / ``force`` to replay a simulation).

        Parameters
        ----------
        u : (N,) or (n, L) array
            Command [A] per step; ``(n, L)``: the sub-step hold (:func:`substep_hold`), this
            plant discretised at the sub-step ``Ts / L``, output at the ``n`` servo instants.
        force : array or None
            Undelayed force [A] added to ``force0`` (same shape rules as ``u``).
        x0, hist0 : arrays or None
            Initial state (default zeros; :meth:`rest_state` for rest).
        t0 : float
            Time of the first step [s] (``output`` effects).
        outputs : bool
            Add the ``output`` effects.
        split : bool
            Return the per-block responses ``(N, nblocks)`` (rigid body first, then each mode;
            no output effects) instead of their sum.
        """
        u, L = substep_hold(u)
        f = np.full(len(u), self.force0)
        if force is not None:
            f = f + substep_hold(force, L)[0]
        x0 = np.zeros(self.n) if x0 is None else np.asarray(x0, float)
        hist0 = np.zeros(self.m + 1) if hist0 is None else np.asarray(hist0, float)
        Y = block_responses(self, u, f, x0, hist0)[::L]
        if split:
            return Y
        y = Y.sum(axis=1)
        if outputs and self._outputs:
            t = t0 + self.dt * L * np.arange(len(y))
            y = y + sum(e.output(t) for e in self._outputs)
        return y


def substep_hold(u, L: int | None = None):
    """The sub-step hold of a multirate drive: ``(u_fine, L)``.

    ``u`` of shape ``(n, L)`` is ``L`` currents per servo sample, each held over ``Ts / L``;
    it becomes the sub-step sequence ``u_fine[k L + j] = u[k, j]`` (stepped at ``dt = Ts / L``;
    the servo instants are ``u_fine[::L]``).  A 1-D ``u`` is held over all ``L`` sub-steps
    (``L`` given) or is already the step sequence (``L`` None: ``L = 1``).
    """
    u = np.asarray(u, dtype=float)
    if u.ndim == 2:
        if L is not None and u.shape[1] != L:
            raise ValueError(f"sub-step current has {u.shape[1]} columns, expected {L}")
        return u.reshape(-1), u.shape[1]
    L = 1 if L is None else int(L)
    return (np.repeat(u, L) if L > 1 else u), L


def zoh(A: np.ndarray, B: np.ndarray, h: float):
    """``(e^{A h}, int_0^h e^{A s} ds B)`` via the block-matrix exponential."""
    n, q = A.shape[0], B.shape[1]
    M = np.zeros((n + q, n + q))
    M[:n, :n] = A * h
    M[:n, n:] = B * h
    E = expm(M)
    return E[:n, :n], E[:n, n:]


def _zoh_blocks(A, B, h, blocks, lag):
    """:func:`zoh` of a block-diagonal ``A`` (blocks ``blocks``, plus an optional ``lag`` state
    feeding every block and fed by none), block by block: the same matrices as ``zoh(A, B, h)``
    with exactly zero couplings between blocks."""
    n = A.shape[0]
    Phi, G = np.zeros((n, n)), np.zeros((n, B.shape[1]))
    for s in blocks:
        idx = np.r_[np.arange(n)[s], [] if lag is None else [lag]].astype(int)
        P, Gb = zoh(A[np.ix_(idx, idx)], B[idx], h)
        Phi[np.ix_(idx, idx)] = P
        G[idx] = Gb
    if lag is not None and not blocks:
        Phi[lag, lag], G[lag] = zoh(A[lag:, lag:], B[lag:], h)
    return Phi, G
