"""A deterministic fuzz of the session language (tests/fuzz.py): a few thousand lines from the
grammar, the real sessions and their mutations. No exception but StwError may escape
Session.execute, no failure may be a bug caught only by the catch-all, and a failed line must
leave the scene exactly as it was. `python tests/fuzz.py --lines 100000` runs the full campaign."""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

import fuzz  # noqa: E402

LINES = 3000


def test_fuzzed_lines_fail_only_as_user_errors_and_change_nothing(monkeypatch):
    monkeypatch.setenv("STW_CACHE_DIR", "off")
    found = fuzz.run(LINES, seed=1)
    report = found.report()
    assert found.lines == LINES
    assert not found.escaped, report
    assert not found.internal, report + "\n" + "\n".join(found.traces.values())
    assert found.changed_on_failure == 0, report
    assert found.failed < LINES, report                      # most lines are not refused
    assert all(seconds < 10 for seconds, _ in found.slow), report   # 2 s is the goal; CI is shared
