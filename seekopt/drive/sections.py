"""Sections of a feedback controller: the accepted JSON forms of one discrete SISO section (transfer
function in descending powers of z, or state space), their validation, state-space realisation,
series connection and frequency response.

A section is canonical once :func:`normalise_section` has checked it: ``{"kind": "tf", "num", "den",
"rate_multiple"}`` or ``{"kind": "ss", "A", "B", "C", "D", "rate_multiple"}``, optional ``"label"``;
every problem is a one-line :class:`ControllerError` naming the source.
"""
from __future__ import annotations

import numpy as np

__all__ = ["ControllerError", "normalise_section", "section_ss", "series", "section_freqresp", "STAB_TOL"]

STAB_TOL = 1e-9  # poles with |p| <= 1 + tol are accepted (integrators allowed)


class ControllerError(ValueError):
    """Invalid controller description; the message is one line naming the source file."""


def _arr(x, what, src):
    try:
        a = np.array(x, dtype=float)
    except (TypeError, ValueError):
        raise ControllerError(f"{src}: {what} is not numeric") from None
    if not np.all(np.isfinite(a)):
        raise ControllerError(f"{src}: {what} contains non-finite values")
    return a


def normalise_section(sec, default_m, where):
    """Return a canonical section dict (validated) from any accepted section form."""
    if not isinstance(sec, dict):
        raise ControllerError(f"{where}: section is not a JSON object")
    kind = sec.get("kind") or ("tf" if "num" in sec or "den" in sec else
                               "ss" if any(k in sec for k in "AaBbCcDd") else None)
    if kind not in ("tf", "ss"):
        raise ControllerError(f"{where}: " + (f"unknown kind {kind!r}" if kind else "missing keys") +
                              " (need kind 'tf' with num, den or 'ss' with A, B, C, D)")
    m = sec.get("rate_multiple", default_m)
    if isinstance(m, bool) or not isinstance(m, (int, float)) or not float(m).is_integer() or m < 1:
        raise ControllerError(f"{where} ({kind}): rate_multiple {m!r} is not an integer >= 1")
    out = {"kind": kind}
    if kind == "tf":
        if "num" not in sec or "den" not in sec:
            raise ControllerError(f"{where} (tf): missing key 'num' or 'den'")
        num, den = _arr(sec["num"], "tf num", where), _arr(sec["den"], "tf den", where)
        if num.ndim != 1 or den.ndim != 1:
            raise ControllerError(f"{where} (tf): bad shapes, num and den must be flat lists "
                                  "(descending powers of z)")
        num, den = np.trim_zeros(num, "f"), np.trim_zeros(den, "f")
        if den.size == 0:
            raise ControllerError(f"{where} (tf): denominator is zero")
        num = num if num.size else np.zeros(1)
        if num.size > den.size:
            raise ControllerError(f"{where} (tf): improper (numerator degree {num.size - 1} > "
                                  f"denominator degree {den.size - 1})")
        poles = np.roots(den)
        out.update(num=num.tolist(), den=den.tolist())
    else:
        try:
            A, B, C, D = (sec[k] if k in sec else sec[k.lower()] for k in "ABCD")
        except KeyError:
            raise ControllerError(f"{where} (ss): missing key (needs A, B, C, D)") from None
        A = _arr(A, "ss A", where)
        n = 0 if A.size == 0 else (A.shape[0] if A.ndim == 2 else -1)
        A = A.reshape(n, n) if A.size == 0 else A
        if A.ndim != 2 or A.shape != (n, n):
            raise ControllerError(f"{where} (ss): A has shape {A.shape}, expected square")
        B, C, D = (_arr(v, f"ss {k}", where) for v, k in ((B, "B"), (C, "C"), (D, "D")))
        if B.shape not in ((n,), (n, 1)) or C.shape not in ((n,), (1, n)) or D.size != 1:
            raise ControllerError(f"{where} (ss): bad shapes A {A.shape}, B {B.shape}, C {C.shape}, "
                                  f"D {D.shape} (SISO with {n} states expected)")
        poles = np.linalg.eigvals(A) if n else np.zeros(0)
        out.update(A=A.tolist(), B=B.ravel().tolist(), C=C.ravel().tolist(), D=float(D.ravel()[0]))
    if poles.size and np.max(np.abs(poles)) > 1 + STAB_TOL:
        raise ControllerError(f"{where} ({kind}): unstable (pole magnitude "
                              f"{np.max(np.abs(poles)):.6g} > 1)")
    out["rate_multiple"] = int(m)
    if isinstance(sec.get("label"), str):
        out["label"] = sec["label"]
    return out


