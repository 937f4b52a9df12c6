"""Twenty kill -9s at random moments during solves (issue 11, item 4).

Each trial runs `stw run SESSION --journal J` and kills it with SIGKILL while it solves: a seeded
RNG picks which solve and how far into it (a fraction of that solve's duration, timed on a first
run left to finish). Then :func:`resume` rebuilds the session from the journal and its
checkpoints, and the test checks that

- every command the run acknowledged (printed its ``[N] …`` line for) is in the journal, and the
  journal holds nothing else than the session's first lines;
- the resumed scene is the uninterrupted run's scene after the same lines, to 1e-12, whether
  resume restored the solves from checkpoints or solved them again;
- going on from there (the lines the kill cut off) ends where the uninterrupted run ends (every
  fourth trial, to keep the test near 20 s of CPU).

The runs are forked from a server process that has imported stw and compiled the session's terms
once, so that a trial costs its solves, not a second of imports: each is still a process of its
own writing its journal through the real `stw run`, killed for real.
"""

from __future__ import annotations

import os
import random
import re
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import numpy as np
import pytest

from stw_tui.session.autosave import SOLVE_COMMANDS
from stw_tui.session.resume import resume
from stw_tui.session.session import Session
from stw_tui.sym.language import classify_line

pytestmark = pytest.mark.skipif(not hasattr(os, "fork"), reason="forks the runs it kills")

KILLS = 20
SEED = 11
TOL = 1e-12

# point_mass_2d.stw's problem, with solves of every kind a journal records: whole-scene iterates
# after edits, a refined DOF, a window, a slide that moves it, and a re-weighted goal.
SESSION = """\
time 0 2 knots=8 samples=16
const m = 1, g = 9.81
dof x, y = 0.5
let fx = m*x''
let fy = m*y'' + m*g
constraint start: x = 0, y = 0.5, x' = 1, y' = -3 @ 0
constraint goal:  x = 2, y = 0.5, x' = 0, y' = 0 @ 2
constraint floor: y >= 0 on [0, 2]
objective thrust: fx, fy
iterate 30
shake y amplitude=0.3 seed=1
iterate 30
refine y [0.2, 0.8]
shake x amplitude=0.3 seed=2
iterate 30
window early dofs=y [0, 1]
shake y amplitude=0.2 seed=3
iterate 30
slide early by 1 iterate 10
use all
weight goal 5
iterate 30
"""
LINES = SESSION.splitlines()
SOLVES = [n for n, line in enumerate(LINES, start=1) if classify_line(line).verb in SOLVE_COMMANDS]

# Reads "JOURNAL<TAB>OUTPUT" lines; forks `stw run SESSION --journal JOURNAL` with its output in
# OUTPUT and answers the child's pid; reaps it only after the next line (the test has sent its
# SIGKILL by then, to the child or to its zombie, never to a reused pid) and answers its status.
SERVER = textwrap.dedent("""
    import os, sys
    from stw_tui.cli.main import main
    from stw_tui.session.session import Session
    session = sys.argv[1]
    Session().run_file(session)      # imports, compiled terms and the backend, once for all runs
    print("ready", flush=True)
    while request := sys.stdin.readline():
        journal, output = request.rstrip("\\n").split("\\t")
        pid = os.fork()
        if pid == 0:
            fd = os.open(output, os.O_WRONLY | os.O_CREAT | os.O_TRUNC)
            os.dup2(fd, 1)
            os.dup2(fd, 2)
            os._exit(main(["run", session, "--journal", journal]))
        print(pid, flush=True)
        sys.stdin.readline()             # "reap"
        print(os.waitpid(pid, 0)[1], flush=True)
""")


def reference() -> list[dict]:
    """The uninterrupted run, in this process: the scene after each line."""
    session, after = Session(), []
    session.run_text(SESSION, on_line=lambda number, line, outcome: after.append(_frozen(session)))
    return after


def _frozen(session: Session) -> dict:
    scene = session.scene
    return {"coef": scene.coefficient_vector().copy(), "dofs": list(scene.dofs),
            "windows": dict(scene.windows), "active": scene.active_window,
            "extra": dict(scene.extra_instances), "constraints": set(scene.constraints),
            "weights": {k: c.weight for k, c in scene.constraints.items()}}


def assert_same(resumed: dict, expected: dict, what: str) -> None:
    assert resumed["dofs"] == expected["dofs"], what
    assert resumed["coef"].shape == expected["coef"].shape, what
    np.testing.assert_allclose(resumed["coef"], expected["coef"], rtol=0, atol=TOL, err_msg=what)
    for key in ("windows", "active", "extra", "constraints", "weights"):
        assert resumed[key] == expected[key], f"{what}: {key}"


