"""A window solve that leaves constraints outside the window broken says so and names the window
(issue 52 item 2): on arm_throw with `const g = 9.7`, a solve on the window `near_release` cannot
reach the flight, and the hint used to be "refine the knots there". A windowed solve's objective
is the window's own, and a preview says which of its numbers is which."""

from __future__ import annotations

from pathlib import Path

from stw_tui.session.session import Session

ARM = Path(__file__).resolve().parent.parent / "sessions" / "arm_throw.stw"


def arm_session() -> Session:
    session = Session()
    session.run_file(ARM)       # ends on the window near_release
    return session


def test_a_window_solve_names_the_window_that_cannot_reach_the_failure():
    session = arm_session()
    session.execute("const g = 9.7")
    message = session.execute("iterate 20").message
    assert "objective (window 'near_release')" in message
    assert "B_flight fails outside window 'near_release' ([0.3, 0.75]" in message
    assert "refine the knots there" not in message
    session.execute("use all")
    message = session.execute("iterate 20").message
    assert "outside window" not in message and "objective (window" not in message


def test_a_preview_names_its_numbers():
    session = arm_session()
    for line in ("set preview on", "const g = 9.7"):
        session.execute(line)
    message = session.execute("iterate 20").message
    lines = message.splitlines()
    solve = next(line for line in lines if "iteration(s) with" in line)
    assert "objective (window 'near_release')" in solve        # the window's own objective
    at = lines.index("over the whole animation, proposed and as it is now:")
    assert lines[at + 1].startswith("  proposal: objective") and lines[at + 2].startswith("  now:      objective")
