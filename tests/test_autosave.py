"""Autosave and resume: a journal with checkpoints rebuilds the scene bit for bit without solving
again; damaged or missing checkpoints fall back to solving; a process killed with SIGKILL during
solves loses no acknowledged command."""

import os
import signal
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

import catalogue
from stw_tui.session import autosave, interpreter, paths
from stw_tui.session.autosave import Checkpoints
from stw_tui.session.resume import resume
from stw_tui.session.session import Session

SCENE = catalogue.problem("analytic_landing").text + """iterate 30
key 0.5 x=0.3
iterate 30
window early [0, 0.5]
iterate 30
undo
use all
set adaptive off
iterate 30
"""


def journalled(path: Path, text: str = SCENE) -> Session:
    session = Session(journal_path=path)
    session.checkpoints = Checkpoints(path)
    session.run_text(text)
    return session


def same_scene(a: Session, b: Session) -> None:
    assert np.array_equal(a.scene.coefficient_vector(), b.scene.coefficient_vector())
    assert list(a.scene.dofs) == list(b.scene.dofs)
    assert a.scene.windows == b.scene.windows and a.scene.active_window == b.scene.active_window
    assert a.scene.extra_instances == b.scene.extra_instances
    assert set(a.scene.constraints) == set(b.scene.constraints)


def test_resume_restores_every_solve_from_its_checkpoint_without_solving(tmp_path, monkeypatch):
    path = tmp_path / "s.stw"
    original = journalled(path)
    assert len(Checkpoints(path).load()) == 4          # four iterates, each ran to its end

    def no_solve(*args, **kwargs):
        raise AssertionError("resume solved again")
    monkeypatch.setattr(interpreter, "_solve", no_solve)
    resumed, restored, solved = resume(path)
    monkeypatch.undo()
    assert (restored, solved) == (4, 0)
    same_scene(resumed, original)
    assert resumed.history.lines == original.history.lines   # what `save` writes: the same clean session
    original.journal.path = original.checkpoints = None     # only the resumed one journals on
    # The history is rebuilt too: undo takes back the last solve in both, to the same scene.
    original.execute("undo")
    resumed.execute("undo")
    same_scene(resumed, original)
    # The warm start came back with the checkpoint: the next solve is the same to the bit.
    original.execute("redo")
    resumed.execute("redo")
    original.execute("iterate 5")
    resumed.execute("iterate 5")
    same_scene(resumed, original)
    # The resumed session goes on appending to the journal: resuming again gives the same scene.
    again, restored, _ = resume(path)
    assert restored == 5
    same_scene(again, resumed)


def test_resolve_and_damaged_checkpoints_solve_again(tmp_path):
    path = tmp_path / "s.stw"
    original = journalled(path)
    fresh, restored, solved = resume(path, resolve=True)
    assert (restored, solved) == (0, 4)
    same_scene(fresh, original)
    # A kill while the last checkpoint was written leaves half a line: that solve runs again.
    ckpt = autosave.checkpoint_path(path)
    lines = ckpt.read_text().splitlines()
    ckpt.write_text("\n".join(lines[:-1]) + "\n" + lines[-1][:50])
    partial, restored, solved = resume(path)
    assert (restored, solved) == (3, 1)
    same_scene(partial, original)


def test_state_directory_new_and_latest_journal_and_the_journal_command(tmp_path, monkeypatch):
    monkeypatch.setenv("XDG_STATE_HOME", str(tmp_path / "state"))
    assert paths.state_dir() == tmp_path / "state" / "stw"
    first = paths.new_journal_path("sessions/arm_throw.stw", now=0)
    assert first.parent == tmp_path / "state" / "stw" and first.name.startswith("arm_throw-")
    first.write_text("dof x\n")
    second = paths.new_journal_path("sessions/arm_throw.stw", now=0)
    assert second != first and second.name.endswith("-2.stw")
    second.write_text("dof y\n")
    os.utime(first, ns=(1, 1))
    assert paths.latest_journal() == second
    session = journalled(tmp_path / "j.stw", "dof x\n")
    message = session.execute("journal").message
    assert f"journal: {tmp_path / 'j.stw'}" in message and str(tmp_path / "state" / "stw") in message
    assert Session().execute("journal").message.startswith("journal: none")


