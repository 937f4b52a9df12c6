"""When a window problem counts as solved: one definition for every backend.

The settings ``tol_violation``, ``tol_kkt`` and ``tol_step`` (scene settings, `set NAME VALUE`)
mean the same whichever backend solves: the SQP backends test every iterate with
:func:`is_converged`, and the IPOPT backend tests its final point with it too. They also mean the
same at every mesh, whatever the units of the rows and of the DOF: "converged" is within the
stated tolerances of a KKT point of the discretized problem (:func:`kkt_residual`).
"""

from __future__ import annotations

from typing import Callable

import numpy as np
import scipy.sparse as sps
import scipy.sparse.linalg as spla

from stw_tui.sos.compressed import transpose
from stw_tui.sos.sparse_matvec import matvec

KKT_SLACK_TINY_STEP = 1e2      # a tiny step counts as converged when KKT <= this x tol_kkt ...
KKT_SLACK_STALLED = 1e3        # ... and a failed line search when KKT <= this x tol_kkt
PROJECTION_EPS = 1e-10         # the (2,2) block of the projection system (the QP's KKT_EPS)


def lagrangian_gradient(ev, lam_eq: np.ndarray, lam_ge: np.ndarray) -> np.ndarray:
    """∇R + Σλ∇C over the free control points (rows whose `when` fails carry no multiplier)."""
    r = np.array(ev.gradient, dtype=float, copy=True)
    if lam_eq.size:
        r += matvec(transpose(ev.J_eq), lam_eq * ev.active_eq)
    if lam_ge.size:
        r += matvec(transpose(ev.J_ge), lam_ge * ev.active_ge)
    return r


def kkt_residual(ev, lam_eq: np.ndarray, lam_ge: np.ndarray,
                 newton: Callable[[np.ndarray], np.ndarray] | None = None) -> float:
    """How far ``ev`` is from a KKT point, relative to the objective: sqrt(ε² / max(1, |R|)),
    where ε² = -∇Lᵀp is the Lagrangian's decrease that the Newton step p from here predicts
    (p = ``newton``(∇L): the minimizer of ∇Lᵀp + ½pᵀHp on the null space of the binding rows;
    by default with the Lagrangian's Hessian at ``ev``, :func:`newton_step`).

    Why the Newton decrement. A test on the Lagrangian's gradient ∇L itself cannot mean the
    same at every mesh. A gradient entry is the first variation along one basis function,
    ∂L/∂cᵢ = ⟨δL, Bᵢ⟩, and a cubic B-spline's integral is about one span width h: the entries of
    a smooth residual shrink like h, and the old test, max|∇L| relative to max(1, max|∇R|),
    passed earlier the finer the mesh (the pendulum swing-up "converged" 0.95% above its optimum
    at 1280 spans, after 3 iterations). Scaled to the function space (entries divided by the
    basis integrals, or summed: Σ|∂L/∂cᵢ| → ∫|δL|), the smooth part means the same at every
    mesh, but rounding does not: an objective on th'' = Σ cᵢBᵢ'' (|Bᵢ''| ~ 1/h²) is evaluated to
    about ε_mach|c|/h², and its gradient entries to ε_mach|c|/h³, so the scaled residual cannot
    fall below ~ε_mach|c|/h⁴ — 7e-4 of the pendulum's objective at 5120 spans, above any
    tolerance worth stating. The Newton decrement weighs the residual by the inverse Hessian,
    the norm the problem itself is posed in: mesh-independent (it converges to the continuous
    problem's decrement as h → 0), blind to that rounding (H⁻¹ damps the high frequencies it
    lives in by ~h⁴), and invariant under any rescaling of the DOF, of the rows (each multiplier
    carries its row's units away) and under a change of the curves' basis: affine invariant,
    the stopping test of Newton's method in Boyd & Vandenberghe (9.5.1) and Deuflhard's
    energy-norm test (Newton Methods for Nonlinear Problems, 2.1 and 3.3).

    Meaning. Near a KKT point the Lagrangian (the objective, once the rows hold) is within ½ε²
    of its value there. For an objective that is a sum of squared residuals f (every stw
    objective), ε is the size of the change of the weighted residuals that the step makes,
    √2‖J p‖ in the Gauss-Newton model, and √|R| is their size ‖f‖: the measure is the relative
    distance of the residuals from the KKT point's. IPOPT scales its gradient test by its
    multipliers' size (s_d); this measure needs no such scale, being relative to the objective
    and unit-free by construction.
    """
    r = lagrangian_gradient(ev, lam_eq, lam_ge)
    if not r.any():
        return 0.0
    p = newton_step(ev, lam_eq, lam_ge, r) if newton is None else newton(r)
    if p is None or not np.all(np.isfinite(p)):
        return float("inf")
    decrement = abs(float(r @ p))
    return float(np.sqrt(decrement / max(1.0, abs(float(ev.objective)))))


