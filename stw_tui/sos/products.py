"""Sparse products on fixed sparsity structures, computed as a sparse matrix-vector product.

The window problem's Jacobians (``G @ Pf``) and Hessian (``Pfᵀ D Pf``) multiply matrices whose
sparsity structure never changes between evaluations; only the values of ``G`` and ``D`` do.
``scipy.sparse``'s ``A @ B`` works the structure out anew each time (a symbolic pass, a numeric
pass and a handful of Python-level matrix constructions), which is most of an evaluation's cost on
small problems. A :class:`ProductPlan` works it out once: each entry of ``C = A @ B`` is a sum of
products ``A[i, j] B[j, k]``, and with one factor fixed that sum is one row of a constant sparse
matrix ``M``, so ``C.data = M @ A.data`` (or ``M @ B.data``).

The plan reproduces scipy's ``csr_matmat`` exactly, not just up to rounding: each entry's terms
are added in the order that routine adds them, from zero, and each row's entries are stored in its
order (by last first touch); entries that come out exactly zero are dropped, as it drops them. So
the products are bitwise those of ``A @ B``, and nothing downstream (a factorization, a
matrix-vector product) can tell the difference.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sps

from stw_tui.sos.compressed import csr
from stw_tui.sos.sparse_matvec import matvec


TOUCH_ROUNDS = 8             # passes ProductPlan.touch_order may take before giving up
GRAM_PLAN_TERMS = 200_000    # above this many products scipy's own loop is faster than a plan


class ProductPlan:
    """``C = A @ B`` for CSR structures of A (m x K) and B (K x N), one of them with fixed values.

    Args:
        A, B: CSR matrices giving the structures (stored entries, explicit zeros included, in
            their storage order); the values of the fixed one too.
        fixed: which factor's values are built into the plan, "A" or "B".
        source: optional permutation: the varying factor's stored entry ``p`` is entry
            ``source[p]`` of the vector later passed to :meth:`data` (so that a factor assembled
            from another ordering, such as COO triplets, need not be built at all).
    """

    def __init__(self, A: sps.csr_array, B: sps.csr_array, fixed: str, source: np.ndarray | None = None):
        m, N = A.shape[0], B.shape[1]
        a_col = A.indices[:A.nnz]                      # (arrays may run past the stored entries)
        a_len = np.diff(B.indptr)[a_col]               # terms each stored entry of A starts
        a_term = np.repeat(np.arange(A.nnz), a_len)    # the terms in csr_matmat's order
        b_term = np.repeat(B.indptr[a_col] - np.cumsum(a_len) + a_len, a_len) + np.arange(a_term.size)
        row = np.repeat(np.repeat(np.arange(m), np.diff(A.indptr)), a_len)
        col = B.indices[b_term]
        # Group the terms by output entry (row, col), each group in the order they are added.
        terms, start = _grouped(row.astype(np.int64) * max(N, 1) + col)
        first, out_row, out_col = terms[start], row[terms[start]], col[terms[start]]
        # csr_matmat stores a row's entries last-first-touched first: put the groups in that order.
        place = np.lexsort((-first, out_row))
        counts = np.diff(np.append(start, terms.size))[place]
        terms = terms[_ranges(start[place], counts)]
        varying, constant = (b_term, A.data[a_term]) if fixed == "A" else (a_term, B.data[b_term])
        # A term whose fixed factor is a stored zero adds ±0: leave it out, and the entries it
        # alone touches, which are always zero (csr_matmat drops them). It still counted above,
        # where it may have touched an entry first.
        live = constant[terms] != 0
        live_count = np.bincount(np.repeat(np.arange(place.size), counts)[live], minlength=place.size)
        kept = live_count > 0
        self.shape = (m, N)
        self.indices = out_col[place][kept].astype(np.int32)
        self.indptr = np.zeros(m + 1, dtype=np.int32)
        np.cumsum(np.bincount(out_row[place][kept], minlength=m), out=self.indptr[1:])
        if fixed == "B":   # for matrix(absent=...): every term of each kept entry, in order
            keep_terms = np.repeat(kept, counts)
            self._touch_ptr = np.concatenate([[0], np.cumsum(counts[kept])])
            self._touch_t = terms[keep_terms]
            self._touch_a = a_term[self._touch_t]
            self._first = self._touch_t[self._touch_ptr[:-1]]
            self._row = out_row[place][kept]
        terms = terms[live]
        columns = varying[terms] if source is None else source[varying[terms]]
        size = (B.nnz if fixed == "A" else A.nnz) if source is None else source.size
        term_ptr = np.concatenate([[0], np.cumsum(live_count[kept])])
        # Rows keep their terms in summation order (unsorted columns): csr_matvec adds them so.
        self.M = sps.csr_array((constant[terms], columns, term_ptr), shape=(self.indices.size, size))

    def data(self, values: np.ndarray) -> np.ndarray:
        """The stored values of C (before dropping zeros) from the varying factor's values."""
        return matvec(self.M, values)

    def matrix(self, data: np.ndarray, order: np.ndarray | None = None) -> sps.csr_array:
        """C as scipy's product stores it: ``data`` in place (permuted by ``order``, from
        :meth:`touch_order`), its exact zeros dropped."""
        indices, indptr = self.indices, self.indptr
        if order is not None:
            data, indices = data[order], indices[order]
        return _without_zeros(data, indices, indptr, self.shape)

    def touch_order(self, absent: np.ndarray, rounds: int = TOUCH_ROUNDS):
        """Where C's entries go when A's entries ``absent`` are missing from A (a product that
        made A dropped them as exact zeros; plans with A varying): they touch no entry of C, so
        an entry they touched first moves within its row (its value does not change: they add
        ±0). None: no entry moves. False: working it out would take more than ``rounds`` passes
        (then multiply the compacted A instead)."""
        hit = np.flatnonzero(absent[self._touch_a[self._touch_ptr[:-1]]])
        if not hit.size:
            return None
        # Each such entry is first touched by its first term through a present entry of A:
        # look at the entries' second terms, then their third, ...
        first = self._first.copy()
        first[hit] = np.iinfo(np.int64).max     # never touched: its value is ±0, dropped
        at, end = self._touch_ptr[hit] + 1, self._touch_ptr[hit + 1]
        for _ in range(rounds):
            going = at < end
            hit, at, end = hit[going], at[going], end[going]
            if not hit.size:
                return np.lexsort((-first, self._row))
            touched = ~absent[self._touch_a[at]]
            first[hit[touched]] = self._touch_t[at[touched]]
            hit, at, end = hit[~touched], at[~touched] + 1, end[~touched]
        return False


