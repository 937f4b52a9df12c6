"""Export: CSV and JSON read back and compared with the scene's own evaluation, the arm's joint
positions with an independent forward kinematics, and the file commands' parsing."""

import csv
import json
import os

import numpy as np
import pytest

from conftest import SESSIONS, run_lines
from stw_tui.cli import main as cli
from stw_tui.session.session import Session
from stw_tui.sos.spline import DofCurve
from stw_tui.sym.errors import SourceError, StwError
from stw_tui.sym.symbols import named_symbol

LINKS = (0.35, 0.30, 0.15)   # the arm of sessions/arm_throw.stw


def arm_session() -> Session:
    """arm_throw.stw up to its first solve, with a sketched and shaken motion instead (exporting
    needs a motion, not an optimal one)."""
    lines = SESSIONS.joinpath("arm_throw.stw").read_text().splitlines()
    head = lines[:next(i for i, line in enumerate(lines) if line.startswith("iterate"))]
    s = run_lines(Session(), "\n".join(head) + "\n")
    s.execute("key 0.5 SHOULDER=0.3 ELBOW=1.2 WRIST=-0.4")
    s.execute("key 1.1 SHOULDER=1.9 ELBOW=0.2 WRIST=0.8")
    s.execute("shake SHOULDER ELBOW WRIST amplitude=0.05 seed=2")
    return s


@pytest.fixture(scope="module")
def arm():
    return arm_session()


def read_csv(path):
    with open(path, newline="") as f:
        rows = list(csv.reader(f))
    header, data = rows[0], np.array(rows[1:], dtype=float)
    return {name: data[:, k] for k, name in enumerate(header)}


def forward_kinematics(q1, q2, q3):
    """Planar arm from the origin, each angle relative to the link before."""
    angles = np.cumsum(np.stack([q1, q2, q3]), axis=0)
    points = [np.zeros((2, q1.size))]
    for a, angle in zip(LINKS, angles):
        points.append(points[-1] + a * np.stack([np.cos(angle), np.sin(angle)]))
    return points    # shoulder, elbow, wrist, tip


def test_csv_reads_back_as_the_scenes_own_values(arm, tmp_path):
    out = tmp_path / "arm.csv"
    message = arm.execute(f"export csv {out} fps=24").message
    table = read_csv(out)
    t = table["t"]
    assert t.size == 37 and t[0] == 0 and t[-1] == 1.5 and "37 frames" in message
    assert np.allclose(np.diff(t), 1 / 24, atol=1e-12)
    scene = arm.scene
    for name in scene.dofs:
        for order, suffix in enumerate(("", "'", "''")):
            assert np.max(np.abs(table[name + suffix] - scene.dof_values(name, t, order))) <= 1e-12
    # The ball is the hand's point while held (up to 0.55), its own curve after it.
    held = t < 0.55
    tip = forward_kinematics(table["SHOULDER"], table["ELBOW"], table["WRIST"])[-1]
    assert np.max(np.abs(table["BX"][held] - tip[0][held])) <= 1e-12
    assert np.max(np.abs(table["BY"][held] - tip[1][held])) <= 1e-12
    assert np.array_equal(table["BX"][~held], scene.dofs["BX"].curve.evaluate(t[~held]))
    positions = [n for n in table if n.startswith("arm.")]
    assert {"arm.SHOULDER.x", "arm.ELBOW.y", "arm.WRIST.x", "arm.tip.x", "arm.tip.y", "arm.com.x"} <= set(positions)
    for name in positions:
        expected = np.broadcast_to(scene.evaluate(named_symbol(name), t), t.shape)
        assert np.max(np.abs(table[name] - expected)) <= 1e-12, name


def test_joint_positions_match_an_independent_forward_kinematics(arm, tmp_path):
    out = tmp_path / "arm.csv"
    arm.execute(f"export csv {out} fps=60")
    table = read_csv(out)
    shoulder, elbow, wrist, tip = forward_kinematics(table["SHOULDER"], table["ELBOW"], table["WRIST"])
    assert np.ptp(table["SHOULDER"]) > 1 and np.ptp(table["ELBOW"]) > 0.5   # the arm does move
    for name, point in (("SHOULDER", shoulder), ("ELBOW", elbow), ("WRIST", wrist), ("tip", tip)):
        for axis, k in (("x", 0), ("y", 1)):
            assert np.max(np.abs(table[f"arm.{name}.{axis}"] - point[k])) <= 1e-12, (name, axis)


