"""Pilot tests of what the user types while a session file replays (issue 52 item 4, "no
surprises"): a command that may change the scene waits for the file's end, so the file's own lines
(its `print` checks among them) run on the scene the file builds; a read-only one answers between
two of the file's lines, never inside its `linkage` block."""

from __future__ import annotations

import asyncio
import threading

import test_app_support as support
from stw_tui.app import create_app

SIZE = (120, 40)
GATE = "const gate = 1"     # the file's line that the tests hold in the worker until they type


def gated(app, line: str = GATE) -> threading.Event:
    """Make the worker wait, before it runs ``line``, until the returned event is set: the
    replay is then certainly in progress while the test types."""
    gate = threading.Event()
    run_job = app.runner.run

    def run(job):
        if job.line == line:
            gate.wait(30)
        run_job(job)
    app.runner.run = run
    return gate


def run(scenario, app) -> None:
    async def main():
        async with app.run_test(size=SIZE) as pilot:
            await scenario(pilot)

    asyncio.run(main())


def journal(app) -> list[str]:
    return app.session.journal.replayable()


def log(app) -> str:
    """The console's text, unwrapped (as if the log were wide enough)."""
    return " ".join(support.log_text(app).split())


def test_commands_typed_during_a_replay_wait_for_its_end_and_queries_answer_at_once(tmp_path):
    script = tmp_path / "s.stw"
    script.write_text(f"time 0 1\nconst k = 1\n{GATE}\ndof x\nprint k @ 0\n", encoding="utf-8")
    app = create_app(script, solver_process=False)
    gate = gated(app)

    async def scenario(pilot):
        await support.until(pilot, lambda: app.runner.current is not None and app.runner.current.line == GATE,
                            "at the gated line")
        await support.submit(pilot, "const k = 5")         # changes the scene: after the file
        await support.submit(pilot, "print k @ 0")         # read-only: before the file's next line
        await pilot.press("ctrl+z")                        # a key's command waits too
        text = log(app)
        assert "queued until the replay ends: const k = 5" in text
        assert "queued until the replay ends: undo" in text
        assert "print k" not in text                       # not queued, and not run yet
        gate.set()
        await support.settle(pilot)
        assert journal(app) == ["time 0 1", "const k = 1", GATE, "print k @ 0", "dof x", "print k @ 0",
                                "const k = 5", "undo"]
        assert [p.value for p in app.session.prints] == [1.0, 1.0]   # the file's check saw its own k
        assert app.session.scene.constants["k"] == 1.0     # const k = 5, then the undo, ran after it
        text = log(app)
        assert text.index("end of s.stw") < text.index("running the 2 command(s) typed during the replay") \
            < text.index("stw> const k = 5")
        assert text.index("stw> print k") < text.index("5| print k")   # answered between the lines
        await support.submit(pilot, "const k = 7")         # after the replay: at once, as always
        await support.settle(pilot)
        assert app.session.scene.constants["k"] == 7.0
        assert "queued until the replay ends: const k = 7" not in log(app)

    run(scenario, app)


def test_a_query_typed_during_a_replay_never_lands_inside_the_files_linkage_block(tmp_path):
    script = tmp_path / "arm.stw"
    script.write_text("time 0 1\nconst g = 9.81\nlinkage arm base=fixed\n  J1 revolute a=1 mass=1\n"
                      f"end\n{GATE}\n", encoding="utf-8")
    app = create_app(script, solver_process=False)
    gate = gated(app, "  J1 revolute a=1 mass=1")          # inside the block

    async def scenario(pilot):
        await support.until(pilot, lambda: app.runner.current is not None and app.runner.current.line.startswith("  J1"),
                            "inside the linkage block")
        await support.submit(pilot, "show arm")
        gate.set()
        await support.settle(pilot)
        assert "arm" in app.session.scene.linkages
        assert journal(app)[2:] == ["linkage arm base=fixed\n  J1 revolute a=1 mass=1\nend", "show arm", GATE]

    run(scenario, app)


def test_a_paused_replay_keeps_the_typed_commands_for_its_end(tmp_path):
    script = tmp_path / "s.stw"
    script.write_text(f"time 0 1\nconst k = 1\n{GATE}\nconstraint bad: nosuch = 1 @ 0\nconst z = 3\n",
                      encoding="utf-8")
    app = create_app(script, solver_process=False)
    gate = gated(app)

    async def scenario(pilot):
        await support.until(pilot, lambda: app.runner.current is not None and app.runner.current.line == GATE,
                            "at the gated line")
        await support.submit(pilot, "const k = 5")
        gate.set()
        await support.settle(pilot)
        assert "replay paused: fix it at the console, then F6/F7 to go on; 1 command(s) typed during it " \
               "run at its end" in log(app)
        assert app.session.scene.constants["k"] == 1.0     # still waiting
        await support.submit(pilot, "const fixed = 1")     # paused: what is typed now runs at once
        await support.settle(pilot)
        assert "fixed" in app.session.scene.constants and app.session.scene.constants["k"] == 1.0
        await pilot.press("f7")                            # the rest of the file, then the typed line
        await support.settle(pilot)
        assert journal(app)[-3:] == ["const fixed = 1", "const z = 3", "const k = 5"]
        assert app.session.scene.constants["k"] == 5.0

    run(scenario, app)
