"""Pilot tests of the TUI: the console, the worker, cancel, panels that emit commands, stepping.

There is no async test plugin here, so each test runs its scenario with ``asyncio.run``.
"""

from __future__ import annotations

import asyncio
import os

import pytest

import test_app_support as support
from conftest import ENDLESS
from stw_tui.app import create_app
from stw_tui.session.session import Session
from stw_tui.sos.backend import Status

JET = support.SESSIONS / "particle_jet.stw"
SIZE = (120, 40)


def run(scenario, app, size=SIZE, settle=True):
    """Run ``scenario(pilot)`` inside ``app`` at a fixed size (once it has settled, by default)."""

    async def main():
        async with app.run_test(size=size) as pilot:
            if settle:
                await support.settle(pilot)
            await scenario(pilot)

    asyncio.run(main())


def jet_without_iterate() -> Session:
    """The particle-jet scene, set up but not solved."""
    session = Session()
    text = JET.read_text().split("iterate")[0]
    session.run_text(text)
    return session


def test_typed_commands_go_through_the_session_and_journal():
    app = create_app()

    async def scenario(pilot):
        await pilot.press(*"dof x", "enter")          # typed key by key
        await support.settle(pilot)
        await support.submit(pilot, "const g = 9.81")
        await support.settle(pilot)
        assert list(app.session.scene.dofs) == ["x"]
        assert app.session.journal.replayable() == ["dof x", "const g = 9.81"]
        text = support.log_text(app)
        assert "stw> dof x" in text and "g = 9.81" in text
        assert app.query_one("#dof-panel").row_count == 1      # the panel shows it live

    run(scenario, app)


def test_error_is_shown_with_a_caret_and_the_scene_is_unchanged():
    app = create_app()

    async def scenario(pilot):
        await support.submit(pilot, "dof x")
        await support.submit(pilot, "constraint c: x = @ 0")
        await support.settle(pilot)
        lines = support.log_text(app).splitlines()
        caret = [i for i, line in enumerate(lines) if line.strip() == "^"]
        assert caret, lines
        assert "constraint c: x = @ 0" in lines[caret[0] - 1]
        assert "column" in lines[caret[0] - 2]
        assert app.session.scene.constraints == {}
        assert app.session.journal.replayable() == ["dof x"]

    run(scenario, app)


def test_history_and_tab_completion():
    app = create_app()

    async def scenario(pilot):
        field = app.repl.input
        await support.submit(pilot, "const gravity = 9.81")
        await support.settle(pilot)
        await pilot.press("up")
        assert field.value == "const gravity = 9.81"
        await pilot.press("down")
        assert field.value == ""
        field.value, field.cursor_position = "pri", 3
        await pilot.press("tab")
        assert field.value == "print "
        await pilot.press(*"gra", "tab")
        assert field.value == "print gravity "
        field.value, field.cursor_position = "d", 1      # several commands: listed in the log
        await pilot.press("tab")
        assert field.value == "d"
        assert "damp  delete  diff  dof" in support.log_text(app)

    run(scenario, app)


def test_tab_completes_a_path_and_open_runs_the_file(tmp_path, monkeypatch):
    (tmp_path / "jumps").mkdir()
    (tmp_path / "jumps" / "high.stw").write_text("const h = 2\ndof x\n")
    (tmp_path / "jumps" / "high.csv").write_text("")
    monkeypatch.chdir(tmp_path)
    app = create_app()

    async def scenario(pilot):
        field = app.repl.input
        field.focus()
        await pilot.press(*"open ju", "tab")
        assert field.value == "open jumps/"                     # a directory: waits for more
        await pilot.press("tab")
        assert field.value == "open jumps/high."                # two files: the common prefix...
        assert "high.stw  high.csv" in support.log_text(app)     # ...and the names, .stw first
        await pilot.press("s", "tab")
        assert field.value == "open jumps/high.stw "
        await pilot.press("enter")
        await support.settle(pilot)
        assert "x" in app.session.scene.dofs and "h" in app.session.scene.constants, support.log_text(app)

    run(scenario, app)


def test_linkage_block_shows_a_continuation_prompt():
    app = create_app()

    async def scenario(pilot):
        prompt = app.query_one("#prompt")
        await support.submit(pilot, "const g = 9.81")
        await support.submit(pilot, "linkage arm base=fixed")
        await support.settle(pilot)
        assert str(prompt.render()).startswith("...")
        await support.submit(pilot, "  J1 revolute a=1 mass=1")
        await support.submit(pilot, "end")
        await support.settle(pilot)
        assert "arm" in app.session.scene.linkages, support.log_text(app)
        assert "...>   J1 revolute" in support.log_text(app)
        assert "J1" in app.session.scene.dofs
        assert str(prompt.render()).startswith("stw")

    run(scenario, app)


def test_iterate_runs_in_the_worker_and_updates_status_and_plots():
    app = create_app(session=jet_without_iterate(), show_timing=False)

    async def scenario(pilot):
        await pilot.press("f5")                     # `iterate 10` from the key
        await support.settle(pilot)
        assert app.session.journal.replayable()[-1] == "iterate 10"
        assert app.session.runs[-1].status is Status.CONVERGED
        # Idle, the status shows the scene the solve left (its objective, dense and instance
        # violations), not the solve's last iterate (issue 52 item 2: tests/test_app_status.py)
        status = str(app.status_line.render_text())
        objective = app.session.runs[-1].reports[-1].objective
        assert f"obj {objective:.6g}  dense " in status and "ms/it" not in status, status
        assert len(app.query_one("#conv-plot").reports) >= 1
        assert abs(app.session.scene.dofs["x"].curve.evaluate([0.5])[0] - 0.5) < 1e-6

    run(scenario, app)


