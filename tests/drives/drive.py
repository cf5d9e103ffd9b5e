"""The independent test drive: truth plant + digital controller + noise, closed in a 2DOF loop.

Per servo sample ``k`` (period ``Ts``)::

    y_meas(k) = y(k Ts) + run-out + flutter + sensor noise        PES sampled at the servo instant
    c(k, j)   = u_ff(k) + C[r - y_meas](k, j),  j = 0..L-1         held for Ts/L each (controller ZOH)
    plant input i(t) = lag * sat(c(t - tau)),  tau = plant delay + extra delay + computation delay

The plant (:class:`tests.drives.plant.PlantStepper`) is integrated on a fine grid between the
exact break points of the delayed commands.  :func:`make_log` runs a seek schedule and returns an
:class:`identification.logs.seeklog.SeekLog` (the log format; nothing else of the package is used).
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from identification.logs.seeklog import SeekLog

from .controller import DigitalController
from .disturbance import Noise
from .plant import PlantStepper, TruthPlant
from .seeks import Schedule, plan_seeks, rigid_reference

__all__ = ["Drive", "Trace", "run", "make_log", "closed_loop_poles"]


@dataclass
class Drive:
    """An independent drive.  ``firmware_k0`` / ``firmware_delay_s`` are what its firmware assumes
    for the seek profiles and the reference (default: the truth's ``k0`` and total input delay)."""

    plant: TruthPlant
    controller: DigitalController
    noise: Noise = field(default_factory=Noise)
    computation_delay_s: float = 0.0
    firmware_k0: float | None = None
    firmware_delay_s: float | None = None
    spindle_hz: float | None = 120.0
    nodes: int = 16
    rk4_step: float = 0.002
    name: str = "test drive"

    @property
    def sample_rate_hz(self) -> float:
        return self.controller.sample_rate_hz

    @property
    def total_delay_s(self) -> float:
        """Command to current delay [s]: plant input delay + extra delay + computation delay."""
        return self.plant.input_delay_s + self.computation_delay_s

    def stepper(self) -> PlantStepper:
        return PlantStepper(self.plant, self.sample_rate_hz, self.controller.L, self.computation_delay_s,
                            nodes=self.nodes, rk4_step=self.rk4_step)

    def with_plant(self, plant: TruthPlant) -> "Drive":
        return Drive(plant, self.controller, self.noise, self.computation_delay_s, self.firmware_k0,
                     self.firmware_delay_s, self.spindle_hz, self.nodes, self.rk4_step, self.name)


@dataclass
class Trace:
    """Servo-rate traces of one closed-loop run."""

    position_track: np.ndarray        # measured
    true_position_track: np.ndarray   # head position without run-out and noise
    current_a: np.ndarray             # mean command over the sub-steps
    current_sub_a: np.ndarray         # (n, L) sub-step commands
    u_ff_a: np.ndarray
    reference_track: np.ndarray


def run(drive: Drive, u_ff, r, position0: float | None = None, current0: float | None = None,
        seed: int | None = None, stepper: PlantStepper | None = None) -> Trace:
    """Closed loop for ``len(r)`` servo samples from rest at ``position0`` (default ``r[0]``) with
    ``current0`` in the delay line (default the holding current); the controller starts at zero.
    ``seed`` draws the noise (None: no noise at all)."""
    r = np.asarray(r, dtype=float)
    n = len(r)
    uff = np.zeros(n)
    u_in = np.asarray(u_ff, dtype=float)[:n]
    uff[:len(u_in)] = u_in
    fs = drive.sample_rate_hz
    p0 = float(r[0] if position0 is None else position0)
    st = stepper or drive.stepper()
    st.reset(p0, drive.plant.holding_current(p0) if current0 is None else current0)
    ctrl = drive.controller
    ctrl.reset()
    L = ctrl.L
    if seed is None:
        d_meas, f_noise = np.zeros(n), np.zeros(n)
    else:
        rng = np.random.default_rng(seed)
        d_meas, f_noise = drive.noise.measurement(n, fs, rng), drive.noise.force(n, rng)
    d_meas = d_meas + drive.plant.output_effect(np.arange(n) / fs)
    y_true = np.empty(n)
    sub = np.empty((n, L))
    out, step, cstep = st.output, st.step, ctrl.step
    for k in range(n):
        y = out()
        y_true[k] = y
        c = uff[k] + cstep(r[k] - (y + d_meas[k]))
        sub[k] = c
        step(c, f_noise[k])
    return Trace(y_true + d_meas, y_true, sub.mean(axis=1), sub, uff, r)


def make_log(drive: Drive, schedule: Schedule | None = None, noise_seed: int | None = 0,
             log_substeps: bool = True) -> SeekLog:
    """Run ``schedule`` on ``drive`` and return the seek log (``noise_seed`` None: no noise).

    Columns: the mean command ``current_a``, the measured ``position_track``, the ``target_track``;
    extra ``u_ff_a``, ``reference_track`` and, for a multirate controller with ``log_substeps``,
    ``current_sub1_a`` .. ``current_subL_a``."""
    sch = schedule or Schedule()
    fs = drive.sample_rate_hz
    k0_fw = drive.firmware_k0 or drive.plant.k0
    tau_fw = drive.total_delay_s if drive.firmware_delay_s is None else drive.firmware_delay_s
    seeks, n = plan_seeks(sch, k0_fw, fs)
    u_ff = np.zeros(n)
    p_start = seeks[0].from_track if seeks else 0.5 * sum(sch.stroke_track)
    r = np.full(n, p_start)
    target = np.full(n, p_start)
    tail = 64 + int(np.ceil(tau_fw * fs))
    for s in seeks:
        m = len(s.u_ff)
        u_ff[s.start:s.start + m] = s.u_ff
        end = min(n, s.start + m + tail)
        r[s.start:end] = s.from_track + rigid_reference(s.u_ff, k0_fw, fs, tau_fw, end - s.start)
        r[end:] = s.to_track
        target[s.start:] = s.to_track
    tr = run(drive, u_ff, r, seed=None if noise_seed is None else sch.seed * 1000 + noise_seed)
    k0 = max(0, int(round(sch.preroll_s * fs)) - int(round(sch.keep_before_s * fs)))
    sl = slice(k0, n)
    L = drive.controller.L
    extra = {"u_ff_a": tr.u_ff_a[sl], "reference_track": r[sl]}
    if L > 1 and log_substeps:
        extra.update({f"current_sub{j + 1}_a": tr.current_sub_a[sl, j] for j in range(L)})
    meta = {"generator": "tests.drives", "drive": drive.name, "seed": str(sch.seed), "n_seeks": str(sch.n_seeks),
            "noise": "off" if noise_seed is None else f"seed {noise_seed}"}
    spindle = drive.plant.runout[0] if drive.plant.runout is not None else drive.spindle_hz   # run-out is at the spindle
    if spindle:
        meta.update(rpm=f"{60.0 * spindle:.10g}", sectors=f"{fs / spindle:.10g}")
    return SeekLog.from_arrays(np.arange(n - k0) / fs, tr.current_a[sl], tr.position_track[sl], target[sl], fs,
                               track_pitch_nm=drive.plant.track_pitch_nm, metadata=meta, extra=extra)


def _lifted_controller(ctrl: DigitalController):
    """``(A, B, C, D)`` of the controller over one servo period, from its own stepping."""
    sizes = [s.A.shape[0] for s in ctrl.sections]
    nc = sum(sizes)

    def set_state(z):
        out, i = [], 0
        for m in sizes:
            out.append(np.array(z[i:i + m], dtype=float))
            i += m
        ctrl.x = out

    cols_x, cols_u = [], []
    for j in range(nc + 1):
        z = np.zeros(nc)
        e = 0.0
        if j < nc:
            z[j] = 1.0
        else:
            e = 1.0
        set_state(z)
        u = ctrl.step(e)
        cols_x.append(np.concatenate(ctrl.x) if nc else np.zeros(0))
        cols_u.append(u)
    ctrl.reset()
    X, U = np.array(cols_x).T.reshape(nc, nc + 1), np.array(cols_u).T
    return X[:, :nc], X[:, nc], U[:, :nc], U[:, nc]


def closed_loop_poles(drive: Drive) -> np.ndarray:
    """Eigenvalues of the linear closed loop over one servo period (plant without state-dependent
    effects, saturation ignored); all inside the unit circle when the drive is stable."""
    lin = replace(drive.plant, kt_coeffs=(), bias_knots_track=(), bias_table_a=(), coulomb_a=0.0,
                  viscous_a_per_tps=0.0, current_limit_a=None, dead_zone_a=0.0)
    st = PlantStepper(lin, drive.sample_rate_hz, drive.controller.L, drive.computation_delay_s, rk4_step=drive.rk4_step)
    Ac, Bc, Cc, Dc = _lifted_controller(drive.controller)
    n, H, L, nc = st.n, st.H, st.L, Ac.shape[0]
    Phi, G = st.period[:, :n], st.period[:, n:n + H]
    N = n + (H - L) + nc
    M = np.zeros((N, N))
    for j in range(N):
        s = np.zeros(N)
        s[j] = 1.0
        x, mem, xc = s[:n], s[n:n + H - L], s[n + H - L:]
        e = -(st.c_out @ x)
        u = Cc @ xc + Dc * e
        hist = np.concatenate([mem, u])
        M[:n, j] = Phi @ x + G @ hist
        M[n:n + H - L, j] = hist[L:]
        M[n + H - L:, j] = Ac @ xc + Bc * e
    return np.linalg.eigvals(M)
