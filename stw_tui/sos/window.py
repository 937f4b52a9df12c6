"""The window problem: a spacetime window of a scene as a sparse nonlinear program.

Free variables are the control points of the window's DOF whose support meets the window's time
interval; every other control point is fixed (paper 4.2). Constraint instances (placed by
instances.py) and objective quadrature points are taken over the whole part of the animation that
the free control points can change, so the window problem minimizes exactly the scene's objective
with everything outside held fixed, and cannot break a constraint outside the window.

Evaluation is vectorized: DOF quantities at all instances are one sparse product ``P @ coef``
(``P`` stacks the B-spline basis rows of every term variable at every instance); Jacobians and
Hessians follow by the chain rule as sparse products ``G @ Pf`` and ``Pfᵀ D Pf`` where ``G`` and
``D`` hold the compiled local derivatives on fixed sparsity patterns. No Python loop runs over
instances or control points; one runs over term groups (constraints and objective terms).
"""

from __future__ import annotations

import copy
import hashlib
import operator
import threading
from collections import OrderedDict
from dataclasses import dataclass, field
from functools import cached_property, lru_cache

import numpy as np
import scipy.sparse as sps
import sympy as sp

from stw_tui.sos.affine_rows import AffineRows
from stw_tui.sos.attachments import pieces
from stw_tui.sos.compressed import add, csr, transpose
from stw_tui.sos.instances import bound_extra_times, bound_times, kept_times, relation_instances, structure_key
from stw_tui.sos.products import GRAM_PLAN_TERMS, GramPlan, ProductPlan
from stw_tui.sos.scene import Scene
from stw_tui.sos.sparse_matvec import matvec
from stw_tui.sos.spline import gauss_legendre_nodes, times_checker
from stw_tui.sym import limits
from stw_tui.sym.compiler import CompiledTerm, compile_term
from stw_tui.sym.errors import StwError
from stw_tui.sym.kinds import TermKind
from stw_tui.sym.symbols import dof_symbol

EQ, GE, OBJ = TermKind.EQ, TermKind.GE, TermKind.OBJ
HESSIAN_PLAN_AFTER = 4   # Hessians assembled by plain sparse products before a plan is made

# Bytes an `iterate` allocates per entry of its largest arrays (memory_estimate). A stored sparse
# entry is 12 bytes (a float64 and an int32 column); the Hessian of the Lagrangian is held about
# ten times at its peak: the Gauss-Newton product and its temporaries, its sum with the second
# derivatives, the KKT matrix, its column form and its factors. Measured with tracemalloc on the
# issue's sum of 99 DOF (125-136 bytes per Hessian entry, 10 to 99 DOF, 100 to 400 knot spans).
BYTES_PER_HESSIAN_ENTRY = 130
# A basis row's entry (P) or a Jacobian entry: the triplets they are made from (three 8-byte
# arrays), P's and G's CSR forms, the Jacobian's values and its product plan.
BYTES_PER_ROW_ENTRY = 60
SPAN_REACH = 7   # cubic B-spline coefficients whose supports meet one coefficient's (i-3 .. i+3)
# The comparisons of a `when` condition, as operators: numpy arrays and torch tensors both take them.
_RELATIONS = {
    sp.StrictGreaterThan: operator.gt, sp.GreaterThan: operator.ge,
    sp.StrictLessThan: operator.lt, sp.LessThan: operator.le,
    sp.Equality: operator.eq, sp.Unequality: operator.ne,
}


def relation_nodes(tree: sp.Basic) -> list[sp.Basic]:
    """The relations (leaves) of a ``when`` condition, in a fixed order."""
    return [node for node in sp.preorder_traversal(tree) if isinstance(node, tuple(_RELATIONS))]


def evaluate_condition_tree(node: sp.Basic, leaf_values: dict, filled):
    """Where a boolean tree of relations holds, given each leaf's ``lhs - rhs`` at n times.

    Array-generic (numpy here, torch in the torch backend): leaves are compared with 0 by Python's
    operators and combined with ``&``, ``|`` and ``~``; ``filled(flag)`` makes the n-long boolean
    array that a literal true or false stands for.
    """
    if node is sp.true or node is sp.false:
        return filled(node is sp.true)
    if isinstance(node, (sp.And, sp.Or)):
        parts = [evaluate_condition_tree(a, leaf_values, filled) for a in node.args]
        out = parts[0]
        for part in parts[1:]:
            out = out & part if isinstance(node, sp.And) else out | part
        return out
    if isinstance(node, sp.Not):
        return ~evaluate_condition_tree(node.args[0], leaf_values, filled)
    return _RELATIONS[type(node)](leaf_values[node], 0.0)


def numpy_filled(n: int):
    """``filled`` for :func:`evaluate_condition_tree` on numpy arrays of n times."""
    return lambda flag: np.full(n, flag, dtype=bool)


@dataclass(eq=False)
class Condition:
    """A compiled ``when`` condition: a boolean tree whose leaves are (lhs - rhs) terms."""

    tree: sp.Basic
    leaves: list[tuple[sp.Basic, CompiledTerm, int]] = field(default_factory=list)  # (node, term, slot offset)

    def evaluate(self, slot_values: np.ndarray, times: np.ndarray, scene_params) -> np.ndarray:
        """Where the condition holds at each of the times, from the slot values of its leaves."""
        n = len(times)
        leaf_values = {}
        for node, term, offset in self.leaves:
            x = slot_values[offset:offset + term.k * n].reshape(term.k, n).T
            leaf_values[node] = term.value(x, times, scene_params(term))
        return evaluate_condition_tree(self.tree, leaf_values, numpy_filled(n))


