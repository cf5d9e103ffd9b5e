"""THE discretisation of a :class:`~identification.model.plant.ModalPlant` and the one stepping engine.

Zero-order hold on the command over each step ``dt`` with a fractional input delay
``tau = (m + f) dt`` handled exactly (modified z-transform)::

    x[k+1] = Phi x[k] + Gamma_old u[k-m-1] + Gamma_new u[k-m] + Gamma_f f[k]
    Gamma_new = int_0^{(1-f)dt} e^{A s} ds B,   Gamma_old = int_0^{dt} e^{A s} ds B - Gamma_new

where ``f[k]`` is the undelayed force channel (bias, state-dependent forces).  A multirate
drive's sub-step hold is the same discretisation at ``dt / L``.
"""
from __future__ import annotations

import math

import numpy as np
from scipy.linalg import expm

from identification.model.effects import AmplifierLag, PivotSpringDamper

__all__ = ["DiscretePlant", "block_tf", "zoh"]


class DiscretePlant:
    """A :class:`ModalPlant` discretised at ``dt`` (ZOH, fractional delay) that steps itself.

    Usage::

        dp = plant.discretize(dt); dp.reset(position=0.0)
        for k in range(n): y[k] = dp.output(); dp.step(u[k])

    Nonlinear effects are evaluated from the state at the start of each step and
    held over the step (``input`` effects on the command before the delay line,
    ``force`` effects on the undelayed force channel).
    """

    def __init__(self, plant: ModalPlant, dt: float):
        self.plant, self.dt = plant, float(dt)
        A, B, Bf, C = plant.state_space()
        self.A, self.C = A, C
        n = A.shape[0]
        tau = plant.total_delay_s / self.dt
        self.m = int(math.floor(tau + 1e-9))
        frac = max(tau - self.m, 0.0)
        self.Phi, G_full = zoh(A, np.column_stack([B, Bf]), self.dt)
        _, G_new = zoh(A, np.column_stack([B, Bf]), (1.0 - frac) * self.dt)
        self.G_new = G_new[:, 0]
        self.G_old = G_full[:, 0] - self.G_new
        self.G_f = G_full[:, 1]
        self.n = n
        self._inputs = [e for e in plant.effects if e.kind == "input"]
        self._forces = [e for e in plant.effects if e.kind == "force"]
        self._outputs = [e for e in plant.effects if e.kind == "output"]
        pivot = [e for e in plant.effects if isinstance(e, PivotSpringDamper)]
        # pivot rest offset: spring force w^2 (p - rest) = w^2 p - w^2 rest -> constant force
        self._pivot_force = 0.0
        if pivot:
            wp = 2 * math.pi * pivot[0].freq_hz
            self._pivot_force = wp ** 2 * pivot[0].rest_track / plant.k0
        self.x = np.zeros(n)
        self.hist = np.zeros(self.m + 1)
        self.k = 0
        self.t0 = 0.0

    # --------------------------------------------------------------- helpers
    def net_force(self, position: float, velocity: float) -> float:
        """Undelayed current-equivalent force: bias + state-dependent effects."""
        f = self.plant.bias_a + self._pivot_force
        for e in self._forces:
            f += e.force(position, velocity)
        return f

    def command(self, u: float, position: float) -> float:
        for e in self._inputs:
            u = e.input_map(u, position)
        return u

    def reset(self, position: float = 0.0, velocity: float = 0.0, current: float | None = None,
              t0: float = 0.0) -> None:
        """Rest state at ``position``: modes deflected statically by the net input, delay
        line (and amplifier) filled with ``current`` (default: the holding current)."""
        p = self.plant
        f = self.net_force(position, velocity)
        if current is None:
            pivot = [e for e in p.effects if isinstance(e, PivotSpringDamper)]
            need = (2 * math.pi * pivot[0].freq_hz) ** 2 * position / p.k0 if pivot else 0.0
            cmd = need - f
            current = cmd  # input maps (saturation, Kt) ignored for the hold estimate
        cmd = self.command(float(current), position)
        net = cmd + f
        x = np.zeros(self.n)
        x[0], x[1] = position, velocity
        for i, m in enumerate(p.all_modes()):
            x[2 + 2 * i] = p.k0 * m.gain * net / m.omega ** 2
        if any(isinstance(e, AmplifierLag) for e in p.effects):
            x[-1] = cmd
        self.x = x
        self.hist = np.full(self.m + 1, cmd)
        self.k = 0
        self.t0 = t0

    @property
    def time(self) -> float:
        return self.t0 + self.k * self.dt

    def output(self) -> float:
        """Head position [track] now (before this step's input)."""
        y = float(self.C @ self.x)
        for e in self._outputs:
            y += float(e.output(self.time))
        return y

    def step(self, u: float) -> None:
        """Advance one ``dt`` with command current ``u`` [A] held over the step."""
        pos, vel = self.x[0], self.x[1]
        cmd = self.command(u, pos) if self._inputs else u
        f = self.net_force(pos, vel)
        u_new = cmd if self.m == 0 else self.hist[self.m - 1]
        u_old = self.hist[self.m]
        self.x = self.Phi @ self.x + self.G_new * u_new + self.G_old * u_old + self.G_f * f
        if self.m > 0:
            self.hist[1:] = self.hist[:-1]
        self.hist[0] = cmd
        self.k += 1

    def augmented_ss(self):
        """Linear discrete system (command -> position) with the delay line as states.

        State ``[x, u(k-1), ..., u(k-m-1)]``; exact for the linear part of the plant."""
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


def block_tf(Phi: np.ndarray, c: np.ndarray, g: np.ndarray):
    """Transfer function ``c (zI - Phi)^-1 g`` of one 2-state block of a :class:`DiscretePlant`
    (rigid body or one mode): numerator ``[n1, n0]`` and denominator ``[1, a1, a2]`` in powers of
    ``z^-1`` after one sample (``(n1 z + n0) / (z^2 + a1 z + a2)``)."""
    (p00, p01), (p10, p11) = Phi
    n1 = c[0] * g[0] + c[1] * g[1]
    n0 = -c[0] * p11 * g[0] + c[0] * p01 * g[1] + c[1] * p10 * g[0] - c[1] * p00 * g[1]
    return np.array([n1, n0]), np.array([1.0, -(p00 + p11), p00 * p11 - p01 * p10])


def zoh(A: np.ndarray, B: np.ndarray, h: float):
    """``(e^{A h}, int_0^h e^{A s} ds B)`` via the block-matrix exponential."""
    n, q = A.shape[0], B.shape[1]
    M = np.zeros((n + q, n + q))
    M[:n, :n] = A * h
    M[:n, n:] = B * h
    E = expm(M)
    return E[:n, :n], E[:n, n:]