WORKER = textwrap.dedent("""
    import sys
    from stw_tui.session.autosave import Checkpoints
    from stw_tui.session.session import Session
    from pathlib import Path
    path = Path(sys.argv[1])
    session = Session(journal_path=path)
    session.checkpoints = Checkpoints(path)
    for line in sys.stdin.read().splitlines():
        session.execute(line)
        print("ack", line, flush=True)
""")


@pytest.mark.parametrize("kill_after", [4, 7, 9])
def test_kill_9_during_solves_loses_no_acknowledged_command(tmp_path, kill_after):
    """SIGKILL after the worker acknowledged ``kill_after`` lines, while it solves the next
    ones: resume holds every acknowledged line, and its scene is that of an uninterrupted run of
    the lines the journal kept."""
    path = tmp_path / "k.stw"
    lines = SCENE.replace("iterate 30", "iterate 30\niterate 30").splitlines()
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)}
    worker = subprocess.Popen([sys.executable, "-c", WORKER, str(path)], stdin=subprocess.PIPE,
                              stdout=subprocess.PIPE, text=True, env=env)
    worker.stdin.write("\n".join(lines) + "\n")
    worker.stdin.close()
    acked = []
    while len(acked) < kill_after:
        out = worker.stdout.readline()
        assert out, "the worker ended early"
        acked.append(out.removeprefix("ack ").rstrip("\n"))
    worker.send_signal(signal.SIGKILL)
    worker.wait()
    resumed, restored, solved = resume(path)
    kept = [e.text for e in resumed.journal.entries if e.ok]
    assert kept[:len(acked)] == acked               # every acknowledged command survived
    uninterrupted = Session()
    uninterrupted.run_text("\n".join(kept) + "\n")
    same_scene(resumed, uninterrupted)


def test_stw_autosaves_by_default_and_resume_opens_the_last_journal(tmp_path, monkeypatch, capsys):
    import stw_tui.app as app_module
    from stw_tui.cli import main as cli

    monkeypatch.setenv("XDG_STATE_HOME", str(tmp_path / "state"))
    opened = {}

    def fake_run_app(session_path=None, step=False, journal=None, exit_process=True, session=None, notes=None):
        opened.update(session_path=session_path, journal=journal, session=session, notes=notes)
        return 0
    monkeypatch.setattr(app_module, "run_app", fake_run_app)
    assert cli.main([]) == 0
    journal = opened["journal"]
    assert journal.parent == tmp_path / "state" / "stw" and journal.name.startswith("session-")
    original = journalled(journal, "time 0 1 knots=8\ndof x\nconstraint c: x = 1 @ 1\nobjective o: x''\niterate 10\n")
    assert cli.main(["--resume"]) == 0
    assert opened["notes"] == [f"resumed {journal}: 5 command(s), 1 solve(s) restored from checkpoints, "
                               "0 solved again; Up recalls its commands"]   # said in the TUI, not the shell
    assert "resumed" not in capsys.readouterr().err
    same_scene(opened["session"], original)
    assert opened["session"].journal.path == journal
    assert cli.main(["--resume", str(tmp_path / "missing.stw")]) == 1
    note = autosave.kept_note(journal)
    assert str(journal) in note and f"stw --resume {journal}" in note


def test_open_runs_a_saved_session_line_by_line_and_journals_its_lines(tmp_path):
    saved = tmp_path / "my session.stw"
    first = Session()
    first.run_text(SCENE)
    first.execute(f'save "{saved}"')
    s = Session(journal_path=tmp_path / "j.stw")
    outcome = s.execute(f'open "{saved}"')
    assert outcome.message.startswith(f"opened {saved}: ")
    same_scene(s, first)
    # The journal holds the file's lines, not `open`: replaying it needs no file.
    saved.unlink()
    journal = (tmp_path / "j.stw").read_text()
    assert "open" not in journal and "iterate 30" in journal
    replay = Session()
    replay.run_text(journal)
    same_scene(replay, first)
    s.execute("undo")          # each line is its own step: undo takes back the last solve only
    assert len(s.history.undo_steps) > 3
    bad = tmp_path / "bad.stw"
    bad.write_text("dof z\nconstraint c: nosuch = 1 @ 0\ndof w\n")
    with pytest.raises(Exception, match=r"bad.stw: .*line 2.*\(1 line\(s\) before it were applied\)"):
        s.execute(f"open {bad}")
    assert "z" in s.scene.dofs and "w" not in s.scene.dofs
    with pytest.raises(Exception, match="cannot open"):
        s.execute(f"open {tmp_path / 'missing.stw'}")
