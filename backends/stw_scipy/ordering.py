"""SuperLU's column ordering of a KKT structure, worked out once and replayed bit for bit.

``splu(K, permc_spec="COLAMD")`` orders K's columns (COLAMD, then a postorder of the column
elimination tree) on every call; on the interior-point KKT systems of a few hundred rows that is
about 40% of the factorization, and the order depends on K's sparsity structure only, which stays
fixed while the method runs. scipy takes no ordering of ours, but factorizing the symmetrically
permuted K' = P K Pᵀ in NATURAL order does exactly the same arithmetic, bit for bit, when:

* P is the final ``perm_c`` of a COLAMD factorization of that structure (the postorder included):
  NATURAL keeps it as it is (scipy sets SymmetricMode for NATURAL, so no postorder of its own);
* rows move with their columns: SuperLU prefers the diagonal as pivot (for column j, row
  perm_c⁻¹[j] of K), which stays K's diagonal entry;
* each column of K' keeps K's stored order of its rows (relabelled, not re-sorted): SuperLU's
  depth-first searches visit a column's rows in stored order, and that order decides the order
  of its updates (sorted rows give other round-off: iterates that drift apart, more iterations).

splu sorts the rows of a matrix not marked canonical (``sum_duplicates``): K' is marked so. It has
no duplicates, and its rows are left in K's order on purpose.

The same holds for the positive-definiteness test's symmetric MMD_AT_PLUS_A ordering (its other
options are kept in the replay).

Other direct solvers on the package index were measured against this on the systems the bundled
sessions factorize (40 of basketball's, 459-715 rows, and 21 of the arm's, 114-210; one thread,
medians, factorization and solve): none beats SuperLU on basketball from scratch (KLU of kvxopt
1.33x its time, MUMPS LDLᵀ 1.64x, UMFPACK 1.9x, MKL PARDISO 3.4x: its analysis alone costs
3 ms); with the analysis reused as here, PARDISO's LU takes 0.72x (MUMPS and KLU 0.94x, within
noise) but brings 1.7 GB of MKL, and its LDLᵀ is not accurate on these near-singular systems
(residuals 100x SuperLU's and worse on a fifth of them). On the arm's, KLU takes 0.60x SuperLU
(0.32x reused), where the banded LU (banded.py) already takes about 0.5x, and converting to its
matrices costs more than the factorization. None is worth its dependency here.

QDLDL (``qdldl`` 0.1.9, OSQP's LDLᵀ without pivoting for quasi-definite KKT systems, its symbolic
factorization reused per structure) was measured on every system of the first solves (172 of the
arm's, 573 of basketball's; factorization and two solves): 1.08x the banded LU's time on the arm's
and 0.31-0.42x SuperLU's on basketball's, but with relative residuals of 0.2 and 0.7 (medians; up
to 3e4 and 2.5e23) against 7e-8 and 5e-8 here. With their (2,2) block of -1e-10 and a Hessian
convex only on the rows' null space, these systems are quasi-definite in name only: a
factorization without pivoting is not accurate on them, and no refinement recovers that.
"""

from __future__ import annotations

import threading

import numpy as np
import scipy.sparse as sps
import scipy.sparse.linalg as spla

from stw_scipy.banded import BandPlan
from stw_tui.sos.compressed import same_structure, structure

ORDERINGS_KEPT = 12   # structures always remembered: interior point, working sets, curvature tests ...
# ... and older ones up to this many stored entries of K in all (24 bytes each kept: 48 MB). A
# window's working sets each have a structure of their own: the arm's first solve meets 27,
# basketball's 104 (about 18,000 entries each), and the next `iterate` of the window meets them again.
ORDERINGS_ENTRIES = 2_000_000


