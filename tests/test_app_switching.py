"""Switching panels (F2) and plots (F3) through a Deck (issue 52 item 5): the keys cycle the
views, the shown one has the focus and the tab strip says which, a click on a tab shows it, and a
panel that missed a refresh while hidden is filled once, before it is shown (it was drawn empty,
then filled, then refitted: three draws)."""

from __future__ import annotations

import test_app
import test_app_support as support
from stw_tui.app import create_app
from stw_tui.app.deck import Deck, TabStrip
from stw_tui.app.panel_base import ScenePanel
from stw_tui.app.panels import EquationsPanel
from stw_tui.app.plots import ScenePlot

JET = support.SESSIONS / "particle_jet.stw"
PANELS = ["tab-dof", "tab-eqns", "tab-const", "tab-win", "tab-time", "tab-opt"]
PLOTS = ["tab-curves", "tab-expr", "tab-figure", "tab-conv"]


def run(scenario, app, size=(80, 24)):
    """test_app's runner, at 80x24 (the size these switches are measured at)."""
    test_app.run(scenario, app, size=size)


def shown(app, deck_id: str) -> list[str]:
    """The ids of the deck's views that are displayed (exactly one)."""
    deck = app.query_one(f"#{deck_id}", Deck)
    return [tab for tab, view in deck.views.items() if view.display]


def test_f2_and_f3_cycle_the_views_focus_the_shown_one_and_mark_its_tab():
    app = create_app(JET, show_timing=False, blink=False)

    async def scenario(pilot):
        panels, plots = app.query_one("#panels", Deck), app.query_one("#plots", Deck)
        start = plots.active
        await pilot.press("f2")                         # focuses the panels: no switch
        assert panels.active == "tab-dof" and isinstance(app.focused, ScenePanel)
        assert app.focused is panels.current and panels.query_one(TabStrip).marked
        assert not plots.query_one(TabStrip).marked
        for expected in PANELS[1:] + PANELS[:1]:
            await pilot.press("f2")
            assert panels.active == expected and shown(app, "panels") == [expected]
            assert app.focused is panels.view(expected)
            strip = panels.query_one(TabStrip)
            assert strip.titles[strip.active].lower() == expected.removeprefix("tab-")
        await pilot.press("f3")                         # focuses the plots: no switch
        assert plots.active == start and isinstance(app.focused, ScenePlot)
        assert plots.query_one(TabStrip).marked and not panels.query_one(TabStrip).marked
        order = PLOTS[PLOTS.index(start) + 1:] + PLOTS[:PLOTS.index(start) + 1]
        for expected in order:
            await pilot.press("f3")
            assert plots.active == expected and shown(app, "plots") == [expected]
            assert app.focused is plots.view(expected)
        await pilot.press("escape")
        assert app.focused is app.repl.input
        assert not panels.query_one(TabStrip).marked and not plots.query_one(TabStrip).marked

    run(scenario, app)


def test_a_click_on_a_tab_shows_it_and_focuses_its_view():
    app = create_app(JET, show_timing=False, blink=False)

    async def scenario(pilot):
        panels = app.query_one("#panels", Deck)
        strip = panels.query_one(TabStrip)
        start, _ = strip.spans()[PANELS.index("tab-win")]
        await pilot.click(TabStrip, offset=(start + 1, 0))
        await pilot.pause()
        assert panels.active == "tab-win" and shown(app, "panels") == ["tab-win"]
        assert app.focused is panels.view("tab-win")

    run(scenario, app)


def test_setting_active_shows_the_tab_as_before():
    """Tests and the app set ``#plots``' ``active`` as they did on the TabbedContent."""
    app = create_app(JET, show_timing=False, blink=False)

    async def scenario(pilot):
        plots = app.query_one("#plots", Deck)
        plots.active = "tab-conv"
        await pilot.pause()
        assert shown(app, "plots") == ["tab-conv"]

    run(scenario, app)


