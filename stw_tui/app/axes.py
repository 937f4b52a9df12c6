"""Plot axes and titles that read well in a terminal (pure functions, no Textual).

plotext puts its ticks at evenly spaced raw values (labels such as 0.33, -0.32, 0.63) and, for
a constant series, zooms into the floating-point noise (labels 20 digits wide). These helpers
choose round ticks (1, 2, 2.5, 5 × 10^k), give a constant series a sensible range, and pick the
longest title that fits the plot (plotext drops a title that does not fit instead of cutting it).
"""

from __future__ import annotations

import math
from typing import Iterable, Sequence

STEPS = (1.0, 2.0, 2.5, 5.0, 10.0)


def value_limits(values: Iterable[float]) -> tuple[float, float]:
    """The range to plot ``values`` over: their extent, or around the value when it is constant
    (relative spread below 1e-9: noise, not signal). Non-finite values are ignored."""
    finite = [v for v in values if math.isfinite(v)]
    if not finite:
        return -1.0, 1.0
    lo, hi = min(finite), max(finite)
    middle = 0.5 * (lo + hi)
    if hi - lo <= 1e-9 * max(1.0, abs(middle)):
        pad = 0.5 * max(abs(middle), 1.0)
        return middle - pad, middle + pad
    return lo, hi


def nice_step(span: float, count: int) -> float:
    """A round step (1, 2, 2.5 or 5 × 10^k) giving about ``count`` ticks over ``span``."""
    raw = span / max(count - 1, 1)
    power = 10.0 ** math.floor(math.log10(raw))
    return next(m * power for m in STEPS if m * power >= raw * (1 - 1e-9))


def tick_label(value: float, step: float) -> str:
    """``value`` with the decimals that ``step`` needs (and no '-0')."""
    if abs(value) < step * 1e-6:
        value = 0.0
    big = max(abs(value), step)
    if big >= 1e5 or step < 1e-4:
        return f"{value:.3g}"
    decimals = max(0, -math.floor(math.log10(step) + 1e-9))
    if round(step / 10.0 ** -decimals, 6) % 1:   # 2.5 × 10^k needs one more
        decimals += 1
    return f"{value:.{decimals}f}".replace("-0.", "0.") if value == 0 else f"{value:.{decimals}f}"


def nice_ticks(lo: float, hi: float, count: int = 5, integer: bool = False) -> tuple[list[float], list[str]]:
    """Round ticks inside [lo, hi] (about ``count``; whole numbers only when ``integer``), with
    their labels."""
    if not (math.isfinite(lo) and math.isfinite(hi)) or hi <= lo:
        return [], []
    step = nice_step(hi - lo, max(count, 2))
    if integer:
        step = max(1.0, round(step) if step != 2.5 else 2.0)
    first = math.ceil(lo / step - 1e-9)
    ticks = []
    k = first
    while k * step <= hi + step * 1e-9:
        ticks.append(k * step)
        k += 1
    return ticks, [tick_label(t, step) for t in ticks]


def title_room(width: int, label_width: int) -> int:
    """Characters a plotext title can have on a plot ``width`` cells wide whose y labels are
    ``label_width`` wide: it is centred on the canvas and dropped unless it fits entirely."""
    canvas_start = label_width + 1
    centre = canvas_start + (width - canvas_start - 1) // 2
    return max(0, 2 * (width - 2 - centre))


def fit_title(variants: Sequence[str], room: int) -> str:
    """The first of ``variants`` (most detailed first) that fits ``room``; else the last, cut."""
    for title in variants:
        if len(title) <= room:
            return title
    last = variants[-1] if variants else ""
    return last[:max(room - 1, 0)] + "…" if room > 1 else ""
