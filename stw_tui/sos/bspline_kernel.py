"""B-spline basis values by de Boor's recursion in numpy, operation for operation as scipy's.

scipy.interpolate computes design matrices and spline values with ``_deBoor_D`` (C++, in
``_dierckx``), one point at a time. Importing scipy.interpolate also imports scipy.optimize,
scipy.special, scipy.spatial and scipy.fft: some 0.3 s of a 1.1 s `stw run`, for three small
loops. Here the same recursion runs on all points at once, each level as whole-array operations
in the order the C code does them, so every value equals scipy's bit for bit (tests/
test_bspline_kernel.py checks it against scipy on random knots, times and orders). Least
squares fits and knot insertion are scipy's routines replayed the same way.

Why the C code's zero-width guard (``if (xb == xa)``) is not needed: the interval ``ell`` is the
last one with ``t[ell] <= x``, clipped to ``[k, n - 1]``, so ``t[ell] < t[ell + 1]`` on a knot
vector whose first and last spans are not empty (DofCurve's), and every ``xa <= t[ell] <
t[ell + 1] <= xb``.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np
import scipy.sparse as sps


def intervals(knots: np.ndarray, times: np.ndarray, degree: int) -> np.ndarray:
    """For each time, the index ``ell`` with ``knots[ell] <= t < knots[ell + 1]``, as scipy's
    ``_find_interval`` picks it: the last nonempty span for t at the right end, the first for t
    before the left end (counted among the knots between the clamped ends, so no clipping)."""
    inner = knots[degree + 1:knots.size - degree - 1]
    return np.searchsorted(inner, times, side="right") + degree


@lru_cache(maxsize=8)
def _offsets(degree: int) -> np.ndarray:
    """(2k, 1) offsets 1 - k .. k from ell of the knots de Boor's recursion reads."""
    offsets = np.arange(1 - degree, degree + 1)[:, None]
    offsets.flags.writeable = False
    return offsets


def nonzero_basis(knots: np.ndarray, times: np.ndarray, degree: int, nu: int = 0
                  ) -> tuple[np.ndarray, np.ndarray]:
    """The ``degree + 1`` basis functions (their ``nu``-th derivatives) nonzero at each time.

    Args:
        knots: nondecreasing knot vector, first and last spans nonempty.
        times: 1-D float64 times (outside the knots: the end polynomials continued).
        degree: the spline degree k.
        nu: derivative order, 0..k.
    Returns:
        (values, ell): values of shape (k + 1, len(times)), row a holding basis function
        ``ell - k + a`` at each time, and ell from :func:`intervals`.
    """
    k = degree
    ell = intervals(knots, times, k)
    # knots[ell + o] for o = 1 - k .. k, row o + k - 1: every knot the recursion reads.
    near = knots.take(ell + _offsets(k))
    before, after = times - near, near - times         # x - knots[ell + o], knots[ell + o] - x
    h = np.ones((1, times.size))
    for j in range(1, k + 1):
        xb, xa = near[k:k + j], near[k - j:k]          # knots[ell + n], knots[ell + n - j], n = 1..j
        if j <= k - nu:
            # C: h[n-1] += w*(xb - x); h[n] = w*(x - xa), w = hh[n-1]/(xb - xa), n = 1..j; so
            # h[0] = 0.0 + down[0] (exact), h[i] = up[i-1] + down[i], h[j] = up[j-1].
            w = h / (xb - xa)
            up, down = w * before[k - j:k], w * after[k:k + j]
            h = np.concatenate((down[:1], up[:-1] + down[1:], up[-1:]))
        else:
            # C: h[n-1] -= w; h[n] = w, w = j*hh[n-1]/(xb - xa); so h[0] = 0.0 - w[0] (exact),
            # h[i] = w[i-1] - w[i], h[j] = w[j-1].
            w = (j * h) / (xb - xa)
            h = np.concatenate((-w[:1], w[:-1] - w[1:], w[-1:]))
    return h, ell


def spline_values(knots: np.ndarray, coef: np.ndarray, times: np.ndarray, degree: int,
                  nu: int = 0) -> np.ndarray:
    """The spline's ``nu``-th derivative at ``times``, as ``BSpline(knots, coef, degree)(times,
    nu)`` gives it: the basis values times their control points, summed in the C code's order."""
    h, ell = nonzero_basis(knots, times, degree, nu)
    return combine(coef, h, columns(ell, degree))


def columns(ell: np.ndarray, degree: int) -> np.ndarray:
    """(k + 1, len(ell)): the control points ``ell - k + a`` that the rows a of
    :func:`nonzero_basis` multiply."""
    return (ell - degree) + np.arange(degree + 1)[:, None]