def endless_jet() -> Session:
    """The particle-jet scene made endless (conftest.ENDLESS): `iterate N` runs all N iterations."""
    session = jet_without_iterate()
    for line in ENDLESS.splitlines():
        session.execute(line)
    return session


async def wait_for_reports(pilot) -> None:
    """Wait until the running solve has reported an iteration."""
    for _ in range(500):
        await pilot.pause(0.02)
        if pilot.app.runner.reports:
            return
    raise AssertionError("the solve reported no iteration")


def test_f4_stops_a_solve_at_an_iteration_boundary_and_queues_commands():
    app = create_app(session=endless_jet())

    async def scenario(pilot):
        await support.submit(pilot, "iterate 100000")
        await wait_for_reports(pilot)
        assert app.runner.solving
        await support.submit(pilot, "const k = 2")           # waits for the solve
        assert "queued" in support.log_text(app)
        await pilot.press("f4")
        await support.settle(pilot)
        run_result = app.session.runs[-1]
        assert run_result.status is Status.STOPPED
        assert 0 < len(run_result.reports) < 100000
        assert app.session.scene.constants["k"] == 2           # the queued command ran after
        # A stopped solve is journalled as the iterations it ran, so a replay matches.
        ran = len(run_result.reports)
        assert app.session.journal.replayable()[-2:] == [f"iterate {ran} adapt=0", "const k = 2"]

    run(scenario, app)


def test_escape_returns_to_the_console_and_never_stops_a_solve():
    app = create_app(session=endless_jet())

    async def scenario(pilot):
        await support.submit(pilot, "iterate 60")
        await wait_for_reports(pilot)
        await pilot.press("f3")                              # focus a plot
        assert app.focused is app.query_one("#curves-plot")
        await pilot.press("escape")
        assert app.focused is app.repl.input
        await pilot.press("escape")                          # at the console: still nothing stops
        await support.settle(pilot)
        assert not app.runner.stop_requested.is_set()
        assert app.session.runs[-1].status is not Status.STOPPED
        assert len(app.session.runs[-1].reports) >= 60

    run(scenario, app)


def test_a_replay_halts_and_says_so_when_its_solve_is_stopped(tmp_path):
    script = tmp_path / "endless.stw"
    script.write_text(JET.read_text().split("iterate")[0] + ENDLESS + "iterate 100000\nconst k = 2\n")
    app = create_app(script)

    async def scenario(pilot):
        await wait_for_reports(pilot)
        await pilot.press("f4")
        await support.settle(pilot)
        assert app.session.runs[-1].status is Status.STOPPED
        assert "k" not in app.session.scene.constants          # the line after did not run
        text = support.log_text(app)
        assert "replay halted: the solve at line 17 was stopped" in text, text
        assert "end of endless.stw" not in text
        assert app.script.upcoming() == (18, "const k = 2")
        await pilot.press("f7")                                 # the rest, on request
        await support.settle(pilot)
        assert app.session.scene.constants["k"] == 2

    run(scenario, app, settle=False)


def quit_latency(app, start) -> float:
    """Seconds from Ctrl+Q, pressed once ``start(pilot)`` has returned, until the app has exited."""
    import time

    pressed = []

    async def main():
        async with app.run_test(size=SIZE) as pilot:
            await support.settle(pilot)
            await start(pilot)
            pressed.append(time.monotonic())
            await pilot.press("ctrl+q")
        return time.monotonic() - pressed[0]

    return asyncio.run(main())


def test_ctrl_q_quits_at_once_during_a_solve():
    app = create_app(session=endless_jet())

    async def start(pilot):
        await support.submit(pilot, "iterate 100000")
        await wait_for_reports(pilot)
        pids.append(app.runner.solver.pid)                    # the process that solves
        await pilot.press("f3")                               # from a plot too

    pids = []
    assert quit_latency(app, start) < 1.0
    thread = app.runner.thread
    thread.join(timeout=10)                 # the solve's process was killed: its wait ends at once
    assert not thread.is_alive()
    assert pids[0] is not None and app.runner.solver.pid is None
    with pytest.raises(ProcessLookupError):                   # the solve is gone with it, and ...
        os.kill(pids[0], 0)
    assert app.session.runs == []                             # ... the session is as before it


def test_the_solver_process_ends_with_the_app():
    app = create_app(session=jet_without_iterate(), show_timing=False)
    pids = []

    async def scenario(pilot):
        await support.submit(pilot, "iterate 10")
        await support.settle(pilot)
        pids.append(app.runner.solver.pid)

    run(scenario, app)                                        # leaves run_test without Ctrl+Q
    assert pids[0] is not None and app.runner.solver.pid is None
    with pytest.raises(ProcessLookupError):
        os.kill(pids[0], 0)


def test_ctrl_q_does_not_wait_for_a_job_that_cannot_be_stopped():
    import time

    from stw_tui.app.messages import Job

    app = create_app()

    async def start(pilot):
        app.runner.submit(Job("", origin="compare", task=lambda session: time.sleep(5)))
        app.runner.submit(Job("const k = 1"))                 # queued: never runs
        await pilot.pause(0.1)
        assert app.runner.thread.is_alive()

    assert quit_latency(app, start) < 1.0
    assert app.runner.thread.is_alive()                        # abandoned, not waited for
    assert not app.runner.queue


