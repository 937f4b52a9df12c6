"""`stw --resume` inside the TUI (issue 52 item 4): the console says what was restored (the line
used to reach the shell only after quitting), and Up recalls the resumed session's commands."""

from __future__ import annotations

import asyncio

import test_app_support as support
import stw_tui.app as app_module
from stw_tui.cli import main as cli
from stw_tui.session.autosave import Checkpoints
from stw_tui.session.session import Session
from stw_tui.sym.errors import StwError

LINES = ["time 0 1 knots=8", "dof x", "const g = 9.81", "constraint c: x = 1 @ 1", "objective o: x''", "iterate 10",
         "print x @ 0.5"]


def test_resume_says_what_it_restored_in_the_console_and_fills_the_history(tmp_path, monkeypatch, capsys):
    journal = tmp_path / "kept.stw"
    session = Session(journal_path=journal)
    session.checkpoints = Checkpoints(journal)
    for line in LINES[:3]:
        session.execute(line)
    try:
        session.execute("dof y = ")        # refused: journalled as a comment, not recalled
    except StwError:
        pass
    session.execute("linkage arm base=fixed")
    session.execute("  J1 revolute a=1")
    session.execute("end")
    for line in LINES[3:]:
        session.execute(line)
    session.execute(f"export csv {tmp_path / 'x.csv'}")   # journalled as a comment
    opened = {}

    def capture(session_path=None, step=False, journal=None, exit_process=True, session=None, notes=None):
        opened.update(session=session, notes=notes)
        return 0
    monkeypatch.setattr(app_module, "run_app", capture)
    assert cli.main(["--resume", str(journal)]) == 0
    assert "resumed" not in capsys.readouterr().err           # not on the shell's hidden screen
    app = app_module.create_app(session=opened["session"], notes=opened["notes"])

    async def scenario(pilot):
        await support.settle(pilot)
        text = " ".join(support.log_text(app).split())
        assert (f"resumed {journal}: 8 command(s), 1 solve(s) restored from checkpoints, 0 solved again; "
                "Up recalls its commands") in text
        field = app.repl.input
        field.focus()
        recalled = []
        for _ in range(12):
            await pilot.press("up")
            recalled.append(field.value)
        assert recalled == ["print x @ 0.5", "iterate 10", "objective o: x''", "constraint c: x = 1 @ 1", "end",
                            "  J1 revolute a=1", "linkage arm base=fixed", "const g = 9.81", "dof x", "time 0 1 knots=8",
                            "time 0 1 knots=8", "time 0 1 knots=8"]   # the oldest stays
        await pilot.press(*["down"] * 11)
        assert field.value == ""                                 # back past the newest: the draft
        await pilot.press("up", "enter")                         # a recalled line runs as typed
        await support.settle(pilot)
        assert app.session.journal.entries[-1].text == "print x @ 0.5" and app.session.journal.entries[-1].ok

    async def main():
        async with app.run_test(size=(120, 40)) as pilot:
            await scenario(pilot)

    asyncio.run(main())
