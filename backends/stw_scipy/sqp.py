"""The SciPy backend: the shared SQP (stw_tui.sos.sqp) on sparse linear algebra.

The SQP itself — its QP, elastic mode, step limit, merit acceptance test and termination — lives
in the core (:mod:`stw_tui.sos.sqp`); this backend supplies SciPy's sparse KKT solves (linear.py),
dense LAPACK ones on small windows (dense.py), and evaluates the window problem with the core's
compiled numpy terms.
"""

from __future__ import annotations

import os

from stw_tui.sos.backend import BackendOption
from stw_tui.sos.sqp import SQP_OPTIONS, SQPBackend

from .dense import DENSE_MAX, NumpyDenseAlgebra, window_rows
from .linear import SOLVERS, SparseAlgebra

FACTORS = ("auto", "sparse", "superlu", "dense")

LINEAR_OPTIONS = (
    BackendOption("solver", str, "direct", "linear solver for the KKT system (with inequality "
                  "instances, the interior-point systems are always factorized)", SOLVERS),
    BackendOption("lin_tol", float, 1e-12, "relative tolerance of the iterative solvers", minimum=0.0,
                  exclusive=True),
    BackendOption("lin_maxiter", int, 1000, "iteration limit of the iterative solvers", minimum=1),
    BackendOption("factor", str, "auto", "direct factorizations: auto (dense LU on windows of up to "
                  f"{DENSE_MAX} rows, else as sparse), sparse (LAPACK's banded LU where a KKT system "
                  "is a narrow band in reverse Cuthill-McKee order, else SuperLU), superlu (always) "
                  "or dense (always)", FACTORS),
)


class ScipyBackend(SQPBackend):
    """SQP with a sparse KKT solve: direct (banded LU or SuperLU; dense LU on small windows),
    MINRES, or CG on the least-squares form."""

    name = "scipy"
    options = LINEAR_OPTIONS + SQP_OPTIONS

    def algebra(self, problem) -> SparseAlgebra | NumpyDenseAlgebra:
        single_threaded_blas()
        factor = self.config["factor"]
        if self.config["solver"] == "direct" and (
                factor == "dense" or factor == "auto" and window_rows(problem) <= DENSE_MAX):
            return NumpyDenseAlgebra()
        return SparseAlgebra(self.config["solver"], self.config["lin_tol"], self.config["lin_maxiter"],
                             "superlu" if factor == "superlu" else "auto")


_BLAS_THREAD_VARIABLES = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")
_blas_limited = False


def single_threaded_blas() -> None:
    """Limit BLAS (the OpenBLAS of numpy and of scipy) to one thread, once a process, unless the
    user set a thread count in the environment. A window problem's LAPACK calls are small: on two
    cores OpenBLAS's threads turn the blocked banded Cholesky of basketball's curvature tests
    (459 rows, half-width 83, 0.5 ms) into stalls of up to 180 ms, and cost luxo's interior-point
    solves a quarter of their time (231 -> 170 ms single-threaded). One thread also makes the
    numbers independent of the machine's core count (a threaded sum splits differently)."""
    global _blas_limited
    if _blas_limited or any(v in os.environ for v in _BLAS_THREAD_VARIABLES):
        return
    _blas_limited = True
    try:
        from threadpoolctl import threadpool_limits
    except ImportError:   # pragma: no cover - a dependency of the package; a partial install
        return
    threadpool_limits(limits=1, user_api="blas")
