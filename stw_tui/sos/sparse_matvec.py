"""Sparse matrix-vector products without scipy's per-call dispatch.

``A @ x`` on a scipy sparse array checks for scalars, shapes and dtypes in Python before it
calls the compiled kernel (``csr_matvec`` / ``csc_matvec``); on the few-hundred-row systems of a
window problem those checks cost several times the product itself, and the interior-point method
makes thousands of such products per solve. :func:`matvec` calls the same kernel directly, so the
result is bitwise ``A @ x``; anything but a float64 CSR/CSC array times a float64 vector (or a
scipy without the kernel) takes the ordinary route.

A CSR product of at least PARALLEL_NNZ entries, in rows of SPLIT_ROW_NNZ or more on average, is
split into row ranges of about equal entries, one per core, the kernel run on each at once (it
releases the GIL): each row is still one sequential sum, so the result is the same, bit for bit.
The torch backend's Hessian of basketball is a 4.7-million-entry product: 2.9 ms on one core,
1.6 ms on two.
"""

from __future__ import annotations

import os
from concurrent.futures import ThreadPoolExecutor

import numpy as np
import scipy.sparse as sps

try:   # the kernels scipy's own products call (private, stable since scipy 0.x; guarded anyway)
    from scipy.sparse._sparsetools import csc_matvec, csr_matvec
    _KERNELS = {"csr": csr_matvec, "csc": csc_matvec}
except ImportError:   # pragma: no cover - a scipy that moved them: the public route
    _KERNELS = {}
_FLOAT64 = np.dtype(np.float64)
# the classes whose products take the kernels (scipy's sparse arrays and matrices keep ``_shape``)
_PROBES = [cls((1, 1)) for cls in (sps.csr_array, sps.csr_matrix, sps.csc_array, sps.csc_matrix)]
_BY_CLASS = {probe.__class__: _KERNELS[probe.format] for probe in _PROBES
             if probe.format in _KERNELS and getattr(probe, "_shape", None) == (1, 1)}


def matvec(m, x: np.ndarray) -> np.ndarray:
    """``m @ x``, bitwise, for a scipy sparse array ``m`` and a 1-D vector ``x``."""
    # By class and stored arrays, not scipy's format/dtype/shape properties: an SQP step makes
    # a dozen products, and those Python-level properties were most of each one's checks.
    kernel = _BY_CLASS.get(m.__class__)
    if (kernel is None or x.__class__ is not np.ndarray or x.ndim != 1 or x.dtype != _FLOAT64
            or m.data.dtype != _FLOAT64 or len(m._shape) != 2 or x.shape[0] != m._shape[1]):
        return m @ x
    rows, cols = m._shape
    out = np.zeros(rows)
    nnz = m.indptr[-1]
    parts = _PARTS if kernel is _KERNELS["csr"] and nnz >= PARALLEL_NNZ and nnz >= SPLIT_ROW_NNZ * rows else 1
    if parts == 1:
        kernel(rows, cols, m.indptr, m.indices, m.data, x, out)
        return out
    # Row ranges by entries; each range's slice of indptr indexes the whole indices and data
    # (the kernel reads entries Ap[i]..Ap[i+1] of them), so nothing is copied.
    bounds = [0, *np.searchsorted(m.indptr, m.indptr[-1] * np.arange(1, parts) / parts), m.shape[0]]
    ranges = [(lo, hi) for lo, hi in zip(bounds[:-1], bounds[1:]) if hi > lo]

    def run(lo, hi):
        kernel(hi - lo, m.shape[1], m.indptr[lo:hi + 1], m.indices, m.data, x, out[lo:hi])
    waiting = [_pool().submit(run, lo, hi) for lo, hi in ranges[1:]]
    run(*ranges[0])
    for job in waiting:
        job.result()
    return out


PARALLEL_NNZ = 600_000   # entries from which a CSR product is split over the cores (handing a
                         # range to a thread costs ~0.1 ms on these VMs: split / whole on 2 cores
                         # is 1.35 at 200k entries, 1.0 at 400k, 0.8 at 800k, 0.53 at 1.6M), when its
SPLIT_ROW_NNZ = 8        # rows hold this many on average: a long output of short rows (a basis
                         # matrix's 260k rows of 1.5) costs more split (page faults contend)


def _cores() -> int:
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:   # pragma: no cover - not on Linux
        return os.cpu_count() or 1


_PARTS = min(_cores(), 4)   # the split's ranges: more than 4 gain nothing on a product this size
_POOL: tuple[int, ThreadPoolExecutor] | None = None


def _pool() -> ThreadPoolExecutor:
    """The split's worker threads, made on first use in this process (a forked child, such as
    a survey's worker process, has none of its parent's threads: it makes its own)."""
    global _POOL
    if _POOL is None or _POOL[0] != os.getpid():
        _POOL = (os.getpid(), ThreadPoolExecutor(max_workers=_PARTS - 1, thread_name_prefix="stw-matvec"))
    return _POOL[1]
