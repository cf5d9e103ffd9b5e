"""Is this plant and this controller a working servo loop?  Checked before any long computation.

Two checks, both exact and cheap (well under a millisecond of linear algebra for a drive):

* **sample rate** -- a plant identified at ``fs`` (its ``sample_rate_hz``) belongs to the drive's
  controller at that rate; a controller at another rate is the wrong controller.
* **closed-loop stability** -- the eigenvalues of the lifted closed loop at the PES rate: the
  plant's linear part discretised as the simulator runs it (:class:`~identification.model.discrete.DiscretePlant`
  at the controller's sub-step ``1 / (L fs)``, its delay line as states), stepped ``L`` times per PES
  sample with the sub-step currents of :meth:`~seekopt.drive.controller.Controller.lifted_ss`::

      x_p+ = Phi^L x_p + sum_j Phi^(L-1-j) G u_j,   u_j = C_j x_c + D_j e,   x_c+ = A_c x_c + B_c e,
      e = r - C_p x_p

  The loop is stable when every eigenvalue lies strictly inside the unit circle.  A negated PID,
  a gain fifty times too high or a controller at another rate fails here with the offending pole.
"""
from __future__ import annotations

import dataclasses
import math

import numpy as np

__all__ = ["LoopError", "closed_loop_poles", "check_loop", "RATE_TOL"]

#: relative disagreement of the plant's and the controller's sample rates still taken as equal
RATE_TOL = 1e-6


class LoopError(ValueError):
    """The plant and controller do not make a working loop (one-line message naming the files)."""


def closed_loop_poles(plant, controller) -> np.ndarray:
    """Eigenvalues of the linear 2DOF loop lifted to the PES rate (see the module notes).

    Parameters
    ----------
    plant : ModalPlant
        Only its linear part is used (bias and nonlinear effects do not move poles).
    controller : Controller

    Returns
    -------
    ndarray of complex
        Poles in the z-plane of the PES rate ``controller.sample_rate_hz``.
    """
    fs, L = float(controller.sample_rate_hz), int(controller.fast_multiple)
    # the linear part (as ModalPlant.linear_part, without its JSON round trip: effects from outside
    # the library, e.g. a study's, stay usable)
    linear = dataclasses.replace(plant, bias_a=0.0, effects=[e for e in plant.effects if e.kind == "structural"])
    Ap, Bp, Cp, _ = linear.discretize(1.0 / (fs * L)).augmented_ss()
    Ac, Bc, Cc, Dc = controller.lifted_ss()
    n, nc = Ap.shape[0], Ac.shape[0]
    # plant over one PES sample: x+ = Phi^L x + sum_j Phi^(L-1-j) Bp u_j
    powers = [np.eye(n)]
    for _ in range(L):
        powers.append(Ap @ powers[-1])
    M = np.column_stack([powers[L - 1 - j] @ Bp[:, 0] for j in range(L)])     # (n, L)
    A = np.zeros((n + nc, n + nc))
    A[:n, :n] = powers[L] - M @ Dc @ Cp          # e = -y with r = 0
    A[:n, n:] = M @ Cc
    A[n:, :n] = -Bc @ Cp
    A[n:, n:] = Ac
    return np.linalg.eigvals(A)


def check_loop(plant, controller, plant_name: str = "the plant", controller_name: str | None = None) -> None:
    """Raise :class:`LoopError` if ``controller`` is not the drive's controller for ``plant``.

    Parameters
    ----------
    plant : ModalPlant
    controller : Controller
    plant_name, controller_name : str
        How the user named them, used verbatim in the message: e.g. ``"plant plant.json"`` and
        ``"ctrl.json"`` (default ``"controller '<its name>'"``).

    Raises
    ------
    LoopError
        ``"ctrl.json: controller runs at 50000 Hz but plant plant.json was identified at 26400 Hz; ..."``
        or ``"ctrl.json: closed loop with plant plant.json is unstable (pole |z| = 1.2 at 0 Hz); ..."``.
    """
    cname = controller_name or f"controller {controller.name!r}"
    fc, fp = float(controller.sample_rate_hz), plant.sample_rate_hz
    if fp is not None and abs(fc - fp) > RATE_TOL * fp:
        raise LoopError(f"{cname}: controller runs at {fc:g} Hz but {plant_name} was identified at "
                        f"{fp:g} Hz; use the drive's controller at {fp:g} Hz")
    poles = closed_loop_poles(plant, controller)
    if not np.all(np.isfinite(poles)):
        raise LoopError(f"{cname}: closed loop with {plant_name} cannot be evaluated (non-finite poles)")
    i = int(np.argmax(np.abs(poles)))
    rho = float(abs(poles[i]))
    if rho >= 1.0 - 1e-9:
        f = abs(math.atan2(poles[i].imag, poles[i].real)) * fc / (2 * math.pi)
        raise LoopError(f"{cname}: closed loop with {plant_name} is unstable (pole |z| = {rho:.4g} at "
                        f"{f:.0f} Hz); check the controller's sign, gain and sample rate")
