"""The window problem on torch: values and local derivatives by lowered term programs.

Everything fixed during an `iterate` is built once, as tensors on the chosen device: the slot
matrix ``Pf``, the slot values of the fixed control points, every term group's instance times,
weights and parameters, and the sparsity patterns of the Jacobians and of the Hessian of the
Lagrangian. An evaluation is one of a batch of starts of one structure (a solve of its own is a
batch of one: :func:`evaluations_of`), the same code on every device:

- slot values are one sparse product ``V = V_fixed + S Pfᵀ`` (sparse.py: scipy's on the CPU);
- every term's values, local gradients and (where they will be used) local second derivatives
  come from one call of its program on its inputs gathered from V (calls.py);
- Jacobians ``G @ Pf`` and the Hessian ``Pfᵀ D Pf + Jₒᵀ W Jₒ`` are sums of fixed contributions
  per nonzero (Pattern): a sparse product on the CPU, padded gathers on a device (deterministic,
  no atomics).
"""

from __future__ import annotations

import copy
from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sps
import torch

from stw_tui.sos.compressed import csr
from stw_tui.sos.window import EQ, GE, OBJ, MeritValues, evaluate_condition_tree
from stw_tui.sym.errors import StwError

from .calls import CallPlan
from .lower import LoweredTerm, lower
from .sparse import SparseMatrix

def _index_dtype(*largest: int):
    """int32 where every number up to ``largest`` fits, as scipy keeps sparse indices; else int64."""
    return np.int32 if max(largest) < 2**31 - 1 else np.int64


