"""The solver process (stw_tui/session/child_process.py): a solve run there leaves the session
exactly as one run here would, streams its reports, stops when asked, and a child that dies costs
only the command."""

from __future__ import annotations

import os
import signal
import threading

import numpy as np
import pytest

from conftest import ENDLESS
from stw_tui.session.child_process import NotPortable, SolverProcess, runs_in_solver_process
from stw_tui.session.session import Session
from stw_tui.sos.backend import Status
from stw_tui.sym.errors import SourceError, StwError

JET = """time 0 1
dof x = 0
dof y = 0
const g = 9.81
let f = x'' - 1
objective fuel: f
constraint start: x = 0, x' = 0 @ 0
constraint goal: x = 0.5 @ 1
"""


@pytest.fixture
def solver():
    process = SolverProcess()
    yield process
    process.close()




def jet(endless: bool = False) -> Session:
    session = Session()
    session.run_text(JET + (ENDLESS if endless else ""))
    return session


def test_a_solve_in_the_child_leaves_the_session_as_one_here_would(solver):
    here, there = jet(), jet()
    mine = []
    expected = here.execute("iterate 10", on_report=lambda r: mine.append(r) or True)
    streamed = []
    session, outcome, error = solver.execute(there, "iterate 10", 7, lambda r: streamed.append(r) or True,
                                             lambda: False)
    assert error is None and outcome.message == expected.message
    assert session is not there and there.runs == []                 # the copy sent is not changed
    for name, dof in here.scene.dofs.items():
        assert np.array_equal(session.scene.dofs[name].curve.coef, dof.curve.coef)   # bit for bit
    assert [r.objective for r in streamed] == [r.objective for r in mine]
    assert session.journal.replayable()[-1] == "iterate 10"
    again, outcome, error = solver.execute(session, "print x @ 1", None, lambda r: True, lambda: False)
    assert error is None and abs(again.prints[-1].value - 0.5) < 1e-9   # the same process, next command


def test_a_bad_command_comes_back_as_its_error_with_line_and_column(solver):
    session, outcome, error = solver.execute(jet(), "iterate abc", 3, lambda r: True, lambda: False)
    assert outcome is None and isinstance(error, SourceError)
    assert (error.line, error.column) == (3, 9), str(error)
    assert session.journal.entries[-1].ok is False                  # recorded as failed, as here


def test_a_stop_ends_the_solve_in_the_child_at_the_next_iteration(solver):
    session = jet(endless=True)
    reports = []
    session, outcome, error = solver.execute(session, "iterate 100000", None,
                                             lambda r: reports.append(r) or True, lambda: len(reports) >= 3)
    assert error is None and session.runs[-1].status is Status.STOPPED
    assert 3 <= len(session.runs[-1].reports) < 100


def test_a_child_that_dies_costs_only_the_command(solver):
    session = jet(endless=True)
    killed = threading.Event()

    def on_report(report):
        if not killed.is_set():
            killed.set()
            os.kill(solver.pid, signal.SIGKILL)
        return True
    with pytest.raises(StwError, match=r"solver process ended during `iterate 100000` \(exit code -9\); "
                                       r"the scene is as it was"):
        solver.execute(session, "iterate 100000", None, on_report, lambda: False)
    assert session.runs == [] and solver.pid is None
    after, _, error = solver.execute(session, "iterate 5", None, lambda r: True, lambda: False)   # a new child
    assert error is None and len(after.runs) == 1


def test_a_session_that_does_not_pickle_is_not_portable(solver):
    session = jet()
    session.unpicklable = threading.Lock()
    with pytest.raises(NotPortable):
        solver.execute(session, "iterate 5", None, lambda r: True, lambda: False)


def test_only_solves_run_in_the_child():
    assert runs_in_solver_process("iterate 20") and runs_in_solver_process("slide w by 0.1")
    assert not runs_in_solver_process("dof x = 0") and not runs_in_solver_process("# iterate")
    assert not runs_in_solver_process("survey 10")   # a survey runs its own processes


ORPHAN = """
import sys, threading
from stw_tui.session.child_process import SolverProcess
from stw_tui.session.session import Session

def main():
    session = Session()
    session.run_text(sys.argv[1])
    solver = SolverProcess()
    def report(r):
        if report.first:
            report.first = False
            print(solver.pid, flush=True)
        return True
    report.first = True
    print(solver.execute(session, "iterate 100000", None, report, lambda: False)[2], flush=True)

if __name__ == "__main__":
    main()
"""


def test_a_solve_does_not_outlive_a_killed_stw(tmp_path):
    import subprocess
    import sys
    import time

    script = tmp_path / "orphan.py"
    script.write_text(ORPHAN)
    text = JET + ENDLESS
    stw = subprocess.Popen([sys.executable, str(script), text], stdout=subprocess.PIPE, text=True)
    try:
        child = int(stw.stdout.readline())
        os.kill(stw.pid, signal.SIGKILL)                  # no close(), no cleanup: a lost terminal
        stw.wait(timeout=10)
        deadline = time.monotonic() + 15
        while time.monotonic() < deadline and _running(child):
            time.sleep(0.05)
        assert not _running(child), "the solver process went on solving after stw was killed"
    finally:
        stw.kill()


def _running(pid: int) -> bool:
    """Whether ``pid`` is a live process (a zombie, dead but not yet reaped by init, is not)."""
    try:
        with open(f"/proc/{pid}/stat") as stat:
            return stat.read().rsplit(")", 1)[1].split()[0] != "Z"
    except FileNotFoundError:
        return False
