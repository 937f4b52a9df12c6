"""F4 ends a solve within an iteration (issue 52 item 5): the shared SQP reads the stop flag in
its attempts, line search and QP loops (stw_tui/sos/stopping.py), drops the iteration it was in,
and keeps the whole ones, journalled as `iterate K adapt=0` so a replay reaches the same scene."""

from __future__ import annotations

from pathlib import Path

import pytest

from conftest import ENDLESS
from stw_tui.session.session import Session
from stw_tui.sos.backend import Status

SESSIONS = Path(__file__).resolve().parent.parent / "sessions"


def prefix(name: str) -> str:
    """The session's lines before its first `iterate`, then settings that never converge."""
    return (SESSIONS / name).read_text(encoding="utf-8").split("\niterate")[0] + "\n" + ENDLESS


@pytest.mark.parametrize("name, looks", [("particle_jet.stw", 1), ("arm_throw.stw", 3)])
def test_a_stop_asked_during_an_iteration_ends_it_there_and_keeps_the_whole_ones(name, looks):
    """The flag turns true at its ``looks``-th reading after the first iteration: at the first
    attempt (particle_jet, equality rows only) or inside the QP's loops (arm_throw's joint
    limits). Before, the iteration ran to its end and the stop came at the boundary after it."""
    session = Session()
    session.run_text(prefix(name))
    reports, readings = [], []

    def on_report(report) -> bool:
        reports.append(report)
        return True                     # never stops at a boundary: only the flag stops it

    def cancelled() -> bool:
        if reports:
            readings.append(len(reports))
        return len(readings) >= looks
    on_report.cancelled = cancelled

    outcome = session.execute("iterate 50", on_report=on_report)
    assert outcome.run.status is Status.STOPPED
    assert len(outcome.run.reports) == 1 and len(reports) == 1, "the second iteration ran to its end"
    assert readings == [1] * looks
    assert session.journal.commands()[-1] == "iterate 1 adapt=0"

    replayed = Session()
    replayed.run_text(prefix(name))
    replayed.execute("iterate 1 adapt=0")
    assert (session.scene.coefficient_vector() == replayed.scene.coefficient_vector()).all()


def test_a_stop_asked_before_the_first_iteration_lets_it_finish():
    """The first iteration always completes: a stopped solve keeps at least one (`iterate 0`
    does not parse)."""
    session = Session()
    session.run_text(prefix("particle_jet.stw"))

    def on_report(report) -> bool:
        return True
    on_report.cancelled = lambda: True

    outcome = session.execute("iterate 50", on_report=on_report)
    assert outcome.run.status is Status.STOPPED and len(outcome.run.reports) == 1
    assert session.journal.commands()[-1] == "iterate 1 adapt=0"