def newton_step(ev, lam_eq: np.ndarray, lam_ge: np.ndarray, r: np.ndarray) -> np.ndarray | None:
    """The Newton step -H⁻¹∇L on the null space of the live equality rows and the binding
    inequality rows (λ < 0), with the Lagrangian's Hessian at ``ev``, by one sparse LU: for a
    backend that has no factorization of its own at hand (the IPOPT backend's final point).
    None when the system is singular."""
    H = sps.csr_array(ev.lagrangian_hessian(lam_eq * ev.active_eq, lam_ge * ev.active_ge))
    parts = []
    if ev.J_eq.shape[0]:
        parts.append(sps.csr_array(ev.J_eq)[np.flatnonzero(ev.active_eq)])
    if ev.J_ge.shape[0]:
        parts.append(sps.csr_array(ev.J_ge)[np.flatnonzero(ev.active_ge & (lam_ge < 0))])
    A = sps.vstack(parts, format="csr") if parts else sps.csr_array((0, r.size))
    return projected_newton(H, A, r, _sparse_kkt_solve)


def _sparse_kkt_solve(H, A, g: np.ndarray) -> np.ndarray | None:
    """x of [[H, Aᵀ], [A, -PROJECTION_EPS·I]] [x; y] = [g; 0] by one sparse LU (None: singular)."""
    m = A.shape[0]
    K = sps.block_array([[H, A.T], [A, -PROJECTION_EPS * sps.eye_array(m)]], format="csc") if m else sps.csc_array(H)
    try:
        return spla.splu(K).solve(np.concatenate([g, np.zeros(m)]))[:H.shape[0]]
    except RuntimeError:
        return None


def projected_newton(H, A, r: np.ndarray, solve) -> np.ndarray | None:
    """The step -H⁻¹r on the null space of the rows A, on the variables that H or A reads
    (:func:`read_variables`; zero along the others), by ``solve(H, A, g)``, which gives x of
    [[H, Aᵀ], [A, -PROJECTION_EPS·I]] [x; y] = [g; 0] on those variables, or None when singular.
    H and A are sparse or dense alike. None as well when r is not zero along an unread variable."""
    read = read_variables(H, A)
    if r[~read].any():   # a direction nothing curves or bounds, along which ∇L is not zero
        return None
    x = solve(H[read][:, read], A[:, read], -r[read])
    if x is None:
        return None
    p = np.zeros(r.size)
    p[read] = x
    return p


def read_variables(H, A) -> np.ndarray:
    """The free control points that the Lagrangian's Hessian or a row reads. The Newton system
    is singular along the others (a held ball's control points inside its hold: arm_throw's
    final point under IPOPT had 16), where the step is zero and leaves the decrement alone."""
    return (np.asarray(abs(H).sum(axis=1)).ravel() > 0) | (np.asarray(abs(A).sum(axis=0)).ravel() > 0)


def is_converged(violation: float, kkt: float, settings: dict, tiny_step: bool = False,
                 stalled: bool = False) -> bool:
    """Violation within ``tol_violation`` and the KKT residual (:func:`kkt_residual`) within
    ``tol_kkt``.

    The violation is each row's own, in its units (a position in metres, a torque in N·m), as
    the rows are written: a row is a value at one time, so it means the same at every mesh.

    A tiny step (or a line search that failed on merit noise at machine precision) is no proof on
    its own — a heavy proximal term makes steps tiny — so it counts only when the KKT residual is
    near its tolerance too (then rounding is what is left).
    """
    if violation > settings["tol_violation"]:
        return False
    tol = settings["tol_kkt"]
    return (kkt <= tol or (tiny_step and kkt <= KKT_SLACK_TINY_STEP * tol)
            or (stalled and kkt <= KKT_SLACK_STALLED * tol))