def section_ss(sec):
    """(A, B[n], C[n], D) numpy realisation of one canonical section."""
    if sec["kind"] == "tf":
        num, den = np.asarray(sec["num"]), np.asarray(sec["den"])
        if den.size == 1:
            return np.zeros((0, 0)), np.zeros(0), np.zeros(0), float(num[-1] / den[0])
        return tf2ss(num, den)
    return (np.asarray(sec["A"], float).reshape(len(sec["B"]), len(sec["B"])),
            np.asarray(sec["B"], float), np.asarray(sec["C"], float), float(sec["D"]))


def tf2ss(num, den):
    """Controller canonical realisation ``(A, B[n], C[n], D)`` of the SISO transfer function
    ``num(z) / den(z)`` (descending powers), with :func:`scipy.signal.tf2ss`'s normalisation and
    state order, entry for entry (``tests/test_startup.py`` compares them): written here
    because importing :mod:`scipy.signal` costs ~0.8 s of CPU, more than a whole ``seekopt design``
    start-up should (issue 12).  ``den`` of length >= 2 (a static gain is handled by the caller)."""
    den = np.trim_zeros(np.atleast_1d(np.asarray(den, dtype=float)), "f")
    num = np.atleast_1d(np.asarray(num, dtype=float))
    if den.size == 0:
        raise ValueError("Denominator must have at least one nonzero element.")
    num, den = num / den[0], den / den[0]
    lead = 0
    while lead < num.size - 1 and abs(num[lead]) <= 1e-14:     # leading zeros (at least one kept)
        lead += 1
    num = num[lead:]
    M, K = num.size, den.size
    if M > K:
        raise ValueError("Improper transfer function. `num` is longer than `den`.")
    num = np.concatenate([np.zeros(K - M), num])
    if K == 1:
        return np.zeros((1, 1)), np.zeros(1), np.zeros(1), float(num[0])
    A = np.vstack([-den[1:][None, :], np.eye(K - 2, K - 1)])
    B = np.eye(K - 1, 1).ravel()
    C = num[1:] - num[0] * den[1:]
    return A, B, C, float(num[0])


def series(s1, s2):
    """Series connection s1 -> s2 of SISO (A, B, C, D): x = [x1; x2]."""
    A1, B1, C1, D1 = s1
    A2, B2, C2, D2 = s2
    n1, n2 = A1.shape[0], A2.shape[0]
    A = np.block([[A1, np.zeros((n1, n2))], [np.outer(B2, C1), A2]])
    return A, np.concatenate([B1, B2 * D1]), np.concatenate([D2 * C1, C2]), D2 * D1


def section_freqresp(sec, z):
    """Frequency response of one section at complex points ``z``."""
    if sec["kind"] == "tf":
        return np.polyval(sec["num"], z) / np.polyval(sec["den"], z)
    A, B, C, D = section_ss(sec)
    n = A.shape[0]
    if n == 0:
        return np.full(z.shape, D, dtype=complex)
    M = z[:, None, None] * np.eye(n) - A
    x = np.linalg.solve(M, np.broadcast_to(B[:, None], (z.size, n, 1)))
    return x[:, :, 0] @ C + D