def test_editing_a_constant_in_the_panel_emits_the_command_line():
    app = create_app(JET)

    async def scenario(pilot):
        for _ in range(3):
            await pilot.press("f2")                  # DOF, Eqns, Const
        panel = app.query_one("#const-panel")
        assert app.focused is panel
        await pilot.press("down", "enter")           # row g
        await pilot.press(*"3.7", "enter")
        await support.settle(pilot)
        assert app.session.journal.replayable()[-1] == "const g = 3.7"
        assert app.session.scene.constants["g"] == 3.7
        assert "panel> const g = 3.7" in support.log_text(app)
        await pilot.press("escape")                  # back to the console
        assert app.focused is app.repl.input

    run(scenario, app)


def test_dof_and_equation_panels_emit_window_and_weight_commands():
    app = create_app(support.SESSIONS / "point_mass_2d.stw")

    async def scenario(pilot):
        await pilot.press("f2", "i")                 # take x out of the window `all`
        await support.settle(pilot)
        assert app.session.journal.replayable()[-1] == "window w1 dofs=y"
        await pilot.press("f2", "down", "down", "w", *"5", "enter")   # floor's weight
        await support.settle(pilot)
        assert app.session.journal.replayable()[-1] == "weight floor 5"
        await pilot.press("enter")                   # plot floor over time
        assert app.query_one("#expr-plot").name_shown == "floor"
        assert app.query_one("#plots").active == "tab-expr"

    run(scenario, app)


def test_step_mode_runs_one_line_per_key_then_the_rest():
    app = create_app(JET, step=True)

    async def scenario(pilot):
        assert app.session.journal.replayable() == []
        await pilot.press("f6")
        await support.settle(pilot)
        assert app.session.journal.replayable() == ["time 0 1 knots=12"]
        assert "step: line 7 next" in str(app.status_line.render_text())
        await pilot.press("f7")
        await support.settle(pilot)
        expected = Session()
        expected.run_file(JET)
        assert app.session.journal.replayable() == expected.journal.replayable()

    run(scenario, app)


def test_figure_scrubs_and_plays():
    app = create_app(support.SESSIONS / "cat_mouse.stw")

    async def scenario(pilot):
        # A scene with point objects opens on the figure player: F3 focuses it
        assert app.query_one("#plots").active == "tab-figure"
        await pilot.press("f3")
        figure = app.query_one("#figure-plot")
        assert app.focused is figure
        await pilot.press("right", "right")
        assert abs(figure.t - 2 * 2.0 / figure.FRAMES) < 1e-9
        await pilot.press("space")
        assert figure.playing
        await support.until(pilot, lambda: figure.t > 4 * 2.0 / figure.FRAMES, "two frames played")
        await pilot.press("space")
        assert not figure.playing

    run(scenario, app)


def test_curves_are_redrawn_from_each_iteration_while_a_solve_runs():
    import numpy as np

    from stw_tui.app.messages import PlotDataComputed
    from stw_tui.app.plot_data import DofPlotData
    from stw_tui.sos.spline import DofCurve

    session = endless_jet()
    before = session.scene.dofs["x"].curve
    app = create_app(session=session)
    computed = []   # (data, solving) of each result the Curves plot received (the others follow too)

    def hook(message):
        if isinstance(message, PlotDataComputed) and isinstance(message.data, DofPlotData):
            computed.append((message.data, app.runner.solving))

    async def main():
        async with app.run_test(size=SIZE, message_hook=hook) as pilot:
            await support.settle(pilot)
            # A solve that runs until a redraw lands while it runs, then stopped: a fixed count
            # of iterations (30 took about 10 ms) can end before the first redraw does.
            await support.submit(pilot, "iterate 100000")
            await support.until(pilot, lambda: any(solving and data.name == "x" for data, solving in computed),
                                "a live redraw while solving")
            await pilot.press("f4")
            await support.settle(pilot)
            return app.query_one("#curves-plot").data

    final = asyncio.run(main())
    live = [data for data, solving in computed if solving and data.name == "x"]
    assert "stopped" in app.session.runs[-1].status.value      # the F4, not the iteration limit
    # Each live curve is the spline of one reported iterate's control points, computed here anew.
    reported = [r.coefficients for r in app.session.runs[-1].reports]
    times = np.asarray(live[0].series.times)
    curves = [DofCurve(before.knots, c).evaluate(times) for c in reported]
    assert any(np.allclose(live[0].series.values, c, atol=1e-12) for c in curves)
    assert not np.allclose(live[0].series.values, before.evaluate(times))   # not the scene before
    assert app.session.scene.dofs["x"].curve is not before                  # the solve moved on
    # After the solve the plot shows the solved scene.
    assert np.allclose(final.series.values, app.session.scene.dofs["x"].curve.evaluate(times), atol=1e-12)


