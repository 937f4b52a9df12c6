"""SVG snapshots of the TUI at 80x24 and 120x40 (pytest-textual-snapshot).

Deterministic by construction: fixed sizes, no cursor blink, no ms/iteration in the status line,
and every snapshot waits until the worker, the replay and the throttled redraws are done.
Update after an intended change with ``pytest tests/test_app_snapshots.py --snapshot-update``.
"""

from __future__ import annotations

import test_app_support as support
from stw_tui.app import create_app

JET = support.SESSIONS / "particle_jet.stw"


def quiet_app(*args, **kwargs):
    return create_app(*args, show_timing=False, blink=False, **kwargs)


def test_empty_session_80x24(snap_compare):
    async def run_before(pilot):
        await support.settle(pilot)

    assert snap_compare(quiet_app(), terminal_size=(80, 24), run_before=run_before)


def test_particle_jet_replayed_120x40(snap_compare):
    async def run_before(pilot):
        await support.settle(pilot)

    assert snap_compare(quiet_app(JET), terminal_size=(120, 40), run_before=run_before)


def test_particle_jet_stepped_equations_80x24(snap_compare):
    """Stepped up to the line before `iterate` (no solver digits), Equations panel in front."""

    async def run_before(pilot):
        await support.settle(pilot)
        for _ in range(7):
            await pilot.press("f6")
            await support.settle(pilot)
        await pilot.press("f2", "f2")
        await support.settle(pilot)

    assert snap_compare(quiet_app(JET, step=True), terminal_size=(80, 24), run_before=run_before)


def test_cat_mouse_figure_120x40(snap_compare):
    async def run_before(pilot):
        await support.settle(pilot)
        await pilot.press("f3")                        # the Figure it opens on
        await pilot.press(*["right"] * 20)              # t = 1 of [0, 2]
        await support.settle(pilot)

    app = quiet_app(support.SESSIONS / "cat_mouse.stw")
    assert snap_compare(app, terminal_size=(120, 40), run_before=run_before)


def test_help_screen_80x24(snap_compare):
    async def run_before(pilot):
        await support.settle(pilot)
        await pilot.press("f1")
        await pilot.pause()

    assert snap_compare(quiet_app(), terminal_size=(80, 24), run_before=run_before)


def test_help_searched_120x40(snap_compare):
    async def run_before(pilot):
        await support.settle(pilot)
        await pilot.press("f1", *"window")
        await pilot.pause()

    assert snap_compare(quiet_app(), terminal_size=(120, 40), run_before=run_before)


def test_particle_jet_replayed_80x24(snap_compare):
    """Status line, footer and plot title at 80 columns."""

    async def run_before(pilot):
        await support.settle(pilot)

    assert snap_compare(quiet_app(JET), terminal_size=(80, 24), run_before=run_before)


def test_cat_mouse_figure_80x24(snap_compare):
    """The player's time stays in the figure's title at 80 columns."""

    async def run_before(pilot):
        await support.settle(pilot)
        await pilot.press("f3")                        # the Figure it opens on
        await pilot.press(*["right"] * 20)
        await support.settle(pilot)

    app = quiet_app(support.SESSIONS / "cat_mouse.stw")
    assert snap_compare(app, terminal_size=(80, 24), run_before=run_before)


def test_constant_dof_curves_80x24(snap_compare):
    """A constant DOF: round labels around its value, not floating-point noise."""

    async def run_before(pilot):
        await support.settle(pilot)
        await support.submit(pilot, "dof x = -pi/2")
        await support.settle(pilot)
        await pilot.press("f3")
        await support.settle(pilot)

    assert snap_compare(quiet_app(), terminal_size=(80, 24), run_before=run_before)


def test_verb_groups_in_equations_80x24(snap_compare):
    """A verb's constraints indented under a heading row with its word, scope and worst violation."""
    import catalogue

    lines = catalogue.problem("analytic_arm3").text.splitlines() + [
        "dof BX, BY", "constraint hang: SHOULDER = -pi/2 @ 0", "hold B at arm.tip on [0.2, 0.55]",
        "ballistic B on [0.55, 1.5]", "constraint goal: BX = 1.5, BY = 0.5 @ 1.5"]

    async def run_before(pilot):
        await support.settle(pilot)
        for line in lines:
            await support.submit(pilot, line)
            await support.settle(pilot)
        await pilot.press("f2", "f2")
        await support.settle(pilot)

    assert snap_compare(quiet_app(), terminal_size=(80, 24), run_before=run_before)