@dataclass(eq=False)
class TermGroup:
    """One compiled expression evaluated at a set of instance times.

    ``kind`` is EQ (= 0), GE (>= 0) or OBJ (squared and integrated; a ``linear`` objective
    group enters as its signed weights times its values, not squared: `maximize`). Slot ``(a, i)`` — the
    value of variable ``a`` at instance ``i`` — lives at ``slot_offset + a * n + i`` of the slot
    vector; the group's rows are ``row_offset .. row_offset + n`` among the rows of its kind.
    """

    label: str
    source: str
    kind: TermKind
    term: CompiledTerm
    times: np.ndarray
    weights: np.ndarray
    params: np.ndarray
    slot_offset: int = 0
    row_offset: int = 0
    condition: Condition | None = None
    basis: list | None = None   # basis rows computed while choosing instances, until assembly
    linear: bool = False   # OBJ only: Σ weight × value (signed weights) instead of Σ weight × value²

    @property
    def n(self) -> int:
        """The number of instances (rows) in the group."""
        return len(self.times)


@dataclass(eq=False)
class Evaluation:
    """Everything one SQP iteration needs at the current free values ``s``."""

    s: np.ndarray
    objective: float
    gradient: np.ndarray
    c_eq: np.ndarray
    J_eq: sps.csr_array
    c_ge: np.ndarray
    J_ge: sps.csr_array
    active_eq: np.ndarray      # bool: equality rows whose `when` holds
    active_ge: np.ndarray      # bool: inequality rows whose `when` holds
    _problem: "WindowProblem" = field(repr=False, default=None)
    _hess_data: dict = field(repr=False, default_factory=dict)
    _residual: np.ndarray = field(repr=False, default=None)
    _J_obj: sps.csr_array = field(repr=False, default=None)
    _gauss_newton: sps.csr_array = field(repr=False, default=None)

    def max_violation(self) -> float:
        """The largest violation of a live row at ``s`` (see :meth:`WindowProblem.max_violation`)."""
        return WindowProblem.max_violation(self)

    def lagrangian_hessian(self, lam_eq: np.ndarray, lam_ge: np.ndarray) -> sps.csr_array:
        """∇²R + Σ λ ∇²C over the free variables (sparse, symmetric)."""
        return self._problem._hessian(self, lam_eq, lam_ge)

    def gauss_newton(self) -> sps.csr_array:
        """2 Jᵀ W J of the objective residuals: positive semidefinite, no second derivatives.

        Computed once per evaluation (the exact Hessian adds it too); callers must not modify it."""
        if self._gauss_newton is None:
            self._gauss_newton = self._problem._gauss_newton(self)
        return self._gauss_newton


@lru_cache(maxsize=None)
def _pair_rows(pairs: tuple[tuple[int, int], ...]) -> np.ndarray:
    """Each Hessian pair once, an off-diagonal one twice: a group's entries of D, in order."""
    return np.repeat(np.arange(len(pairs)), [1 if a == b else 2 for a, b in pairs])


def _triplet_structure(rows, cols, shape) -> tuple[sps.csr_array, np.ndarray] | None:
    """The CSR structure ``csr_array((data, (rows, cols)))`` gets, and the permutation from the
    triplets to its stored entries; None when an entry repeats (then values would be summed)."""
    order = np.lexsort((cols, rows))
    r, c = rows[order], cols[order]
    if np.any((r[1:] == r[:-1]) & (c[1:] == c[:-1])):
        return None
    indptr = np.zeros(shape[0] + 1, dtype=np.int64)
    np.cumsum(np.bincount(r, minlength=shape[0]), out=indptr[1:])
    return sps.csr_array((np.ones(r.size), c, indptr), shape=shape), order


@lru_cache(maxsize=4)
def _plan_set_of(structure: bytes) -> tuple[dict, dict]:
    """The plans (by kind) and the uses before a plan, shared by the window problems whose
    structure has this digest (WindowProblem._plan_set); filled in as they are made."""
    return {}, {"hess": 0, "gram": 0}


@dataclass(frozen=True)
class BasisRows:
    """Rows of P in triplet form, for ``n`` instances: row ``r`` maps all coefficients to one
    variable of a term at instance ``r``. A window build makes hundreds of these, and scipy's
    checks on every small sparse matrix cost more than the rows; P is built from them at once."""

    row: np.ndarray
    col: np.ndarray
    data: np.ndarray
    n: int

    def kept(self, keep: np.ndarray) -> "BasisRows":
        """The rows of the instances where ``keep`` holds, numbered anew in order."""
        mask = keep[self.row]
        number = np.cumsum(keep) - 1
        return BasisRows(number[self.row[mask]], self.col[mask], self.data[mask], int(keep.sum()))


def _stacked(blocks: list[BasisRows], n_cols: int) -> sps.csr_array:
    """P: the blocks' rows one after another, as ``sps.csr_array((data, (row, col)))`` makes it
    (a COO sort and a sum of duplicates, the largest part of a small window's build). Each block
    lists its entries row by row, so the concatenation is P's CSR arrays once each row's columns
    are sorted (a derivative row at a curve's start lists them descending); scipy's route is
    taken where rows come out of order or a row holds a column twice."""
    starts = np.cumsum([0] + [block.n for block in blocks])
    n_rows = int(starts[-1])
    data = np.concatenate([b.data for b in blocks] or [np.zeros(0)]).astype(float, copy=False)
    row = np.concatenate([b.row + start for b, start in zip(blocks, starts)] or [np.zeros(0, int)])
    col = np.concatenate([b.col for b in blocks] or [np.zeros(0, int)])
    if max(n_rows, n_cols, row.size) >= 2**31 - 1 or np.any(row[1:] < row[:-1]):
        return sps.csr_array((data, (row, col)), shape=(n_rows, n_cols))
    indptr = np.zeros(n_rows + 1, np.int32)
    np.cumsum(np.bincount(row, minlength=n_rows), out=indptr[1:])
    P = csr(data, col.astype(np.int32), indptr, (n_rows, n_cols))
    P.sort_indices()
    if np.any((P.indices[1:] == P.indices[:-1]) & (row[1:] == row[:-1])):
        return sps.csr_array((data, (row, col)), shape=(n_rows, n_cols))
    P.has_canonical_format = True   # sorted, and no row holds a column twice (checked)
    return P