def combine(coef: np.ndarray, h: np.ndarray, at: np.ndarray) -> np.ndarray:
    """Σ_a coef[at[a]] h[a]: basis values (:func:`nonzero_basis`) times their control points
    (:func:`columns`), added from a = 0 up as scipy's ``_evaluate_spline`` adds them (its values,
    bit for bit)."""
    terms = coef[at]
    terms *= h
    out = terms[0] + terms[1] if h.shape[0] > 1 else terms[0].copy()
    for a in range(2, h.shape[0]):
        out += terms[a]
    return out


def design_matrix(times: np.ndarray, knots: np.ndarray, degree: int) -> sps.csr_array:
    """``BSpline.design_matrix(times, knots, degree)``: the (len(times), n) basis matrix, with
    all ``degree + 1`` entries of a row stored, zeros included, as scipy stores them."""
    h, ell = nonzero_basis(knots, times, degree)
    index = np.int32 if times.size * (degree + 1) < np.iinfo(np.int32).max else np.int64
    rows = np.arange(0, (times.size + 1) * (degree + 1), degree + 1, dtype=index)
    return sps.csr_array((h.T.ravel(), columns(ell, degree).T.ravel().astype(index), rows),
                         shape=(times.size, knots.size - degree - 1))


def least_squares(times: np.ndarray, values: np.ndarray, knots: np.ndarray, degree: int,
                  w: np.ndarray) -> np.ndarray:
    """The control points of ``make_lsq_spline(times, values, knots, degree, w=w,
    method="norm-eq")``: minimize Σ (w_j (values_j - s(times_j)))² through the banded normal
    equations, accumulated point by point in scipy's order (``_norm_eq_lsq``) and solved by
    banded Cholesky, as scipy solves them.

    Args:
        times: nondecreasing 1-D times inside the knots; values and w: one per time.
    Raises:
        numpy.linalg.LinAlgError: the normal matrix is not positive definite (too few times in
            some basis function's support).
    """
    from scipy.linalg import cho_solve_banded, cholesky_banded   # loaded with scipy.sparse.linalg

    k, n = degree, knots.size - degree - 1
    h, ell = nonzero_basis(knots, times, k)
    weight = w * w
    # Entry (r, s), s <= r, of point j adds h[r] h[s] w_j² at band r - s of column ell - k + s.
    r, s = np.tril_indices(k + 1)
    band = np.zeros((k + 1, n))
    at = columns(ell, k).T                            # (points, k + 1)
    np.add.at(band, ((r - s)[None, :], at[:, s]),
              (h[r].T * h[s].T) * weight[:, None])     # added point after point, as scipy adds
    rhs = np.zeros(n)
    np.add.at(rhs, at, (h.T * values[:, None]) * weight[:, None])
    return cho_solve_banded((cholesky_banded(band, lower=True), True), rhs)


def insert_knot(knots: np.ndarray, coef: np.ndarray, x: float, degree: int,
                times: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """The same spline with the knot ``x`` inserted ``times`` times (Boehm insertion): what
    scipy.interpolate.insert gives, bit for bit, without importing scipy.interpolate.

    FITPACK's ``insert``/``fpinst``, one insertion at a time: the interval ``l`` with
    ``t[l] <= x < t[l + 1]``, then for
    ``i = l, l - 1, ..., l - degree + 1``: ``fac = (x - tt[i]) / (tt[i + degree + 1] - tt[i])``
    over the new knots ``tt`` and ``c'[i] = fac * c[i] + (1 - fac) * c[i - 1]``; the
    coefficients before are kept, those after move up one place.

    Raises:
        ValueError: ``x`` not strictly inside the curve's span (a knot there would add nothing).
    """
    knots, coef = np.asarray(knots, float), np.asarray(coef, float)
    k = degree
    for _ in range(int(times)):
        n = knots.size
        if not knots[k] < x < knots[n - k - 1]:
            raise ValueError(f"knot {x} not inside the spline's span ({knots[k]}, {knots[n - k - 1]})")
        ell = int(np.searchsorted(knots, x, side="right")) - 1
        new_knots = np.concatenate([knots[:ell + 1], [x], knots[ell + 1:]])
        n_coef = n - k - 1
        new_coef = np.empty(n_coef + 1)
        new_coef[ell + 1:] = coef[ell:n_coef]
        i = np.arange(ell - k + 1, ell + 1)
        fac = (x - new_knots[i]) / (new_knots[i + k + 1] - new_knots[i])
        new_coef[i] = fac * coef[i] + (1.0 - fac) * coef[i - 1]
        new_coef[:ell - k + 1] = coef[:ell - k + 1]
        knots, coef = new_knots, new_coef
    return knots, coef
