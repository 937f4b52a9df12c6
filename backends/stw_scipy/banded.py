"""LAPACK's banded LU (``dgbtrf``) of KKT systems whose band is narrow once their rows and
columns are put in reverse Cuthill–McKee order.

A window problem's KKT matrix couples a control point with those a few knot spans away, and a
constraint row with the control points its instances touch: in RCM order the bundled sessions'
systems are bands of half-width 3-38 (the pendulum, the point mass, luxo, acrobat, the arm).
There LAPACK's banded LU with partial pivoting costs a fraction of SuperLU's general sparse LU,
whose per-call analysis dominates at these sizes (same-run medians, this machine): the arm's
interior-point systems, 184 rows, half-width 38: 114 µs against 240; acrobat's, 742 rows,
half-width 23: 345 µs against 1.7 ms; luxo's, 295 rows: 189 µs against 744; the point mass's,
46 rows: 9 µs against 101. Basketball's systems are wider (half-width 56-87, 603-714 rows):
banded they cost 0.9-2.6 ms against SuperLU's 0.9-2.9 (1.0-1.9x faster on one BLAS thread), but
the solve then takes 97 iterations instead of 88 to a point 1.8e-5 away, slower on the whole: a
structure wider than BAND_MAX stays with SuperLU.

RCM's start matters: scipy's, a node of least degree, can sit midway along the time axis and
double the band (:func:`_rcm` then starts again from the far end: acrobat's and luxo's working
sets, 164 of their 610 factorizations, went from SuperLU to bands of 24-33).

A :class:`BandPlan` is worked out once per sparsity structure (the permutation and where each of
K's stored entries goes in LAPACK's band storage), so the next K of that structure is one
scatter of its values and one ``dgbtrf``.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sps
from scipy.linalg import lapack
from scipy.sparse.csgraph import breadth_first_order, reverse_cuthill_mckee

from stw_tui.sos.compressed import csr, same_structure, structure

BAND_MAX = 48   # widest half-bandwidth factorized banded (basketball's 56-87 stay with SuperLU)
# ... and tested for positive definiteness by a banded Cholesky, where SuperLU's LDLᵀ costs 2x
# as much at half-width 83 (basketball, 459 rows) and 5-7x at 41-62 (459-6000 rows)
CHOLESKY_BAND_MAX = 96


def _rcm(m, limit: int | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, int]:
    """Reverse Cuthill-McKee of a compressed array's (symmetric) pattern: the permutation, each
    index's rank in it, the ranks of each stored entry's outer (pointer) and inner (index)
    position, and the half-bandwidth they span. Were the pattern not symmetric, as RCM's symmetric
    mode takes it, the order would only be worse: the width is measured on the entries.

    scipy's RCM starts from a node of least degree, and on some working-set systems that start
    doubles the band (acrobat's: 48-65 where 24-27 can be had; luxo's: 60-73 against 31-33):
    such a node can sit midway along the time axis, and the search then spreads both ways.
    Where its band is wider than ``limit``, RCM is run again from the node scipy's order ends
    with, at the far end of the graph (one step of George and Liu's search for a pseudo-peripheral
    node; more steps gave nothing narrower on the bundled sessions), and the narrower order kept.
    Systems narrow enough keep scipy's order exactly."""
    perm = reverse_cuthill_mckee(m, symmetric_mode=True).astype(np.intp)
    owner = np.repeat(np.arange(m.shape[0]), np.diff(m.indptr))   # each stored entry's outer index
    found = _band(m, perm, owner)
    if limit is not None and found[-1] > limit:
        other = _band(m, _rcm_from(m, perm), owner)
        if other[-1] < found[-1]:
            found = other
    return found


def _band(m, perm: np.ndarray, owner: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, int]:
    """_rcm's answer for the order ``perm`` of ``m``'s rows and columns (``owner``: each stored
    entry's outer index)."""
    n, nnz = m.shape[0], m.indptr[-1]
    rank = np.empty(n, dtype=np.intp)
    rank[perm] = np.arange(n)
    outer, inner = rank[owner], rank[m.indices[:nnz]]
    return perm, rank, outer, inner, int(np.abs(outer - inner).max(initial=0))


def _rcm_from(m, scipys: np.ndarray) -> np.ndarray:
    """Reverse Cuthill-McKee of ``m``'s (symmetric) pattern from the node scipy's order
    ``scipys`` ends with: a breadth-first order that visits each node's neighbours by increasing
    degree (each row's entries are sorted by their column's rank in degree order, in scipy's C
    code), reversed. Nodes the search does not reach (other components) follow in scipy's order;
    their band is their own."""
    n, nnz = m.shape[0], m.indptr[-1]
    by_degree = np.argsort(np.diff(m.indptr), kind="stable")
    degree_rank = np.empty(n, dtype=m.indices.dtype)
    degree_rank[by_degree] = np.arange(n)
    pattern = csr(np.ones(nnz), degree_rank[m.indices[:nnz]], m.indptr.copy(), m.shape)
    pattern.has_sorted_indices = False
    pattern.sort_indices()
    pattern.indices = by_degree[pattern.indices].astype(m.indices.dtype)   # back to m's numbering
    # directed: the pattern is symmetric, and the search then skips the transpose it would make
    # (4.6x faster, the same order on every bundled system)
    order = breadth_first_order(pattern, int(scipys[0]), directed=True, return_predecessors=False)
    if order.size < n:
        order = np.concatenate([order, scipys[~np.isin(scipys, order)][::-1]])
    return order[::-1].astype(np.intp)


