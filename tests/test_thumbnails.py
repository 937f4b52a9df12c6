"""Braille thumbnails of stick figures (stw_tui/app/thumbnails.py), checked dot by dot."""

from stw_tui.app.thumbnails import DOT_BITS, render, strip
from stw_tui.session.figure import Figure

BRAILLE = 0x2800


def _dots(lines: list[str]) -> set[tuple[int, int]]:
    """The (x, y) dots set in ``lines`` (y down), decoded independently of the renderer's table:
    Unicode numbers dots 1-2-3 and 7 down the left column, 4-5-6 and 8 down the right."""
    left, right = (1, 2, 3, 7), (4, 5, 6, 8)
    found = set()
    for row, line in enumerate(lines):
        for col, ch in enumerate(line):
            bits = ord(ch) - BRAILLE
            assert 0 <= bits < 256, ch
            for side, numbers in enumerate((left, right)):
                for k, n in enumerate(numbers):
                    if bits & (1 << (n - 1)):
                        found.add((2 * col + side, 4 * row + k))
    return found


def test_the_bit_table_is_unicodes_dot_numbering():
    assert [DOT_BITS[0][k] for k in range(4)] == [1 << 0, 1 << 1, 1 << 2, 1 << 6]
    assert [DOT_BITS[1][k] for k in range(4)] == [1 << 3, 1 << 4, 1 << 5, 1 << 7]


def test_a_standing_rod_fills_one_column_and_a_lying_one_the_bottom_row():
    standing = Figure(0.0, segments=[((0.0, 0.0), (0.0, 1.0))])
    lines = render(standing, 2, 1, standing.bounds())
    assert _dots(lines) == {(2, y) for y in range(4)}          # centred: 1.5 dots rounds to 2
    lying = Figure(0.0, segments=[((0.0, 0.0), (3.0, 0.0))])
    dots = _dots(render(lying, 2, 1, lying.bounds()))
    assert {x for x, _ in dots} == {0, 1, 2, 3} and len({y for _, y in dots}) == 1


def test_a_diagonal_goes_from_bottom_left_to_top_right():
    diagonal = Figure(0.0, segments=[((0.0, 0.0), (1.0, 1.0))])
    dots = _dots(render(diagonal, 2, 1, diagonal.bounds()))
    assert (min(x for x, _ in dots), max(y for _, y in dots)) in dots       # bottom left (y down)
    assert (max(x for x, _ in dots), min(y for _, y in dots)) in dots       # top right
    assert len(dots) == 4                                                   # 4 x 4 dots: one per row


def test_a_strip_shares_one_scale_so_a_moving_figure_is_seen_to_move():
    frames = [Figure(t, points=[("m", (t, 0.0))]) for t in (0.0, 1.0)]
    first, second = strip(frames, width=2, height=1).split(" ")
    assert [x for x, _ in _dots([first])] == [0]        # the first frame's dot on the left edge
    assert [x for x, _ in _dots([second])] == [3]       # the second's on the right edge
    assert strip([]) == ""