def test_json_holds_the_same_columns_the_curves_and_a_replayable_session(arm, tmp_path):
    out = tmp_path / "arm.json"
    arm.execute(f"export json {out}")
    doc = json.loads(out.read_text())
    assert doc["format"] == "stw-motion" and doc["fps"] == 30 and doc["span"] == [0.0, 1.5]
    columns = {k: np.array(v) for k, v in doc["columns"].items()}
    csv_out = tmp_path / "arm.csv"
    arm.execute(f"export csv {csv_out} fps=30")
    table = read_csv(csv_out)
    assert list(columns) == list(table)
    for name in table:
        assert np.array_equal(columns[name], table[name]), name
    t = columns["t"]
    for name, dof in arm.scene.dofs.items():
        saved = doc["dofs"][name]
        curve = DofCurve(np.array(saved["knots"]), np.array(saved["control_points"]))
        assert np.array_equal(curve.coef, dof.curve.coef) and np.array_equal(curve.knots, dof.curve.knots)
        own = t >= 0.55 if name in ("BX", "BY") else t >= 0       # the ball's curve is its own after release
        assert np.max(np.abs(curve.evaluate(t[own], 2) - columns[name + "''"][own])) <= 1e-12
        assert (saved["lo"], saved["hi"]) == (dof.lo, dof.hi)
    replay = run_lines(Session(), doc["session"])
    assert np.array_equal(replay.scene.coefficient_vector(), arm.scene.coefficient_vector())


def test_export_changes_nothing_and_is_not_a_step_nor_replayed(tmp_path):
    s = run_lines(Session(), "time 0 1 knots=6\ndof x = t^2\nconst k = 2\n")
    before = s.scene.coefficient_vector().copy()
    out = tmp_path / "x.csv"
    s.execute(f"export csv {out}")
    assert np.array_equal(s.scene.coefficient_vector(), before)
    assert s.journal.entries[-1].text.startswith("# export csv")
    s.execute("undo")    # undoes `const k = 2`, not the export
    assert "k" not in s.scene.constants
    out.unlink()
    run_lines(Session(), s.journal.text())     # a replay does not write the file again
    assert not out.exists()


def test_frames_cover_the_span():
    from stw_tui.session.export import frame_times

    s = run_lines(Session(), "time 0.25 1.3 knots=6\ndof x\n")
    t = frame_times(s.scene, 10)
    assert t[0] == 0.25 and t.size == 11 and t[-1] <= 1.3


@pytest.mark.parametrize("line, column, words", [
    ("export xml out.xml", 8, "unknown export format"),
    ("export", 7, "needs a format"),
    ("export csv", 11, "needs a file"),
    ("export csv out.csv fps=0", 24, "fps must be"),
    ("export csv out.csv fps=x1", 24, "fps must be"),
    ("export csv out.csv speed=3", 20, "unexpected 'speed=3'"),
    ('export csv "out.csv', 12, "not closed"),
])
def test_export_errors_say_where(line, column, words):
    s = run_lines(Session(), "dof x\n")
    with pytest.raises(SourceError) as info:
        s.execute(line)
    assert words in info.value.message
    assert info.value.column == column


def test_export_paths_are_plain_text(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "sub").mkdir()
    s = run_lines(Session(), "dof x = t\n")
    s.execute("export csv ../out-1.csv fps=5  # a comment")
    s.execute('export json "sub/with space #1.json"')
    assert (tmp_path.parent / "out-1.csv").exists() and (tmp_path / "sub" / "with space #1.json").exists()
    (tmp_path.parent / "out-1.csv").unlink()
    with pytest.raises(StwError, match="cannot write sub: sub is a folder"):
        s.execute("export csv sub")      # a folder
    with pytest.raises(StwError, match="cannot write nowhere/x.csv: there is no folder nowhere$") as info:
        s.execute("export csv nowhere/x.csv")
    assert ".tmp" not in str(info.value)
    (tmp_path / "locked").mkdir(mode=0o500)
    if not os.access(tmp_path / "locked", os.W_OK):   # (root may write anywhere)
        with pytest.raises(StwError, match="cannot write locked/x.csv: Permission denied$"):
            s.execute("export csv locked/x.csv")


