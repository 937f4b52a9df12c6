"""No limit can lock the session (issue 54, item 7): each has a floor that keeps `set limit` and
`undo` parseable, and the journal's comments (a refused line quoted in `# failed:`) are not
subject to line limits, so a resume reads them back."""

import pytest

from stw_tui.session.resume import resume
from stw_tui.session.session import Session
from stw_tui.sym import limits
from stw_tui.sym.errors import SourceError, StwError


def test_a_limit_below_its_floor_is_refused():
    session = Session()
    with pytest.raises(SourceError, match="limit line_length must be at least 200"):
        session.execute("set limit line_length 3")
    assert session.scene.limits == {}


@pytest.mark.parametrize("name", list(limits.LIMITS))
def test_every_limit_at_its_floor_leaves_the_session_usable(name):
    session = Session()
    session.run_text("time 0 1 knots=4\ndof x\n")
    session.execute(f"set limit {name} {limits.LIMITS[name].floor}")
    session.execute("undo")
    session.execute("redo")
    session.execute(f"set limit {name} {limits.LIMITS[name].default}")
    assert session.scene.limits[name] == limits.LIMITS[name].default


def test_resume_reads_a_failed_line_longer_than_the_limit(tmp_path):
    journal = tmp_path / "j.stw"
    session = Session(journal_path=journal)
    session.execute("time 0 1 knots=4")
    session.execute("set limit line_length 200")
    long = "const a = " + "1 + " * 46 + "nope"      # 198 characters, within the limit; fails
    with pytest.raises(StwError, match="nope"):
        session.execute(long)
    assert any(len(line) > 200 and line.startswith("# failed:") for line in journal.read_text().splitlines())
    resumed, _, _ = resume(journal)
    assert resumed.scene.limits == {"line_length": 200} and resumed.scene.knots == 4
