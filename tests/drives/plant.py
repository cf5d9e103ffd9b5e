"""The truth plant of an independent test drive, integrated on a fine grid.

Written for the tests and on purpose sharing NO dynamics code with
``identification/model/discrete.py`` or ``seekopt/drive/simulator.py``: its own continuous
state space, its own handling of the zero-order hold, the multirate sub-step hold and the
input delay (break points placed exactly on the time axis), and its own integrator (the
classical fourth-order Runge-Kutta method on a fine grid).  Physics (current ``i`` [A] to
head position ``y`` [track])::

    F   = Kt(p)/Kt0 * i(t) + bias_a + bias(p) + friction(v) + force noise   (current-equivalent, A)
    p'' = k0 F  (- pivot spring)                     rigid body, k0 in track/(A s^2)
    q_r'' + 2 zeta_r w_r q_r' + w_r^2 q_r = k0 g_r F  each mode, w_r = 2 pi f_r (natural frequency)
    y   = p + sum_r q_r (+ run-out and sensor noise, added by the drive)
    i(t) = lag * sat( c(t - delay) )                 c: the controller's held sub-step commands

``delay`` is the plant's input delay plus the extra delay plus the drive's computation delay;
``lag`` the amplifier's first-order lag (when present).

Integration: over one servo period the delayed command changes at ``L`` known instants; the
nonlinear forces (``Kt(p)``, ``bias(p)``, friction) are evaluated at ``nodes`` equally spaced
instants per servo period (and at every command change) and held until the next one; with an
amplifier lag (the current moves between nodes) they are the mean of the force at the two ends of
the interval (Heun: the ``Kt(p) i(t)`` error falls as nodes^-2 instead of nodes^-1).  Between
those instants the plant is linear time invariant with constant inputs and is advanced by RK4
on a fine grid (``h * |eig(A)| <= rk4_step``, default 0.002), precomputed once as matrices (RK4 on a linear
system with constant input is a fixed matrix per step).  Without state-dependent effects the
whole servo period is one matrix (exact up to the RK4 error, ~1e-10 relative).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np

__all__ = ["ModeSpec", "TruthPlant", "PlantStepper", "rk4_flow", "open_loop", "damped_free_response"]


@dataclass(frozen=True)
class ModeSpec:
    """``k0 * gain / (s^2 + 2 zeta w s + w^2)``, ``w = 2 pi freq_hz`` (natural frequency)."""

    freq_hz: float
    zeta: float
    gain: float


@dataclass
class TruthPlant:
    """Rigid body + modes + bias + delay, and the effects a real drive adds.

    Units: k0 [track/(A s^2)], currents [A], positions [track], times [s], frequencies [Hz].
    ``extra_modes`` are modes the drive has beyond the declared ones (the library's
    ``extra_mode`` effect); the simulation treats them like ``modes``.
    """

    k0: float
    modes: tuple = ()
    bias_a: float = 0.0
    delay_s: float = 0.0
    track_pitch_nm: float | None = None
    amplifier_bandwidth_hz: float | None = None      # first-order current-amplifier lag
    extra_delay_s: float = 0.0
    bias_knots_track: tuple = ()                     # piecewise-linear position bias, held beyond the ends
    bias_table_a: tuple = ()
    kt_coeffs: tuple = ()                            # Kt/Kt0 = 1 + sum c_i x^(i+1), x = (p - center)/scale
    kt_center_track: float = 0.0
    kt_scale_track: float = 10000.0
    coulomb_a: float = 0.0
    viscous_a_per_tps: float = 0.0
    current_limit_a: float | None = None             # amplifier saturation
    dead_zone_a: float = 0.0                         # amplifier dead zone (an effect outside the library)
    pivot: tuple | None = None                       # (freq_hz, zeta, rest_track)
    extra_modes: tuple = ()
    runout: tuple | None = None                      # (spindle_hz, harmonics, cos_track, sin_track)

    def __post_init__(self):
        self.modes = tuple(m if isinstance(m, ModeSpec) else ModeSpec(*m) for m in self.modes)
        self.extra_modes = tuple(m if isinstance(m, ModeSpec) else ModeSpec(*m) for m in self.extra_modes)
        if len(self.bias_knots_track) != len(self.bias_table_a):
            raise ValueError("bias_knots_track and bias_table_a differ in length")

    # ------------------------------------------------------------------ effects as data
    def with_effects(self, effects) -> "TruthPlant":
        """A copy with effects given in the plant-JSON form ``{"effect": name, "params": {...}}``
        (the library's names; parsed here, not by the library)."""
        out = replace(self)
        for e in effects:
            name, p = e["effect"], dict(e.get("params", {}))
            if name == "input_delay":
                out.extra_delay_s += float(p["delay_s"])
            elif name == "amplifier_lag":
                out.amplifier_bandwidth_hz = float(p["bandwidth_hz"])
            elif name == "pivot_spring_damper":
                out.pivot = (float(p["freq_hz"]), float(p["zeta"]), float(p.get("rest_track", 0.0)))
            elif name == "extra_mode":
                out.extra_modes = out.extra_modes + (ModeSpec(float(p["freq_hz"]), float(p["zeta"]), float(p["gain"])),)
            elif name == "current_saturation":
                out.current_limit_a = float(p["limit_a"])
            elif name == "torque_constant_variation":
                out.kt_coeffs = tuple(float(c) for c in p["coeffs"])
                out.kt_center_track = float(p.get("center_track", 0.0))
                out.kt_scale_track = float(p.get("scale_track", 10000.0))
            elif name == "position_bias":
                out.bias_knots_track = tuple(float(x) for x in p["knots_track"])
                out.bias_table_a = tuple(float(x) for x in p["bias_a"])
            elif name == "friction":
                out.coulomb_a = float(p["coulomb_a"])
                out.viscous_a_per_tps = float(p.get("viscous_a_per_tps", 0.0))
            elif name == "dead_zone":
                out.dead_zone_a = float(p["width_a"])
            elif name == "periodic_disturbance":
                out.runout = (float(p["spindle_hz"]), tuple(p["harmonics"]), tuple(p["cos_track"]),
                              tuple(p["sin_track"]))
            else:
                raise ValueError(f"test drive: effect {name!r} is not simulated")
        return out

    @property
    def all_modes(self) -> tuple:
        return self.modes + self.extra_modes

    @property
    def input_delay_s(self) -> float:
        return self.delay_s + self.extra_delay_s

    @property
    def state_dependent(self) -> bool:
        """Whether a force depends on the head's position or velocity (needs the node stepping)."""
        return bool(self.kt_coeffs or self.bias_knots_track or self.coulomb_a or self.viscous_a_per_tps)

    # ------------------------------------------------------------------ continuous dynamics
    def continuous(self):
        """``(A, b_cmd, b_force, c_out, i_index)``: ``x' = A x + b_cmd c + b_force F_extra``,
        ``y = c_out x``.  States: p [track], v [track/s], (amplifier current [A]), then
        (q_r [track], q_r' [track/s]) per mode.  ``i_index`` is the amplifier state or None."""
        lag = self.amplifier_bandwidth_hz is not None
        modes = self.all_modes
        n = 2 + (1 if lag else 0) + 2 * len(modes)
        A = np.zeros((n, n))
        b_force = np.zeros(n)
        c_out = np.zeros(n)
        A[0, 1] = 1.0
        b_force[1] = self.k0
        c_out[0] = 1.0
        if self.pivot is not None:
            wp = 2 * math.pi * self.pivot[0]
            A[1, 0] = -wp * wp
            A[1, 1] = -2 * self.pivot[1] * wp
        j0 = 3 if lag else 2
        for r, m in enumerate(modes):
            j = j0 + 2 * r
            w = 2 * math.pi * m.freq_hz
            A[j, j + 1] = 1.0
            A[j + 1, j] = -w * w
            A[j + 1, j + 1] = -2 * m.zeta * w
            b_force[j + 1] = self.k0 * m.gain
            c_out[j] = 1.0
        if lag:
            wa = 2 * math.pi * self.amplifier_bandwidth_hz
            A[:, 2] += b_force          # the amplifier's current is a force
            A[2, 2] = -wa
            b_cmd = np.zeros(n)
            b_cmd[2] = wa
            return A, b_cmd, b_force, c_out, 2
        return A, b_force.copy(), b_force, c_out, None

    def constant_force_a(self) -> float:
        """Undelayed constant force [A]: bias plus the pivot spring's rest offset."""
        f = self.bias_a
        if self.pivot is not None:
            f += (2 * math.pi * self.pivot[0]) ** 2 * self.pivot[2] / self.k0
        return f

    def state_force_a(self, p: float, v: float, i: float) -> float:
        """State-dependent force [A] beyond ``i + constant_force_a``: ``(Kt(p)/Kt0 - 1) i + bias(p)
        + friction(v)`` (Coulomb ``-coulomb sign(v)`` plus viscous ``-b v``)."""
        f = 0.0
        if self.kt_coeffs:
            x = (p - self.kt_center_track) / self.kt_scale_track
            f += i * sum(c * x ** (k + 1) for k, c in enumerate(self.kt_coeffs))
        if self.bias_knots_track:
            f += float(np.interp(p, self.bias_knots_track, self.bias_table_a))
        if self.coulomb_a or self.viscous_a_per_tps:
            f -= self.coulomb_a * (1.0 if v > 0 else -1.0 if v < 0 else 0.0) + self.viscous_a_per_tps * v
        return f

    def holding_current(self, position: float) -> float:
        """Current [A] that holds the head at rest at ``position`` (bias, position bias, Kt(p), pivot)."""
        need = 0.0
        if self.pivot is not None:
            need = (2 * math.pi * self.pivot[0]) ** 2 * position / self.k0
        f = self.constant_force_a() + self.state_force_a(position, 0.0, 0.0)
        kt = 1.0 + self.state_force_a(position, 0.0, 1.0) - self.state_force_a(position, 0.0, 0.0)
        return (need - f) / kt

    def saturate(self, c):
        """The amplifier's memoryless input map: dead zone, then saturation."""
        if self.dead_zone_a:
            c = np.sign(c) * np.maximum(np.abs(c) - self.dead_zone_a, 0.0)
        if self.current_limit_a is None:
            return c
        return np.clip(c, -self.current_limit_a, self.current_limit_a)

    def rest_state(self, position: float, current: float) -> np.ndarray:
        """At rest at ``position`` with ``current`` [A] flowing: modes deflected statically."""
        A, _, _, _, ii = self.continuous()
        x = np.zeros(A.shape[0])
        x[0] = position
        i = float(self.saturate(current))
        net = i + self.constant_force_a() + self.state_force_a(position, 0.0, i)
        j0 = 2 if ii is None else 3
        for r, m in enumerate(self.all_modes):
            x[j0 + 2 * r] = self.k0 * m.gain * net / (2 * math.pi * m.freq_hz) ** 2
        if ii is not None:
            x[ii] = i
        return x

    def output_effect(self, t) -> np.ndarray:
        """Run-out added to the measured position at times ``t`` [s] (``periodic_disturbance``)."""
        t = np.asarray(t, dtype=float)
        out = np.zeros_like(t)
        if self.runout is not None:
            f0, hs, cs, ss = self.runout
            for h, a, b in zip(hs, cs, ss):
                out += a * np.cos(2 * math.pi * h * f0 * t) + b * np.sin(2 * math.pi * h * f0 * t)
        return out


def rk4_flow(M: np.ndarray, duration: float, rk4_step: float = 0.002) -> np.ndarray:
    """RK4 on ``z' = M z`` over ``duration`` [s] with equal steps ``h``, ``h * |eig(M)|max <= rk4_step``.

    For a linear system one RK4 step is the matrix ``I + hM + (hM)^2/2 + (hM)^3/6 + (hM)^4/24``;
    the flow is its ``N``-th power.  Local error ~ ``(h |eig|)^5 / 120`` relative."""
    n = M.shape[0]
    if duration <= 0:
        return np.eye(n)
    rho = max(np.max(np.abs(np.linalg.eigvals(M))), 1.0 / duration)
    N = int(math.ceil(duration * rho / rk4_step))
    hM = M * (duration / N)
    T = np.eye(n)
    term = np.eye(n)
    for k in range(1, 5):
        term = term @ hM / k
        T = T + term
    return np.linalg.matrix_power(T, N)


class PlantStepper:
    """A :class:`TruthPlant` advanced one servo period at a time.

    Parameters
    ----------
    plant : TruthPlant
    sample_rate_hz : float
        Servo (PES) rate ``fs``; the period ``Ts = 1/fs`` [s].
    substeps : int
        ``L`` command values per period, each held for ``Ts / L`` (the controller's ZOH).
    extra_delay_s : float
        Delay added to the plant's input delay (the drive's computation delay) [s].
    nodes : int
        Instants per period at which state-dependent forces are re-evaluated (held in between).
    rk4_step : float
        RK4 step as a fraction of the fastest eigenvalue's time constant.
    """

    def __init__(self, plant: TruthPlant, sample_rate_hz: float, substeps: int = 1, extra_delay_s: float = 0.0,
                 nodes: int = 16, rk4_step: float = 0.002):
        self.plant = plant
        self.Ts = 1.0 / float(sample_rate_hz)
        self.L = int(substeps)
        self.tau = plant.input_delay_s + float(extra_delay_s)
        A, bc, bf, c_out, ii = plant.continuous()
        self.n, self.c_out, self.i_index = A.shape[0], c_out, ii
        self.nonlinear = plant.state_dependent
        hL = self.Ts / self.L
        # break points of the delayed command within [0, Ts): j hL + tau (mod Ts); plus the force nodes
        pts = {0.0, self.Ts}
        for j in range(self.L):
            pts.add(math.fmod(j * hL + self.tau, self.Ts))
        if self.nonlinear:
            pts.update(self.Ts * i / nodes for i in range(nodes))
        pts = sorted(pts)
        merged = [pts[0]]
        for t in pts[1:]:
            if t - merged[-1] > 1e-12 * self.Ts:
                merged.append(t)
        merged[-1] = self.Ts
        self.edges = np.array(merged)
        # relative command index d (global sub-step k L + d) in force on each interval
        mids = 0.5 * (self.edges[:-1] + self.edges[1:])
        d = np.floor((mids - self.tau) / hL + 1e-9).astype(int)
        self.d_min = int(min(d.min(), 0))
        self.H = self.L - self.d_min                    # command history kept: c[kL + d_min .. kL + L - 1]
        self.slot = d - self.d_min
        # interval maps from RK4 on the augmented system [x; c; F]' = [[A, bc, bf], 0, 0]
        M = np.zeros((self.n + 2, self.n + 2))
        M[:self.n, :self.n] = A
        M[:self.n, self.n] = bc
        M[:self.n, self.n + 1] = bf
        self.maps = []
        cache = {}
        for a, b in zip(self.edges[:-1], self.edges[1:]):
            key = round((b - a) / self.Ts, 12)
            if key not in cache:
                cache[key] = rk4_flow(M, b - a, rk4_step)[:self.n]
            E = cache[key]
            self.maps.append((E[:, :self.n], E[:, self.n], E[:, self.n + 1]))
        # the whole period as one matrix (linear plants): x+ = Phi x + G hist + Gf F
        Phi = np.eye(self.n)
        G = np.zeros((self.n, self.H))
        Gf = np.zeros(self.n)
        for (P, gc, gf), s in zip(self.maps, self.slot):
            Phi, G, Gf = P @ Phi, P @ G, P @ Gf + gf
            G[:, s] += gc
        self.period = np.ascontiguousarray(np.column_stack([Phi, G, Gf]))
        self.x = np.zeros(self.n)
        self.hist = np.zeros(self.H)
        self._v = np.zeros(self.n + self.H + 1)

    def reset(self, position: float = 0.0, current: float = 0.0, velocity: float = 0.0) -> None:
        """At rest (modes statically deflected) at ``position`` with ``current`` [A] in the delay line."""
        self.x = self.plant.rest_state(position, current)
        self.x[1] = velocity
        self.hist[:] = self.plant.saturate(current)

    def output(self) -> float:
        """Head position [track] at the sampling instant (no run-out, no noise)."""
        return float(self.c_out @ self.x)

    def step(self, commands, force_a: float = 0.0) -> None:
        """Advance one servo period: ``commands`` are this period's ``L`` held command currents [A]
        (applied after the delay); ``force_a`` an undelayed force held over the period (noise)."""
        H, L = self.H, self.L
        self.hist[:H - L] = self.hist[L:]
        self.hist[H - L:] = self.plant.saturate(np.asarray(commands, dtype=float))
        f = self.plant.constant_force_a() + force_a
        if not self.nonlinear:
            v = self._v
            v[:self.n] = self.x
            v[self.n:self.n + H] = self.hist
            v[-1] = f
            self.x = self.period @ v
            return
        x, ii, plant = self.x, self.i_index, self.plant
        for (P, gc, gf), s in zip(self.maps, self.slot):
            c = self.hist[s]
            free = P @ x + gc * c
            if ii is None:                  # the current is the held command: constant over the interval
                x = free + gf * (f + plant.state_force_a(x[0], x[1], c))
            else:                           # the lagged current moves within the interval: trapezoidal force (Heun)
                f0 = plant.state_force_a(x[0], x[1], x[ii])
                xp = free + gf * (f + f0)
                x = free + gf * (f + 0.5 * (f0 + plant.state_force_a(xp[0], xp[1], xp[ii])))
        self.x = x


def open_loop(plant: TruthPlant, current, sample_rate_hz: float, position0: float = 0.0, velocity0: float = 0.0,
              history_a: float | None = None, modes_only: bool = False, **stepper_options) -> np.ndarray:
    """Head position [track] at each sample from logged commands: ``current`` of shape ``(n,)`` (held
    over the sample) or ``(n, L)`` (held sub-steps).  Starts at rest (modes statically deflected by
    ``history_a`` + the bias), ``history_a`` in the delay line (default: the first command).
    ``modes_only``: the modes' deflection alone (the position less the rigid body's, without the
    cancellation of subtracting two large positions)."""
    u = np.asarray(current, dtype=float)
    u = u.reshape(len(u), -1)
    st = PlantStepper(plant, sample_rate_hz, substeps=u.shape[1], **stepper_options)
    st.reset(position0, u[0, 0] if history_a is None else history_a, velocity0)
    if modes_only:
        st.c_out = st.c_out.copy()
        st.c_out[0] = 0.0
    y = np.empty(len(u))
    for k in range(len(u)):
        y[k] = st.output()
        st.step(u[k])
    return y


def damped_free_response(n: int, fs: float, freq_hz: float, zeta: float, amplitude: float = 1.0,
                         phase: float = 0.0) -> np.ndarray:
    """Free vibration of a mode, sampled at ``t = k/fs``: ``Re(A e^{j phase} e^{s t})`` with the pole
    ``s = w (-zeta + j sqrt(1 - zeta^2))``, ``w = 2 pi freq_hz`` (natural frequency)."""
    w = 2 * math.pi * freq_hz
    s = w * complex(-zeta, math.sqrt(1.0 - zeta * zeta))
    t = np.arange(n) / fs
    return np.real(amplitude * np.exp(1j * phase) * np.exp(s * t))