def _columns(P: sps.csr_array, columns: np.ndarray) -> sps.csr_array:
    """``P[:, columns]`` for distinct ``columns`` (the free control points), as scipy's indexing
    makes it: each row keeps its entries in stored order, renumbered, without its two passes and
    checks (a few hundred µs a window build)."""
    if P.indices.dtype != np.int32 or P.indptr.dtype != np.int32:
        return P[:, columns].tocsr()
    number = np.full(P.shape[1], -1, np.int32)
    number[columns] = np.arange(columns.size, dtype=np.int32)
    renumbered = number[P.indices]
    kept = renumbered >= 0
    before = np.zeros(kept.size + 1, np.int32)
    np.cumsum(kept, out=before[1:])
    return csr(P.data[kept], renumbered[kept], before[P.indptr], (P.shape[0], columns.size))


_BUILT_KEPT = 4   # window problems kept by structure (a session's few windows and phases)
_BUILT: OrderedDict = OrderedDict()
_BUILT_LOCK = threading.Lock()


def forget_builds() -> None:
    """Forget the window problems kept by structure: the next `iterate` builds its window."""
    with _BUILT_LOCK:
        _BUILT.clear()


def _structure_key(scene: Scene, window_name: str | None) -> tuple:
    """Everything a window build reads from the scene but its control points and DOF damping:
    what instance times depend on (instances.structure_key), the window, the constraints,
    objectives and DOF bounds in order, added instances, constants' values (terms' parameters
    and the affine rows' values) and the quadrature."""
    name = window_name or scene.active_window
    window = scene.windows[name]
    return (structure_key(scene), name, window.dofs, window.interval,
            tuple((c.name, c.relations, c.at, c.interval, c.when, c.weight, c.samples)
                  for c in scene.constraints.values()),
            tuple((o.name, o.exprs, o.interval, o.at, o.weight, o.sense) for o in scene.objectives.values()),
            tuple((d.name, d.lo, d.hi) for d in scene.dofs.values()),
            frozenset(scene.extra_instances.items()), frozenset(scene.constants.items()),
            scene.settings["quadrature"])


@dataclass(frozen=True)
class MeritValues:
    """Objective and constraint values without derivatives, for line searches."""

    objective: float
    c_eq: np.ndarray
    c_ge: np.ndarray
    active_eq: np.ndarray
    active_ge: np.ndarray