def test_views_never_compile_or_evaluate_on_the_ui_thread(monkeypatch):
    """Plots only render: terms are compiled and evaluated by the worker and in the plots'
    background threads, never on the UI thread, whatever the keys (scrub, play, switch, solve)."""
    import threading

    from stw_tui.session import figure
    from stw_tui.sos import scene, spline
    from stw_tui.sym import compiler

    on_ui, elsewhere = [], []

    def watch(name, function):
        def watched(*args, **kwargs):
            thread = threading.current_thread()
            (on_ui if thread is threading.main_thread() else elsewhere).append((name, thread.name))
            return function(*args, **kwargs)
        return watched

    monkeypatch.setattr(compiler, "compile_term", watch("compile_term", compiler.compile_term))
    monkeypatch.setattr(scene.Scene, "evaluate", watch("Scene.evaluate", scene.Scene.evaluate))
    monkeypatch.setattr(spline.DofCurve, "evaluate", watch("DofCurve.evaluate", spline.DofCurve.evaluate))
    monkeypatch.setattr(figure, "scene_figure", watch("scene_figure", figure.scene_figure))
    app = create_app(support.SESSIONS / "cat_mouse.stw")

    async def scenario(pilot):
        app.query_one("#plots").active = "tab-curves"            # (it opened on the figure)
        await pilot.press("f3", "v", "right_square_bracket")     # Curves: velocity, next DOF
        await support.settle(pilot)
        await pilot.press("f3", "right_square_bracket")          # Expr: the next equation
        await support.settle(pilot)
        await pilot.press("f3")                                  # Figure
        figure = app.query_one("#figure-plot")
        await support.until(pilot, lambda: app.focused is figure, "the figure focused")
        await pilot.press("right", "right", "end")               # scrub
        await pilot.press("space")
        # wait for the player's state, not a fixed time: on a loaded machine a press that came
        # before the figure was ready left it playing in a hidden tab, and the app never settled
        await support.until(pilot, lambda: figure.playing, "playing")
        await pilot.pause(0.3)
        await pilot.press("space")
        await support.until(pilot, lambda: not figure.playing, "stopped")
        await pilot.press("f3")                                  # Conv
        await support.submit(pilot, "iterate 5")
        await pilot.press("f3", "f3")                            # Curves, Expr while it solves
        await support.settle(pilot)
        await pilot.press("f3")                                  # Figure after the solve
        await support.settle(pilot)

    run(scenario, app)
    assert not on_ui, on_ui
    views = {name for name, thread in elsewhere if thread.startswith("stw-") and thread != "stw-session"}
    assert {"Scene.evaluate", "DofCurve.evaluate", "scene_figure"} <= views, elsewhere   # the watch works


def test_keys_typed_fast_in_a_plot_all_reach_the_console_in_order():
    """Keys that arrive before the focus has moved (a fast typist, a paste over SSH) are not lost."""
    from textual import events

    app = create_app()

    async def scenario(pilot):
        await pilot.press("f3")
        assert app.focused is app.query_one("#curves-plot")
        for character in "print":     # one loop turn apart: the later ones are already queued for the plot
            app.post_message(events.Key(character, character))
            await asyncio.sleep(0)
        await support.until(pilot, lambda: app.repl.input.value == "print", "all five keys at the console")
        assert app.focused is app.repl.input

    run(scenario, app)


def test_compare_key_in_the_opt_panel_shows_a_row_per_installed_backend():
    from stw_tui.app.dialogs import CompareScreen
    from stw_tui.sos.backend import available_backends

    app = create_app(session=jet_without_iterate(), show_timing=False)

    async def scenario(pilot):
        journal = list(app.session.journal.replayable())
        for _ in range(6):
            await pilot.press("f2")                  # DOF, Eqns, Const, Win, Time, Opt
        assert app.focused is app.query_one("#opt-panel")
        await pilot.press("c")
        await support.settle(pilot, timeout=120)
        for _ in range(100):
            if isinstance(app.screen, CompareScreen):
                break
            await pilot.pause(0.02)
        screen = app.screen
        assert isinstance(screen, CompareScreen), support.log_text(app)
        table = screen.query_one("#compare-table")
        names = sorted(available_backends())
        assert table.row_count == len(names)
        assert [r["backend"] for r in screen.rows] == names
        assert all(r["converged"] for r in screen.rows)
        assert [table.get_row_at(i)[2] for i in range(table.row_count)] == ["yes"] * len(names)
        assert app.session.journal.replayable() == journal   # not a journalled command
        await pilot.press("escape")
        assert not isinstance(app.screen, CompareScreen)

    run(scenario, app)


def test_typing_in_a_panel_or_plot_goes_to_the_console():
    app = create_app(support.SESSIONS / "point_mass_2d.stw")

    async def scenario(pilot):
        await pilot.press("f3")                              # a plot (the figure: a point mass)
        assert app.focused is app.query_one("#figure-plot")
        await pilot.press(*"print")
        assert app.focused is app.repl.input
        assert app.repl.input.value == "print"
        await pilot.press("f2")                              # a panel: its own keys still work
        assert app.focused is app.query_one("#dof-panel")
        await pilot.press("space", "x", "@", "0")
        assert app.focused is app.repl.input
        assert app.repl.input.value == "print x@0"
        await pilot.press("f2", "i")                         # `i` is the DOF panel's key
        await support.settle(pilot)
        assert app.session.journal.replayable()[-1] == "window w1 dofs=y"
        assert app.repl.input.value == "print x@0"

    run(scenario, app)


