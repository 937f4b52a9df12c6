"""The SQP every iterative backend runs: one step, one QP, one line search, one termination test.

* :mod:`.algebra` — the linear-algebra interface a backend implements (vectors, matrices, KKT solves);
* :mod:`.qp` — the QP subproblem (a KKT solve, or Mehrotra's interior-point method; hard or elastic);
* :mod:`.curvature` — the least shift that makes an exact model convex where the QP needs it;
* :mod:`.solver` — :class:`SQPBackend`, the SQP step with its elastic mode, step limit, merit
  acceptance test and infeasibility diagnosis;
* :mod:`.termination` — the convergence test every backend (IPOPT included) applies.

Free of torch: backends bring their own arrays through :class:`LinearAlgebra`.
"""

from stw_tui.sos.sqp.algebra import KKTSystem, LinearAlgebra, SingularSystem
from stw_tui.sos.sqp.qp import KKT_EPS, QPResult, solve_qp
from stw_tui.sos.sqp.solver import SQP_OPTIONS, SQPBackend, SQPInner
from stw_tui.sos.sqp.termination import is_converged, kkt_residual

__all__ = ["KKTSystem", "LinearAlgebra", "SingularSystem", "KKT_EPS", "QPResult", "solve_qp",
           "SQP_OPTIONS", "SQPBackend", "SQPInner", "is_converged", "kkt_residual"]
