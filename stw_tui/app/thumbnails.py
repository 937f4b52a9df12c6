"""Stick-figure thumbnails in Braille characters (pure functions, no Textual).

A Braille character is a 2 x 4 grid of dots (U+2800 + one bit per dot), so a thumbnail of
``width`` x ``height`` characters is a ``2*width`` x ``4*height`` dot canvas. The frames of a
strip share one scale, so a figure that travels or grows between frames is seen to do so.
"""

from __future__ import annotations

from collections.abc import Sequence

BRAILLE = 0x2800
# Bit of the dot at (column, row) of one character (Unicode's numbering: 1-2-3 down the left
# column, 4-5-6 down the right, then 7 and 8 on the bottom row).
DOT_BITS = ((0x01, 0x02, 0x04, 0x40), (0x08, 0x10, 0x20, 0x80))

Point = tuple[float, float]


def bounds_of(frames: Sequence) -> tuple[float, float, float, float]:
    """(xmin, xmax, ymin, ymax) over every segment and point of ``frames`` (Figure objects)."""
    boxes = [frame.bounds() for frame in frames]
    return (min(b[0] for b in boxes), max(b[1] for b in boxes),
            min(b[2] for b in boxes), max(b[3] for b in boxes))


def _line(x0: int, y0: int, x1: int, y1: int):
    """The dots of a straight line from (x0, y0) to (x1, y1), both ends included (Bresenham)."""
    dx, dy = abs(x1 - x0), -abs(y1 - y0)
    sx, sy = (1 if x0 < x1 else -1), (1 if y0 < y1 else -1)
    err = dx + dy
    while True:
        yield x0, y0
        if x0 == x1 and y0 == y1:
            return
        e2 = 2 * err
        if e2 >= dy:
            err += dy
            x0 += sx
        if e2 <= dx:
            err += dx
            y0 += sy


def render(frame, width: int, height: int, box: tuple[float, float, float, float]) -> list[str]:
    """``frame`` (segments and points, y up) drawn into ``height`` lines of ``width`` Braille
    characters, ``box`` mapped onto the canvas with equal scales on x and y, centred."""
    cols, rows = 2 * width, 4 * height
    xmin, xmax, ymin, ymax = box
    # Braille dots are as far apart across as down, so one scale serves both axes.
    scale = min((cols - 1) / max(xmax - xmin, 1e-12), (rows - 1) / max(ymax - ymin, 1e-12))
    x_pad = ((cols - 1) - (xmax - xmin) * scale) / 2
    y_pad = ((rows - 1) - (ymax - ymin) * scale) / 2

    def dot(p: Point) -> tuple[int, int]:
        return (round(x_pad + (p[0] - xmin) * scale), round((rows - 1) - y_pad - (p[1] - ymin) * scale))

    bits = [[0] * width for _ in range(height)]

    def plot(x: int, y: int) -> None:
        if 0 <= x < cols and 0 <= y < rows:
            bits[y // 4][x // 2] |= DOT_BITS[x % 2][y % 4]

    for start, end in frame.segments:
        for x, y in _line(*dot(start), *dot(end)):
            plot(x, y)
    for _, p in frame.points:
        plot(*dot(p))
    return ["".join(chr(BRAILLE + b) for b in row) for row in bits]


def strip(frames: Sequence, width: int = 5, height: int = 2) -> str:
    """The frames side by side, one space apart, on a common scale: ``height`` lines of text."""
    if not frames:
        return ""
    box = bounds_of(frames)
    drawn = [render(frame, width, height, box) for frame in frames]
    return "\n".join(" ".join(lines[row] for lines in drawn) for row in range(height))


def has_geometry(frames: Sequence) -> bool:
    """Whether the frames hold anything to draw (a scene without a linkage or a point has none)."""
    return any(frame.segments or frame.points for frame in frames)


def curves(values: Sequence[Sequence[float]], width: int, height: int) -> str:
    """Each row of ``values`` (one DOF's samples over time) as a line across the whole thumbnail,
    all on one value scale and stretched over the width: the motion when there is no figure."""
    from stw_tui.session.figure import Figure   # here: importing the app must not load sympy/scipy

    rows = [list(map(float, row)) for row in values if len(row) > 1]
    if not rows:
        return ""
    low = min(min(row) for row in rows)
    high = max(max(row) for row in rows)
    cols, dots_high = 2 * width - 1, 4 * height - 1
    scale = dots_high / (high - low) if high > low else 0.0
    segments = []
    for row in rows:
        xs = [k * cols / (len(row) - 1) for k in range(len(row))]
        ys = [(v - low) * scale if scale else dots_high / 2 for v in row]
        segments += list(zip(zip(xs, ys), zip(xs[1:], ys[1:])))
    return "\n".join(render(Figure(0.0, segments), width, height, (0.0, cols, 0.0, dots_high)))