class Ordering:
    """The replay of one factorization's column order (``spec``), for K's of one sparsity
    structure; ``options``: splu's other keyword arguments, the same in the replay."""

    def __init__(self, K: sps.csc_array, perm_c: np.ndarray, spec: str, options: dict):
        self.spec, self.options = spec, options
        n, nnz = K.shape[0], K.indptr[-1]
        self.perm = np.asarray(perm_c, dtype=np.intp)   # column (and row) i of K is perm[i] of K'
        old = np.empty(n, dtype=np.intp)
        old[self.perm] = np.arange(n)                    # column k of K' is column old[k] of K
        self.inverse = old
        counts = np.diff(K.indptr)[old]
        self.indptr = np.zeros(n + 1, dtype=np.intc)
        np.cumsum(counts, out=self.indptr[1:])
        # K's storage position of each entry of K', column by column in K's stored row order
        self.source = np.repeat(K.indptr[old] - self.indptr[:-1], counts) + np.arange(nnz)
        self.indices = self.perm[K.indices[self.source]].astype(np.intc)
        self.key = structure(K)
        self._permuted = None   # K' (factorize_values), made on first use
        self._lock = threading.Lock()   # K' is shared by every algebra that kept this ordering

    def fits(self, K: sps.csc_array, spec: str, options: dict) -> bool:
        """Whether K has this structure and is to be factorized the same way."""
        return spec == self.spec and options == self.options and same_structure(K, self.key)

    def factorize(self, K: sps.csc_array) -> "PermutedLU":
        """What ``splu(K, permc_spec=spec, **options)`` gives, bit for bit, without the ordering."""
        return self.factorize_values(K.data)

    def factorize_values(self, data: np.ndarray) -> "PermutedLU":
        """:meth:`factorize` of the K of this structure whose CSC values are ``data``: K itself
        need not be built. K' is one matrix kept for the purpose, its values swapped in (building
        a scipy matrix checks its arrays, which costs more than the gather)."""
        with self._lock:
            if self._permuted is None:
                shape = (self.indptr.size - 1,) * 2
                self._permuted = sps.csc_array((np.zeros(self.source.size), self.indices, self.indptr),
                                               shape=shape)
            Kp = self._permuted
            Kp.data = data[self.source]
            Kp.has_canonical_format = True   # no duplicates; rows in K's order on purpose (see above)
            lu = spla.splu(Kp, permc_spec="NATURAL", **self.options)
        return PermutedLU(lu, self.perm, self.inverse)


class PermutedLU:
    """Solves K x = b with ``lu``, the factorization of K' = P K Pᵀ (perm None: of K itself)."""

    def __init__(self, lu, perm: np.ndarray | None, inverse: np.ndarray | None = None):
        self.lu, self.perm = lu, perm
        self.inverse = inverse   # perm's inverse (then the rhs is gathered, not scattered)

    def solve(self, rhs: np.ndarray) -> np.ndarray:
        """x with K x = rhs (rhs a vector, or a matrix of right-hand sides in columns)."""
        if self.perm is None:
            return self.lu.solve(rhs)
        if self.inverse is not None:
            return self.lu.solve(np.asarray(rhs, dtype=float)[self.inverse])[self.perm]
        b = np.empty(np.shape(rhs))
        b[self.perm] = rhs
        return self.lu.solve(b)[self.perm]


def factorize(K: sps.csc_array, orderings: list | None, spec: str = "COLAMD", *,
              band_max: int = 0, **options):
    """splu(K, permc_spec=spec, **options), replaying the ordering of K's structure when
    ``orderings`` (most recent first) holds it, and remembering it there otherwise (splu sorts a
    non-canonical K in place first: its ordering is not remembered).

    ``band_max`` > 0: a KKT system (COLAMD, no other options) whose structure is a band of at
    most that half-width in reverse Cuthill-McKee order is factorized by LAPACK's banded LU
    instead (banded.py); its plan is remembered in ``orderings`` like an ordering.

    Raises:
        RuntimeError: SuperLU's "Factor is exactly singular" (or a banded LU's zero pivot).
    """
    if orderings is None or not K.has_canonical_format:
        return PermutedLU(spla.splu(K, permc_spec=spec, **options), None)
    for i, ordering in enumerate(orderings):
        if ordering.fits(K, spec, options):
            orderings.insert(0, orderings.pop(i))
            return ordering.factorize(K)
    if band_max and spec == BandPlan.spec and options == BandPlan.options:
        plan = BandPlan.of(K, band_max)
        if plan is not None:
            _remember(orderings, plan)
            return plan.factorize(K)
    lu = spla.splu(K, permc_spec=spec, **options)
    _remember(orderings, Ordering(K, lu.perm_c, spec, options))
    return PermutedLU(lu, None)


def _remember(orderings: list, plan) -> None:
    """Put ``plan`` first in ``orderings``; keep the newest ORDERINGS_KEPT, and older ones while
    the structures kept hold at most ORDERINGS_ENTRIES stored entries in all."""
    orderings.insert(0, plan)
    entries = 0
    for i, kept in enumerate(orderings):
        entries += kept.key[2].size
        if i >= ORDERINGS_KEPT and entries > ORDERINGS_ENTRIES:
            del orderings[i:]
            return
