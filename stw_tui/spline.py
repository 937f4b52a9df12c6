"""DOF curves: cubic B-splines with their own clamped knot vectors, built on scipy.interpolate.

Values, velocities and accelerations at any times are linear in the control points, ``X = B S``,
``Ẋ = B' S``, ``Ẍ = B'' S``, with sparse basis matrices (at most four nonzeros a row). The
derivative bases are the lower-degree design matrices times the sparse B-spline differentiation
matrix, so every matrix comes from ``BSpline.design_matrix`` in one vectorized call.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Sequence

import numpy as np
import scipy.sparse as sps
from scipy.interpolate import BSpline, insert

DEGREE = 3


def clamped_uniform_knots(t0: float, t1: float, spans: int) -> np.ndarray:
    inner = np.linspace(t0, t1, spans + 1)
    return np.concatenate([[t0] * DEGREE, inner, [t1] * DEGREE])


def _difference_matrix(knots: np.ndarray, degree: int) -> sps.csr_array:
    """D with (D @ c) = coefficients of the derivative spline (degree-1, knots[1:-1])."""
    n = len(knots) - degree - 1
    scale = degree / (knots[degree + 1:degree + n] - knots[1:n])
    rows = np.arange(n - 1)
    data = np.concatenate([-scale, scale])
    return sps.csr_array((data, (np.concatenate([rows, rows]), np.concatenate([rows, rows + 1]))),
                         shape=(n - 1, n))


def gauss_legendre_nodes(breakpoints: np.ndarray, points_per_span: int, a: float, b: float
                         ) -> tuple[np.ndarray, np.ndarray]:
    """Composite Gauss–Legendre rule on [a, b], split at the breakpoints inside it.

    Piecewise polynomials of degree <= 2*points_per_span - 1 on those pieces integrate exactly.
    Returns:
        (times, weights), both 1-D.
    """
    cuts = np.unique(np.concatenate([[a, b], breakpoints[(breakpoints > a) & (breakpoints < b)]]))
    x, w = np.polynomial.legendre.leggauss(int(points_per_span))
    lo, hi = cuts[:-1, None], cuts[1:, None]
    half = (hi - lo) / 2
    times = (lo + hi) / 2 + half * x[None, :]
    weights = half * w[None, :]
    return times.ravel(), weights.ravel()


@dataclass(frozen=True, eq=False)
class DofCurve:
    """A cubic B-spline DOF curve. Immutable: every modifier returns a new curve."""

    knots: np.ndarray
    coef: np.ndarray

    # --- construction ------------------------------------------------------------------------
    @classmethod
    def uniform(cls, t0: float, t1: float, spans: int, value: float = 0.0) -> "DofCurve":
        """A constant curve on clamped uniform knots (``spans`` knot intervals)."""
        knots = clamped_uniform_knots(t0, t1, spans)
        return cls(knots, np.full(len(knots) - DEGREE - 1, float(value)))

    @classmethod
    def fit(cls, t0: float, t1: float, spans: int, f: Callable[[np.ndarray], np.ndarray]) -> "DofCurve":
        """Least-squares fit of ``f`` on clamped uniform knots (exact for cubics)."""
        return cls.uniform(t0, t1, spans).refit(f)

    def refit(self, f: Callable[[np.ndarray], np.ndarray]) -> "DofCurve":
        """Same knots, least-squares fit to ``f`` sampled at Gauss points of every span."""
        times, weights = gauss_legendre_nodes(self.breakpoints, 6, self.t0, self.t1)
        times = np.concatenate([times, [self.t0, self.t1]])
        weights = np.concatenate([weights, [1e-3, 1e-3]])
        values = np.broadcast_to(np.asarray(f(times), dtype=float), times.shape)
        B = self.basis(times).toarray()
        sw = np.sqrt(weights)
        coef, *_ = np.linalg.lstsq(B * sw[:, None], values * sw, rcond=None)
        return self.with_coef(coef)

    def with_coef(self, coef: np.ndarray) -> "DofCurve":
        coef = np.asarray(coef, dtype=float)
        if coef.shape != self.coef.shape:
            raise ValueError(f"expected {self.coef.size} control points, got {coef.size}")
        return DofCurve(self.knots, coef)

    # --- properties --------------------------------------------------------------------------
    @property
    def degree(self) -> int:
        return DEGREE

    @property
    def t0(self) -> float:
        return float(self.knots[0])

    @property
    def t1(self) -> float:
        return float(self.knots[-1])

    @property
    def n_coef(self) -> int:
        return self.coef.size

    @property
    def breakpoints(self) -> np.ndarray:
        return np.unique(self.knots)

    @property
    def spans(self) -> int:
        return self.breakpoints.size - 1

    def support(self) -> np.ndarray:
        """(n_coef, 2) time interval where each control point's basis function is nonzero."""
        n = self.n_coef
        return np.column_stack([self.knots[:n], self.knots[DEGREE + 1:DEGREE + 1 + n]])

    def span_width(self) -> float:
        return float(np.diff(self.breakpoints).max())

    # --- evaluation --------------------------------------------------------------------------
    def basis(self, times: np.ndarray, order: int = 0) -> sps.csr_array:
        """Sparse (len(times), n_coef) matrix M with M @ coef = the order-th derivative at times.

        Raises:
            ValueError: a time outside [t0, t1] or an order other than 0, 1, 2.
        """
        times = np.atleast_1d(np.asarray(times, dtype=float))
        if order not in (0, 1, 2):
            raise ValueError(f"derivative order must be 0, 1 or 2, not {order}")
        if times.size and (times.min() < self.t0 - 1e-12 or times.max() > self.t1 + 1e-12):
            raise ValueError(f"times must lie in [{self.t0:g}, {self.t1:g}]")
        times = np.clip(times, self.t0, self.t1)
        knots, degree = self.knots, DEGREE
        chain = None
        for _ in range(order):
            D = _difference_matrix(knots, degree)
            chain = D if chain is None else D @ chain
            knots, degree = knots[1:-1], degree - 1
        M = BSpline.design_matrix(times, knots, degree)
        return sps.csr_array(M if chain is None else M @ chain)

    def evaluate(self, times, order: int = 0) -> np.ndarray:
        return BSpline(self.knots, self.coef, DEGREE, extrapolate=False)(
            np.clip(np.asarray(times, dtype=float), self.t0, self.t1), nu=order)

    # --- user tools (paper 4.1, 4.2, 4.3) ----------------------------------------------------
    def refined(self, a: float, b: float, factor: int = 2) -> "DofCurve":
        """Insert knots splitting every span that overlaps (a, b) into ``factor`` parts (Boehm).

        The curve is unchanged; the knot vector becomes non-uniform.
        """
        bp = self.breakpoints
        lo, hi = bp[:-1], bp[1:]
        hit = (lo < b) & (hi > a)
        new = np.concatenate([lo[hit] + (hi[hit] - lo[hit]) * j / factor for j in range(1, factor)])
        tck = (self.knots, np.concatenate([self.coef, np.zeros(DEGREE + 1)]), DEGREE)
        for knot in np.sort(new):
            tck = insert(knot, tck)
        knots = np.asarray(tck[0])
        return DofCurve(knots, np.asarray(tck[1])[:len(knots) - DEGREE - 1])

    def sketched(self, keys: Sequence[tuple[float, float]], smoothness: float = 1e-3) -> "DofCurve":
        """Bend the curve smoothly through keyframes ("sketching", paper 4.1).

        The displacement D = X_new - X minimizes Σ (D(t_k) - (v_k - X(t_k)))² + smoothness ∫D''²
        + 1e-9 ∫D², so keys are met closely and the change fades smoothly away from them.
        """
        if not keys:
            return self
        t_keys = np.array([k[0] for k in keys], dtype=float)
        target = np.array([k[1] for k in keys], dtype=float) - self.evaluate(t_keys)
        times, weights = gauss_legendre_nodes(self.breakpoints, 4, self.t0, self.t1)
        B2 = self.basis(times, 2).toarray()
        B0 = self.basis(times, 0).toarray()
        K = self.basis(t_keys, 0).toarray()
        system = K.T @ K + smoothness * (B2.T * weights) @ B2 + 1e-9 * (B0.T * weights) @ B0
        delta = np.linalg.solve(system, K.T @ target)
        return self.with_coef(self.coef + delta)

    def filtered(self, passes: int = 1) -> "DofCurve":
        """Smooth the control points with a (1, 2, 1)/4 filter; the end control points stay."""
        c = self.coef.copy()
        for _ in range(passes):
            c[1:-1] = (c[:-2] + 2 * c[1:-1] + c[2:]) / 4
        return self.with_coef(c)

    def shaken(self, amplitude: float, rng: np.random.Generator) -> "DofCurve":
        """Add seeded Gaussian noise of the given amplitude to every control point."""
        return self.with_coef(self.coef + amplitude * rng.standard_normal(self.n_coef))