def test_headless_export_matches_the_console(tmp_path, capsys):
    session_file = tmp_path / "jet.stw"
    session_file.write_text(SESSIONS.joinpath("particle_jet.stw").read_text())
    out = tmp_path / "jet.json"
    assert cli.main(["export", str(session_file), "--format", "json", "-o", str(out), "--fps", "50",
                     "--what", "f"]) == 0
    assert "wrote" in capsys.readouterr().out
    doc = json.loads(out.read_text())
    s = Session()
    s.run_file(session_file)
    for name, dof in s.scene.dofs.items():
        assert np.array_equal(np.array(doc["dofs"][name]["control_points"]), dof.curve.coef)
        t = np.array(doc["columns"]["t"])
        assert np.max(np.abs(np.array(doc["columns"][name + "'"]) - dof.curve.evaluate(t, 1))) <= 1e-12
    t = np.array(doc["columns"]["t"])
    assert np.array_equal(np.array(doc["columns"]["f"]), s.scene.evaluate(named_symbol("f"), t))
    assert cli.main(["export", str(tmp_path / "missing.stw"), "-o", str(out)]) == 1


def test_save_writes_a_session_that_replays_to_the_same_scene(tmp_path):
    s = run_lines(Session(), SESSIONS.joinpath("particle_jet.stw").read_text())
    s.execute("shake x amplitude=0.01 seed=3")
    s.execute("snapshot a")
    s.execute("iterate 2")
    s.execute("restore a")
    with pytest.raises(StwError):
        s.execute("weight nosuch 2")
    out = tmp_path / "again.stw"
    assert "saved" in s.execute(f"save {out}").message
    assert s.journal.entries[-1].text == f"# save {out}"
    replay = Session()
    replay.run_file(out)
    assert np.array_equal(replay.scene.coefficient_vector(), s.scene.coefficient_vector())
    s.execute("undo")     # `save` is not a step: this undoes the restore
    assert not np.array_equal(s.scene.coefficient_vector(), replay.scene.coefficient_vector())
    with pytest.raises(SourceError, match="save needs a file"):
        s.execute("save")


def _same_scene(a: Session, b: Session) -> None:
    """The same curves bit for bit (knots and control points), constants and objective."""
    from stw_tui.session.snapshots import measure

    assert list(a.scene.dofs) == list(b.scene.dofs)
    for name in a.scene.dofs:
        assert np.array_equal(a.scene.dofs[name].curve.knots, b.scene.dofs[name].curve.knots), name
        assert np.array_equal(a.scene.dofs[name].curve.coef, b.scene.dofs[name].curve.coef), name
    assert a.scene.constants == b.scene.constants
    assert measure(a.scene).objective == measure(b.scene).objective


def test_save_writes_only_the_lines_that_make_the_scene(tmp_path):
    """Issue 52 item 4: no failed lines, no undone lines nor the `undo`, no queries; a `restore` or
    an `accept` as the lines that made that state. Replayed headless, the file gives the scene;
    `save --journal` keeps everything, as before."""
    jet = SESSIONS.joinpath("particle_jet.stw").read_text()
    setup = [line for line in jet.split("iterate")[0].splitlines() if line.strip() and not line.startswith("#")]
    s = run_lines(Session(), "\n".join(setup) + "\n")
    typed = ["print x @ 0.5", "const k = 3", "undo", "shake x amplitude=0.05 seed=4", "show fuel",
             "snapshot shaken", "iterate 3", "help iterate", "const g = 1.6", "undo", "redo",
             "restore shaken", "set preview on", "iterate 2", "reject", "iterate 4", "accept",
             "cse fuel", "const k = 2", "undo"]
    for line in typed[:3]:
        s.execute(line)
    with pytest.raises(StwError):
        s.execute("weight nosuch 2")                 # failed: never saved
    for line in typed[3:]:
        s.execute(line)
    out = tmp_path / "clean.stw"
    message = s.execute(f"save {out}").message
    assert message.startswith(f"saved {len(setup) + 4} command line(s)")
    assert "--journal" in message
    assert out.read_text().splitlines() == [*setup, "shake x amplitude=0.05 seed=4", "set preview on",
                                            "iterate 4", "accept"]
    replay = Session()
    replay.run_file(out)
    _same_scene(replay, s)
    # --journal: everything, as the journal holds it (the failed line as a comment)
    everything = tmp_path / "journal.stw"
    assert s.execute(f"save {everything} --journal").message == \
        f"saved {len(setup) + len(typed)} command line(s) to {everything}"
    text = everything.read_text()
    assert "# failed: weight nosuch 2" in text and "\nundo\n" in text and "\nprint x @ 0.5\n" in text
    assert text.splitlines()[-1] == f"# save {out}"
    replay = Session()
    replay.run_file(everything)
    _same_scene(replay, s)


