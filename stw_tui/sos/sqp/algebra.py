"""The linear algebra the SQP and its QP are written over.

One SQP (sqp/solver.py) and one QP (sqp/qp.py) serve every backend; what differs between
backends is where vectors and matrices live and how the KKT system

    K = [[H, Aᵀ], [A, -diag(e)]]

is solved: SciPy sparse (SuperLU, MINRES, CG on the least-squares form) or torch (dense LU on the
CPU or a CUDA device). A backend supplies a :class:`LinearAlgebra`; the QP touches its vectors
only through Python's arithmetic operators (``+ - * /`` and unary ``-``, which numpy arrays and
torch tensors share), comparisons with ``<``/``>`` and boolean-mask indexing, and the methods
below. Nothing here imports torch.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from typing import Any, Callable, Sequence

import numpy as np

Vector = Any   # a backend's 1-D float64 array (numpy.ndarray, torch.Tensor, ...)
Matrix = Any   # a backend's 2-D matrix (scipy sparse, dense torch.Tensor, ...)


class SingularSystem(ArithmeticError):
    """The KKT matrix is exactly singular (the factorization broke down)."""


class KKTSystem(ABC):
    """K = [[H, Aᵀ], [A, -diag(e)]], ready to solve for any right-hand side."""

    iterations: int = 0   # linear-solver iterations spent so far (a factorization counts 1)
    fallbacks: int = 0    # iterative solves replaced by a factorization so far

    @abstractmethod
    def solve(self, rhs: Vector) -> Vector:
        """x with K x = rhs. Raises SingularSystem when K cannot be factorized."""


class LinearAlgebra(ABC):
    """Vectors, matrices and KKT solves of one backend."""

    # --- vectors ----------------------------------------------------------------------------
    @abstractmethod
    def vector(self, values: np.ndarray) -> Vector:
        """A backend vector holding a copy of ``values``."""

    @abstractmethod
    def numpy(self, v: Vector) -> np.ndarray:
        """``v`` as a numpy array on the host."""

    @abstractmethod
    def full(self, n: int, value: float) -> Vector:
        """A vector of ``n`` entries equal to ``value``."""

    @abstractmethod
    def concat(self, parts: Sequence[Vector]) -> Vector:
        """The vectors one after the other."""

    @abstractmethod
    def maximum(self, v: Vector, floor: float) -> Vector:
        """Elementwise max(v, floor)."""

    @abstractmethod
    def max_abs(self, v: Vector) -> float:
        """max |v_i| (0 for an empty vector)."""

    def dot(self, a: Vector, b: Vector) -> float:
        """aᵀb as a float."""
        return float(a @ b)

    def zeros(self, n: int) -> Vector:
        """A vector of n zeros."""
        return self.full(n, 0.0)

    def max_step(self, v: Vector, dv: Vector, cap: float = 1.0) -> float:
        """Largest α <= cap keeping v + α dv >= 0 (the interior-point ratio test)."""
        neg = dv < 0
        if not bool(neg.any()):
            return cap
        return float(min(cap, float((-v[neg] / dv[neg]).min())))

    # --- matrices ---------------------------------------------------------------------------
    @abstractmethod
    def matrix(self, m: Any) -> Matrix:
        """A backend matrix from a scipy sparse matrix (or from one of its own, unchanged)."""

    @abstractmethod
    def diagonal_matrix(self, v: np.ndarray) -> Matrix:
        """diag(v) from a numpy vector."""

    @abstractmethod
    def rows(self, m: Matrix, index: np.ndarray) -> Matrix:
        """The rows ``index`` of ``m``."""

    @abstractmethod
    def stack_rows(self, parts: Sequence[Matrix]) -> Matrix:
        """The matrices one above the other."""

    @abstractmethod
    def matvec(self, m: Matrix, x: Vector) -> Vector:
        """m @ x."""

    @abstractmethod
    def rmatvec(self, m: Matrix, x: Vector) -> Vector:
        """mᵀ @ x."""

    @abstractmethod
    def add(self, a: Matrix, b: Matrix) -> Matrix:
        """a + b (same shape)."""

    @abstractmethod
    def gram(self, a: Matrix, w: Vector) -> Matrix:
        """aᵀ diag(w) a."""

    @abstractmethod
    def max_abs_diagonal(self, m: Matrix) -> float:
        """max |m_ii|."""

    def row_squares(self, a: Matrix) -> np.ndarray:
        """Σ_j a_ij² for each row i, as numpy. The default, for a backend that does not supply
        it, gives every row the widest column's Σ_i a_ij²: the curvature test then weighs its rows
        as it did before it scaled each to unit length."""
        gram = self.gram(a, self.full(a.shape[0], 1.0))
        return np.full(a.shape[0], self.max_abs_diagonal(gram))

    @abstractmethod
    def kkt(self, H: Matrix, A: Matrix, e: float | Vector, exact: bool = False) -> KKTSystem:
        """The system [[H, Aᵀ], [A, -diag(e)]] (``e`` a scalar or one entry per row of A).

        ``exact``: factorize whatever the backend's preferred solver (interior-point systems
        are too ill-conditioned for unpreconditioned Krylov methods). Raises SingularSystem.
        """

    def barrier_kkt(self, H: Matrix, Ai: Matrix, Ae: Matrix) -> Callable[[Vector, Vector], KKTSystem]:
        """The interior-point method's systems of one QP, [[H + Aᵢᵀ diag(q) Aᵢ, Aₑᵀ], [Aₑ, -diag(e)]]
        as a function of (q, e): H, Aᵢ and Aₑ stay fixed while the method runs, so a backend may
        prepare their assembly once. Each call is :meth:`kkt` with ``exact`` (raises
        SingularSystem). The default assembles each system anew."""
        return lambda q, e: self.kkt(self.add(H, self.gram(Ai, q)), Ae, e, exact=True)

    def working_set_kkt(self, H: Matrix, Ae: Matrix, Ai: Matrix, e: float) -> Callable[[Vector], KKTSystem]:
        """The working-set systems of one QP, [[H, Aᵀ], [A, -e I]] with A the rows of Aₑ and the
        rows of Aᵢ that a bool vector ``binding`` picks, as a function of ``binding``: H, Aₑ and
        Aᵢ stay fixed while the active-set method tries its sets, so a backend may prepare their
        assembly once. Each call is :meth:`kkt` with ``exact`` (raises SingularSystem). The
        default stacks the rows and assembles each system anew."""
        def system(binding: Vector) -> KKTSystem:
            A = self.stack_rows([Ae, self.rows(Ai, np.flatnonzero(self.numpy(binding)))])
            return self.kkt(H, A, e, exact=True)
        return system

    @abstractmethod
    def positive_definite(self, m: Matrix) -> bool:
        """Whether the symmetric matrix ``m`` is positive definite (a Cholesky-type factorization
        without pivoting meets only positive pivots)."""

    def identity(self, n: int) -> Matrix:
        """The n x n identity matrix."""
        return self.diagonal_matrix(np.ones(n))

    def jacobian(self, ev: Any, kind: str) -> Matrix:
        """The Jacobian of the equality ("eq") or inequality ("ge") rows of evaluation ``ev``."""
        return self.matrix(ev.J_eq if kind == "eq" else ev.J_ge)


class DenseMatrices:
    """The matrix products of a :class:`LinearAlgebra` on dense 2-D arrays that have ``@``,
    ``.T`` and broadcasting: numpy's (stw_scipy.dense) and torch's (stw_torch.linalg) alike,
    written once. Put it before the LinearAlgebra base of a dense algebra."""

    def matvec(self, m: Matrix, x: Vector) -> Vector:
        """m @ x."""
        return m @ x

    def rmatvec(self, m: Matrix, x: Vector) -> Vector:
        """mᵀ @ x."""
        return m.T @ x

    def add(self, a: Matrix, b: Matrix) -> Matrix:
        """a + b."""
        return a + b

    def gram(self, a: Matrix, w: Vector) -> Matrix:
        """aᵀ diag(w) a, w scaling a's rows by broadcasting."""
        return a.T @ (w[:, None] * a)