def test_the_focused_area_is_marked():
    from stw_tui.app.deck import TabStrip

    app = create_app()

    def active_tab(group: str):
        """The drawn style of the active tab's label and of its underline."""
        strip = app.query_one(f"#{group}").query_one(TabStrip)
        labels, bar = strip.render().renderables
        start, _ = strip.spans()[strip.active]
        return str([span.style for span in labels.spans if span.start <= start + 1 < span.end]), \
            str(bar.highlight_style)

    def marks():
        console = app.repl.styles.border_top[1]
        return console, active_tab("panels"), active_tab("plots")

    async def scenario(pilot):
        at_console = marks()
        await pilot.press("f3")
        await pilot.pause()
        at_plots = marks()
        await pilot.press("f2")
        await pilot.pause()
        at_panels = marks()
        assert at_console[0] != at_plots[0] == at_panels[0]         # the console's rule
        assert at_plots[2] != at_console[2] == at_panels[2]         # the plots' active tab
        assert at_panels[1] != at_console[1] == at_plots[1]         # the panels' active tab

    run(scenario, app)


def test_f1_opens_a_scrollable_searchable_help_screen_and_help_cmd_still_prints():
    from stw_tui.app.help_screen import HelpScreen

    app = create_app()

    async def scenario(pilot):
        await pilot.press("f3")                              # from anywhere
        await pilot.press("f1")
        screen = app.screen
        assert isinstance(screen, HelpScreen)
        titles = [section.title for section in screen.sections]
        assert titles[:4] == ["Getting started", "Keys", "Panel columns", "Commands"] and "iterate" in titles
        keys = screen.sections[1].body
        assert "F4" in keys.upper() and "Stop" in keys and "Prev DOF" in keys and "Complete" not in keys
        assert "In/out: put the DOF in or out of the active window" in keys     # the hint's short text, then more
        columns = screen.sections[2].body        # the panels' abbreviated headings, in full
        assert "DOF panel" in columns and "  sp         knot spans" in columns and "Eqns panel" in columns
        body = screen.query_one("#help-body")
        assert body.max_scroll_y > 0
        await pilot.press("pagedown")
        await pilot.pause()
        assert body.scroll_y > 0
        await pilot.press(*"linkage")                         # typing searches
        await pilot.pause()
        shown = [s.title for s, w in zip(screen.sections, screen.query(".help-section")) if w.display]
        assert shown and all("linkage" in (s.title + s.body).lower() for s in screen.sections
                             if s.title in shown)
        assert "linkage" in shown and "time" not in shown
        await pilot.press("q")                               # part of a search: typed
        assert isinstance(app.screen, HelpScreen)
        assert screen.query_one("#help-search").value == "linkageq"
        await pilot.press("escape")
        assert not isinstance(app.screen, HelpScreen)
        await support.submit(pilot, "help")                   # the same screen from the console
        assert isinstance(app.screen, HelpScreen)
        await pilot.pause()
        await pilot.press("q")                               # empty search: q closes
        assert not isinstance(app.screen, HelpScreen)
        await support.submit(pilot, "help iterate")           # one command, in the console
        await support.settle(pilot)
        assert "iterate [N] [adapt=R]" in support.log_text(app)

    run(scenario, app)


async def type_in_palette(pilot, text: str) -> None:
    """Type ``text`` into the open command palette's search field: all but its last character set
    at once, the last one pressed (the palette searches on every change of the field; pressing
    each of the test's 49 characters took most of its time)."""
    from textual.command import CommandPalette
    from textual.containers import Horizontal
    from textual.widgets import Input

    palette = pilot.app.screen
    assert isinstance(palette, CommandPalette)
    field = palette.query_one("#--input", Horizontal).query_one(Input)   # the search field
    assert field.has_focus
    field.value = text[:-1]
    field.cursor_position = len(field.value)
    await pilot.press(text[-1])
    assert field.value == text


async def palette_found(pilot):
    """Wait until the command palette has finished its search for what was typed and shows a match."""
    from textual.command import CommandList, CommandPalette
    from textual.worker import WorkerState

    def found() -> bool:
        palette = pilot.app.screen
        if not isinstance(palette, CommandPalette):
            return False
        searching = any(worker.group == CommandPalette._GATHER_COMMANDS_GROUP
                        and worker.state in (WorkerState.PENDING, WorkerState.RUNNING)
                        for worker in pilot.app.workers)
        listed = palette.query_one(CommandList)
        return not searching and listed.option_count > 0 and listed.highlighted is not None

    await support.until(pilot, found, "a match in the command palette")


def test_command_palette_offers_actions_commands_and_scene_names():
    from textual.command import CommandPalette

    app = create_app(support.SESSIONS / "point_mass_2d.stw")

    async def scenario(pilot):
        await pilot.press("ctrl+p")
        await pilot.pause()
        assert isinstance(app.screen, CommandPalette)
        await type_in_palette(pilot, "plot dof y")
        await palette_found(pilot)
        await pilot.press("enter")
        await support.until(pilot, lambda: app.query_one("#curves-plot").dof == "y", "the Curves plot on y")
        assert not isinstance(app.screen, CommandPalette)
        assert app.query_one("#plots").active == "tab-curves"
        assert app.query_one("#curves-plot").dof == "y"
        await pilot.press("ctrl+p")
        await type_in_palette(pilot, "plot constraint floor")
        await palette_found(pilot)
        await pilot.press("enter")
        await support.until(pilot, lambda: app.query_one("#expr-plot").name_shown == "floor", "floor plotted")
        await pilot.press("ctrl+p")
        await type_in_palette(pilot, "command refine")
        await palette_found(pilot)
        await pilot.press("enter")
        await support.until(pilot, lambda: app.repl.input.value == "refine ", "refine at the prompt")
        assert app.focused is app.repl.input
        app.repl.input.value = ""
        await pilot.press("ctrl+p")
        await type_in_palette(pilot, "help")
        await palette_found(pilot)
        await pilot.press("enter")
        from stw_tui.app.help_screen import HelpScreen
        await support.until(pilot, lambda: isinstance(app.screen, HelpScreen), "the help shown")

    run(scenario, app)