def test_a_hidden_panel_is_filled_once_before_it_shows_and_not_refitted_after():
    app = create_app(JET, show_timing=False, blink=False)

    async def scenario(pilot):
        await pilot.press("f2")                          # the DOF panel in front
        eqns = app.query_one(EquationsPanel)
        rebuilt = []                                     # the panel's display at each rebuild
        clear = eqns.clear

        def counted(*args, **kwargs):
            rebuilt.append(eqns.display)
            return clear(*args, **kwargs)
        eqns.clear = counted
        await support.submit(pilot, "constraint extra: x = 0.25 @ 0.25")
        await support.settle(pilot)
        assert rebuilt == [] and eqns.id in app._stale   # hidden: not rebuilt
        await pilot.press("f2")                          # focus back on the panels ...
        await pilot.press("f2")                          # ... then the Eqns panel
        await support.settle(pilot)
        await pilot.pause(0.2)
        assert app.query_one("#panels", Deck).active == "tab-eqns" and app.focused is eqns
        assert rebuilt == [False], "drawn more than once (or filled after it was shown)"
        assert "extra" in [eqns.coordinate_to_cell_key((row, 0)).row_key.value for row in range(eqns.row_count)]
        # Shown again with nothing changed: nothing is rebuilt.
        await pilot.press("f2", *["f2"] * 5)
        await support.settle(pilot)
        assert app.query_one("#panels", Deck).active == "tab-eqns" and rebuilt == [False]

    run(scenario, app)


def frames_drawn(plot) -> list[str]:
    """The text of every frame ``plot`` renders from now on (a list that grows)."""
    drawn, render = [], plot.render

    def recorded():
        text = render()
        drawn.append(str(text))
        return text
    plot.render = recorded
    return drawn


def test_a_plot_shown_during_a_solve_draws_the_newest_iterate_in_its_first_frame():
    """While a solve runs, only the shown plot was redrawn with its iterates: F3 showed the next
    plot with an old one, then drew it again once its data and text came back (issue 52 item 5,
    F3 settled at p95 140 ms in tmux). The plot F3 shows next now follows the iterates too, in
    the background, and after a switch the one after it catches up, so each switch draws the
    plot once, with the newest (here Expr was next at the report, Figure only after the switch)."""
    from stw_tui.app.messages import IterationReported
    from stw_tui.app.plots import ExpressionPlot, FigurePlot
    from stw_tui.sos.backend import StepReport

    app = create_app(JET, show_timing=False, blink=False)

    async def scenario(pilot):
        plots = app.query_one("#plots", Deck)
        frames = {cls: frames_drawn(app.query_one(cls)) for cls in (ExpressionPlot, FigurePlot)}
        plots.active = "tab-curves"
        await pilot.press("f3")                          # focuses the Curves plot
        for _ in PLOTS:                                  # each shown once, back to Curves
            await pilot.press("f3")
            await support.settle(pilot)
        assert plots.active == "tab-curves"
        before = {cls: drawn[-1] for cls, drawn in frames.items()}   # as each was last shown
        for drawn in frames.values():
            drawn.clear()
        moved = 1.5 * app._shown.coefficient_vector() + 0.25   # an iterate that moves every plot
        app.post_message(IterationReported(StepReport(1, 1.0, 0.1, 0.1, 1.0, 1, 0, coefficients=moved)))
        await support.settle(pilot)
        assert frames == {ExpressionPlot: [], FigurePlot: []}   # hidden: not drawn
        for cls in (ExpressionPlot, FigurePlot):
            await pilot.press("f3")
            await support.settle(pilot)
            await pilot.pause(0.2)
            assert plots.current is app.query_one(cls)
            drawn = frames[cls]
            assert drawn and drawn[0] != before[cls], f"{cls.__name__}: first drawn with the old iterate"
            assert set(drawn) == {drawn[0]}, f"{cls.__name__}: drawn {len(set(drawn))} different ways"

    run(scenario, app)