def _row_entries(indptr: np.ndarray, rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """For each requested CSR row, its stored entries: (owner index into ``rows``, position);
    int32 where the numbers fit (a Hessian's millions of contributions: half the memory to fill)."""
    counts = indptr[rows + 1] - indptr[rows]
    total = int(counts.sum())
    index = _index_dtype(total, rows.size, int(indptr[-1]))
    owner = np.repeat(np.arange(rows.size, dtype=index), counts)
    first = np.repeat((indptr[rows] - (np.cumsum(counts) - counts)).astype(index), counts)
    return owner, first + np.arange(total, dtype=index)


def _operator(coef, src, start, counts, n_src) -> sps.csr_array:
    """The CSR matrix (nonzero, source) of the contributions ``coef`` of sources ``src``, listed
    nonzero after nonzero (``counts`` of each from ``start``), duplicate pairs summed and each
    row's sources ascending: the listing's own arrays where it is so already (a Jacobian's or
    Hessian's; scipy's construction from pairs took basketball's Hessian 0.44 s)."""
    # int32 indices where they fit, as scipy's own construction makes them: an int64 indptr
    # beside int32 indices had scipy convert the indices (basketball: 0.1 s, 19 MB more)
    index = _index_dtype(np.size(src), n_src)
    src = np.asarray(src).astype(index, copy=False)
    data = np.asarray(coef, float)
    rising = np.greater(src[1:], src[:-1])
    rising[start[1:] - 1] = True           # each row's first source needs no predecessor
    if rising.all():
        indptr = np.append(start, src.size).astype(index)
        op = sps.csr_array((data, src, indptr), shape=(counts.size, n_src), copy=False)
        op.has_canonical_format = True     # ascending and unique in each row, as checked above
        return op
    owner = np.repeat(np.arange(counts.size), counts)
    op = sps.csr_array((data, (owner, src)), shape=(counts.size, n_src))   # sums duplicates
    op.sort_indices()
    return op


PAIRS_CHUNK = 1 << 16   # slot pairs whose products are worked out at a time (_pair_products)
COUNTING_SORT_MAX = 2**22   # key spaces (n_free² of a Hessian) Pattern.of places entries in directly


def _slot_products(Pf: sps.csr_array, row_of: np.ndarray, shape: tuple[int, int]) -> sps.csr_array:
    """The contributions of slots p to a Jacobian J[r, j] = Σ_p G[r, p] Pf[p, j] (``shape``) as
    a CSR matrix C (slot p, key r * n_cols + j) of the entries Pf[p, j], r = row_of[p] the row
    that slot p serves (-1: none)."""
    owner = np.repeat(np.arange(row_of.size), np.diff(Pf.indptr))
    keep = row_of[owner] >= 0
    indptr = np.append(0, np.cumsum(np.diff(Pf.indptr) * (row_of >= 0)))
    return sps.csr_array((Pf.data[keep], row_of[owner[keep]] * shape[1] + Pf.indices[keep], indptr),
                         shape=(row_of.size, max(1, shape[0] * shape[1])))


def _pair_products(indptr, indices, data, p, q, n_cols) -> sps.csr_array:
    """The contributions of slot pairs e = (p_e, q_e) to a Hessian Σ_e D_e Pf[p_e, i] Pf[q_e, j]
    as a CSR matrix C (pair e, key i * n_cols + j) of the products Pf[p_e, i] Pf[q_e, j]: row e
    lists them left entry by left entry, each with every right entry.

    Worked out a chunk of pairs at a time into C's own arrays: the millions of contributions
    are not gathered into temporaries of their size (basketball's Hessian: 4.7 million, and
    freshly allocated memory costs 2-3 ms per MB to touch on these machines).
    """
    left_n = indptr[p + 1] - indptr[p]
    sizes = left_n * (indptr[q + 1] - indptr[q])
    c_ptr = np.zeros(p.size + 1, np.int64)
    np.cumsum(sizes, out=c_ptr[1:])
    total = int(c_ptr[-1])
    index = _index_dtype(total, p.size, int(indptr[-1]))
    keys = np.empty(total, _index_dtype(n_cols * n_cols))
    values = np.empty(total)
    for e0 in range(0, p.size, PAIRS_CHUNK):
        e1 = min(e0 + PAIRS_CHUNK, p.size)
        s0, s1 = int(c_ptr[e0]), int(c_ptr[e1])
        left_owner, left_pos = _row_entries(indptr, p[e0:e1])
        right_owner, right_pos = _row_entries(indptr, q[e0:e1][left_owner])
        left = left_pos[right_owner]
        np.multiply(indices[left], n_cols, out=keys[s0:s1])
        keys[s0:s1] += indices[right_pos]
        np.multiply(data[left], data[right_pos], out=values[s0:s1])
    return sps.csr_array((values, keys, c_ptr.astype(index)), shape=(p.size, n_cols * n_cols), copy=False)


def _padded(start, counts, coef, src, n_src) -> tuple[np.ndarray, np.ndarray]:
    """(coef_pad, src_pad): row u lists the contributions of nonzero u (``counts`` of them from
    ``start`` in ``coef`` and ``src``), padded with coefficient 0 at source ``n_src``."""
    owner = np.repeat(np.arange(counts.size), counts)
    m = int(counts.max(initial=1))
    coef_pad = np.zeros((counts.size, m))
    src_pad = np.full((counts.size, m), n_src, np.int64)
    slot = np.arange(np.size(coef)) - np.repeat(start, counts)
    coef_pad[owner, slot] = coef
    src_pad[owner, slot] = src
    return coef_pad, src_pad


TAIL_AFTER = 3   # Pattern.values_past's calls before it copies the columns it needs out


@dataclass
class Pattern:
    """A fixed CSR pattern whose values are sums of gathered products: on a device
    ``(coef_pad * source[src_pad]).sum(1)``, row u of the padded arrays listing nonzero u's
    contributions (padding: coefficient 0, past the source's end); on the CPU one sparse product
    ``operator @ source``, which skips the padding (an arm's Hessian: 65 ms padded, 1.5 ms)."""

    shape: tuple[int, int]
    crow: torch.Tensor
    col: torch.Tensor
    coef_pad: torch.Tensor | None
    src_pad: torch.Tensor | None
    n_src: int
    crow_np: np.ndarray                    # the host's copies, in the index dtype scipy keeps
    col_np: np.ndarray
    operator: SparseMatrix | None = None   # (nnz, n_src), on the CPU
    _tails: dict = field(default_factory=dict, repr=False)   # start -> operator's columns from it
    _asked: dict = field(default_factory=dict, repr=False)   # start -> values_past calls so far

    def __post_init__(self) -> None:
        # int32 where it fits, as the scipy algebra's own matrices have them: scipy() then hands
        # them over unchecked (compressed.csr), 13 µs less per matrix and evaluation, and the
        # algebra stays on its int32 fast paths (sps.csr_array keeps int64 indices as given)
        if _index_dtype(*self.shape, self.crow_np[-1]) is np.int32:
            self.crow_np, self.col_np = self.crow_np.astype(np.int32), self.col_np.astype(np.int32)

    @classmethod
    def of(cls, C: sps.csr_array, shape, device) -> "Pattern":
        """The pattern of a matrix (``shape``) whose entry at key i * n_cols + j sums its
        contributions C[source, key] times source values (:func:`_slot_products`,
        :func:`_pair_products`). Each key's contributions are listed sources ascending, as
        scipy's CSR-to-CSC conversion places them: over the keys that occur where the key
        space is large (np.unique's sort), over all of them, in one pass, where it is small."""
        keys = None
        if shape[0] * shape[1] > COUNTING_SORT_MAX:
            keys, inverse = np.unique(C.indices, return_inverse=True)
            C = sps.csr_array((C.data, inverse.reshape(-1), C.indptr), shape=(C.shape[0], max(1, keys.size)))
        by_key = C.tocsc()
        sizes = np.diff(by_key.indptr)
        nonzero = np.flatnonzero(sizes)
        return cls._placed(nonzero if keys is None else keys[nonzero], by_key.indptr[nonzero].astype(np.int64),
                           sizes[nonzero].astype(np.int64), by_key.data, by_key.indices, C.shape[0], shape, device)

    @classmethod
    def _placed(cls, uniq, start, counts, coef, src, n_src, shape, device) -> "Pattern":
        """The pattern of the nonzeros ``uniq`` (keys row * n_cols + col, ascending), whose
        contributions ``coef`` of sources ``src`` are listed nonzero after nonzero (``counts``
        of each from ``start``)."""
        r, c = uniq // shape[1], uniq % shape[1]
        crow = np.concatenate([[0], np.cumsum(np.bincount(r, minlength=shape[0]))]).astype(np.int64)
        as_t = lambda a: torch.as_tensor(a, device=device)  # noqa: E731
        if device.type == "cpu":
            return cls(shape, as_t(crow), as_t(c), None, None, n_src, crow, c,
                       SparseMatrix(_operator(coef, src, start, counts, n_src), device, copy=False))
        coef_pad, src_pad = _padded(start, counts, coef, src, n_src)
        return cls(shape, as_t(crow), as_t(c), as_t(coef_pad), as_t(src_pad), n_src, crow, c)

    def entries(self) -> int:
        """The contributions it stores (its operator's on the CPU, the padded arrays' on a device)."""
        return int(self.operator.host.nnz) if self.operator is not None else int(self.coef_pad.numel())

    def values(self, source: torch.Tensor) -> torch.Tensor:
        """The matrix's stored values (CSR order) for a vector of source values, or (B, nnz) for
        each row of a (B, n_src) matrix of them."""
        if self.operator is not None:
            return self.operator @ source if source.dim() == 1 else self.operator.rows(source)
        ext = torch.cat([source, source.new_zeros(*source.shape[:-1], 1)], -1)
        return (self.coef_pad * ext[..., self.src_pad]).sum(-1)

    def values_past(self, tail: torch.Tensor, start: int) -> torch.Tensor:
        """:meth:`values` of a source that is zero before entry ``start`` and ``tail`` from there
        (a Gauss-Newton Hessian): on the CPU from the TAIL_AFTER-th call on without the operator's
        columns before ``start`` (x 0: the same sums; a third of basketball's 4.7 million
        entries), copied out then (30 ms for basketball, some 50 of its products' savings)."""
        self._asked[start] = asked = self._asked.get(start, 0) + 1
        if self.operator is None or (start not in self._tails and asked < TAIL_AFTER):
            return self.values(torch.cat([tail.new_zeros(start), tail]))
        if start not in self._tails:
            self._tails[start] = SparseMatrix(self.operator.host[:, start:], torch.device("cpu"), copy=False)
        return self._tails[start] @ tail

    def scipy(self, values: torch.Tensor) -> sps.csr_array:
        """The matrix with these values as a scipy CSR array (for the scipy linear algebra)."""
        return csr(values.detach().cpu().numpy(), self.col_np, self.crow_np, self.shape)

    def dense(self, values: torch.Tensor) -> torch.Tensor:
        """The matrix with these values as a dense tensor on the values' device."""
        values = torch.as_tensor(values)
        out = values.new_zeros(self.shape)
        rows = torch.repeat_interleave(torch.arange(self.shape[0], device=values.device),
                                       self.crow[1:] - self.crow[:-1])
        out[rows, self.col] = values
        return out


@dataclass(eq=False)
class _Group:
    """A term group lowered to torch."""

    label: str
    kind: str
    term: LoweredTerm
    n: int
    slot: int          # slot offset
    row: int           # row offset among rows of its kind
    inst: int          # offset among all groups' instances
    pairs: tuple
    times: torch.Tensor
    weights: torch.Tensor
    params: torch.Tensor   # (P,)
    condition: object = None
    leaves: list = field(default_factory=list)   # (relation node, LoweredTerm, slot offset, params)


@dataclass(eq=False)
class TorchEvaluation:
    """What one SQP iteration needs at ``s``: the numpy arrays the SQP reads, and the tensors its
    Jacobians and Hessians are made of."""

    tp: "TorchProblem"
    s: np.ndarray
    objective: float
    gradient: np.ndarray
    c_eq: np.ndarray
    c_ge: np.ndarray
    active_eq: np.ndarray
    active_ge: np.ndarray
    t_J: dict                      # kind -> values on tp.jac[kind]
    t_local: dict                  # f_all, g_slot, h_flat (None until needed), v for the Hessian
    hessian_used: bool = False     # whether the Lagrangian's Hessian was asked for
    _scipy_J: dict = field(default_factory=dict)

    @property
    def J_eq(self) -> sps.csr_array:
        """Jacobian of the equality rows (scipy CSR, built once per evaluation)."""
        return self._jacobian(EQ)

    @property
    def J_ge(self) -> sps.csr_array:
        """Jacobian of the inequality rows (scipy CSR, built once per evaluation)."""
        return self._jacobian(GE)

    def _jacobian(self, kind: str) -> sps.csr_array:
        if kind not in self._scipy_J:
            self._scipy_J[kind] = self.tp.jacobian_matrix(kind, self.t_J[kind])
        return self._scipy_J[kind]

    def dense_jacobian(self, kind: str) -> torch.Tensor:
        """Jacobian of the ``kind`` rows as a dense tensor on the device (linear=torch)."""
        return self.tp.jac[kind].dense(self.t_J[kind])

    def max_violation(self) -> float:
        """The largest violation of any row at this point, as the window problem defines it."""
        return self.tp.problem.max_violation(self)

    def lagrangian_hessian(self, lam_eq: np.ndarray, lam_ge: np.ndarray):
        """∇²R + Σλ∇²C: scipy CSR (linear=scipy) or a dense tensor on the device (linear=torch)."""
        self.hessian_used = True
        return self._matrix(self.tp.hessian_values(self, lam_eq, lam_ge))

    def gauss_newton(self):
        """2 Jₒᵀ W Jₒ of the objective residuals only (positive semidefinite), on the same pattern;
        computed once per evaluation (callers must not modify it)."""
        if "gn_matrix" not in self.t_local:
            self.t_local["gn_matrix"] = self._matrix(self.tp.hessian_values(self, None, None))
        return self.t_local["gn_matrix"]

    def _matrix(self, values: torch.Tensor):
        return self.tp.hess.scipy(values) if self.tp.host_linear else self.tp.hess.dense(values)


class TorchProblem:
    """A WindowProblem lowered to torch; evaluated many times during one run of iterations."""

    def __init__(self, problem, device: torch.device, host_linear: bool, autograd: bool = False):
        self.problem = problem
        self.dof_of_free = problem.dof_of_free
        self.damping = problem.damping
        self.device = device
        self.host_linear = host_linear
        self.n_free = problem.n_free
        self.row_counts = dict(problem.row_counts)
        self._dev = dev = dict(dtype=torch.float64, device=device)

        Pf = sps.csr_array(problem.Pf, copy=True)
        Pf.eliminate_zeros()
        Pf.sort_indices()
        self.Pf = SparseMatrix(Pf, device)
        self.PfT = SparseMatrix(sps.csr_array(Pf.T), device)
        fixed = problem.coef0.copy()
        fixed[problem.free] = 0.0
        # slot values of the fixed coefficients
        self.v_fixed = SparseMatrix(problem.P.tocsr(), device) @ torch.as_tensor(fixed, **dev)
        self.n_slots = problem.P.shape[0]

        self.groups: list[_Group] = []
        inst = 0
        for g in problem.groups:
            params = torch.tensor([float(p) for p in g.params], **dev)
            lowered = _Group(g.label, g.kind, lower(g.term), g.n, g.slot_offset, g.row_offset, inst,
                             tuple(g.term.hessian_pairs), torch.as_tensor(g.times, **dev),
                             torch.as_tensor(g.weights, **dev), params, g.condition)
            if g.condition is not None:
                lowered.leaves = [(node, lower(term), offset,
                                   torch.tensor([float(c) for c in problem.term_parameters(term)], **dev))
                                  for node, term, offset in g.condition.leaves]
            self.groups.append(lowered)
            inst += g.n
        self.n_inst = inst
        # Kinds whose rows are all affine (or absent): their Jacobian is the same at every s, so
        # an evaluation on the CPU hands on the solve's first one, values and matrix, as the core
        # window problem does (and the dense algebra makes it dense once a solve, not every step)
        self.constant_kinds = tuple(kind for kind in (EQ, GE)
                                    if all(g.term.affine for g in problem.groups if g.kind == kind))
        self._kept_J: dict = {}   # kind -> (values, scipy matrix) of this solve
        self.plan = CallPlan.build(self.groups, self.n_slots, device, autograd)
        self._last: TorchEvaluation | None = None   # the latest evaluation (its Hessian used?)
        self._expect: bool | None = None   # whether the next evaluation's Hessian will be used
        self._build_patterns(Pf)

    def with_problem(self, problem) -> "TorchProblem":
        """This lowering for ``problem``, a window problem of the same structure (lowerings'
        ``problem_key``) whose control points may differ: only the fixed ones' slot values change."""
        other = copy.copy(self)
        other.problem = problem
        other._last, other._expect = None, None
        other._kept_J = {}
        fixed = problem.coef0.copy()
        fixed[problem.free] = 0.0
        other.v_fixed = torch.as_tensor(sps.csr_array(problem.P) @ fixed, **self._dev)
        return other

    def entries(self) -> int:
        """The stored entries of its Jacobian and Hessian patterns: most of what it holds."""
        return sum(pattern.entries() for pattern in (self.hess, *self.jac.values()))

    # --- fixed patterns ----------------------------------------------------------------------
    def _build_patterns(self, Pf: sps.csr_array) -> None:
        dev = self._dev
        # Per-slot weight (constraint rows are weight * f), owning instance (condition slots own
        # the padding instance n_inst) and Jacobian row; per-instance weight and multiplier.
        w_slot, w_inst = np.zeros(self.n_slots), np.zeros(self.n_inst)
        owner = np.full(self.n_slots, self.n_inst, np.int64)
        row_of = {kind: np.full(self.n_slots, -1, np.int64) for kind in (EQ, GE)}
        is_obj = np.zeros(self.n_inst, bool)
        lam_index = np.full(self.n_inst, self.row_counts[EQ] + self.row_counts[GE], np.int64)
        self.host_rows = {kind: np.zeros(self.row_counts[kind], np.int64) for kind in (EQ, GE, OBJ)}
        d_p, d_q = [], []                 # second-derivative entries of D: slot pairs
        gn_p, gn_q, gn_i = [], [], []     # Gauss-Newton entries of objective groups
        h_offset = 0
        h_src, h_scale = [], []
        for g in self.groups:
            inst, block = np.arange(g.n), slice(g.slot, g.slot + g.term.k * g.n)   # slot a·n + i
            w_inst[g.inst:g.inst + g.n] = weights = g.weights.cpu().numpy()
            owner[block] = g.inst + np.tile(inst, g.term.k)
            self.host_rows[g.kind][g.row:g.row + g.n] = g.inst + inst
            if g.kind == OBJ:
                is_obj[g.inst:g.inst + g.n] = True
            else:
                w_slot[block] = np.tile(weights, g.term.k)
                lam_index[g.inst:g.inst + g.n] = g.row + inst + (self.row_counts[EQ] if g.kind == GE else 0)
                row_of[g.kind][block] = np.tile(g.row + inst, g.term.k)
            for p, (a, b) in enumerate(g.pairs):
                for x, y in ((a, b), (b, a)) if a != b else ((a, b),):
                    d_p.append(g.slot + x * g.n + inst)
                    d_q.append(g.slot + y * g.n + inst)
                    h_src.append(h_offset + p * g.n + inst)
                    h_scale.append(g.inst + inst)
            h_offset += len(g.pairs) * g.n
            if g.kind == OBJ:
                for a in range(g.term.k):
                    for b in range(g.term.k):
                        gn_p.append(g.slot + a * g.n + inst)
                        gn_q.append(g.slot + b * g.n + inst)
                        gn_i.append(g.inst + inst)
        cat = lambda parts: np.concatenate(parts) if parts else np.zeros(0, np.int64)  # noqa: E731
        index = lambda parts: torch.as_tensor(cat(parts), device=self.device)  # noqa: E731
        self.w_slot, self.w_inst = torch.as_tensor(w_slot, **dev), torch.as_tensor(w_inst, **dev)
        self.is_obj = torch.as_tensor(is_obj, device=self.device)
        self.lam_index = torch.as_tensor(lam_index, device=self.device)
        self.slot_owner = torch.as_tensor(owner, device=self.device)
        self.host_weights = {kind: w_inst[rows] for kind, rows in self.host_rows.items()}
        self.conditional = any(g.condition is not None for g in self.groups)
        # Jacobians: J[r, j] = Σ_p G[r, p] Pf[p, j] over the group's slots p of row r.
        self.jac = {kind: Pattern.of(_slot_products(Pf, row_of[kind], (self.row_counts[kind], self.n_free)),
                                     (self.row_counts[kind], self.n_free), self.device) for kind in (EQ, GE)}
        # Hessian: H[i, j] = Σ_e D_e Pf[p_e, i] Pf[q_e, j] over entries e = (p_e, q_e) of the local
        # second derivatives, the Gauss-Newton products of objective groups, and nothing else.
        self.h_src, self.h_scale = index(h_src), index(h_scale)
        self.gn_p, self.gn_q = index(gn_p), index(gn_q)
        # each Gauss-Newton product 2 w g_p g_q is (2 w) g_p g_q: its first factor made once
        self.gn_w2 = 2.0 * self.w_inst[index(gn_i)]
        p, q = np.concatenate([cat(d_p), cat(gn_p)]), np.concatenate([cat(d_q), cat(gn_q)])
        self.hess = Pattern.of(_pair_products(Pf.indptr.astype(np.int64), Pf.indices, Pf.data, p, q, self.n_free),
                               (self.n_free, self.n_free), self.device)

    # --- evaluation --------------------------------------------------------------------------
    def _conditions(self, V: torch.Tensor) -> dict[str, torch.Tensor]:
        """Each start's ``when`` masks at slot values V (B, slots): (B, rows) per kind, every
        group's condition tree over its leaves' values, the starts' instances side by side."""
        B = V.shape[0]
        masks = {kind: torch.ones(B, self.row_counts[kind], dtype=torch.bool, device=self.device)
                 for kind in (EQ, GE)}
        for g in self.groups:
            if g.condition is None:
                continue
            leaf = {node: term(_tile(V, offset, term.k, g.n), _repeat(g.times, B), params)
                    for node, term, offset, params in g.leaves}
            filled = lambda flag, n=g.n: torch.full((B * n,), flag, dtype=torch.bool, device=self.device)  # noqa: E731
            masks[g.kind][:, g.row:g.row + g.n] = evaluate_condition_tree(g.condition.tree, leaf, filled).view(B, g.n)
        return masks

    def _rows(self, f: np.ndarray) -> tuple[float, dict]:
        """The objective and the weighted constraint rows from every instance's value, on the
        host: what the SQP reads is numpy anyway, and a numpy op on a few hundred numbers costs
        a fifth of a torch op."""
        r = f[self.host_rows[OBJ]]
        objective = float(np.dot(self.host_weights[OBJ], r * r))
        return objective, {kind: self.host_weights[kind] * f[self.host_rows[kind]] for kind in (EQ, GE)}

    def merit_values(self, s: np.ndarray) -> MeritValues:
        """Objective and weighted constraint values only (no derivatives), for the line search."""
        return merit_values_of([self], [s])[0]

    def expect_hessian(self, used: bool) -> None:
        """Say whether the next evaluation's Lagrangian Hessian will be used (the SQP knows, from
        the violation at the point it is about to evaluate): its second derivatives are then
        computed with it, or left out. Without a word, the last evaluation's use is the guess."""
        self._expect = used

    def _second(self) -> bool:
        """Whether the evaluation about to run computes second derivatives (see expect_hessian)."""
        expect, self._expect = self._expect, None
        if expect is not None:
            return expect
        return self._last is None or self._last.hessian_used

    def evaluate(self, s: np.ndarray) -> TorchEvaluation:
        """Values, gradients and local second derivatives at ``s``; the second only where they
        will be used (Gauss-Newton steps need none), else hessian_values computes them if asked."""
        return evaluations_of([self], [s], second=self._second())[0]

    def _jacobian_values(self, kind: str, values: torch.Tensor) -> torch.Tensor:
        """The ``kind`` Jacobian's values: a constant kind's are the solve's first, kept."""
        kept = self._kept_J.get(kind)
        if kept is not None:
            return kept[0]
        if kind in self.constant_kinds:
            self._kept_J[kind] = (values, self.jac[kind].scipy(values))
        return values

    def jacobian_matrix(self, kind: str, values) -> sps.csr_array:
        """The ``kind`` Jacobian with these values as a scipy CSR array: for a constant kind's
        kept values, one matrix for the whole solve."""
        kept = self._kept_J.get(kind)
        return kept[1] if kept is not None and kept[0] is values else self.jac[kind].scipy(values)

    def hessian_values(self, ev: TorchEvaluation, lam_eq: np.ndarray, lam_ge: np.ndarray) -> torch.Tensor:
        """Values of ∇²R + Σλ∇²C on the fixed pattern ``self.hess``; without multipliers (None),
        of the Gauss-Newton part 2 Jₒᵀ W Jₒ alone."""
        f, g, h = ev.t_local["f"], ev.t_local["g"], ev.t_local["h"]
        if h is None and lam_eq is not None:
            with torch.no_grad():
                h = ev.t_local["h"] = self.plan.local(ev.t_local["v"][None])[2][0]
        if "gn" not in ev.t_local:     # the Gauss-Newton products: the same for every multiplier
            ev.t_local["gn"] = self.gn_w2 * g[self.gn_p] * g[self.gn_q]
        gn = ev.t_local["gn"]
        if lam_eq is None:
            return self.hess.values_past(gn, self.h_src.shape[0])
        lam = torch.cat([torch.as_tensor(lam_eq, **self._dev), torch.as_tensor(lam_ge, **self._dev),
                         torch.zeros(1, **self._dev)])
        scale = self.w_inst * torch.where(self.is_obj, 2.0 * f, lam[self.lam_index])
        second = h[self.h_src] * scale[self.h_scale]
        return self.hess.values(torch.cat([second, gn]))


def _tile(V: torch.Tensor, offset: int, k: int, n: int) -> torch.Tensor:
    """A block of k rows of n slots from ``offset`` of every start, side by side: (k, B·n)."""
    B = V.shape[0]
    return V[:, offset:offset + k * n].reshape(B, k, n).transpose(0, 1).reshape(k, B * n)


def _repeat(times: torch.Tensor, B: int) -> torch.Tensor:
    return times if B == 1 else times.repeat(B)


def _slot_values(members: list[TorchProblem], points: list[np.ndarray]) -> torch.Tensor:
    """(B, slots): each start's fixed slot values plus its free control points' share."""
    tp = members[0]
    S = torch.as_tensor(np.stack([np.asarray(p, float) for p in points]), **tp._dev)
    fixed = tp.v_fixed[None] if len(members) == 1 else torch.stack([m.v_fixed for m in members])
    return fixed + tp.Pf.rows(S)


def merit_values_of(members: list[TorchProblem], points: list[np.ndarray]) -> list[MeritValues]:
    """:meth:`TorchProblem.merit_values` of every (problem, point), the problems of one structure
    (copies of one lowering, ``with_problem``): one call of each term's program for all."""
    tp = members[0]
    with torch.no_grad():
        V = _slot_values(members, points)
        f = tp.plan.values(V).cpu().numpy()
        masks = {kind: m.cpu().numpy() for kind, m in tp._conditions(V).items()} if tp.conditional else None
    out = []
    for b in range(len(members)):
        objective, c = tp._rows(f[b])
        live = tp.problem.always_live if masks is None else {kind: masks[kind][b] for kind in (EQ, GE)}
        out.append(MeritValues(objective, c[EQ], c[GE], live[EQ], live[GE]))
    return out


def evaluations_of(members: list[TorchProblem], points: list[np.ndarray], second: bool = True
                   ) -> list[TorchEvaluation]:
    """:meth:`TorchProblem.evaluate` of every (problem, point), the problems of one structure:
    one call of each term's program for all, the starts' instances side by side (each still
    depends on its own slots only); ``second``: with second derivatives."""
    tp = members[0]
    B = len(members)
    with torch.no_grad():
        V = _slot_values(members, points)
        f_all, g_slot, h_flat = tp.plan.local(V, second=second)
        # ∇R = Pfᵀ u with u[slot] = 2 w f ∂f/∂slot on objective slots
        scale = torch.cat([torch.where(tp.is_obj, 2.0 * (tp.w_inst * f_all), 0.0), V.new_zeros(B, 1)], 1)
        gradient = tp.PfT.rows(g_slot * scale[:, tp.slot_owner]).cpu().numpy()
        gw = g_slot * tp.w_slot
        J = {kind: tp.jac[kind].values(gw) for kind in (EQ, GE)
             if any(kind not in m._kept_J for m in members)}
        masks = {kind: m.cpu().numpy() for kind, m in tp._conditions(V).items()} if tp.conditional else None
    f_host = f_all.cpu().numpy()
    out = []
    for b, member in enumerate(members):
        objective, c = tp._rows(f_host[b])
        live = tp.problem.always_live if masks is None else {kind: masks[kind][b] for kind in (EQ, GE)}
        ev = TorchEvaluation(
            tp=member, s=np.asarray(points[b], float).copy(), objective=objective, gradient=gradient[b],
            c_eq=c[EQ], c_ge=c[GE], active_eq=live[EQ], active_ge=live[GE],
            t_J={kind: member._jacobian_values(kind, J[kind][b] if kind in J else None) for kind in (EQ, GE)},
            t_local={"f": f_all[b], "g": g_slot[b], "h": None if h_flat is None else h_flat[b], "v": V[b]})
        member._last = ev
        out.append(ev)
    return out


def check_finite(ev: TorchEvaluation, problem) -> None:
    """Raise with the name of the first term group whose values are not finite."""
    if all(np.isfinite(a).all() for a in (ev.objective, ev.gradient, ev.c_eq, ev.c_ge)) \
            and all(bool(torch.isfinite(values).all()) for values in ev.t_J.values()):
        return
    f = ev.t_local["f"].cpu().numpy()
    for g in ev.tp.groups:
        if not np.all(np.isfinite(f[g.inst:g.inst + g.n])):
            raise StwError(f"'{g.label}' is not finite at the starting point (e.g. sqrt or log of a "
                           "negative value); the scene is unchanged")
    raise StwError("the starting point gives non-finite derivatives; the scene is unchanged")