class WindowProblem:
    """The NLP of one spacetime window. Build once per `iterate` (:meth:`of`: or take the last
    build of the same structure); evaluate many times."""

    @classmethod
    def of(cls, scene: Scene, window_name: str | None = None) -> "WindowProblem":
        """The window problem of ``scene``, a copy of one built for a scene of the same structure
        (:func:`_structure_key`) on this scene's control points when there is one, else a new
        build, kept for the next. A user's `iterate`s mostly change the control points only, and
        each built its window anew (basketball's build: 8.6 ms; the pendulum swing-up's: 0.4 ms
        and 0.14 ms of affine rows, of a 4.7 ms `iterate`).

        Raises:
            StwError: as the constructor.
        """
        key = _structure_key(scene, window_name)
        with _BUILT_LOCK:
            found = _BUILT.get(key)
            if found is not None:
                _BUILT.move_to_end(key)
        if found is not None:
            found._check_memory()   # the limit may have been lowered since it was built
            return found._on(scene)
        problem = cls(scene, window_name)
        problem._affine()     # made now, so that the copies share them: the affine rows and the
        problem._plan_set()   # plans of this structure
        with _BUILT_LOCK:
            _BUILT[key] = problem
            while len(_BUILT) > _BUILT_KEPT:
                _BUILT.popitem(last=False)
        return problem._on(scene)

    def _on(self, scene: Scene) -> "WindowProblem":
        """This problem on the control points (and DOF damping) of ``scene``, of its structure."""
        problem = copy.copy(self)
        problem.scene = scene
        problem.coef0 = scene.coefficient_vector()
        return problem

    def __init__(self, scene: Scene, window_name: str | None = None):
        window = scene.windows[window_name or scene.active_window]
        self.scene = scene
        self.window = window
        self.dof_names = tuple(scene.dofs)
        if not self.dof_names:
            raise StwError("there are no DOF: declare one with `dof NAME`")
        self.offsets = {}
        offset = 0
        for name, dof in scene.dofs.items():
            self.offsets[name] = offset
            offset += dof.curve.n_coef
        self.n_total = offset
        self.coef0 = scene.coefficient_vector()
        self.interval = window.interval or (scene.t0, scene.t1)
        self.window_dofs = tuple(window.dofs) if window.dofs else self.dof_names
        missing = [d for d in self.window_dofs if d not in scene.dofs]
        if missing:
            raise StwError(f"window '{window.name}' names unknown DOF {', '.join(missing)}")
        self._select_free()
        self._build_groups()
        self.memory_estimate = self._memory_estimate()
        self._check_memory()   # before the window's large arrays are made
        self._assemble_patterns()

    # --- building ----------------------------------------------------------------------------
    def _select_free(self) -> None:
        a, b = self.interval
        full = a <= self.scene.t0 and b >= self.scene.t1
        free, lo, hi = [], np.inf, -np.inf
        for name in self.window_dofs:
            curve = self.scene.dofs[name].curve
            support = curve.support()
            mask = np.ones(curve.n_coef, bool) if full else curve.touching(a, b)
            idx = np.flatnonzero(mask)
            if idx.size:
                lo, hi = min(lo, support[idx, 0].min()), max(hi, support[idx, 1].max())
            free.append(self.offsets[name] + idx)
        self.free = np.concatenate(free).astype(np.int64) if free else np.zeros(0, np.int64)
        if self.free.size == 0:
            raise StwError(f"window '{self.window.name}' has no free control points")
        self._free_mask = np.zeros(self.n_total, bool)
        self._free_mask[self.free] = True
        # Constraint instances and objective quadrature cover every time the free control points
        # can change: the union of their supports, up to three knot spans past the window. (The
        # paper's one span past it (4.2) lets a window break constraints just outside itself.)
        self.reach = (max(self.scene.t0, lo), min(self.scene.t1, hi))
        self.free_dofs = frozenset(self.window_dofs)
        self.dof_of_free = np.empty(self.free.size, dtype=object)
        pos = 0
        for name, idx in zip(self.window_dofs, free):
            self.dof_of_free[pos:pos + idx.size] = name
            pos += idx.size

    def _memory_estimate(self) -> float:
        """Bytes an `iterate` on this window allocates at its peak, from its sizes alone (the
        groups' instances and variables, the free control points): made before any of it is.

        The largest arrays are the Hessian of the Lagrangian and the matrices made from it (the
        Gauss-Newton product Joᵀ W Jo, the KKT matrix and its factors): a free coefficient of DOF
        a meets the :data:`SPAN_REACH` coefficients of DOF b around it wherever a term couples a
        and b (an objective's residual couples all its DOF, a constraint its second derivatives'),
        but no more entries than the coupling groups' instances make (16 a pair and instance).
        Then P's rows (4 coefficients per variable and instance) and the Jacobians' entries."""
        free_of = {name: int(np.count_nonzero(self.dof_of_free == name)) for name in self.window_dofs}
        pairs: dict[tuple[str, str], float] = {}
        row_entries = 0
        for group in self.groups:
            term, n = group.term, group.n
            dofs = {v.dof for v in term.variables} & self.free_dofs
            row_entries += 4 * n * (term.k + len(dofs))
            if group.kind == OBJ:
                coupled = [(a, b) for a in dofs for b in dofs]
            else:
                coupled = [(term.variables[i].dof, term.variables[j].dof) for i, j in term.hessian_pairs]
                coupled = [p for q in coupled if set(q) <= dofs for p in (q, q[::-1])]
            for a, b in coupled:
                entries = min(SPAN_REACH * min(free_of[a], free_of[b]), 16 * n)
                pairs[a, b] = max(pairs.get((a, b), 0), entries)
        diagonal = sum(SPAN_REACH * free_of[name] for name in self.window_dofs)   # the KKT's own
        hessian = sum(pairs.values()) + diagonal
        return BYTES_PER_HESSIAN_ENTRY * hessian + BYTES_PER_ROW_ENTRY * row_entries

    def _check_memory(self) -> None:
        """Refuse the window when its estimate is over the limit ``memory`` in force.

        Raises:
            LimitError: with the estimate and what it is made of.
        """
        limits.check_memory(self.memory_estimate,
                            f"an iterate on window '{self.window.name}' ({self.n_free} free control points, "
                            f"{sum(g.n for g in self.groups)} instances of {len(self.groups)} term(s)) needs")

    def _compile(self, expr: sp.Basic, scope: tuple[float, float] | None = None) -> CompiledTerm:
        """``expr`` compiled as read on ``scope`` (an attached DOF: see Scene.expand)."""
        return compile_term(self.scene.expand(expr, scope), set(self.scene.dofs), set(self.scene.constants))

    def _params(self, term: CompiledTerm) -> np.ndarray:
        return self.scene.constant_values(term.parameters)

    def _build_groups(self) -> None:
        scene, (ia, ib) = self.scene, self.reach
        self.groups: list[TermGroup] = []
        def inside(times):
            return times[(times >= ia - 1e-12) & (times <= ib + 1e-12)]

        kept = kept_times(scene)
        for c in scene.constraints.values():
            for r_index, rel in enumerate(c.relations):
                label = c.name if len(c.relations) == 1 else f"{c.name}[{r_index + 1}]"
                times = inside(relation_instances(scene, c, rel, kept))
                self._add_group(label, c.name, rel.kind, rel.expr, times, c.weight, c.when,
                                term=self._compile(rel.expr, c.span))
        for name in self.window_dofs:
            dof = scene.dofs[name]
            if dof.lo is None and dof.hi is None:
                continue
            x, n = dof_symbol(name), dof.curve.n_coef
            # Bounds hold on the control points (so, by the convex hull, everywhere); a row per
            # control point, named by the time it stands for.
            points = BasisRows(np.arange(n), self.offsets[name] + np.arange(n), np.ones(n), n)
            times, extra = bound_times(scene, name), inside(bound_extra_times(scene, name))
            for side, bound, expr in (("lo", dof.lo, x - (dof.lo or 0)), ("hi", dof.hi, (dof.hi or 0) - x)):
                if bound is not None:
                    # on the DOF's own curve, also where an attachment reads it as something else
                    # (a planted leg's joint is inverse kinematics there: its range is its own)
                    term = compile_term(expr, set(scene.dofs), set(scene.constants))
                    self._add_group(f"{name}.{side}", f"{name}.bounds", GE, expr, times, 1.0, None,
                                    basis=[points], term=term)
                    self._add_group(f"{name}.{side}+", f"{name}.bounds", GE, expr, extra, 1.0, None, term=term)
        quad = int(scene.settings["quadrature"])
        for o in scene.objectives.values():
            a, b = self.reach
            # `minimize`/`maximize`: the value itself, signed, instead of its square
            linear, sign = o.sense is not None, -1.0 if o.sense == "maximize" else 1.0
            if o.at is not None:      # a terminal cost: each term (squared) at that instant
                if a - 1e-12 <= o.at <= b + 1e-12:
                    self._add_terminal(o, linear, sign)
                continue
            if o.interval is not None:
                a, b = max(a, o.interval[0]), min(b, o.interval[1])
            if b <= a:
                continue
            for e_index, expr in enumerate(o.exprs):
                label = o.name if len(o.exprs) == 1 else f"{o.name}[{e_index + 1}]"
                for lo, hi in pieces(scene, float(a), float(b)):
                    term = self._compile(expr, (float(lo), float(hi)))
                    if not term.dofs & self.free_dofs:
                        continue  # constant over this window
                    breaks = np.unique(np.concatenate([scene.dofs[d].curve.breakpoints for d in term.dofs]))
                    times, weights = gauss_legendre_nodes(breaks, quad, lo, hi)
                    self._add_group(label, o.name, OBJ, expr, times, o.weight, None, term=term,
                                    weights=weights * (sign * o.weight), linear=linear)

    def _add_terminal(self, o, linear: bool, sign: float) -> None:
        """A terminal cost: each term's square at ``o.at``, weighed by ``o.weight`` (one
        quadrature point of weight W, so the objective gains W * e(T)^2); ``linear``: its value,
        times ``sign`` × W (W * e(T) for `minimize`, -W * e(T) for `maximize`)."""
        times = np.array([o.at])
        for e_index, expr in enumerate(o.exprs):
            term = self._compile(expr, (o.at, o.at))
            if term.dofs & self.free_dofs:
                label = o.name if len(o.exprs) == 1 else f"{o.name}[{e_index + 1}]"
                self._add_group(label, o.name, OBJ, expr, times, o.weight, None, term=term,
                                weights=np.array([sign * o.weight]), linear=linear)

    def _basis_rows(self, term: CompiledTerm, times: np.ndarray) -> list[BasisRows]:
        """Per variable of ``term``: the rows mapping all coefficients to its values at ``times``."""
        blocks, checked = [], times_checker(times)
        for var in term.variables:
            curve = self.scene.dofs[var.dof].curve
            local = curve.basis_at(checked(curve), var.order)
            row = np.repeat(np.arange(local.shape[0]), np.diff(local.indptr))
            blocks.append(BasisRows(row, local.indices + self.offsets[var.dof], local.data, len(times)))
        return blocks

    def _add_group(self, label, source, kind, expr, times, weight, when, *, term=None, weights=None,
                   basis=None, linear=False):
        """``basis``: rows mapping all coefficients to the term's variables at ``times`` (default:
        the curves' basis functions at ``times``)."""
        term = term or self._compile(expr)
        if kind != OBJ:
            times, basis = self._touching_free(term, times, basis)
        if times.size == 0 or not term.dofs & self.free_dofs:
            return
        weights = weights if weights is not None else np.full(times.size, float(weight))
        condition = None
        if when is not None and when is not sp.true:
            if when is sp.false:
                return
            condition = Condition(when)
        self.groups.append(TermGroup(label, source, kind, term, times, weights, self._params(term),
                                     condition=condition, basis=basis, linear=linear))

    def _touching_free(self, term: CompiledTerm, times: np.ndarray, blocks=None):
        """Drop instances that no free control point can influence (their Jacobian rows are zero).

        Returns the kept times and their basis rows (reused when P is assembled)."""
        if times.size == 0:
            return times, []
        blocks = blocks if blocks is not None else self._basis_rows(term, times)
        keep = np.zeros(times.size, bool)
        for block in blocks:
            hit = self._free_mask[block.col] & (block.data != 0)
            keep[block.row[hit]] = True
        if keep.all():   # most groups: every instance lies where the window reaches
            return times, blocks
        return times[keep], [block.kept(keep) for block in blocks]

    def _assemble_patterns(self) -> None:
        """Stack basis rows of every group into P and precompute the sparsity of G and D."""
        rows, slot = [], 0
        counts = {EQ: 0, GE: 0, OBJ: 0}
        g_idx = {EQ: ([], []), GE: ([], []), OBJ: ([], [])}
        d_rows, d_cols = [], []
        for group in self.groups:
            n, k = group.n, group.term.k
            group.slot_offset, group.row_offset = slot, counts[group.kind]
            rows.extend(group.basis if group.basis is not None else self._basis_rows(group.term, group.times))
            group.basis = None   # only needed here
            inst = np.arange(n)
            r, c = g_idx[group.kind]
            r.append(group.row_offset + np.tile(inst, k))          # row i, for each variable a
            c.append(slot + np.arange(k * n))                      # its slot a*n + i
            # D's entries, pair by pair, (a, b) and then (b, a) off the diagonal, each n long
            ab = [(x, y) for a, b in group.term.hessian_pairs for x, y in ((a, b), (b, a))[:1 + (a != b)]]
            if ab:
                x, y = np.array(ab).T
                d_rows.append((slot + x[:, None] * n + inst).ravel())
                d_cols.append((slot + y[:, None] * n + inst).ravel())
            slot += k * n
            counts[group.kind] += n
            if group.condition is not None:
                slot = self._add_condition_slots(group, rows, slot)
        self.n_slots = slot
        self.row_counts = counts
        self.P = _stacked(rows, self.n_total)
        self.Pf = _columns(self.P, self.free)
        self._g_pattern = {kind: (np.concatenate(r) if r else np.zeros(0, int),
                                  np.concatenate(c) if c else np.zeros(0, int))
                           for kind, (r, c) in g_idx.items()}
        self._d_pattern = (np.concatenate(d_rows) if d_rows else np.zeros(0, int),
                           np.concatenate(d_cols) if d_cols else np.zeros(0, int))
        self._affine_rows: AffineRows | None = None   # made at the first evaluation (_affine)
        self._constant_jacobians: dict = {}   # of kinds whose rows are all affine (shared read-only)
        self._product_plans: dict | None = None   # shared by equal structures (_plan_set)
        self._uses: dict | None = None   # Hessians and Gauss-Newtons before their plans (shared too)
        # every row's weight, by kind, in row order (read-only: evaluations share them)
        self._row_weights = {kind: np.concatenate([g.weights for g in self.groups if g.kind == kind]
                                                  or [np.zeros(0)]) for kind in (EQ, GE, OBJ)}
        # Objective rows entered linearly (`maximize`, `minimize`): their weights apart from the
        # squared rows', which alone make the Gauss-Newton matrix. None: every row squared.
        self.linear_objective = None
        linear = np.concatenate([np.full(g.n, g.linear) for g in self.groups if g.kind == OBJ]
                                or [np.zeros(0, bool)])
        if linear.any():
            w = self._row_weights[OBJ]
            self.linear_objective = (np.where(linear, 0.0, w), np.where(linear, w, 0.0))
            self._row_weights[OBJ] = self.linear_objective[0]
        # the live masks of a problem without conditional groups, the same at every s (read-only:
        # evaluations share them); None where a `when` decides
        self.always_live = None
        if all(g.condition is None for g in self.groups):
            self.always_live = {kind: np.ones(counts[kind], bool) for kind in (EQ, GE)}
            for mask in self.always_live.values():
                mask.flags.writeable = False
        self.row_group = {kind: np.repeat(np.arange(len(self.groups)),
                                          [g.n if g.kind == kind else 0 for g in self.groups])
                          for kind in (EQ, GE, OBJ)}

    def _add_condition_slots(self, group: TermGroup, rows: list, slot: int) -> int:
        for node in relation_nodes(group.condition.tree):
            term = self._compile(node.lhs - node.rhs)
            group.condition.leaves.append((node, term, slot))
            rows.extend(self._basis_rows(term, group.times))
            slot += term.k * group.n
        return slot

    # --- evaluation --------------------------------------------------------------------------
    @property
    def n_free(self) -> int:
        """The number of free control points (the optimizer's variables)."""
        return self.free.size

    @cached_property
    def PfT(self) -> sps.csr_array:
        """Pfᵀ in CSR, made when a Hessian first needs it (its plan is kept by structure, so
        most window builds never do)."""
        return self.Pf.T.tocsr()

    def initial(self) -> np.ndarray:
        """Current values of the free control points."""
        return self.coef0[self.free].copy()

    def scatter(self, s: np.ndarray) -> np.ndarray:
        """The full coefficient vector with the free values ``s`` put in place."""
        full = self.coef0.copy()
        full[self.free] = s
        return full

    def _slot_values(self, s: np.ndarray) -> np.ndarray:
        return matvec(self.P, self.scatter(s))

    def _group_inputs(self, group: TermGroup, v: np.ndarray) -> np.ndarray:
        n, k = group.n, group.term.k
        return v[group.slot_offset:group.slot_offset + k * n].reshape(k, n).T

    def _conditions(self, v: np.ndarray) -> dict[str, np.ndarray]:
        """Where each row is live (its `when` holds) at slot values ``v``."""
        if self.always_live is not None:   # no conditional group: every row, at every v
            return self.always_live
        masks = {EQ: np.ones(self.row_counts[EQ], bool), GE: np.ones(self.row_counts[GE], bool)}
        for group in self.groups:
            if group.condition is not None:
                masks[group.kind][group.row_offset:group.row_offset + group.n] = group.condition.evaluate(
                    v, group.times, self._params)
        return masks

    def merit_values(self, s: np.ndarray) -> MeritValues:
        """Objective and constraint values only (cheap: no derivatives), for line searches."""
        v = self._slot_values(s)
        out = {EQ: np.empty(self.row_counts[EQ]), GE: np.empty(self.row_counts[GE])}
        objective = 0.0
        for group, f, _, _ in self._local_terms(v, full=False):
            if group.kind == OBJ:
                objective += float(np.dot(group.weights, f if group.linear else f * f))
            else:
                out[group.kind][group.row_offset:group.row_offset + group.n] = group.weights * f
        masks = self._conditions(v)
        return MeritValues(objective, out[EQ], out[GE], masks[EQ], masks[GE])

    def _affine(self) -> AffineRows:
        """The affine groups' values as one product, and their Jacobian values (affine_rows.py),
        made at the first evaluation."""
        if self._affine_rows is None:
            self._affine_rows = AffineRows(self.groups, self.n_slots)
        return self._affine_rows

    def _local_terms(self, v: np.ndarray, full: bool = True):
        """Per group: the group, its values at slot values ``v`` and (``full``) its gradient and
        Hessian entries (``CompiledTerm.full``), else None. An affine group's values come from
        their one product, its gradient and Hessian as None (constant: :meth:`_affine`)."""
        affine = self._affine()
        fa = affine.values(v)
        for group, span in zip(self.groups, affine.span):
            if span is not None:
                yield group, fa[span[0]:span[1]], None, None
            elif full:
                yield (group, *group.term.full(self._group_inputs(group, v), group.times, group.params))
            else:
                yield group, group.term.value(self._group_inputs(group, v), group.times, group.params), None, None

    def first_undefined(self, s: np.ndarray) -> tuple[TermGroup, int, str] | None:
        """The first group and instance where a term's value or gradient is not a finite real
        number at free values ``s`` (where its `when` holds), and which of the two; None: none."""
        v = self._slot_values(s)
        for group, f, grad, _ in self._local_terms(v):
            bad = ~np.isfinite(f)
            if grad is not None:   # an affine group's is finite (affine_rows.py)
                bad |= ~np.all(np.isfinite(grad), axis=1)
            if bad.any() and group.condition is not None:
                bad &= group.condition.evaluate(v, group.times, self._params)
            if bad.any():
                i = int(np.flatnonzero(bad)[0])
                return group, i, "its value" if not np.isfinite(f[i]) else "its derivative"
        return None

    def evaluate(self, s: np.ndarray) -> Evaluation:
        """Values, gradients and (lazily) Hessians at free values ``s``."""
        v = self._slot_values(s)
        counts, kept = self.row_counts, self._constant_jacobians
        values = {EQ: np.empty(counts[EQ]), GE: np.empty(counts[GE]), OBJ: np.empty(counts[OBJ])}
        grads = {EQ: [], GE: [], OBJ: []}   # (of kinds whose Jacobian is not kept)
        hess = []
        affine = self._affine()
        fa = affine.values(v)
        # _local_terms' loop written out: this is every SQP step's evaluation (a small window's
        # steps spent 2% in the generator, the dicts and the unused parts of kept Jacobians)
        for group, span, parts in zip(self.groups, affine.span, affine.jacobian):
            rows = slice(group.row_offset, group.row_offset + group.n)
            if span is not None:   # affine: values from the one product, Jacobian values constant
                values[group.kind][rows], h = fa[span[0]:span[1]], None
            else:
                values[group.kind][rows], grad, h = group.term.full(
                    self._group_inputs(group, v), group.times, group.params)
                # constraint rows scaled by their weights; objective residuals as they are (x 1.0)
                parts = (grad * group.weights[:, None] if group.kind != OBJ else grad).T.ravel()
            if group.kind not in kept:
                grads[group.kind].append(parts)
            hess.append((group, h))
        J, full = {}, {}
        for kind in (EQ, GE, OBJ):
            constant = kept.get(kind)
            if constant is None:
                J[kind], full[kind] = self._jacobian(kind, grads[kind])
                # every row affine, or no row at all: the same at every s
                if kind in affine.kinds or not counts[kind]:
                    kept[kind] = (J[kind], full[kind])
            else:
                J[kind], full[kind] = constant
        w_obj = self._row_weights[OBJ]   # the squared rows' (0 on linear rows)
        residual = values[OBJ]
        objective = float(np.dot(w_obj, residual * residual))
        slope = 2.0 * w_obj * residual
        if self.linear_objective is not None:
            w_lin = self.linear_objective[1]
            objective += float(np.dot(w_lin, residual))
            slope += w_lin
        gradient = matvec(transpose(J[OBJ]), slope) if residual.size else np.zeros(self.n_free)
        weights = self._row_weights
        masks = self._conditions(v)
        return Evaluation(s=s.copy(), objective=objective, gradient=np.asarray(gradient),
                          c_eq=weights[EQ] * values[EQ], J_eq=J[EQ], c_ge=weights[GE] * values[GE], J_ge=J[GE],
                          active_eq=masks[EQ], active_ge=masks[GE], _problem=self,
                          _hess_data={"groups": hess, "w_obj": w_obj, "J_obj_full": full[OBJ]}, _residual=residual, _J_obj=J[OBJ])

    def _plans(self, kind: str):
        """The product G @ Pf of a kind, ("hess") the pair Pfᵀ D, (Pfᵀ D) Pf, or ("gram") the
        Gauss-Newton Joᵀ W Jo, planned once on their fixed structures (products.py: bitwise
        scipy's products, without working the structure out each time). None: triplets that
        repeat an entry, or a Hessian or Gauss-Newton plan not yet worth making (one costs about
        as much as HESSIAN_PLAN_AFTER plain ones)."""
        plans = self._plan_set()
        if kind not in plans:
            if kind in ("hess", "gram"):
                self._uses[kind] += 1
                if self._uses[kind] < HESSIAN_PLAN_AFTER:
                    return None
            if kind == "gram":   # Gauss-Newton 2 Joᵀ W Jo, on the objective Jacobian's plan
                J = self._plans(OBJ)
                terms = 0 if J is None else int((np.diff(J.indptr).astype(np.int64) ** 2).sum())
                plans[kind] = None if J is None or terms > GRAM_PLAN_TERMS else GramPlan(
                    sps.csr_array((np.ones(J.indices.size), J.indices, J.indptr), shape=J.shape))
            elif kind == "hess":
                D = _triplet_structure(*self._d_pattern, (self.n_slots, self.n_slots))
                if D is None:
                    plans[kind] = None
                else:
                    left = ProductPlan(self.PfT, D[0], "A", source=D[1])
                    X = sps.csr_array((np.ones(left.indices.size), left.indices, left.indptr), shape=left.shape)
                    plans[kind] = (left, ProductPlan(X, self.Pf, "B"))
            else:
                rows, cols = self._g_pattern[kind]
                G = _triplet_structure(rows, cols, (self.row_counts[kind], self.n_slots))
                plans[kind] = None if G is None else ProductPlan(G[0], self.Pf, "B", source=G[1])
        return plans[kind]

    def _plan_set(self) -> dict:
        """The plans of every window problem with this one's structure (P's free columns, the
        patterns of G and D), made by whichever problem needed one first. Each `iterate` builds
        its window anew; its plans are the same as the last one's (basketball's Hessian plan
        took about 0.6 s to make)."""
        if self._product_plans is None:
            digest = hashlib.blake2b(digest_size=20)
            for part in (self.Pf.indptr, self.Pf.indices, self.Pf.data,
                         np.array([*self.Pf.shape, self.n_slots, *self.row_counts.values()]),
                         *self._d_pattern, *(a for kind in (EQ, GE, OBJ) for a in self._g_pattern[kind])):
                digest.update(np.ascontiguousarray(part).view(np.uint8))
                digest.update(b"|")
            # The uses are counted over the problems too: `iterate 1` repeated (a user stepping
            # through a solve) would otherwise never reach HESSIAN_PLAN_AFTER in one problem.
            self._product_plans, self._uses = _plan_set_of(digest.digest())
        return self._product_plans

    def _jacobian(self, kind: str, grad_parts: list[np.ndarray]) -> tuple[sps.csr_array, np.ndarray | None]:
        """The Jacobian of the ``kind`` rows, and its values on the plan's whole structure (None
        without a plan)."""
        rows, cols = self._g_pattern[kind]
        data = np.concatenate(grad_parts) if grad_parts else np.zeros(0)
        plan = self._plans(kind)
        if plan is not None:
            full = plan.data(data)
            return plan.matrix(full), full
        G = sps.csr_array((data, (rows, cols)), shape=(self.row_counts[kind], self.n_slots))
        return (G @ self.Pf).tocsr(), None

    def _gauss_newton(self, ev: Evaluation) -> sps.csr_array:
        Jo, w = ev._J_obj, ev._hess_data["w_obj"]
        n = ev.s.size
        if Jo is None or Jo.shape[0] == 0:
            return sps.csr_array((n, n))
        full = ev._hess_data.get("J_obj_full")
        plan = self._plans("gram") if full is not None else None
        if plan is not None:
            return plan.matrix(full, 2.0 * w)
        return sps.csr_array(Jo.T @ (sps.diags_array(2.0 * w) @ Jo))

    def _hessian(self, ev: Evaluation, lam_eq: np.ndarray, lam_ge: np.ndarray) -> sps.csr_array:
        multipliers = {EQ: lam_eq, GE: lam_ge}
        data = []
        w_obj_all, residual = ev._hess_data["w_obj"], ev._residual
        for group, h in ev._hess_data["groups"]:
            if not group.term.hessian_pairs:
                continue
            rows = slice(group.row_offset, group.row_offset + group.n)
            if group.linear:   # w e: its Hessian is w ∇²e
                scale = group.weights
            elif group.kind == OBJ:
                scale = 2.0 * w_obj_all[rows] * residual[rows]
            else:
                scale = multipliers[group.kind][rows] * group.weights
            # Pair p's entries h[:, p] * scale, twice for an off-diagonal pair (D is symmetric).
            data.append((h * scale[:, None]).T[_pair_rows(group.term.hessian_pairs)].ravel())
        data = np.concatenate(data) if data else np.zeros(0)
        plans = self._plans("hess")
        if plans is not None:
            left, right = plans
            X = left.data(data)   # Pfᵀ D on its whole structure; scipy's drops the exact zeros
            order = right.touch_order(X == 0)
            if order is not False:
                return add(right.matrix(right.data(X), order), ev.gauss_newton())
            H = left.matrix(X) @ self.Pf   # its zeros moved too much of the order: as scipy does
            return add(H, ev.gauss_newton())
        d_rows, d_cols = self._d_pattern
        D = sps.csr_array((data, (d_rows, d_cols)), shape=(self.n_slots, self.n_slots))
        H = self.PfT @ D @ self.Pf
        return add(H, ev.gauss_newton())

    # --- reporting ---------------------------------------------------------------------------
    def violation_by_source(self, ev: Evaluation | MeritValues) -> dict[str, float]:
        """Max violation per constraint name (for the equations panel and `print`)."""
        out: dict[str, float] = {}
        for group in self.groups:
            if group.kind == OBJ:
                continue
            rows = slice(group.row_offset, group.row_offset + group.n)
            if group.kind == EQ:
                v = np.abs(ev.c_eq[rows])[ev.active_eq[rows]]
            else:
                v = np.maximum(0, -ev.c_ge[rows])[ev.active_ge[rows]]
            out[group.source] = max(out.get(group.source, 0.0), float(v.max(initial=0.0)))
        return out

    def equality_freedom(self, sources=None) -> tuple[int, int]:
        """(equality instances, free control points they move): of the constraints named in
        ``sources`` (None: the whole window). More instances than control points over-determine
        the curves: refining them (more knots) gives the freedom back."""
        rows, columns = 0, []
        for group in self.groups:
            if group.kind != EQ or (sources is not None and group.source not in sources):
                continue
            rows += group.n
            block = self.Pf[group.slot_offset:group.slot_offset + group.term.k * group.n]
            columns.append(np.asarray(block.indices))
        moved = np.unique(np.concatenate(columns)).size if columns else 0
        return rows, (self.n_free if sources is None else moved)

    def summary(self) -> str:
        """One line saying the window's size: free control points, instances, quadrature points."""
        return (f"window '{self.window.name}': {self.n_free} free control points, "
                f"{self.row_counts[EQ]} equality + {self.row_counts[GE]} inequality instances, "
                f"{self.row_counts[OBJ]} quadrature points")

    # --- backend contract ----------------------------------------------------------------------
    # What a backend may read from a window problem: ``n_free``, ``row_counts``, ``groups`` (their
    # label, source, kind, term, times, weights, params, slot_offset, row_offset, condition), ``P``,
    # ``Pf``, ``free``, ``coef0``, ``dof_of_free``, ``initial``, ``scatter``, ``evaluate``,
    # ``merit_values``, ``violation_by_source``, and the members below. Nothing else (no private
    # attribute, nothing of the scene): the rest may change without notice.
    @property
    def damping(self) -> np.ndarray:
        """Per free variable, the user's damping weight of its DOF (paper 4.3; ``damp DOF W``)."""
        return np.array([self.scene.dofs[name].damp for name in self.dof_of_free], dtype=float)

    @staticmethod
    def max_violation(values: Evaluation | MeritValues) -> float:
        """The largest violation of a live row: |c| of equalities, max(0, -c) of inequalities."""
        eq = np.abs(values.c_eq[values.active_eq]) if values.c_eq.size else np.zeros(0)
        ge = np.maximum(0.0, -values.c_ge[values.active_ge]) if values.c_ge.size else np.zeros(0)
        return float(max(eq.max(initial=0.0), ge.max(initial=0.0)))

    def row_sources(self, kind: str) -> np.ndarray:
        """For every row of ``kind`` ("eq" or "ge"), the name of the constraint (or, for a DOF
        bound, the DOF) it is an instance of."""
        names = np.array([g.source for g in self.groups] or [""], dtype=object)
        return names[self.row_group[kind]] if self.row_group[kind].size else np.zeros(0, dtype=object)

    def jacobian_structure(self, kind: str) -> sps.csr_array:
        """Structural nonzeros (ones) of the Jacobian of the ``kind`` rows over the free variables."""
        rows, cols = self._g_pattern[kind]
        G = sps.csr_array((np.ones(rows.size), (rows, cols)), shape=(self.row_counts[kind], self.n_slots))
        Pf = sps.csr_array(self.Pf, copy=True)
        Pf.data[:] = 1.0                  # explicit zeros stay in the structure
        out = sps.csr_array(G @ Pf)
        out.data[:] = 1.0
        return out

    def hessian_structure(self) -> sps.csr_array:
        """Structural nonzeros (ones) of every Lagrangian Hessian :meth:`Evaluation.lagrangian_hessian`
        can return (the Gauss-Newton part included)."""
        d_rows, d_cols = self._d_pattern
        D = sps.csr_array((np.ones(d_rows.size), (d_rows, d_cols)), shape=(self.n_slots, self.n_slots))
        Pf = sps.csr_array(self.Pf, copy=True)
        Pf.data[:] = 1.0
        Jo = self.jacobian_structure(OBJ)
        out = sps.csr_array(Pf.T @ D @ Pf + Jo.T @ Jo)
        out.data[:] = 1.0
        return out

    def term_parameters(self, term: CompiledTerm) -> np.ndarray:
        """Current values of the constants ``term`` reads (e.g. a `when` condition's leaves)."""
        return self._params(term)

