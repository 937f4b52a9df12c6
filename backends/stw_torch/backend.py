"""The torch backend: the reference SQP with values and derivatives from torch autograd.

The SQP itself — the QP of each step, the regularization that keeps it a descent step, the ℓ1
merit line search with second-order correction, the multiplier update and the convergence tests —
is ``stw_scipy``'s, inherited unchanged, so both backends take the same steps. What differs is
where the numbers come from: every term's sympy expression is lowered to torch here, and the
gradient, Jacobians and Hessian of the Lagrangian come from autograd, assembled on fixed sparse
patterns (evaluate.py). With ``linear=torch`` the QP is solved on the device too (linalg.py).

torch is imported when a solve starts, not when the class is loaded: listing the backend's
options (``help``, the TUI's backend panel) costs nothing.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sps

from stw_scipy.qp import KKT_EPS
from stw_scipy.sqp import ACTIVE_FRACTION, ScipyBackend, _Inner
from stw_tui.backend import BackendOption, SolverState
from stw_tui.errors import StwError


class TorchBackend(ScipyBackend):
    """SQP on torch: lowered expressions, autograd derivatives, sparse or dense KKT solves."""

    name = "torch"
    options = (
        BackendOption("device", str, "auto", "where the tensors live (auto: cuda when available)",
                      ("auto", "cpu", "cuda")),
        BackendOption("linear", str, "auto", "KKT solves: scipy (sparse, on the host, any `solver`) or "
                      "torch (dense LU on the device); auto: torch on cuda, scipy on cpu",
                      ("auto", "scipy", "torch")),
        *ScipyBackend.options,
    )
    capabilities = ScipyBackend.capabilities | {"autograd", "gpu"}

    # --- setup -------------------------------------------------------------------------------
    def init(self, problem, state: SolverState, settings) -> _Inner:
        import torch

        from .evaluate import TorchProblem, check_finite

        want = self.config["device"]
        if want == "auto":
            want = "cuda" if torch.cuda.is_available() else "cpu"
        if want == "cuda" and not torch.cuda.is_available():
            raise StwError("device=cuda, but torch sees no CUDA device (use device=cpu or auto)")
        self.device = torch.device(want)
        if self.device.type == "cpu":
            torch.set_num_threads(1)  # small batched work on 2 cores: threads cost ~50x (DESIGN.md)
        linear = self.config["linear"]
        self.linear = ("torch" if self.device.type == "cuda" else "scipy") if linear == "auto" else linear
        self._torch = torch
        self.tp = TorchProblem(problem, self.device, host_linear=self.linear == "scipy")
        ev = self.tp.evaluate(state.s)
        check_finite(ev, problem)
        return _Inner(state=state, ev=ev, settings=dict(settings))

    # --- one iteration -----------------------------------------------------------------------
    def step(self, problem, inner: _Inner, iteration: int):
        """The SciPy backend's step, with evaluations (and linear algebra) on torch."""
        return super().step(self.tp, inner, iteration)

    def _damping(self, problem, settings, prox: float):
        damp = super()._damping(problem, settings, prox)
        if self.linear == "scipy":
            return damp
        torch = self._torch
        return torch.diag(torch.as_tensor(damp.diagonal(), dtype=torch.float64, device=self.device))

    def _solve_qp(self, H, ev, st: SolverState, **kwargs):
        if self.linear == "scipy":
            return super()._solve_qp(H, ev, st, **kwargs)
        return self._solve_qp_torch(H, ev, st, **kwargs)

    def _solve_qp_torch(self, H, ev, st: SolverState, restore: bool = False):
        """``ScipyBackend._solve_qp`` on dense device tensors (same rows, regularization, outputs).

        ``restore``: the restoration step — the least change that fixes the linearized
        constraints (zero gradient, no multiplier stabilization).
        """
        torch = self._torch
        from . import linalg

        dev = dict(dtype=torch.float64, device=self.device)
        if sps.issparse(H):  # the restoration step's identity comes from the shared SQP step
            H = torch.as_tensor(H.toarray(), **dev)
        eq_rows, ge_rows = np.flatnonzero(ev.active_eq), np.flatnonzero(ev.active_ge)
        J_eq, J_ge = ev.dense_jacobian("eq"), ev.dense_jacobian("ge")
        eq_t, ge_t = torch.as_tensor(eq_rows, device=self.device), torch.as_tensor(ge_rows, device=self.device)
        Ae, ce = J_eq[eq_t], ev.t_c["eq"][eq_t]
        Ai, ci = J_ge[ge_t], ev.t_c["ge"][ge_t]
        g = torch.zeros_like(ev.t_gradient) if restore else ev.t_gradient
        y0 = None if restore else torch.as_tensor(st.lam_eq[eq_rows], **dev)
        n = H.shape[0]
        eye = torch.eye(n, **dev)
        reg, total_its = 0.0, 0
        for _attempt in range(8):
            Hr = H + reg * eye if reg else H
            try:
                qp = linalg.solve_qp(Hr, g, Ae, ce, Ai, ci, y0=y0)
            except RuntimeError:
                reg = max(10 * reg, 1e-8)
                continue
            total_its += qp.linear_iterations
            d = qp.d
            curvature = float(d @ (Hr @ d))
            if curvature >= -1e-12 * float(d @ d) or not bool(d.any()):
                break
            reg = max(10 * reg, 1e-6 * max(1.0, float(H.diagonal().abs().max())))
        z = qp.z.cpu().numpy()
        lam_eq = np.zeros(ev.c_eq.size)
        lam_eq[eq_rows] = qp.y.cpu().numpy()
        lam_ge = np.zeros(ev.c_ge.size)
        lam_ge[ge_rows] = -z
        working = np.zeros(ev.c_ge.size, bool)
        if z.size:
            working[ge_rows[z > ACTIVE_FRACTION * max(1.0, float(z.max()))]] = True
        A_rows = (eq_rows, np.flatnonzero(working))
        Hr = H + reg * eye if reg else H
        factor = []

        def resolve(rhs_c: np.ndarray) -> np.ndarray:
            """Minimum-change step that fixes constraint values rhs_c (second-order correction)."""
            if not factor:
                A = torch.cat([J_eq[torch.as_tensor(A_rows[0], device=self.device)],
                               J_ge[torch.as_tensor(A_rows[1], device=self.device)]], 0)
                factor.append(linalg.DenseKKT(Hr, A, KKT_EPS))
            rhs = torch.cat([torch.zeros(n, **dev), torch.as_tensor(rhs_c, **dev)])
            return factor[0].solve(rhs)[:n].cpu().numpy()

        return qp.d.cpu().numpy(), lam_eq, lam_ge, working, total_its, resolve, A_rows