def test_command_palette_offers_the_session_files_at_hand(tmp_path, monkeypatch):
    from textual.command import CommandPalette

    (tmp_path / "sessions").mkdir()
    (tmp_path / "sessions" / "throw.stw").write_text("dof x\n")
    (tmp_path / "mine.stw").write_text("dof y\n")
    (tmp_path / "two words.stw").write_text("dof z\n")       # `open` takes one word: not offered
    monkeypatch.chdir(tmp_path)
    from stw_tui.app.palette import session_files

    assert [str(p) for p in session_files()] == ["mine.stw", "sessions/throw.stw"]
    app = create_app()

    async def scenario(pilot):
        await pilot.press("ctrl+p", *"open session throw")
        assert isinstance(app.screen, CommandPalette)
        await palette_found(pilot)
        await pilot.press("enter")
        await support.until(pilot, lambda: app.repl.input.value == "open sessions/throw.stw ", "open at the prompt")
        assert app.focused is app.repl.input
        await pilot.press("enter")                             # runs its lines here, journalled
        await support.settle(pilot)
        assert "x" in app.session.scene.dofs and app.session.journal.replayable()[-1] == "dof x"

    run(scenario, app)


def test_key_hints_list_the_app_keys_first_and_a_click_presses_one():
    from stw_tui.app.key_hints import KeyHints

    app = create_app()

    async def scenario(pilot):
        hints = app.query_one(KeyHints)
        keys = [key for key, *_ in hints.hints()]
        assert keys[:5] == ["f1", "f2", "f3", "f4", "f5"] and keys[-1] == "ctrl+q", keys
        assert "f6" not in keys                                 # no session file to step through
        await pilot.press("f3")                                 # the Curves plot's keys come after
        await pilot.pause()
        keys = [key for key, *_ in hints.hints()]
        assert keys.index("ctrl+q") < keys.index("left_square_bracket") < keys.index("v"), keys
        line = str(hints.render())
        assert line.startswith("f1 Help f2 Panels f3 Plots f4 Stop f5 Iterate ^q Quit [ Prev DOF")
        await pilot.click(KeyHints, offset=(line.index("f2") + 1, 0))
        assert app.focused is app.query_one("#dof-panel")

    run(scenario, app, size=(80, 24))


def test_status_measures_the_scene_after_a_change_and_fits_80_columns():
    app = create_app(JET, show_timing=False)

    async def scenario(pilot):
        status = app.status_line
        assert not status.stale and "stale" not in str(status.render_text())
        before = str(status.render_text())
        await support.submit(pilot, "print x @ 0.5")          # read-only: the same numbers
        await support.settle(pilot)
        assert not status.stale and str(status.render_text()) == before
        await support.submit(pilot, "const g = 1.62")
        await support.settle(pilot)
        # measured again, not marked stale: the objective of the scene with the new g
        text = str(status.render_text())
        assert not status.stale and "stale" not in text and text != before, text
        for width in (80, 60, 40):
            line = str(status.render_text(width))
            assert len(line) <= width and "all" in line, line   # the window's name survives
        await pilot.press("f5")
        await support.settle(pilot)
        assert not status.stale

    run(scenario, app, size=(80, 24))


def plot_text(plot) -> str:
    """What a plotext plot shows, as plain text."""
    import re

    return re.sub(r"\x1b\[[0-9;]*m", "", plot.plt.build())


def test_plot_titles_fit_80_columns_and_a_constant_dof_plots_plainly():
    app = create_app(support.SESSIONS / "cat_mouse.stw")

    async def scenario(pilot):
        await pilot.press("f3", "right")                      # the Figure it opened on, one frame on
        await support.settle(pilot)
        figure = app.query_one("#figure-plot")
        assert figure.size.width <= 40
        assert "t = 0.050" in plot_text(figure)                # the player's time, shortened

    run(scenario, app, size=(80, 24))
    app = create_app()

    async def constant(pilot):
        await support.submit(pilot, "dof flat = -pi/2")
        await support.settle(pilot)
        await pilot.press("f3")
        await support.settle(pilot)
        text = plot_text(app.query_one("#curves-plot"))
        assert "flat value" in text, support.log_text(app)
        labels = [line.split("┤")[0].strip() for line in text.splitlines() if "┤" in line]
        assert labels and all(len(label) <= 4 for label in labels), labels    # e.g. -1.5, no noise
        assert "-1.5" in labels

    run(constant, app, size=(80, 24))


