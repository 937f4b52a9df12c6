"""The status line is the truth (issue 52 item 2): after every command that changes the scene it
shows that scene's numbers (its objective over the whole animation, its dense violation with the
constraint worst there, its violation at the instances), measured off the UI thread, never the
numbers of a scene that is gone; a window solve that leaves failures outside the window says so;
a preview says which of its numbers is which.

Each Pilot test reads what the status line shows at 80 columns, as a person would see it.
"""

from __future__ import annotations

import asyncio
import re

import test_app_support as support
from stw_tui.app import create_app
from stw_tui.app.plots import ConvergencePlot
from stw_tui.session.snapshots import measure
from stw_tui.session.session import Session

ARM = support.SESSIONS / "arm_throw.stw"
JET = support.SESSIONS / "particle_jet.stw"
SIZE = (80, 24)


def run(scenario, app, size=SIZE):
    async def main():
        async with app.run_test(size=size) as pilot:
            await support.settle(pilot, timeout=60)
            await scenario(pilot)

    asyncio.run(main())


def shown(app) -> str:
    """The status line as it is drawn at the app's width."""
    status = app.status_line
    return str(status.render_text(status.size.width))


def dense_shown(app) -> float:
    """The dense violation the status line shows."""
    found = re.search(r"dense (\S+)", shown(app))
    assert found, shown(app)
    return float(found.group(1))


def truth(session) -> float:
    """The scene's dense violation, checked here (headless) on the session's scene."""
    return measure(session.scene).dense


async def command(pilot, line: str) -> None:
    await support.submit(pilot, line)
    await support.settle(pilot, timeout=60)


def arm_session() -> Session:
    session = Session()
    session.run_file(ARM)       # ends on the window near_release
    return session


def test_status_shows_the_dense_violation_after_undo_redo_preview_and_reject():
    app = create_app(session=arm_session(), show_timing=False)

    async def scenario(pilot):
        # A resumed (given) session is measured at once: nothing typed yet.
        assert "B_flight" not in shown(app) and dense_shown(app) < 1e-6, shown(app)
        await command(pilot, "const g = 9.7")     # the flight no longer holds, before any solve
        assert "B_flight" in shown(app) and abs(dense_shown(app) - 0.11) < 0.01, shown(app)
        await command(pilot, "iterate 20")        # on near_release: it cannot reach the flight
        log = support.log_text(app)
        assert "B_flight fails outside window 'near_release'" in log and "`use all`" in log, log
        assert "refine the knots there" not in log
        assert "B_flight" in shown(app) and abs(dense_shown(app) - 0.11) < 0.01, shown(app)
        assert "iter " not in shown(app)          # not the window solve's 1e-13
        await command(pilot, "undo")
        await command(pilot, "undo")              # back before `const g`: the motion holds again
        assert "B_flight" not in shown(app) and dense_shown(app) < 1e-6, shown(app)
        assert abs(dense_shown(app) - truth(app.session)) <= 0.01 * truth(app.session) + 1e-15
        await command(pilot, "redo")
        assert abs(dense_shown(app) - 0.11) < 0.01, shown(app)
        # A preview leaves the scene as it was: the status shows the scene's numbers, and the
        # proposal's beside them where the width allows; after `reject`, the scene's alone.
        await command(pilot, "set preview on")
        await command(pilot, "use all")
        await command(pilot, "iterate 30")
        log = support.log_text(app)
        assert "over the whole animation, proposed and as it is now:" in log
        assert abs(dense_shown(app) - 0.11) < 0.01, shown(app)
        assert "proposal obj" in str(app.status_line.render_text())   # the full line
        await command(pilot, "reject")
        assert "proposal" not in str(app.status_line.render_text())
        assert abs(dense_shown(app) - 0.11) < 0.01, shown(app)

    run(scenario, app)


def test_open_shows_the_scene_it_made_not_the_opened_files_last_iterate(tmp_path):
    other = tmp_path / "other.stw"
    other.write_text("dof y\nconstraint yc: y = 1 @ 0.5\nobjective ey: y''\niterate 3\n", encoding="utf-8")
    app = create_app(JET, show_timing=False)

    async def scenario(pilot):
        await command(pilot, f"open {other}")
        assert "opened" in support.log_text(app)
        text = shown(app)
        assert "iter " not in text and "stale" not in text, text
        measures = measure(app.session.scene)
        assert f"obj {measures.objective:.4g}" in text or f"obj {measures.objective:.6g}" in text, text

    run(scenario, app)


def test_survey_keeps_the_status_fresh_and_the_convergence_plot(tmp_path):
    app = create_app(JET, show_timing=False)

    async def scenario(pilot):
        before = shown(app)
        reports = list(app.query_one(ConvergencePlot).reports)
        assert reports                             # the replay's iterate
        await command(pilot, "set scheduler serial")
        await command(pilot, "survey 4 seed=1")
        await pilot.press("escape")                # close the gallery
        await support.settle(pilot)
        assert "stale" not in shown(app) and shown(app) == before, (before, shown(app))
        assert app.query_one(ConvergencePlot).reports == reports   # not "no solve yet"

    run(scenario, app)
