"""When a window problem counts as solved: one definition for every backend.

The settings ``tol_violation``, ``tol_kkt`` and ``tol_step`` (scene settings, `set NAME VALUE`)
mean the same whichever backend solves: the SQP backends test every iterate with
:func:`is_converged`, and the IPOPT backend tests its final point with it too.
"""

from __future__ import annotations

import numpy as np

from stw_tui.sos.compressed import transpose
from stw_tui.sos.sparse_matvec import matvec

KKT_SLACK_TINY_STEP = 1e2      # a tiny step counts as converged when KKT <= this x tol_kkt ...
KKT_SLACK_STALLED = 1e3        # ... and a failed line search when KKT <= this x tol_kkt


def kkt_residual(ev, lam_eq: np.ndarray, lam_ge: np.ndarray) -> float:
    """‖∇R + Σλ∇C‖∞ relative to max(1, ‖∇R‖∞) (rows whose `when` fails carry no multiplier)."""
    r = np.array(ev.gradient, dtype=float, copy=True)
    if lam_eq.size:
        r += matvec(transpose(ev.J_eq), lam_eq * ev.active_eq)
    if lam_ge.size:
        r += matvec(transpose(ev.J_ge), lam_ge * ev.active_ge)
    return float(np.abs(r).max(initial=0.0) / max(1.0, float(np.abs(ev.gradient).max(initial=0.0))))


def is_converged(violation: float, kkt: float, settings: dict, tiny_step: bool = False,
                 stalled: bool = False) -> bool:
    """Violation within ``tol_violation`` and the KKT residual within ``tol_kkt``.

    A tiny step (or a line search that failed on merit noise at machine precision) is no proof on
    its own — a heavy proximal term makes steps tiny — so it counts only when the KKT residual is
    near its tolerance too (then rounding is what is left).
    """
    if violation > settings["tol_violation"]:
        return False
    tol = settings["tol_kkt"]
    return (kkt <= tol or (tiny_step and kkt <= KKT_SLACK_TINY_STEP * tol)
            or (stalled and kkt <= KKT_SLACK_STALLED * tol))