def _grouped(key: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The stable order of ``key`` (non-negative), and where each run of equal keys starts in it.

    Key and position go into one integer, all distinct, so any sort is the stable one: numpy's
    (vectorized) sort of it, then the two halves taken apart, took half the time of a stable
    argsort and a gather of the keys in its order (basketball's Hessian and Jacobian plans, 0.22 s
    to 0.11 s). Keys too wide to share 63 bits with the positions take the argsort."""
    shift = int(key.size).bit_length()
    if key.size and int(key.max()).bit_length() + shift <= 62:
        combined = np.sort((key << shift) | np.arange(key.size))
        return combined & ((1 << shift) - 1), np.flatnonzero(np.diff(combined >> shift, prepend=-1))
    order = np.argsort(key, kind="stable")
    return order, np.flatnonzero(np.diff(key[order], prepend=-1))


def _without_zeros(data, indices, indptr, shape) -> sps.csr_array:
    """The CSR matrix with its exact zeros left out (as scipy's products leave them out)."""
    zero = data == 0
    if zero.any():
        keep = ~zero
        kept = np.concatenate([[0], np.cumsum(keep)])
        data, indices, indptr = data[keep], indices[keep], kept[indptr].astype(np.int32)
    return csr(data, indices, indptr, shape)


def _ranges(starts: np.ndarray, counts: np.ndarray) -> np.ndarray:
    """The concatenated ranges starts[g] .. starts[g] + counts[g]."""
    total = int(counts.sum())
    offsets = np.repeat(starts - np.cumsum(counts) + counts, counts)
    return offsets + np.arange(total)


class GramPlan:
    """``Jᵀ diag(c) J`` for a fixed structure of J (CSR), as ``sps.csr_array(J.T @
    (sps.diags_array(c) @ J))`` computes it: entry (i, j) adds the products (c_r J_rj) J_ri over
    the rows r in ascending order, from zero; rows stored sorted, exact zeros dropped. (Zero
    products, which scipy leaves out, add ±0 here.)"""

    def __init__(self, J: sps.csr_array):
        m, n = J.shape
        length = np.diff(J.indptr)
        pairs = length.astype(np.int64) ** 2
        row = np.repeat(np.arange(m), pairs)
        local = np.arange(int(pairs.sum())) - np.repeat(np.cumsum(pairs) - pairs, pairs)
        width = np.repeat(length, pairs)
        p = J.indptr[row] + local // np.maximum(width, 1)   # J_ri
        q = J.indptr[row] + local % np.maximum(width, 1)    # J_rj
        key = J.indices[p].astype(np.int64) * max(n, 1) + J.indices[q]
        terms, start = _grouped(key)   # by entry (i, j); rows r ascending within one
        entry = key[terms[start]]
        self.shape = (n, n)
        self.indices = (entry % max(n, 1)).astype(np.int32)
        self.indptr = np.zeros(n + 1, dtype=np.int32)
        np.cumsum(np.bincount(entry // max(n, 1), minlength=n), out=self.indptr[1:])
        self._p, self._q = p[terms], q[terms]
        self._row_of_entry = np.repeat(np.arange(m), length)
        term_ptr = np.append(start, terms.size)
        self._sum = sps.csr_array((np.ones(terms.size), np.arange(terms.size), term_ptr),
                                  shape=(start.size, terms.size))

    def values(self, data: np.ndarray, c: np.ndarray) -> np.ndarray:
        """The values of Jᵀ diag(c) J on the plan's whole structure (``indices``, ``indptr``),
        exact zeros included, from J's stored values ``data``."""
        scaled = c[self._row_of_entry] * data             # diag(c) @ J
        return matvec(self._sum, scaled[self._q] * data[self._p])

    def matrix(self, data: np.ndarray, c: np.ndarray) -> sps.csr_array:
        """Jᵀ diag(c) J from J's stored values ``data`` (on the planned structure)."""
        return _without_zeros(self.values(data, c), self.indices, self.indptr, self.shape)