def test_the_figure_player_shows_a_proposal_beside_the_dimmed_scene_until_accepted():
    import catalogue

    session = Session()
    session.run_text(catalogue.problem("analytic_landing").text + "set preview on\n")
    app = create_app(session=session)

    async def scenario(pilot):
        app.query_one("#plots").active = "tab-figure"
        await support.submit(pilot, "iterate 30")
        await support.settle(pilot)
        figure = app.query_one("#figure-plot")
        await support.until(pilot, lambda: figure.info.proposal is not None, "the proposal drawn")
        assert figure.info.proposal.scene is app.session.proposal.scene
        text = plot_text(figure)
        new, now = figure.info.proposal.proposed, figure.info.proposal.current   # both measured, shown
        assert f"obj {new.objective:.4g} (now {now.objective:.4g}) · viol {new.dense:.1e} (now {now.dense:.1e})" in text, text
        figure.focus()
        await pilot.press(*["right"] * 20)                       # t = 0.5: the two motions apart
        await support.settle(pilot)                              # redrawn
        rows = plot_text(figure).splitlines()
        moved = [i for i, row in enumerate(rows) if "●" in row]          # the proposal's point
        kept = [i for i, row in enumerate(rows) if "•" in row]           # the scene's, labelled, dim
        assert moved and kept and moved != kept, "\n".join(rows)
        await pilot.press("f9")                                  # accept: one figure again
        await support.settle(pilot)
        await support.until(pilot, lambda: figure.info.proposal is None, "the proposal gone from the figure")
        assert "proposal" not in plot_text(figure) and "t = " in plot_text(figure)

    run(scenario, app, size=(120, 40))


def test_the_theme_is_remembered_between_runs(tmp_path):
    settings = tmp_path / "stw" / "tui.json"
    first = create_app(settings_path=settings)

    async def change(pilot):
        assert first.theme != "nord"
        first.theme = "nord"                                   # as the palette's Theme command does
        await pilot.pause(0.1)

    run(change, first)
    assert '"nord"' in settings.read_text()
    second = create_app(settings_path=settings)

    async def check(pilot):
        assert second.theme == "nord"

    run(check, second)
    settings.write_text("not json")                            # a broken file is ignored
    third = create_app(settings_path=settings)

    async def default(pilot):
        assert third.theme != "nord"

    run(default, third)


def test_page_up_at_the_prompt_scrolls_the_console_log():
    app = create_app(JET)

    async def scenario(pilot):
        log = app.repl.log_widget
        assert log.max_scroll_y > 0 and log.scroll_y == log.max_scroll_y
        await pilot.press("pageup")
        await pilot.pause()
        assert log.scroll_y < log.max_scroll_y and app.focused is app.repl.input
        await pilot.press("pagedown", "pagedown")
        await pilot.pause()
        assert log.scroll_y == log.max_scroll_y

    run(scenario, app, size=(80, 24))


def test_a_line_longer_than_the_prompt_scrolls_to_keep_the_cursor_in_view():
    # CommandInput sets its scroll width without a layout (console.py): the scrolling must still follow.
    app = create_app()

    async def scenario(pilot):
        field = app.repl.input
        # 89 characters set at once, the 90th typed at the end: the typed key is what must scroll
        # (one key per character took 6.0 of this test's 6.4 s, for the same asserts)
        field.value = "print " + "x" * 89
        field.cursor_position = len(field.value)
        await pilot.press("x")
        await pilot.pause()
        assert field.value == "print " + "x" * 90
        assert field.virtual_size.width == len(field.value) + 1
        assert field.scroll_x > 0 and field.scroll_x == field.max_scroll_x     # the cursor's end shows
        await pilot.press("home")
        await pilot.pause()
        assert field.scroll_x == 0

    run(scenario, app, size=(80, 24))


def test_a_plot_builds_its_figure_once_per_change_off_the_ui_thread(monkeypatch):
    import threading

    from textual_plotext.plot import Plot

    builds = []   # the thread of each build
    original = Plot.build
    monkeypatch.setattr(Plot, "build", lambda self: builds.append(threading.current_thread()) or original(self))
    app = create_app(JET)

    async def scenario(pilot):
        await pilot.press("f3", "f3", "f3", "f3", "f3")    # every plot shown once (and built for its size)
        await support.settle(pilot)
        shown = len(builds)
        await pilot.press("f3", "f3", "f3", "f3", "f2", "escape", "f3")
        await support.settle(pilot)
        assert len(builds) == shown          # the kept text is rendered again, not rebuilt
        figure = app.query_one("#figure-plot")
        app.query_one("#plots").active = "tab-figure"
        figure.focus()
        await support.settle(pilot)
        t = figure.t
        await pilot.press("right")           # a new frame: one new figure, built in the background
        await support.settle(pilot)
        assert figure.t > t and len(builds) == shown + 1
        assert builds[-1] is not threading.main_thread()     # plotext's build is not UI time
        assert f"t = {figure.t:.3f}" in plot_text(figure)

    run(scenario, app, size=(80, 24))


def test_ctrl_z_and_ctrl_y_undo_and_redo_through_the_journal():
    app = create_app()

    async def scenario(pilot):
        await support.submit(pilot, "time 0 1 knots=8")
        await support.submit(pilot, "dof x = t")
        await support.settle(pilot)
        await pilot.press("ctrl+z")
        await support.settle(pilot)
        assert "x" not in app.session.scene.dofs
        await pilot.press("ctrl+y")
        await support.settle(pilot)
        assert "x" in app.session.scene.dofs
        assert app.session.journal.replayable()[-2:] == ["undo", "redo"]

    run(scenario, app)


