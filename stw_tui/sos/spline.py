"""DOF curves: cubic B-splines with their own clamped knot vectors.

Values, velocities and accelerations at any times are linear in the control points, ``X = B S``,
``Ẋ = B' S``, ``Ẍ = B'' S``, with sparse basis matrices (at most four nonzeros a row). The
derivative bases are the lower-degree design matrices times the sparse B-spline differentiation
matrix, so every matrix comes from one design matrix (``BSpline.design_matrix``'s, computed by
bspline_kernel without importing scipy.interpolate). Fitting and knot insertion (user tools)
are bspline_kernel's too: scipy's arithmetic, bit for bit, without its 0.3 s of imports.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from typing import Callable, Sequence

import numpy as np
import scipy.sparse as sps
import scipy.sparse.linalg as spla

from stw_tui.sos import bspline_kernel

DEGREE = 3
# Times this far outside [t0, t1] are rounding noise (e.g. t0 + k*dt sums) and get clamped.
_TIME_SLACK = 1e-12


def times_checker(times) -> Callable[["DofCurve"], np.ndarray]:
    """``curve.checked_times(times)`` for the curves of a term's variables, checked once per time
    span (every curve of a scene has the scene's): the dense check and a window build evaluate
    several variables at the same times, thousands of times."""
    checked: dict[tuple[float, float], np.ndarray] = {}

    def for_curve(curve: "DofCurve") -> np.ndarray:
        span = (curve.t0, curve.t1)
        if span not in checked:
            checked[span] = curve.checked_times(times)
        return checked[span]
    return for_curve


class SharedTimes:
    """Curves evaluated at parts of one array of times, the B-spline basis found once per knot
    vector and derivative order for all the parts.

    The dense check evaluates every relation of a scene at times of its own; on the
    concatenation of them all, each basis and each curve's values are found once for all the
    relations (acrobat's check: 18 basis evaluations and 60 combinations with control points,
    against 121 and 452 one relation at a time), with the same numbers: a curve's value at a
    time depends on that time alone. ``keep``: whether the bases are kept for the next caller
    (:func:`_kept_nonzero_basis`); not for times asked for once (the check's zoom on peaks).
    """

    def __init__(self, times, keep: bool = True):
        self.times = np.asarray(times, dtype=float)
        self.keep = keep
        self._checked = times_checker(self.times)
        self._bases: dict[tuple[bytes, int], tuple[np.ndarray, np.ndarray]] = {}
        self._values: dict[tuple[int, int], np.ndarray] = {}

    def values(self, curve: "DofCurve", order: int, part: slice) -> np.ndarray:
        """The curve's ``order``-th derivative at ``times[part]`` (a view: read-only use)."""
        found = self._values.get((id(curve), order))
        if found is None:
            # at every time at once: the relations of a linkage use most of its curves
            found = bspline_kernel.combine(curve.coef, *self._basis(curve, order))
            self._values[(id(curve), order)] = found
        return found[part]

    def _basis(self, curve: "DofCurve", order: int) -> tuple[np.ndarray, np.ndarray]:
        knots = curve.knots.tobytes()
        found = self._bases.get((knots, order))
        if found is None:
            basis = _kept_nonzero_basis if self.keep else _nonzero_basis
            found = self._bases[(knots, order)] = basis(knots, self._checked(curve).tobytes(), order)
        return found


def clamped_uniform_knots(t0: float, t1: float, spans: int) -> np.ndarray:
    """Clamped knot vector with ``spans`` equal intervals on [t0, t1] (end knots repeated 4 times).

    Raises:
        ValueError: spans < 1 or t1 <= t0.
    """
    if int(spans) < 1 or not t1 > t0:
        raise ValueError(f"need spans >= 1 and t1 > t0, got spans={spans}, [{t0}, {t1}]")
    inner = np.linspace(t0, t1, int(spans) + 1)
    return np.concatenate([[t0] * DEGREE, inner, [t1] * DEGREE]).astype(float)


def _difference_matrix(knots: np.ndarray, degree: int) -> sps.csr_array:
    """D with (D @ c) = coefficients of the derivative spline (degree-1, knots[1:-1])."""
    n = len(knots) - degree - 1
    width = knots[degree + 1:degree + n] - knots[1:n]
    # A zero-width support belongs to an identically zero basis function (repeated knots): drop it.
    scale = np.divide(degree, width, out=np.zeros_like(width), where=width > 0)
    rows = np.arange(n - 1)
    data = np.concatenate([-scale, scale])
    return sps.csr_array((data, (np.concatenate([rows, rows]), np.concatenate([rows, rows + 1]))),
                         shape=(n - 1, n))


def gauss_legendre_nodes(breakpoints: np.ndarray, points_per_span: int, a: float, b: float
                         ) -> tuple[np.ndarray, np.ndarray]:
    """Composite Gauss–Legendre rule on [a, b], split at the breakpoints inside (a, b).

    Piecewise polynomials of degree <= 2*points_per_span - 1 on those pieces integrate exactly.

    Args:
        breakpoints: where the integrand's polynomial pieces change (e.g. unique knots).
        points_per_span: Gauss points in each piece.
        a, b: the interval; a == b gives an empty rule.
    Returns:
        (times, weights), both 1-D and sorted by time; ``weights @ f(times)`` ≈ ∫_a^b f.
    Raises:
        ValueError: points_per_span < 1 or b < a.
    """
    if int(points_per_span) < 1 or b < a:
        raise ValueError(f"need points_per_span >= 1 and a <= b, got {points_per_span}, [{a}, {b}]")
    if a == b:
        return np.zeros(0), np.zeros(0)
    breakpoints = np.asarray(breakpoints, dtype=float)
    cuts = np.unique(np.concatenate([[a, b], breakpoints[(breakpoints > a) & (breakpoints < b)]]))
    x, w = _legendre_rule(int(points_per_span))
    lo, hi = cuts[:-1, None], cuts[1:, None]
    half = (hi - lo) / 2
    times = (lo + hi) / 2 + half * x[None, :]
    weights = half * w[None, :]
    return times.ravel(), weights.ravel()


# Kept by (knots, times, order): every `iterate` builds its window anew, and most of its terms
# ask for the same DOF at the same instances (a linkage session's window build asked for ~800
# bases, ~100 of them distinct).
@lru_cache(maxsize=256)
def _kept_basis(knots: bytes, times: bytes, order: int) -> sps.csr_array:
    """DofCurve.basis of the curves on these knots (float64 bytes), read-only: it is shared by
    every caller."""
    knots_, times_, degree = np.frombuffer(knots), np.frombuffer(times), DEGREE
    chain = None
    for _ in range(order):  # at most two sparse factors, not a loop over points
        D = _difference_matrix(knots_, degree)
        chain = D if chain is None else D @ chain
        knots_, degree = knots_[1:-1], degree - 1
    M = bspline_kernel.design_matrix(times_, knots_, degree)
    M = M if chain is None else sps.csr_array(M @ chain)
    for part in (M.data, M.indices, M.indptr):
        part.flags.writeable = False
    return M


def _nonzero_basis(knots: bytes, times: bytes, order: int) -> tuple[np.ndarray, np.ndarray]:
    """bspline_kernel.nonzero_basis of the curves on these knots at these times (float64 bytes)
    and the control points each value multiplies (bspline_kernel.columns), read-only."""
    h, ell = bspline_kernel.nonzero_basis(np.frombuffer(knots), np.frombuffer(times), DEGREE, order)
    at = bspline_kernel.columns(ell, DEGREE)
    h.flags.writeable = at.flags.writeable = False
    return h, at


# Kept as _kept_basis is: the dense check evaluates its grids, and the plots their curves, at
# the same times check after check, and the recursion costs some 50 us, ten times the sum over
# its four terms on a few hundred times.
_kept_nonzero_basis = lru_cache(maxsize=512)(_nonzero_basis)


@lru_cache(maxsize=16)
def _legendre_rule(points: int) -> tuple[np.ndarray, np.ndarray]:
    """Gauss–Legendre nodes and weights on [-1, 1], read-only (leggauss solves an eigenproblem
    each call, and every objective of every window build asks)."""
    return tuple(_readonly(a) for a in np.polynomial.legendre.leggauss(points))


def _readonly(a: np.ndarray) -> np.ndarray:
    a = np.array(a, dtype=float)  # a private copy: callers' arrays can't alias the curve
    a.flags.writeable = False
    return a


@dataclass(frozen=True, eq=False)
class DofCurve:
    """A cubic B-spline DOF curve. Immutable (read-only arrays): every modifier returns a new curve.

    Attributes:
        knots: full clamped knot vector, first and last knot repeated 4 times.
        coef: control points, ``len(knots) - 4`` of them.
    """

    knots: np.ndarray
    coef: np.ndarray

    def __post_init__(self) -> None:
        knots, coef = _readonly(self.knots), _readonly(self.coef)
        if knots.ndim != 1 or knots.size < 2 * (DEGREE + 1) or np.any(np.diff(knots) < 0):
            raise ValueError("knots must be a nondecreasing 1-D array of at least 8 entries")
        if np.any(knots[:DEGREE + 1] != knots[0]) or np.any(knots[-DEGREE - 1:] != knots[-1]):
            raise ValueError("knots must be clamped (first and last knot repeated 4 times)")
        if not knots[-1] > knots[0]:
            raise ValueError("knots must span a nonempty time interval")
        if coef.shape != (knots.size - DEGREE - 1,):
            raise ValueError(f"expected {knots.size - DEGREE - 1} control points, got shape {coef.shape}")
        object.__setattr__(self, "knots", knots)
        object.__setattr__(self, "coef", coef)

    # --- construction ------------------------------------------------------------------------
    @classmethod
    def uniform(cls, t0: float, t1: float, spans: int, value: float = 0.0) -> "DofCurve":
        """A constant curve on clamped uniform knots.

        Args:
            t0, t1: time interval.
            spans: number of knot intervals (>= 1).
            value: the constant.
        Raises:
            ValueError: spans < 1 or t1 <= t0.
        """
        knots = clamped_uniform_knots(t0, t1, spans)
        return cls(knots, np.full(len(knots) - DEGREE - 1, float(value)))

    @classmethod
    def fit(cls, t0: float, t1: float, spans: int, f: Callable[[np.ndarray], np.ndarray]) -> "DofCurve":
        """Least-squares fit of ``f`` on clamped uniform knots (exact for cubics); see ``refit``."""
        return cls.uniform(t0, t1, spans).refit(f)

    def refit(self, f: Callable[[np.ndarray], np.ndarray]) -> "DofCurve":
        """Same knots, least-squares fit to ``f``.

        Samples at 6 Gauss points a span weighted by the Gauss weights approximate the L2
        projection (exact for f in the spline space, e.g. any cubic); the two end points join
        with a small weight so the fitted end values track f(t0), f(t1).

        Args:
            f: vectorized function of a 1-D time array (a scalar result is broadcast).
        Returns:
            The fitted curve.
        """
        times, weights = gauss_legendre_nodes(self.breakpoints, 6, self.t0, self.t1)
        times = np.concatenate([[self.t0], times, [self.t1]])
        weights = np.concatenate([[1e-3], weights, [1e-3]])
        values = np.broadcast_to(np.asarray(f(times), dtype=float), times.shape)
        # Σ (w_j (y_j - s(x_j)))² by banded normal equations (make_lsq_spline's "norm-eq"; its
        # QR differs by ~1e-14 relative and needs scipy.interpolate, 0.3 s to import). The change
        # from the start value is fitted: B-splines sum to one, so a constant comes out exact,
        # not within rounding of itself (a pose the session states, e.g. -pi/2).
        start = values[0]
        change = bspline_kernel.least_squares(times, values - start, self.knots, DEGREE, np.sqrt(weights))
        return self.with_coef(change + start)

    def with_coef(self, coef: np.ndarray) -> "DofCurve":
        """The same knots with other control points.

        Raises:
            ValueError: wrong number of control points.
        """
        coef = _readonly(coef)
        if coef.shape != self.coef.shape:
            raise ValueError(f"expected {self.coef.size} control points, got shape {coef.shape}")
        # its knots were checked when this curve was made (the checks were 2% of a small solve)
        curve = object.__new__(DofCurve)
        object.__setattr__(curve, "knots", self.knots)
        object.__setattr__(curve, "coef", coef)
        return curve

    # --- properties --------------------------------------------------------------------------
    @property
    def degree(self) -> int:
        """The polynomial degree of the curve (cubic)."""
        return DEGREE

    @property
    def t0(self) -> float:
        """The time the curve starts (its first knot)."""
        return float(self.knots[0])

    @property
    def t1(self) -> float:
        """The time the curve ends (its last knot)."""
        return float(self.knots[-1])

    @property
    def n_coef(self) -> int:
        """The number of control points."""
        return self.coef.size

    @property
    def breakpoints(self) -> np.ndarray:
        """The unique knots, sorted."""
        return np.unique(self.knots)

    @property
    def spans(self) -> int:
        """Number of nonzero knot intervals."""
        return self.breakpoints.size - 1

    def support(self) -> np.ndarray:
        """(n_coef, 2) array: [knots[l], knots[l+4]], where control point l's basis is nonzero."""
        n = self.n_coef
        return np.column_stack([self.knots[:n], self.knots[DEGREE + 1:DEGREE + 1 + n]])

    def touching(self, a: float, b: float) -> np.ndarray:
        """(n_coef,) bool: the control points whose basis is nonzero somewhere inside (a, b), the
        ones a window over [a, b] frees."""
        support = self.support()
        return (support[:, 0] < b) & (support[:, 1] > a)

    def greville(self) -> np.ndarray:
        """The time each control point stands for: the mean of the DEGREE knots inside its
        support (Greville abscissae)."""
        n = self.n_coef
        return np.mean([self.knots[k:k + n] for k in range(1, DEGREE + 1)], axis=0)

    def span_width(self) -> float:
        """The largest knot interval (a safe one-span window margin on non-uniform knots)."""
        return float(np.diff(self.breakpoints).max())

    # --- evaluation --------------------------------------------------------------------------
    def checked_times(self, times) -> np.ndarray:
        """``times`` as a 1-D float array clamped to [t0, t1] (:meth:`values_at` takes these).

        Raises:
            ValueError: not 1-D, or a time outside [t0, t1] beyond rounding (NaN included).
        """
        times = np.atleast_1d(np.asarray(times, dtype=float))
        if times.ndim != 1:
            raise ValueError("times must be a scalar or a 1-D array")
        if times.size and not (times.min() >= self.t0 - _TIME_SLACK and times.max() <= self.t1 + _TIME_SLACK):
            raise ValueError(f"times must lie in [{self.t0:g}, {self.t1:g}]")
        return np.clip(times, self.t0, self.t1)

    def basis(self, times: np.ndarray, order: int = 0) -> sps.csr_array:
        """Sparse matrix M with M @ coef = the order-th time derivative at ``times``.

        Args:
            times: 1-D times in [t0, t1] (both ends closed).
            order: 0 (value), 1 (velocity) or 2 (acceleration).
        Returns:
            csr_array of shape (len(times), n_coef), at most 4 nonzeros a row.
        Raises:
            ValueError: a time outside [t0, t1] (NaN included) or another order.
        """
        if order not in (0, 1, 2):
            raise ValueError(f"derivative order must be 0, 1 or 2, not {order}")
        return self.basis_at(self.checked_times(times), order)

    def basis_at(self, times: np.ndarray, order: int) -> sps.csr_array:
        """:meth:`basis` at times already checked (:meth:`checked_times`): a term's variables
        share their times, and a window build asked for some 13000 checks of the same arrays."""
        if times.size == 0:  # nothing to look up
            return sps.csr_array((0, self.n_coef))
        return _kept_basis(self.knots.tobytes(), times.tobytes(), order)

    def evaluate(self, times, order: int = 0) -> np.ndarray:
        """Values (order 0) or derivatives (1, 2) at ``times``.

        Returns:
            1-D array, one entry per time.
        Raises:
            ValueError: as ``basis``.
        """
        if order not in (0, 1, 2):
            raise ValueError(f"derivative order must be 0, 1 or 2, not {order}")
        return self.values_at(self.checked_times(times), order)

    def values_at(self, times: np.ndarray, order: int) -> np.ndarray:
        """:meth:`evaluate` at times already checked (:meth:`checked_times`): several orders
        and curves at the same times check them once (the dense check, Scene.evaluator)."""
        if times.size == 0:
            return np.zeros(0)
        h, at = _kept_nonzero_basis(self.knots.tobytes(), times.tobytes(), order)
        return bspline_kernel.combine(self.coef, h, at)

    # --- user tools (paper 4.1, 4.2, 4.3) ----------------------------------------------------
    def refined(self, a: float, b: float, factor: int = 2) -> "DofCurve":
        """Split every knot span overlapping (a, b) into ``factor`` equal parts (Boehm insertion).

        The curve is unchanged (up to rounding); the knot vector becomes non-uniform.

        Args:
            a, b: the interval; a span [u, v] is split when u < b and v > a.
            factor: parts per split span (2 inserts the midpoints).
        Raises:
            ValueError: factor < 2 or b < a.
        """
        if int(factor) < 2 or b < a:
            raise ValueError(f"need factor >= 2 and a <= b, got factor={factor}, [{a}, {b}]")
        bp = self.breakpoints
        lo, hi = bp[:-1], bp[1:]
        slack = 1e-9 * (self.t1 - self.t0)   # a knot within rounding of a or b is a or b
        hit = (lo < b - slack) & (hi > a + slack)
        fractions = np.arange(1, int(factor)) / int(factor)
        new = np.sort((lo[hit, None] + (hi - lo)[hit, None] * fractions[None, :]).ravel())
        knots, coef = self.knots, self.coef
        for knot in new:  # one insertion per new knot; a user tool, not a hot path
            knots, coef = bspline_kernel.insert_knot(knots, coef, float(knot), DEGREE)
        return DofCurve(knots, coef)

    def with_knot(self, t: float, multiplicity: int = 1) -> "DofCurve":
        """The same curve with a knot at ``t`` repeated ``multiplicity`` times in all (Boehm
        insertion). Knots already within rounding of ``t`` count toward it (and ``t`` snaps to
        them). A knot of multiplicity 2 lets the acceleration jump there; 3, the velocity.

        Raises:
            ValueError: t outside (t0, t1) or multiplicity not in 1..3.
        """
        if not 1 <= int(multiplicity) <= DEGREE or not self.t0 < t < self.t1:
            raise ValueError(f"need t inside ({self.t0}, {self.t1}) and multiplicity 1..3, got {t}, {multiplicity}")
        near = np.abs(self.knots - t) <= 1e-12 * (self.t1 - self.t0)
        if near.any():
            t = float(self.knots[near][0])
        missing = int(multiplicity) - int(np.count_nonzero(self.knots == t))
        if missing <= 0:
            return self
        return DofCurve(*bspline_kernel.insert_knot(self.knots, self.coef, t, DEGREE, missing))

    def sketched(self, keys: Sequence[tuple[float, float]], smoothness: float = 1e-3,
                 anchor: float = 1e-9) -> "DofCurve":
        """Bend the curve smoothly through keyframes ("keyframe sketch", paper 4.1).

        Returns X + D where the displacement D minimizes
        Σ_k (D(t_k) - (v_k - X(t_k)))² + smoothness ∫D''² + anchor ∫D².
        With the default tiny ``anchor`` D is, to within the key residual, the minimal-curvature
        interpolant of the key offsets: a single key shifts the whole curve by a (near) constant,
        and beyond the outermost keys D continues linearly. A larger anchor makes the change
        local, decaying over a length of about (smoothness / anchor) ** 0.25.

        Args:
            keys: (time, value) pairs, times in [t0, t1].
            smoothness: weight of the bending energy (smaller: keys met more closely).
            anchor: weight pulling D toward 0 (> 0 keeps the system nonsingular).
        Returns:
            The sketched curve; ``self`` when there are no keys.
        Raises:
            ValueError: a key time outside [t0, t1], or smoothness < 0 or anchor <= 0.
        """
        if not len(keys):
            return self
        if smoothness < 0 or anchor <= 0:
            raise ValueError("need smoothness >= 0 and anchor > 0")
        keys = np.asarray(keys, dtype=float).reshape(-1, 2)
        target = keys[:, 1] - self.evaluate(keys[:, 0])
        K = self.basis(keys[:, 0])
        # 4 Gauss points a span integrate D''² and D² (degree <= 6 pieces) exactly.
        times, weights = gauss_legendre_nodes(self.breakpoints, 4, self.t0, self.t1)
        W = sps.diags_array(weights)
        B2, B0 = self.basis(times, 2), self.basis(times, 0)
        system = K.T @ K + smoothness * (B2.T @ W @ B2) + anchor * (B0.T @ W @ B0)
        delta = spla.spsolve(sps.csc_array(system), K.T @ target)
        return self.with_coef(self.coef + delta)

    def filtered(self, passes: int = 1) -> "DofCurve":
        """Smooth the control points with a (1, 2, 1)/4 filter, ``passes`` times.

        The first and last control points stay, so the end values X(t0), X(t1) are preserved.

        Raises:
            ValueError: passes < 0.
        """
        if passes < 0:
            raise ValueError(f"passes must be >= 0, not {passes}")
        c = self.coef.copy()
        for _ in range(int(passes)):  # each pass is one vectorized stencil
            c[1:-1] = (c[:-2] + 2 * c[1:-1] + c[2:]) / 4
        return self.with_coef(c)

    def shaken(self, amplitude: float, rng: np.random.Generator, moved: np.ndarray | None = None) -> "DofCurve":
        """Add ``amplitude * rng.standard_normal(n_coef)`` to the control points (seeded rng), or
        only to those where the boolean mask ``moved`` holds (the same draws, the rest left)."""
        noise = amplitude * rng.standard_normal(self.n_coef)
        return self.with_coef(self.coef + (noise if moved is None else np.where(moved, noise, 0.0)))