class Runs:
    """`stw run` processes forked by the server, each with its journal and its output file."""

    def __init__(self, folder: Path):
        self.folder = folder
        session = folder / "kills.stw"
        session.write_text(SESSION)
        env = {**os.environ, "PYTHONPATH": os.pathsep.join(sys.path), "OMP_NUM_THREADS": "1",
               "OPENBLAS_NUM_THREADS": "1"}
        self.server = subprocess.Popen([sys.executable, "-u", "-c", SERVER, str(session)], env=env,
                                       stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
        self.count = 0

    def _say(self, line: str) -> str:
        self.server.stdin.write(line + "\n")
        self.server.stdin.flush()
        return self.server.stdout.readline()

    def start(self) -> tuple[int, Path, Path]:
        """A new run: its pid, journal and output."""
        if self.count == 0:
            assert self.server.stdout.readline().strip() == "ready"
        self.count += 1
        journal, output = self.folder / f"j{self.count}.stw", self.folder / f"out{self.count}.txt"
        return int(self._say(f"{journal}\t{output}")), journal, output

    def kill(self, pid: int) -> bool:
        """SIGKILL the run (a finished one is a zombie until now); whether the kill ended it."""
        os.kill(pid, signal.SIGKILL)
        return os.WIFSIGNALED(self.wait())

    def wait(self) -> int:
        """The wait status of the last run, once it has ended."""
        return int(self._say("reap"))

    def close(self) -> None:
        self.server.stdin.close()
        self.server.wait(timeout=30)


def acknowledged(output: Path) -> int:
    """The last line number the run printed as done (0 when none)."""
    try:
        text = output.read_text(encoding="utf-8", errors="replace")
    except OSError:
        return 0
    return max((int(n) for n in re.findall(r"^\[(\d+)\] ", text, flags=re.M)), default=0)


def wait_for(output: Path, number: int, timeout: float = 60) -> float:
    """Wait until the run has acknowledged line ``number``; returns when it was seen."""
    deadline = time.monotonic() + timeout
    while acknowledged(output) < number:
        assert time.monotonic() < deadline, f"the run did not reach line {number}: {output.read_text()}"
        time.sleep(0.002)
    return time.monotonic()


def solve_durations(runs: Runs, after: list[dict]) -> dict[int, float]:
    """How long each solve line takes a run here and now, from one run left to finish (whose
    journal resumes to the uninterrupted scene, every solve from its checkpoint)."""
    _, journal, output = runs.start()
    seen = {number: wait_for(output, number) for number in range(1, len(LINES) + 1)}
    assert runs.wait() == 0
    resumed, restored, solved = resume(journal)
    assert (restored, solved) == (len(SOLVES), 0)
    assert_same(_frozen(resumed), after[-1], "the run left to finish")
    return {n: seen[n] - seen[n - 1] for n in SOLVES}


def test_twenty_kill_9s_during_solves_lose_no_acknowledged_command(tmp_path):
    runs = Runs(tmp_path)
    rng = random.Random(SEED)
    tally = {"mid-solve": 0, "re-solved": 0, "restored": 0, "finished": 0}
    try:
        after = reference()             # while the server starts
        seconds = solve_durations(runs, after)
        for trial in range(KILLS):
            solve = rng.choice(SOLVES)
            delay = rng.uniform(0.0, 1.1) * seconds[solve]     # into the solve, or just past it
            pid, journal, output = runs.start()
            wait_for(output, solve - 1)
            time.sleep(delay)
            killed = runs.kill(pid)
            acked = acknowledged(output)          # all it printed before it died
            what = f"trial {trial}: killed {delay:.3f} s after line {solve - 1}, {acked} line(s) acknowledged"

            resumed, restored, solved = resume(journal)
            kept = [e.text for e in resumed.journal.entries if e.ok]
            assert len(kept) >= acked, what                         # every acknowledged line survived
            assert kept == LINES[:len(kept)], what                  # and nothing else was kept
            assert restored + solved == sum(1 for n in SOLVES if n <= len(kept)), what
            if kept:
                assert_same(_frozen(resumed), after[len(kept) - 1], what)
            tally["finished" if not killed else "mid-solve" if len(kept) < solve else
                  "re-solved" if solved else "restored"] += 1
            if trial % 4 == 0:      # go on from there (in memory): the same end as without a kill
                resumed.journal.path = resumed.checkpoints = None
                resumed.run_text("\n".join(LINES[len(kept):]) + "\n")
                assert_same(_frozen(resumed), after[-1], what + ", then the rest of the session")
    finally:
        runs.close()
    print(f"{KILLS} kill -9s during solves: {tally}")
    assert tally["mid-solve"] > 0, tally          # the kills did land inside solves
