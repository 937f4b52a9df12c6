"""The TUI at 80x24 and below, read off the screen as a person sees it (issue 52 item 3).

Each test runs the app under Pilot at a fixed terminal size and reads the composed screen's text
(what the terminal would show), not the widgets' state alone: the Eqns panel's violation in view,
headers and key hints that fit, the "too small" screen below 80x24 and back, the console rewrapped
after a resize, and the figure player in front with axes that hold still.
"""

from __future__ import annotations

import asyncio

import test_app_support as support
from stw_tui.app import create_app

JET = support.SESSIONS / "particle_jet.stw"

LONG_NAME = "start_at_rest_with_a_long_descriptive_name"
SCENE = f"""time 0 1 knots=8
dof x
constraint {LONG_NAME}: x = 0, x' = 0 @ 0
constraint end: x = 1 @ 1
objective effort: x''
"""


def run(scenario, app, size):
    async def main():
        async with app.run_test(size=size) as pilot:
            await support.settle(pilot)
            await scenario(pilot)

    asyncio.run(main())


def screen_lines(app) -> list[str]:
    """The terminal's rows as text, as the compositor draws them."""
    return [strip.text for strip in app.screen._compositor.render_strips()]


async def shown(pilot) -> list[str]:
    await support.settle(pilot)
    await pilot.pause(0.1)
    return screen_lines(pilot.app)


def test_the_equations_panel_shows_each_violation_beside_its_name_at_80x24(tmp_path):
    path = tmp_path / "long.stw"
    path.write_text(SCENE)
    app = create_app(path, show_timing=False, blink=False)

    async def scenario(pilot):
        await pilot.press("f2", "f2")                                   # DOF, Eqns
        panel = app.query_one("#eqns-panel")
        lines = await shown(pilot)
        right = panel.region.right                                      # where the plots begin
        assert right <= 42, panel.region
        header = next(line for line in lines if line.startswith("name"))
        assert "max viol" in header[:right] and "scope" in header[:right], header
        for name in (LONG_NAME, "end"):
            violation = f"{panel.info.violations[name]:.2e}"
            # the row of the constraint: its (possibly cut) name at the left, its violation in view
            row = next(line for line in lines if line.startswith(name[:10]))
            assert violation in row[:right], (name, row)
        long_row = next(line for line in lines if line.startswith(LONG_NAME[:10]))
        assert "…" in long_row[:right]                                  # the long name is cut, and says so
        assert LONG_NAME not in long_row
        # the objective and its scope, and the panel never reaches past its half of the screen
        assert any(line.startswith("effort") and "span" in line[:right] for line in lines)
        assert panel.virtual_size.width > panel.size.width              # kind, weight, definition: scroll right

    run(scenario, app, size=(80, 24))


def test_headers_and_key_hints_fit_80_columns():
    app = create_app(JET, show_timing=False, blink=False)

    async def scenario(pilot):
        await pilot.press("f2")                                        # the DOF panel
        lines = await shown(pilot)
        right = app.query_one("#dof-panel").region.right
        header = next(line for line in lines if line.startswith("DOF"))
        assert header[:right].split() == ["DOF", "win", "lo", "hi", "sp", "cp", "damp", "keys"], header
        hints = lines[-1]
        assert len(hints) == 80 and hints.startswith("f1 Help f2 Panels f3 Plots f4 Stop f5 Iterate")
        # whole hints only: the DOF panel's seven keys do not all fit, and an ellipsis says so
        assert "i In/out" in hints and hints.rstrip().endswith("…"), hints
        for _ in range(5):
            await pilot.press("f2")                                    # ... Opt
        lines = await shown(pilot)
        assert lines[-1].rstrip().endswith("i Iterate s Shake c Compare"), lines[-1]
        # option lists are cut to the panel, with an ellipsis; `help` has them whole
        right = app.query_one("#opt-panel").region.right
        factor = next(line for line in lines if line.strip().startswith("factor"))
        assert factor[:right].rstrip().endswith("…"), factor

    run(scenario, app, size=(80, 24))