def test_save_keeps_a_linkage_block_whole_and_a_stopped_solve_as_it_ran(tmp_path):
    s = run_lines(Session(), "time 0 1 knots=6\nconst g = 9.81\nlinkage arm base=fixed\n  J1 revolute a=1 mass=1\nend\n"
                             "constraint up: arm.tip.y = 1 @ 1\nobjective effort: tau_J1\n")
    s.execute("iterate 3 adapt=0")
    s.execute("undo")
    s.execute("iterate 2 adapt=0")
    out = tmp_path / "arm.stw"
    s.execute(f"save {out}")
    assert out.read_text() == ("time 0 1 knots=6\nconst g = 9.81\nlinkage arm base=fixed\n  J1 revolute a=1 mass=1\nend\n"
                               "constraint up: arm.tip.y = 1 @ 1\nobjective effort: tau_J1\niterate 2 adapt=0\n")
    replay = Session()
    replay.run_file(out)
    _same_scene(replay, s)


def test_save_journal_option_parses_anywhere_after_save(tmp_path):
    s = run_lines(Session(), "dof x\nprint x @ 0\n")
    s.execute(f"save --journal {tmp_path / 'a.stw'}")
    s.execute(f"save {tmp_path / 'a.stw'} --journal overwrite")
    assert (tmp_path / "a.stw").read_text() == f"dof x\nprint x @ 0\n# save --journal {tmp_path / 'a.stw'}\n"
    s.execute(f'save "{tmp_path / "--journal"}"')     # quoted: a file of that name
    assert (tmp_path / "--journal").read_text() == "dof x\n"
    with pytest.raises(SourceError, match="unexpected '--jornal' after the file"):
        s.execute(f"save {tmp_path / 'b.stw'} --jornal")


def test_only_export_and_save_lines_are_read_as_plain_text():
    s = run_lines(Session(), "dof x\n")
    with pytest.raises(SourceError, match="unexpected character"):
        s.execute('print x "')          # the tokenizer's error, not a path's
    with pytest.raises(SourceError, match="unknown command 'exports'"):
        s.execute("exports csv out.csv")


def test_what_adds_subexpressions_as_columns(arm, tmp_path):
    out = tmp_path / "arm.csv"
    arm.execute(f"export csv {out} fps=20 what=tau_ELBOW,arm.tip.x',arm.tip.x")
    table = read_csv(out)
    t = table["t"]
    assert list(table).count("arm.tip.x") == 1
    for name in ("tau_ELBOW", "arm.tip.x'"):
        expected = arm.scene.evaluate(named_symbol(name), t)
        assert np.max(np.abs(table[name] - expected)) <= 1e-12 * max(1, np.max(np.abs(expected))), name
    # the hand's velocity, by the chain rule on the exported joint angles and velocities
    angles = np.cumsum([table["SHOULDER"], table["ELBOW"], table["WRIST"]], axis=0)
    rates = np.cumsum([table["SHOULDER'"], table["ELBOW'"], table["WRIST'"]], axis=0)
    velocity = -sum(a * np.sin(q) * w for a, q, w in zip(LINKS, angles, rates))
    assert np.max(np.abs(table["arm.tip.x'"] - velocity)) <= 1e-12
    with pytest.raises(StwError, match="what=nosuch: not a subexpression"):
        arm.execute(f"export csv {out} what=nosuch")
    with pytest.raises(SourceError, match="names separated by commas"):
        arm.execute(f"export csv {out} what=a+b")


def test_a_file_that_cannot_be_written_whole_keeps_its_old_text_and_leaves_no_temporary(tmp_path):
    from stw_tui.session.atomic_file import replace_text

    path = tmp_path / "out.csv"
    replace_text(path, "old\r\n")                      # newlines as given, not translated
    assert path.read_bytes() == b"old\r\n"
    with pytest.raises(UnicodeEncodeError):
        replace_text(path, "new" + "\ud800")          # fails while writing: after the file exists
    assert path.read_bytes() == b"old\r\n" and [p.name for p in tmp_path.iterdir()] == ["out.csv"]
    with pytest.raises(OSError):
        replace_text(tmp_path / "missing" / "out.csv", "text")
