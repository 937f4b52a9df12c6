"""The journal is a log that never tears (issue 54 item 5): a line refused by a full disk leaves the
file as it was and changes nothing (`undo` pops no step, `snapshot` keeps none), and a resume reads
a torn last line or bytes that are not UTF-8 with a note, keeping the rest."""

import errno
import os

import pytest

from stw_tui.session.resume import resume
from stw_tui.session.session import Session
from stw_tui.sym.errors import StwError


def full_disk_once(monkeypatch, how: str) -> None:
    """The next journal write is refused with ENOSPC: at fsync, or after a 5-byte fragment."""
    real = {"fsync": os.fsync, "write": os.write}
    armed = [True]

    def fsync(fd):
        if how == "fsync" and armed[0]:
            armed[0] = False
            raise OSError(errno.ENOSPC, "No space left on device")
        return real["fsync"](fd)

    def write(fd, data):
        if how == "write" and armed[0]:
            armed[0] = False
            real["write"](fd, bytes(data[:5]))
            raise OSError(errno.ENOSPC, "No space left on device")
        return real["write"](fd, data)

    monkeypatch.setattr(os, "fsync", fsync)
    monkeypatch.setattr(os, "write", write)


def session_with(path, *lines) -> Session:
    session = Session(journal_path=path)
    for line in lines:
        session.execute(line)
    return session


@pytest.mark.parametrize("how", ["fsync", "write"])
def test_a_refused_line_leaves_the_file_and_the_scene_as_they_were(tmp_path, monkeypatch, how):
    path = tmp_path / "j.stw"
    session = session_with(path, "const a = 1")
    before = path.read_bytes()
    full_disk_once(monkeypatch, how)
    with pytest.raises(StwError, match="could not record"):
        session.execute("const b = 2")
    assert path.read_bytes() == before
    assert "b" not in session.scene.constants
    session.execute("const c = 3")
    assert path.read_bytes() == before + b"const c = 3\n"   # on its own line, not after a fragment
    resumed, _, _ = resume(path)
    assert set(resumed.scene.constants) == {"a", "c"}


def test_a_refused_undo_pops_no_step(tmp_path, monkeypatch):
    path = tmp_path / "j.stw"
    session = session_with(path, "const a = 1", "const b = 2", "const c = 3")
    for _ in range(2):
        full_disk_once(monkeypatch, "fsync")
        with pytest.raises(StwError, match="could not record"):
            session.execute("undo")
    assert len(session.history.undo_steps) == 3 and not session.history.redo_steps
    assert set(session.scene.constants) == {"a", "b", "c"}
    session.execute("undo")   # takes back `const c = 3` only, as the journal's replay does
    assert set(session.scene.constants) == {"a", "b"}
    assert set(resume(path)[0].scene.constants) == {"a", "b"}


def test_a_refused_redo_changes_nothing(tmp_path, monkeypatch):
    path = tmp_path / "j.stw"
    session = session_with(path, "const a = 1", "const b = 2", "undo")
    full_disk_once(monkeypatch, "fsync")
    with pytest.raises(StwError, match="could not record"):
        session.execute("redo")
    assert len(session.history.undo_steps) == 1 and len(session.history.redo_steps) == 1
    assert set(session.scene.constants) == {"a"}


def test_a_refused_snapshot_is_not_kept(tmp_path, monkeypatch):
    path = tmp_path / "j.stw"
    session = session_with(path, "const a = 1")
    full_disk_once(monkeypatch, "fsync")
    with pytest.raises(StwError, match="could not record"):
        session.execute("snapshot one")
    assert "one" not in session.history.snapshots
    with pytest.raises(StwError, match="no snapshot named 'one'"):
        session.execute("restore one")


def test_resume_drops_a_torn_last_line_and_cuts_it_off(tmp_path):
    path = tmp_path / "j.stw"
    path.write_bytes(b"const a = 1\nconst b = 2\nconst c = 3")   # killed before the newline
    notes = []
    session, _, _ = resume(path, on_note=notes.append)
    assert set(session.scene.constants) == {"a", "b"}
    assert len(notes) == 1 and "line 3" in notes[0] and "const c = 3" in notes[0]
    session.execute("const d = 4")
    assert path.read_bytes() == b"const a = 1\nconst b = 2\nconst d = 4\n"


def test_resume_of_a_cut_inside_a_utf8_character_keeps_the_earlier_lines(tmp_path):
    path = tmp_path / "j.stw"
    path.write_bytes(b"const a = 1\n# caf\xc3")   # the second byte of "é" never reached the disk
    notes = []
    session, _, _ = resume(path, on_note=notes.append)
    assert set(session.scene.constants) == {"a"}
    assert len(notes) == 1 and "line 2" in notes[0] and "caf" in notes[0]


def test_resume_skips_a_line_that_is_not_utf8_and_keeps_the_rest(tmp_path):
    path = tmp_path / "j.stw"
    path.write_bytes(b"const a = 1\n# \xff\xfe\nconst b = 2\n")
    notes = []
    session, _, _ = resume(path, on_note=notes.append)
    assert set(session.scene.constants) == {"a", "b"}
    assert len(notes) == 1 and "line 2" in notes[0] and "not valid UTF-8" in notes[0]