def test_below_80x24_a_screen_says_so_and_goes_when_the_terminal_is_large_enough():
    from stw_tui.app.help_screen import HelpScreen
    from stw_tui.app.dialogs import TooSmallScreen

    app = create_app(JET, show_timing=False, blink=False)

    async def scenario(pilot):
        assert not isinstance(app.screen, TooSmallScreen)
        await pilot.resize_terminal(60, 20)
        await support.until(pilot, lambda: isinstance(app.screen, TooSmallScreen), "the too-small screen")
        await pilot.pause(0.1)
        text = "\n".join(screen_lines(app))
        assert "The terminal is 60×20: make it at least 80×24" in text, text
        assert "Curves" not in text and "stw>" not in text              # not the broken layout
        focused = app.screen_stack[0].focused
        await pilot.press("f2", "f1", "f3")                              # the main screen's keys do nothing here
        assert isinstance(app.screen, TooSmallScreen) and app.screen_stack[0].focused is focused
        await pilot.resize_terminal(79, 30)                              # one column short: still too small
        await pilot.pause(0.1)
        assert "The terminal is 79×30" in "\n".join(screen_lines(app))
        await pilot.resize_terminal(80, 24)
        await support.until(pilot, lambda: not isinstance(app.screen, TooSmallScreen), "the screen gone")
        await pilot.pause(0.1)
        lines = screen_lines(app)
        assert "Curves" in lines[0] and any(line.startswith("stw>") for line in lines)
        assert len(app.screen_stack) == 1
        # over the help screen too, which comes back with the size
        await pilot.press("f1")
        await pilot.resize_terminal(70, 24)
        await support.until(pilot, lambda: isinstance(app.screen, TooSmallScreen), "the too-small screen")
        await pilot.resize_terminal(100, 30)
        await support.until(pilot, lambda: isinstance(app.screen, HelpScreen), "the help back")
        assert not any(isinstance(screen, TooSmallScreen) for screen in app.screen_stack)

    run(scenario, app, size=(80, 24))

    small = create_app(show_timing=False, blink=False)

    async def starts_small(pilot):
        await pilot.pause(0.1)
        assert isinstance(small.screen, TooSmallScreen)
        assert "make it at least 80×24" in "\n".join(screen_lines(small))
        await pilot.press("ctrl+q")                                     # still quits

    run(starts_small, small, size=(60, 20))
    assert small.return_code == 0 or small.return_code is None


def test_console_text_rewraps_when_the_terminal_is_resized():
    app = create_app(show_timing=False, blink=False)
    words = " ".join(f"word{i:03d}" for i in range(50))                  # 399 characters

    async def scenario(pilot):
        log = app.repl.log_widget
        app.repl.write_note(words)
        await pilot.pause(0.1)

        def rows() -> list[str]:
            return [line.text.rstrip() for line in log.lines if "word" in line.text]

        at_80 = rows()
        assert len(at_80) == 5 and max(map(len, at_80)) <= 79, at_80
        await pilot.resize_terminal(160, 30)
        await support.until(pilot, lambda: len(rows()) == 3, "the note rewrapped at 160 columns")
        assert max(map(len, rows())) > 79
        assert " ".join(rows()).split() == words.split()                 # the same text, in order
        # what is seen on screen: the note's first row is now longer than 80 columns
        await pilot.pause(0.1)
        assert any(line.startswith("word000") and "word012" in line for line in screen_lines(app))
        await pilot.resize_terminal(80, 24)
        await support.until(pilot, lambda: len(rows()) == 5, "the note rewrapped at 80 columns")
        assert max(map(len, rows())) <= 79 and log.virtual_size.width <= 79
        await support.until(pilot, lambda: log.max_scroll_y > 0 and log.is_vertical_scroll_end,
                            "the newest lines still in view")
        assert screen_lines(app)[-4].startswith("word040")               # the note's last row, above the prompt

    run(scenario, app, size=(80, 24))


def test_the_player_opens_on_the_figure_with_axes_fixed_over_the_motion():
    from stw_tui.app.plots import FigurePlot

    app = create_app(support.SESSIONS / "point_mass_2d.stw", show_timing=False, blink=False)

    async def scenario(pilot):
        assert app.query_one("#plots").active == "tab-figure"            # a point mass: the figure in front
        figure = app.query_one(FigurePlot)
        await pilot.press("f3")                                         # F3 focuses it; Space plays
        assert app.focused is figure
        seen = set()
        positions = []
        for _ in range(figure.FRAMES):
            await pilot.press("right")
            await support.settle(pilot)
            seen.add(figure.axes[:2])
            positions += [p for _, p in figure.data.points]
        assert len(seen) == 1, seen                                     # the same axes at every frame
        (x0, x1), (y0, y1) = seen.pop()
        assert all(x0 <= x <= x1 and y0 <= y <= y1 for x, y in positions)   # over the whole motion
        assert min(y for _, y in positions) < 0.1 < 0.4 < max(y for _, y in positions)   # and it moves
        await pilot.press("space")
        await support.until(pilot, lambda: figure.playing, "playing")
        await pilot.press("space")

    run(scenario, app, size=(80, 24))


def test_a_still_point_has_short_ticks_and_a_lone_dof_stays_on_the_curves():
    from stw_tui.app.plots import FigurePlot

    app = create_app(show_timing=False, blink=False)

    async def scenario(pilot):
        await support.submit(pilot, "dof q")                             # a lone DOF: no figure to open on
        await support.settle(pilot)
        assert app.query_one("#plots").active == "tab-curves"
        await support.submit(pilot, "dof x, y")                          # a point that never moves
        await support.settle(pilot)
        assert app.query_one("#plots").active == "tab-figure"
        figure = app.query_one(FigurePlot)
        await pilot.press("f3", "right", "right")
        await support.settle(pilot)
        axes = figure.axes
        await pilot.press("right")
        await support.settle(pilot)
        assert figure.axes == axes
        labels = [*axes[2], *axes[3]]
        assert labels and all(len(label) <= 5 for label in labels), labels   # not 0.000000000000044
        text = "\n".join(screen_lines(app))
        assert "0.0000" not in text

    run(scenario, app, size=(80, 24))