def test_an_autosaved_session_says_where_its_journal_is_and_preview_accept_work_from_the_console(tmp_path):
    from stw_tui.session.autosave import Checkpoints

    journal = tmp_path / "j.stw"
    session = jet_without_iterate()
    session.journal.path = journal
    session.checkpoints = Checkpoints(journal)
    app = create_app(session=session)

    async def scenario(pilot):
        assert f"journal: {journal}" in support.log_text(app)
        await support.submit(pilot, "set preview on")
        await support.settle(pilot)
        before = app.session.scene.coefficient_vector().copy()
        await support.submit(pilot, "iterate 20")
        await support.settle(pilot)
        assert (app.session.scene.coefficient_vector() == before).all()
        assert "`accept` takes the result" in support.log_text(app)
        await support.submit(pilot, "iterate 20")
        await support.settle(pilot)
        await pilot.press("f10")                        # reject
        await support.settle(pilot)
        assert (app.session.scene.coefficient_vector() == before).all() and app.session.proposal is None
        await support.submit(pilot, "iterate 20")
        await support.settle(pilot)
        await pilot.press("f9")                         # accept
        await support.settle(pilot)
        assert not (app.session.scene.coefficient_vector() == before).all()
        assert journal.read_text().splitlines()[-5:] == ["iterate 20", "iterate 20", "reject", "iterate 20", "accept"]

    run(scenario, app)


def test_a_journalled_session_is_made_by_the_worker_after_the_app_shows(tmp_path):
    """`stw SESSION` journals by default: its session is made off the UI thread, as an unjournalled
    one is, so the first frame does not wait for the core's imports (numpy, scipy, sympy)."""
    import subprocess
    import sys

    journal = tmp_path / "j.stw"
    shown = subprocess.run(
        [sys.executable, "-c", "import sys\nfrom stw_tui.app import create_app\n"
         f"app = create_app(journal={str(journal)!r}, solver_process=False)\n"
         "print(app.session, sorted(m for m in ('sympy', 'scipy', 'stw_tui.session.session') if m in sys.modules))"],
        capture_output=True, text=True, check=True).stdout.split()
    assert shown == ["None", "[]"]

    app = create_app(journal=journal, solver_process=False)

    async def scenario(pilot):
        await support.submit(pilot, "dof x")
        await support.submit(pilot, "constraint c: x = 1 @ 0")
        await support.submit(pilot, "objective o: x''")
        await support.submit(pilot, "iterate 2")
        await support.settle(pilot)
        assert app.session.journal.path == journal and app.session.checkpoints is not None
        assert f"journal: {journal}" in support.log_text(app)

    run(scenario, app)
    assert journal.read_text(encoding="utf-8").splitlines()[:3] == ["dof x", "constraint c: x = 1 @ 0",
                                                                    "objective o: x''"]


def test_a_replay_measures_the_scene_once_at_its_end_and_again_where_it_pauses(tmp_path, monkeypatch):
    """The views redraw at most ten times a second: a replay measures the scene for them
    (the dense check, the figure's bounds) after its last line only, and, where it pauses on an
    error, at the pause, so the equations panel never shows an earlier scene's violations."""
    import stw_tui.app.runner as runner_module

    measured = []
    real = runner_module.scene_info
    monkeypatch.setattr(runner_module, "scene_info", lambda scene, proposal=None, dense=None: measured.append(
        sorted(scene.constraints)) or real(scene, proposal, dense))
    script = tmp_path / "s.stw"
    script.write_text("time 0 1\ndof x\nconstraint a: x = 1 @ 0\nconstraint b: x = 2 @ 1\n"
                      "objective o: x''\niterate 5\nprint x @ 0.5\n", encoding="utf-8")
    app = create_app(script, solver_process=False)

    async def scenario(pilot):
        assert measured[-1] == ["a", "b"] and len(measured) == 2      # at startup, after the last line
        assert app._info.violations["b"] < 1e-6                      # the solved scene's own
        broken = tmp_path / "broken.stw"
        broken.write_text("constraint c: x = 0 @ 0.5\nconstraint d: x = @ 1\nconstraint e: x = 3 @ 1\n",
                          encoding="utf-8")
        app._open(broken)
        await support.settle(pilot)
        assert "replay paused" in support.log_text(app)
        assert measured[-1] == ["a", "b", "c"] and len(measured) == 3    # measured where it paused
        assert app._info.violations["c"] > 0.5

    run(scenario, app)


def test_a_replay_refreshes_the_views_twice_a_second_and_its_end_at_once(tmp_path):
    from stw_tui.app.app import REPLAY_VIEW_INTERVAL, VIEW_INTERVAL

    script = tmp_path / "s.stw"
    script.write_text("time 0 1\ndof x\nconstraint a: x = 1 @ 0\nobjective o: x''\niterate 3\n", encoding="utf-8")
    app = create_app(script, solver_process=False)
    seen = []
    refresh = app._refresh_views

    def recording(info=None):
        refresh(info)
        seen.append((app.script is not None and app.script.upcoming() is not None,
                     app._views.throttle.interval, app._views.pending))
    app._refresh_views = recording

    async def scenario(pilot):
        # the startup job's and the four lines' before the last
        assert [interval for more, interval, _ in seen if more] == [REPLAY_VIEW_INTERVAL] * 5
        assert seen[-1] == (False, VIEW_INTERVAL, False)     # the last line: shown at once
        assert not app._views.pending

    run(scenario, app)


def test_a_live_redraw_due_as_the_app_closes_is_dropped():
    # a solve's report arriving just before Ctrl+Q (or a test's end) left a redraw due, which
    # then found no status line: NoMatches at shutdown
    app = create_app()

    async def scenario(pilot):
        pass

    run(scenario, app)
    app._latest_report = object()      # a report still due when the widgets are gone
    app._show_latest_report()
    assert app._latest_report is None
