"""Vectors as numpy arrays: the part of a LinearAlgebra that the scipy backend's sparse and dense
algebras share."""

from __future__ import annotations

import numpy as np

from stw_tui.sos.sqp.algebra import LinearAlgebra


class NumpyVectors(LinearAlgebra):
    """float64 numpy vectors (the matrices and KKT solves are the subclass's)."""

    def vector(self, values):
        return np.array(values, dtype=float)

    def numpy(self, v):
        return np.asarray(v, dtype=float)

    def full(self, n, value):
        return np.full(n, float(value))

    def concat(self, parts):
        return np.concatenate(parts)

    def maximum(self, v, floor):
        return np.maximum(v, floor)

    def max_abs(self, v):
        return float(np.abs(v).max(initial=0.0))

    def max_step(self, v, dv, cap=1.0):
        # The generic test in fewer numpy calls: no any() first (none negative: +inf, so the cap)
        neg = dv < 0
        return float(min(cap, float(np.minimum.reduce(-v[neg] / dv[neg], initial=np.inf))))
