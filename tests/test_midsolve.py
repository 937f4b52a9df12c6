"""Checkpoints of a running solve (stw_tui/session/midsolve.py): a journalled session writes the iterate a
solve has reached every few seconds, atomically; a resume after a kill during the solve starts
from that iterate, journals it as the stopped solve it became, and says so."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

import catalogue
from conftest import ENDLESS
from stw_tui.session import autosave, interpreter, midsolve
from stw_tui.session.autosave import Checkpoints
from stw_tui.session.resume import resume
from stw_tui.session.session import Session

ROOT = Path(__file__).resolve().parent.parent
SETUP = catalogue.problem("analytic_landing").text.split("iterate")[0] + "set adaptive off\n"


def same_scene(a: Session, b: Session) -> None:
    assert np.array_equal(a.scene.coefficient_vector(), b.scene.coefficient_vector())
    assert a.scene.windows == b.scene.windows and a.scene.extra_instances == b.scene.extra_instances


class Ticks:
    """A clock that advances one second per solver iteration (driven by the report callback)."""

    def __init__(self):
        self.now = 0.0

    def __call__(self) -> float:
        return self.now


def journalled_with_clock(path: Path, every: float) -> tuple[Session, Ticks]:
    session = Session(journal_path=path)
    session.checkpoints = Checkpoints(path)
    ticks = Ticks()
    session.checkpoints.midsolve = midsolve.MidSolve(path, every=every, clock=ticks)
    session.run_text(SETUP)
    return session, ticks


def test_a_running_solve_is_checkpointed_once_per_period_and_the_file_goes_when_it_ends(tmp_path):
    path = tmp_path / "s.stw"
    session, ticks = journalled_with_clock(path, every=2.0)
    written, seen = [], {}
    real_write = session.checkpoints.midsolve.write

    def spy(scene, warm, offset, trail, k):
        written.append(k)
        real_write(scene, warm, offset, trail, k)
    session.checkpoints.midsolve.write = spy
    size_before = path.stat().st_size

    def on_report(report):
        ticks.now += 1.0                    # each iteration "takes" a second
        if midsolve.midsolve_path(path).exists():
            seen[report.iteration] = json.loads(midsolve.midsolve_path(path).read_text())
    outcome = session.execute("iterate 30", on_report=on_report)
    assert len(outcome.run.reports) == 5 and outcome.run.converged
    # Iteration k is checked at clock k-1: due at 2 s after the start, then 2 s after each write.
    assert written == [3, 5]
    record = seen[4]                       # what a kill during iteration 4 would have left
    assert record["iteration"] == 3 and record["text"] == "iterate 3 adapt=0"
    assert record["command"] == "iterate 30" and record["offset"] == size_before
    assert not list(tmp_path.glob("*.tmp"))                     # replaced by rename, none left
    assert not midsolve.midsolve_path(path).exists()           # the solve ended: journalled instead
    assert path.read_text().splitlines()[-1] == "iterate 30"


def _kill_during_iteration_4(tmp_path) -> tuple[Path, dict, Session]:
    """A journal and running checkpoint as a kill during the 4th iteration of `iterate 30` leaves
    them, and the session that ran on."""
    path = tmp_path / "s.stw"
    session, ticks = journalled_with_clock(path, every=2.0)
    saved = {}

    def on_report(report):
        ticks.now += 1.0
        if report.iteration == 4:
            saved["journal"] = path.read_bytes()
            saved["running"] = midsolve.midsolve_path(path).read_bytes()
    session.execute("iterate 30", on_report=on_report)
    path.write_bytes(saved["journal"])
    midsolve.midsolve_path(path).write_bytes(saved["running"])
    ckpt = autosave.checkpoint_path(path)
    ckpt.unlink(missing_ok=True)           # the finished solve's checkpoint was written after the kill
    return path, json.loads(saved["running"]), session


def test_resume_after_a_kill_mid_solve_starts_from_its_last_checkpoint(tmp_path, monkeypatch):
    path, record, finished = _kill_during_iteration_4(tmp_path)
    notes = []

    def no_solve(*args, **kwargs):
        raise AssertionError("resume solved again")
    monkeypatch.setattr(interpreter, "_solve", no_solve)
    resumed, restored, solved = resume(path, on_note=notes.append)
    monkeypatch.undo()
    assert (restored, solved) == (0, 0)
    assert len(notes) == 1 and "`iterate 30` at iteration 3 (checkpoint of" in notes[0] \
        and "journalled as `iterate 3 adapt=0`" in notes[0]
    restored_coef = np.concatenate([record["coef"][n] for n in resumed.scene.dofs])
    assert np.array_equal(resumed.scene.coefficient_vector(), restored_coef)     # bit for bit
    assert not np.array_equal(restored_coef, finished.scene.coefficient_vector())  # not the end state
    # The journal now holds the stopped solve; replaying it reaches the same iterate, to the bit.
    assert path.read_text().splitlines()[-1] == "iterate 3 adapt=0"
    replay = Session()
    replay.run_text(path.read_text())
    same_scene(resumed, replay)
    # The running checkpoint is used once: it became a finished one, so a second resume restores
    # the solve from there without solving, and the next iterate continues warm, as after a stop.
    assert not midsolve.midsolve_path(path).exists()
    again, restored, solved = resume(path, on_note=notes.append)
    assert (restored, solved) == (1, 0) and len(notes) == 1
    same_scene(again, resumed)
    replay.execute("iterate 30")
    again.execute("iterate 30")
    same_scene(again, replay)


def test_resolve_solves_the_killed_solve_again_up_to_its_checkpoint(tmp_path):
    path, record, _ = _kill_during_iteration_4(tmp_path)
    notes = []
    resumed, restored, solved = resume(path, resolve=True, on_note=notes.append)
    assert "solved again" in notes[0]
    restored_coef = np.concatenate([record["coef"][n] for n in resumed.scene.dofs])
    assert np.array_equal(resumed.scene.coefficient_vector(), restored_coef)


def test_a_checkpoint_of_another_journal_state_is_not_restored(tmp_path):
    path, _, _ = _kill_during_iteration_4(tmp_path)
    with path.open("a") as out:            # a line acknowledged after the checkpoint: it is stale
        out.write("const k = 1\n")
    notes = []
    resumed, _, _ = resume(path, on_note=notes.append)
    assert notes == [] and resumed.journal.replayable()[-1] == "const k = 1"


def test_a_checkpoint_during_a_later_slide_position_replays_the_positions_before_it(tmp_path):
    path = tmp_path / "s.stw"
    session = Session(journal_path=path)
    session.checkpoints = Checkpoints(path)
    session.checkpoints.midsolve = midsolve.MidSolve(path, every=0.0)
    session.run_text(SETUP + "window early [0, 0.4]\n")
    texts = []
    real_write = session.checkpoints.midsolve.write
    session.checkpoints.midsolve.write = lambda *a: (texts.append(a[3].lines + [f"iterate {a[4]} adapt=0"]),
                                                     real_write(*a))
    session.execute("slide early by 0.3 iterate 3")
    assert texts[0] == ["window early [0.0, 0.4]", "iterate 1 adapt=0"]
    later = [t for t in texts if t[0] == "window early [0.0, 0.4]" and len(t) == 4]
    assert later and later[0][1] == "iterate 3" and later[0][2].endswith(", 0.7]")


def test_stw_run_killed_with_sigkill_during_a_long_iterate_resumes_from_its_running_checkpoint(
        tmp_path, monkeypatch):
    """A real `stw run --journal J` process, killed with SIGKILL in the middle of an endless solve;
    `stw --resume J` starts from the last running checkpoint and says so."""
    import stw_tui.app as app_module
    from stw_tui.cli import main as cli

    jet = (ROOT / "sessions" / "particle_jet.stw").read_text().split("iterate")[0]
    script = tmp_path / "endless.stw"
    script.write_text(jet + ENDLESS + "iterate 1000000\n")
    journal = tmp_path / "j.stw"
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(sys.path), midsolve.EVERY_VARIABLE: "0.2",
           "STW_CACHE_DIR": "off"}
    process = subprocess.Popen([sys.executable, "-m", "stw_tui.cli", "run", str(script), "--journal", str(journal)],
                               env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    running = midsolve.midsolve_path(journal)
    deadline = time.monotonic() + 120
    try:
        while time.monotonic() < deadline and process.poll() is None:
            record = midsolve.MidSolve(journal).load()
            if record is not None and record["iteration"] >= 5:
                break
            time.sleep(0.05)
        assert process.poll() is None, process.stderr.read()
        os.kill(process.pid, signal.SIGKILL)
    finally:
        process.kill()
        process.wait()
    assert process.returncode == -signal.SIGKILL
    record = json.loads(running.read_text())
    assert "iterate 1000000" not in journal.read_text()          # never acknowledged: still running
    opened = {}

    def fake_run_app(session_path=None, step=False, journal=None, exit_process=True, session=None, notes=None):
        opened.update(session=session, notes=notes)
        return 0
    monkeypatch.setattr(app_module, "run_app", fake_run_app)
    assert cli.main(["--resume", str(journal)]) == 0
    notes = "\n".join(opened["notes"])       # said in the TUI's console
    k = record["iteration"]
    assert f"resumed from the running solve's last checkpoint: `iterate 1000000` at iteration {k} " in notes
    resumed = opened["session"]
    assert np.array_equal(resumed.scene.coefficient_vector(), np.array(record["coef"]["x"]))
    assert journal.read_text().splitlines()[-1] == f"iterate {k} adapt=0"
    replay = Session()
    replay.run_text(journal.read_text())
    np.testing.assert_allclose(replay.scene.coefficient_vector(), resumed.scene.coefficient_vector(),
                               rtol=0, atol=1e-12)
