"""The README's session table: one row per bundled session, each saying what its motion shows."""

import re

from conftest import ROOT, SESSIONS


def test_every_bundled_session_has_one_row_in_the_readme_table():
    rows = re.findall(r"^\| `([^`]+\.stw)` \| (.+) \|$", (ROOT / "README.md").read_text(), re.MULTILINE)
    names = [name for name, _ in rows]
    assert sorted(names) == sorted(p.name for p in SESSIONS.glob("*.stw")), "add or drop rows in README.md"
    assert all(len(what.split()) >= 8 for _, what in rows)     # a line on the motion, not a title