class BandPlan:
    """How K's of one sparsity structure are factorized banded: an RCM permutation ``perm``
    (row and column k of K' = P K Pᵀ are perm[k] of K), the half-bandwidth of K' and where each
    stored entry of K (CSC order) lands in LAPACK's band storage."""

    spec, options = "COLAMD", {}   # what it stands in for: SuperLU's factorization of a KKT

    def __init__(self, K: sps.csc_array, perm: np.ndarray, rank: np.ndarray, width: int,
                 i: np.ndarray, j: np.ndarray):
        self.perm, self.rank, self.width = perm, rank, width
        self.rows = 3 * width + 1   # LAPACK's LDAB: kl + ku + 1 rows of K', kl more for the fill of pivoting
        # entry (i, j) of K' sits at row kl + ku + i - j, column j of the band, stored by columns
        self.at = (2 * width + i - j) + j * self.rows
        self.key = structure(K)

    @classmethod
    def of(cls, K: sps.csc_array, band_max: int = BAND_MAX) -> "BandPlan | None":
        """The plan for K's structure, or None when its RCM band is wider than ``band_max``."""
        if K.shape[0] == 0:
            return None
        perm, rank, j, i, width = _rcm(K, band_max)   # CSC: the pointer is the column, the index the row
        return cls(K, perm, rank, width, i, j) if width <= band_max else None

    def fits(self, K: sps.csc_array, spec: str, options: dict) -> bool:
        """Whether K has this structure and stands for SuperLU's factorization of a KKT."""
        return spec == self.spec and options == self.options and same_structure(K, self.key)

    def factorize(self, K: sps.csc_array) -> "BandedLU":
        """The banded LU of K (of this structure)."""
        return self.factorize_values(K.data)

    def factorize_values(self, data: np.ndarray) -> "BandedLU":
        """The banded LU of the K of this structure whose CSC values are ``data``.

        Raises:
            RuntimeError: a pivot is exactly zero (as SuperLU's "Factor is exactly singular").
        """
        n = self.perm.size
        band = np.zeros((self.rows, n), order="F")
        band.T.reshape(-1)[self.at] = data[:self.at.size]   # (band.T is C-ordered: a flat view)
        lu, pivots, info = lapack.dgbtrf(band, self.width, self.width, overwrite_ab=1)
        if info > 0:
            raise RuntimeError("Factor is exactly singular")
        if info < 0:   # pragma: no cover - an argument LAPACK refuses: a bug here
            raise ValueError(f"dgbtrf: illegal argument {-info}")
        return BandedLU(lu, pivots, self.width, self.perm, self.rank)


class BandedLU:
    """Solves K x = b with the banded LU of K' = P K Pᵀ."""

    def __init__(self, lu: np.ndarray, pivots: np.ndarray, width: int, perm: np.ndarray,
                 rank: np.ndarray):
        self.lu, self.pivots, self.width, self.perm, self.rank = lu, pivots, width, perm, rank

    def solve(self, rhs: np.ndarray) -> np.ndarray:
        """x with K x = rhs (rhs a vector, or a matrix of right-hand sides in columns)."""
        b = np.asarray(rhs, dtype=float)[self.perm]
        x, info = lapack.dgbtrs(self.lu, self.width, self.width, b, self.pivots, overwrite_b=1)
        if info < 0:   # pragma: no cover - an argument LAPACK refuses: a bug here
            raise ValueError(f"dgbtrs: illegal argument {-info}")
        return x[self.rank]


class CholeskyBandPlan:
    """The positive-definiteness test of symmetric matrices of one sparsity structure by LAPACK's
    banded Cholesky (``dpbtrf``) in RCM order: where each stored entry of the lower triangle of
    M' = P M Pᵀ lands in the band storage (the upper triangle's entries are its mirror)."""

    def __init__(self, m: sps.csr_array, width: int, keep: np.ndarray, at: np.ndarray):
        self.width, self.keep, self.at, self.n = width, keep, at, m.shape[0]
        self.key = structure(m)

    @classmethod
    def of(cls, m: sps.csr_array, band_max: int = CHOLESKY_BAND_MAX) -> "CholeskyBandPlan | None":
        """The plan for ``m``'s structure; None when its RCM band is wider than ``band_max`` or an
        entry of its lower triangle is stored twice (scipy would sum the two)."""
        if m.shape[0] == 0:
            return None
        _, _, i, j, width = _rcm(m, band_max)   # CSR: the pointer is the row, the index the column
        if width > band_max:
            return None
        keep = np.flatnonzero(i >= j)
        at = (i - j)[keep] + j[keep] * (width + 1)   # row i - j, column j of the lower band
        if np.bincount(at).max(initial=0) > 1:
            return None
        return cls(m, width, keep, at)

    def fits(self, m: sps.csr_array) -> bool:
        """Whether ``m`` has this plan's structure."""
        return same_structure(m, self.key)

    def positive_definite(self, m: sps.csr_array) -> bool:
        """Whether ``m`` (of this structure) is positive definite: its Cholesky factorization runs
        to the end with finite pivots (LAPACK may carry a NaN through instead of stopping)."""
        band = np.zeros((self.width + 1, self.n), order="F")
        band.T.reshape(-1)[self.at] = m.data[self.keep]
        factor, info = lapack.dpbtrf(band, lower=1, overwrite_ab=1)
        return info == 0 and bool(np.isfinite(factor[0]).all())
