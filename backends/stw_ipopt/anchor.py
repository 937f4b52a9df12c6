"""The pendulum swing-up stated directly in CasADi, nothing of stw's: `stw bench --anchors`' IPOPT
reference (stw_tui.cli.bench_targets.native_ipopt_pendulum reaches it as
``IpoptBackend.pendulum_reference``: casadi stays in the backends) and the ipopt backend's tests'."""

from __future__ import annotations

import casadi
import numpy as np
import scipy.sparse as sps
from scipy.interpolate import BSpline


def pendulum_nlp(spans: int, quadrature: int, g: float, t1: float = 2.0):
    """``(solver, target)``: the swing-up stated directly in CasADi as its users write it (nothing
    of stw's): control points as one SX vector, the basis matrices from scipy's BSpline at the same
    Gauss-Legendre nodes, ``Σ w (θ'' + g sin θ)²`` with the four boundary conditions
    ``[θ(0), θ(t1), θ'(0), θ'(t1)] = target``, ``nlpsol`` with IPOPT's exact Hessian and MUMPS."""
    knots = np.concatenate([[0.0] * 3, np.linspace(0.0, t1, spans + 1), [t1] * 3])
    n = spans + 3
    x, w = np.polynomial.legendre.leggauss(quadrature)
    cuts = np.linspace(0.0, t1, spans + 1)
    half = (cuts[1:] - cuts[:-1])[:, None] / 2
    times = ((cuts[1:] + cuts[:-1])[:, None] / 2 + half * x[None, :]).ravel()
    weights = (half * w[None, :]).ravel()

    def basis(ts, order):   # column j: the j-th basis function's order-th derivative at ts
        eye = np.eye(n)
        m = sps.csc_matrix(np.column_stack([BSpline(knots, eye[j], 3).derivative(order)(ts)
                                            if order else BSpline(knots, eye[j], 3)(ts) for j in range(n)]))
        m.eliminate_zeros()
        m.sort_indices()
        return casadi.DM(casadi.Sparsity(m.shape[0], m.shape[1], m.indptr.tolist(), m.indices.tolist()), m.data)

    s = casadi.SX.sym("s", n)
    u = casadi.mtimes(basis(times, 2), s) + g * casadi.sin(casadi.mtimes(basis(times, 0), s))
    ends = np.array([0.0, t1])
    constraints = casadi.vertcat(casadi.mtimes(basis(ends, 0), s), casadi.mtimes(basis(ends, 1), s))
    solver = casadi.nlpsol("pendulum", "ipopt", {"x": s, "f": casadi.dot(casadi.DM(weights), u * u),
                                                 "g": constraints},
                           {"ipopt": {"print_level": 0, "sb": "yes", "tol": 1e-8}, "print_time": False})
    return solver, np.array([0.0, np.pi, 0.0, 0.0])
