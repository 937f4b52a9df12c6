"""Files are written only where asked and never clobbered (issue 54, item 2): `save`, `export` and
`--journal` refuse an existing file unless told (`overwrite`), never write through a link or to
anything but a regular file, write whole with the user's umask; a replayed session file writes
only inside its own folder; `open` of a file that is not a session does not quote it."""

import os
import stat

import pytest

from stw_tui.cli.main import main
from stw_tui.session.session import Session
from stw_tui.sym.errors import StwError

SCENE = "time 0 1 knots=4\ndof x\n"


def scene() -> Session:
    session = Session()
    session.run_text(SCENE)
    return session


def test_save_and_export_refuse_an_existing_file_unless_told(tmp_path):
    target = tmp_path / "bashrc"
    target.write_text("alias ls='ls -F'\n")
    os.chmod(target, 0o644)
    session = scene()
    for line in (f"save {target}", f"export csv {target}"):
        with pytest.raises(StwError, match=r"exists \(add `overwrite` to replace it\)"):
            session.execute(line)
    assert target.read_text() == "alias ls='ls -F'\n"
    old = os.umask(0o027)
    try:
        session.execute(f"save {target} overwrite")
        session.execute(f"export csv {tmp_path / 'new.csv'}")
    finally:
        os.umask(old)
    assert target.read_text().startswith("time 0 1")
    assert stat.S_IMODE(target.stat().st_mode) == 0o640          # the umask's, not mkstemp's 0600
    assert stat.S_IMODE((tmp_path / "new.csv").stat().st_mode) == 0o640
    assert not [p for p in tmp_path.iterdir() if p.name.endswith(".tmp")]


@pytest.mark.parametrize("umask, mode", [(0o022, 0o644), (0o077, 0o600), (0o002, 0o664)])
def test_saved_and_exported_files_follow_the_umask(tmp_path, monkeypatch, umask, mode):
    """A new file's mode is 0666 less the umask, as for any program's; and writing one never sets
    the umask (it is process-wide: another thread's file made meanwhile would get a wrong mode)."""
    session = scene()
    old = os.umask(umask)
    try:
        calls = []
        monkeypatch.setattr(os, "umask", lambda *args: calls.append(args) or umask)
        for line in (f"save {tmp_path / 'a.stw'}", f"save {tmp_path / 'b.stw'} --journal", f"export csv {tmp_path / 'a.csv'}", f"export json {tmp_path / 'a.json'}"):
            session.execute(line)
        monkeypatch.undo()
    finally:
        os.umask(old)
    assert calls == []
    for name in ("a.stw", "b.stw", "a.csv", "a.json"):
        assert stat.S_IMODE((tmp_path / name).stat().st_mode) == mode, name
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.csv", "a.json", "a.stw", "b.stw"]


def test_never_through_a_link_nor_onto_a_device(tmp_path):
    secret = tmp_path / "secret"
    secret.write_text("keep\n")
    link = tmp_path / "link.csv"
    link.symlink_to(secret)
    fifo = tmp_path / "fifo.json"
    os.mkfifo(fifo)
    session = scene()
    for line in (f"export csv {link} overwrite", f"save {link}", f"export json {fifo} overwrite"):
        with pytest.raises(StwError, match="not a regular file"):
            session.execute(line)
    assert link.is_symlink() and secret.read_text() == "keep\n"
    assert stat.S_ISFIFO(fifo.lstat().st_mode)


def test_a_replayed_file_writes_only_in_its_own_folder(tmp_path, monkeypatch):
    folder = tmp_path / "sessions"
    folder.mkdir()
    monkeypatch.chdir(tmp_path)
    (folder / "out.stw").write_text(SCENE + "save ../escaped.stw\n")
    with pytest.raises(StwError, match="line 3: a session file may write only inside its own folder"):
        Session().run_file(folder / "out.stw")
    assert not (tmp_path / "escaped.stw").exists()
    (folder / "in.stw").write_text(SCENE + f"save {folder}/here.stw\nexport csv {folder}/sub/../there.csv\n"
                                   "save here.stw\n")   # relative to the working folder: outside
    (folder / "sub").mkdir()
    with pytest.raises(StwError, match="line 5: a session file may write only inside"):
        Session().run_file(folder / "in.stw")
    assert (folder / "here.stw").is_file() and (folder / "there.csv").is_file()
    session = Session()     # `open` from the console: the opened file's folder, not the typed line's
    with pytest.raises(StwError, match="may write only inside its own folder"):
        session.execute(f"open {folder / 'out.stw'}")
    session.execute(f"save {tmp_path / 'typed.stw'}")   # typed: wherever the user says
    assert (tmp_path / "typed.stw").is_file()


def test_open_of_a_file_that_is_not_a_session_does_not_quote_it(tmp_path):
    secrets = tmp_path / "secrets.env"
    secrets.write_text("\n# config\nTOKEN=s3cr3t-value\n")
    with pytest.raises(StwError, match="is not an stw session") as info:
        Session().execute(f"open {secrets}")
    assert "TOKEN" not in str(info.value) and "s3cr3t" not in str(info.value)


def test_journal_refuses_an_existing_file_unless_told(tmp_path, capsys):
    session_file = tmp_path / "s.stw"
    session_file.write_text(SCENE)
    journal = tmp_path / "j.stw"
    journal.write_text("precious\n")
    assert main(["run", str(session_file), "--journal", str(journal)]) == 2
    assert "--overwrite" in capsys.readouterr().err and journal.read_text() == "precious\n"
    link = tmp_path / "link.stw"
    link.symlink_to(journal)
    assert main(["run", str(session_file), "--journal", str(link), "--overwrite"]) == 2
    assert "not a regular file" in capsys.readouterr().err and journal.read_text() == "precious\n"
    assert main(["run", str(session_file), "--journal", str(journal), "--overwrite"]) == 0
    assert journal.read_text() == SCENE
