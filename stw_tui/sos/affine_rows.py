"""The affine term groups of a window problem, evaluated together as one sparse product.

Boundary conditions, keyframes, waypoints and bounds are affine in their DOF quantities
(``x - 0.25``, ``x'``): their gradient depends on time and constants only, so it is the same at
every evaluation of a window problem. Each such group cost a call of its compiled term per
evaluation and per merit test (about 5 µs, whatever its size): on a small window most of both
(the pendulum swing-up, 4 affine groups of 5: an evaluation 78 -> 45 µs, a merit test 38 -> 19.5
µs once they are taken together). Here their values at any slot values ``v`` are
``L v + f0``: L holds each group's gradient at its slots, f0 its value where its variables are
zero, both computed once by the compiled term itself.

A product rounds as the compiled term does where a term is one variable plus a constant (most of
them); a sum of several variables may differ from the compiled order in the last bit.
"""

from __future__ import annotations

import numpy as np

from stw_tui.sos.compressed import csr
from stw_tui.sos.sparse_matvec import matvec
from stw_tui.sym.kinds import TermKind


class AffineRows:
    """The values and constant Jacobian values of the affine groups of a window problem.

    ``span[i]``: where group i's values lie in :meth:`values`'s result (None: the group is not
    evaluated here); ``jacobian[i]``: its Jacobian values as WindowProblem.evaluate lays them out
    (slot by slot, constraint rows scaled by their weights); ``kinds``: the kinds (EQ, GE, OBJ)
    whose groups are all evaluated here, so that their Jacobians are constant.
    """

    def __init__(self, groups: list, n_slots: int):
        self.span: list[tuple[int, int] | None] = [None] * len(groups)
        self.jacobian: list[np.ndarray | None] = [None] * len(groups)
        cols, data, widths, offsets = [], [], [], []
        at = 0
        for i, group in enumerate(groups):
            if not group.term.affine or group.n == 0:
                continue
            n, k = group.n, group.term.k
            f0, grad, _ = group.term.full(np.zeros((n, k)), group.times, group.params)
            if not (np.all(np.isfinite(f0)) and np.all(np.isfinite(grad))):
                continue   # a coefficient undefined somewhere: the compiled term says where
            self.span[i] = (at, at + n)
            scaled = grad * group.weights[:, None] if group.kind != TermKind.OBJ else grad
            self.jacobian[i] = np.array(scaled.T.ravel())
            # row i: variable a's entry at its slot a*n + i, for a = 0..k-1 (columns ascending)
            cols.append((group.slot_offset + np.arange(n)[:, None] + n * np.arange(k)).ravel())
            data.append(np.asarray(grad, float).ravel())
            widths.append(np.full(n, k))
            offsets.append(np.asarray(f0, float))
            at += n
        self.L = None
        if at:
            indptr = np.zeros(at + 1, np.int64)
            np.cumsum(np.concatenate(widths), out=indptr[1:])
            index = np.int32 if max(n_slots, indptr[-1]) < np.iinfo(np.int32).max else np.int64
            self.L = csr(np.concatenate(data), np.concatenate(cols).astype(index), indptr.astype(index),
                         (at, n_slots))
        self.f0 = np.concatenate(offsets) if at else np.zeros(0)
        self.kinds = {g.kind for g in groups} - {g.kind for g, span in zip(groups, self.span) if span is None}

    def values(self, v: np.ndarray) -> np.ndarray:
        """Every affine group's values at slot values ``v``, group after group."""
        if self.L is None:
            return self.f0
        return matvec(self.L, v) + self.f0
