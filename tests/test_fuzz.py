"""A deterministic fuzz of the session language (tests/fuzz.py): a few thousand lines from the
grammar, the real sessions and their mutations. No exception but StwError may escape
Session.execute, no failure may be a bug caught only by the catch-all, and a failed line must
leave the scene exactly as it was. `python tests/fuzz.py --lines 100000` runs the full campaign."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

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
    assert not found.heavy, report                           # no line used 500 MB of its own
    assert len(found.largest) == 10 and "largest lines (their own peak memory):" in report


def _allocating(megabytes: int):
    """An ``execute`` that touches ``megabytes`` of fresh memory, frees it and succeeds."""
    import numpy as np

    def execute(line):
        block = np.ones(megabytes * 2**20 // 8)
        del block
    return execute


def test_each_lines_own_peak_memory_is_measured_even_when_freed_before_it_ends():
    memory = fuzz.LineMemory()
    if not memory.exact:
        pytest.skip("needs Linux's resettable peak RSS (/proc/self/clear_refs)")
    baseline = memory.start()
    _allocating(150)("")
    assert 140 <= memory.used(baseline) < 200             # 150 MB, freed before the line ended
    baseline = memory.start()                             # the next line starts from its own RSS
    assert memory.used(baseline) < 20


def test_a_line_over_the_memory_limit_is_counted_and_shown(monkeypatch):
    from stw_tui.session.session import Session

    monkeypatch.setattr(fuzz, "MEMORY_MB", 100.0)
    memory = fuzz.LineMemory()
    if not memory.exact:
        pytest.skip("needs Linux's resettable peak RSS (/proc/self/clear_refs)")
    found = fuzz.Findings()
    session = Session()
    session.execute = _allocating(150)
    fuzz._one(session, "print big", found, memory)
    session.execute = _allocating(0)
    fuzz._one(session, "print small", found, memory)
    assert [line for _, line in found.heavy] == ["print big"] and not found.clean
    report = found.report()
    assert "lines over 100 MB of their own: 1" in report
    assert report.index("MB: 'print big'") < report.index("MB: 'print small'")   # the largest first
