"""Pilot test of the survey gallery (stw_tui/app/gallery.py): it fills in as a survey runs, Enter
plays an optimum in the figure player, `a` adopts it through the `adopt K` command."""

from __future__ import annotations

import asyncio
from dataclasses import replace

import numpy as np
import test_app_support as support

import catalogue
from stw_tui.app import create_app
from stw_tui.app.gallery import GALLERY_COLUMNS, THUMBNAIL, GalleryScreen
from stw_tui.app.messages import SurveyProgressed
from stw_tui.app.thumbnails import curves, has_geometry
from stw_tui.session.figure import scene_figure
from stw_tui.session.session import Session
from stw_tui.session.survey import preview_scene

PENDULUM = catalogue.problem("analytic_pendulum_swing_up").text + """set scheduler serial
"""


def test_gallery_fills_in_plays_and_adopts():
    session = Session()
    session.run_text(PENDULUM)
    app = create_app(session=session)

    async def scenario(pilot):
        await support.settle(pilot)
        await support.submit(pilot, "survey 12 seed=1 amplitude=3")
        await support.settle(pilot, timeout=120)
        screen = app.screen
        assert isinstance(screen, GalleryScreen), support.log_text(app)
        grid = screen.query_one("#gallery-table")
        optima = app.session.survey.optima
        assert grid.row_count == len(optima) >= 2
        assert screen.query_one("#gallery-progress").progress == 12
        # Each row's thumbnail: the pendulum has no figure to draw, so its angle over time, as the
        # curve of the motion the start reached (rebuilt here from its control points).
        frames_column = list(GALLERY_COLUMNS).index("frames")
        for rank, optimum in enumerate(optima, start=1):
            cell = str(grid.get_row(str(rank))[frames_column])
            preview = preview_scene(app.session.scene, optimum.best)
            times = np.linspace(preview.t0, preview.t1, 4)
            assert not has_geometry([scene_figure(preview, float(t)) for t in times])
            theta = preview.dofs["th"].curve.evaluate(np.linspace(preview.t0, preview.t1, 201))
            assert cell == curves([theta], 4 * THUMBNAIL[0] + 3, THUMBNAIL[1])
            lines = cell.split("\n")
            assert len(lines) == THUMBNAIL[1] and all(len(line) == 4 * THUMBNAIL[0] + 3 for line in lines)
            assert any(ch != chr(0x2800) for ch in cell.replace(" ", "").replace("\n", ""))  # dots drawn
        cells = [str(grid.get_row(str(r))[frames_column]) for r in range(1, len(optima) + 1)]
        assert len(set(cells)) > 1                   # distinct optima look different
        await pilot.press("down", "enter")           # play optimum 2
        await pilot.pause()
        assert not isinstance(app.screen, GalleryScreen)
        figure = app.query_one("#figure-plot")
        assert figure.playing and "playing optimum 2" in support.log_text(app)
        np.testing.assert_allclose(figure.scene.dofs["th"].curve.evaluate(np.linspace(0, 2.5, 201)),
                                   optima[1].best.motion[0], atol=1e-12)
        figure.action_play()                          # pause it
        app.action_gallery()
        await pilot.pause()
        assert isinstance(app.screen, GalleryScreen)
        await pilot.press("a")                        # adopt the optimum under the cursor (1)
        await support.settle(pilot, timeout=60)
        assert app.session.journal.replayable()[-1] == "\n".join(optima[0].best.lines)
        assert "adopted optimum 1" in support.log_text(app)

    async def main():
        async with app.run_test(size=(120, 40)) as pilot:
            await scenario(pilot)

    asyncio.run(main())


def test_f4_cancels_the_starts_left():
    session = Session()
    session.run_text(PENDULUM)
    app = create_app(session=session)

    async def scenario(pilot):
        await support.settle(pilot)
        await support.submit(pilot, "survey 500 seed=1 amplitude=3")
        for _ in range(3000):                         # until the first start is back
            await pilot.pause(0.02)
            if isinstance(app.screen, GalleryScreen):
                break
        assert isinstance(app.screen, GalleryScreen)
        # F4, as the binding runs it: pilot.press would wait for the busy worker to go idle
        app.action_stop()
        await support.settle(pilot, timeout=120)
        survey = app.session.survey
        assert survey.cancelled and 1 <= len(survey.results) < 500
        assert "cancelled" in support.log_text(app)
        assert app.session.journal.replayable()[-1].startswith("# survey 500")

    async def main():
        async with app.run_test(size=(120, 40)) as pilot:
            await scenario(pilot)

    asyncio.run(main())


def test_the_gallery_opens_on_a_surveys_first_table_whatever_its_count():
    """A newer table replaces one the UI has not handled yet (SurveyProgressed.can_replace): under
    load the first table the UI saw already held two results, and the gallery, which opened on
    a table of at most one, never opened (the tmux survey test timed out waiting for it)."""
    session = Session()
    session.run_text(PENDULUM)
    session.execute("survey 3 seed=1")
    first = session.survey
    session.execute("survey 3 seed=2")
    second = session.survey
    assert first.plan is not second.plan and len(first.results) == len(second.results) == 3
    app = create_app(session=session)

    async def scenario(pilot):
        await support.settle(pilot)
        app.post_message(SurveyProgressed(replace(first, results=first.results[:2])))
        await pilot.pause()
        assert isinstance(app.screen, GalleryScreen)
        await pilot.press("escape")
        await pilot.pause()
        assert not isinstance(app.screen, GalleryScreen)
        app.post_message(SurveyProgressed(replace(first, results=list(first.results))))
        await pilot.pause()
        assert not isinstance(app.screen, GalleryScreen)     # closed for the rest of that survey
        app.post_message(SurveyProgressed(replace(second, results=list(second.results))))
        await pilot.pause()
        assert isinstance(app.screen, GalleryScreen)         # the next survey opens it again
        assert app.screen.table.plan is second.plan

    async def main():
        async with app.run_test(size=(120, 40)) as pilot:
            await scenario(pilot)

    asyncio.run(main())
