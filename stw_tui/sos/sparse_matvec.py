"""Sparse matrix-vector products without scipy's per-call dispatch.

``A @ x`` on a scipy sparse array checks for scalars, shapes and dtypes in Python before it
calls the compiled kernel (``csr_matvec`` / ``csc_matvec``); on the few-hundred-row systems of a
window problem those checks cost several times the product itself, and the interior-point method
makes thousands of such products per solve. :func:`matvec` calls the same kernel directly, so the
result is bitwise ``A @ x``; anything but a float64 CSR/CSC array times a float64 vector (or a
scipy without the kernel) takes the ordinary route.
"""

from __future__ import annotations

import numpy as np

try:   # the kernels scipy's own products call (private, stable since scipy 0.x; guarded anyway)
    from scipy.sparse._sparsetools import csc_matvec, csr_matvec
    _KERNELS = {"csr": csr_matvec, "csc": csc_matvec}
except ImportError:   # pragma: no cover - a scipy that moved them: the public route
    _KERNELS = {}


def matvec(m, x: np.ndarray) -> np.ndarray:
    """``m @ x``, bitwise, for a scipy sparse array ``m`` and a 1-D vector ``x``."""
    kernel = _KERNELS.get(getattr(m, "format", None))
    if (kernel is None or x.__class__ is not np.ndarray or x.ndim != 1 or x.dtype != np.float64
            or m.dtype != np.float64 or m.ndim != 2 or x.shape[0] != m.shape[1]):
        return m @ x
    out = np.zeros(m.shape[0])
    kernel(m.shape[0], m.shape[1], m.indptr, m.indices, m.data, x, out)
    return out
