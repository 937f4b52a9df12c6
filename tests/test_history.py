"""Undo, redo and named snapshots: exact, journalled, and replayable."""

import dataclasses

import numpy as np
import pytest

from conftest import run_lines
from stw_tui.errors import StwError
from stw_tui.history import History
from stw_tui.session import Session

TWO_D = """
time 0 2 knots=16 samples=32
const m = 1, g = 9.81
dof x, y = 0.5
let fy = m*y'' + m*g
constraint start: x = 0, y = 0.5, x' = 1, y' = -3 @ 0
constraint goal:  x = 2, y = 0.5, x' = 0, y' = 0 @ 2
objective thrust: x'', fy
"""

ARM = """
time 0 1 knots=8
const g = 9.81
linkage arm base=fixed
  SHOULDER revolute a=0.35 mass=2.0
  ELBOW    revolute a=0.30 mass=1.5
end
constraint reach: arm.tip.x = 0.4, arm.tip.y = 0.3 @ 1
objective effort: tau_SHOULDER, tau_ELBOW
"""


def state(scene) -> dict:
    """Everything a scene holds, comparable with ==: curves as raw bytes of their knots and
    control points (bit for bit), every other field as it is."""
    out = {}
    for f in dataclasses.fields(scene):
        value = getattr(scene, f.name)
        if f.name == "dofs":
            value = {n: (d.curve.coef.tobytes(), np.asarray(d.curve.knots).tobytes(), d.lo, d.hi, d.damp,
                         tuple(d.keys)) for n, d in value.items()}
        out[f.name] = value
    return out


def warm_bytes(session):
    w = session.warm
    if w is None:
        return None
    return (w.signature, w.state.s.tobytes(), w.state.lam_eq.tobytes(), w.state.lam_ge.tobytes(),
            w.state.working_set.tobytes(), w.state.merit_weight)


STEPS = [
    "time 0 2 knots=20", "const m = 2", "dof z = t", "dof x knots=10", "dof y lo=-5 hi=5",
    "let h = x + y", "constraint mid: y = 1 @ 1", "constraint band: y >= -1 on [0, 2] samples=8",
    "objective small: x on [0.5, 1.5] weight=0.1", "key 1 x=0.7", "window w dofs=y [0.5, 1.5]", "use all",
    "weight goal 10", "damp x 0.3", "filter y 2", "shake x amplitude=0.01 seed=4", "refine y [0.5, 1]",
    "refine x @ 0.75 multiplicity=2", "backend scipy", "set dense_tol 1e-7", "set samples 20",
    "instances start clear", "delete thrust", "iterate 2",
]


@pytest.mark.parametrize("command", STEPS)
def test_undo_restores_the_scene_bit_for_bit(command):
    s = run_lines(Session(), TWO_D + "iterate 2\n")
    before, warm = state(s.scene), warm_bytes(s)
    s.execute(command)
    s.execute("undo")
    assert state(s.scene) == before
    assert warm_bytes(s) == warm


def test_undo_then_redo_gives_back_the_command_exactly():
    s = run_lines(Session(), TWO_D + "iterate 2\n")
    s.execute("iterate 3")
    after, warm = state(s.scene), warm_bytes(s)
    s.execute("undo")
    s.execute("redo")
    assert state(s.scene) == after and warm_bytes(s) == warm


def test_undo_of_a_linkage_block_and_a_solve():
    s = Session()
    s.run_text("time 0 1 knots=8\nconst g = 9.81\n")
    empty = state(s.scene)
    s.run_text(ARM)
    s.execute("iterate 3")
    solved = s.scene.coefficient_vector().copy()
    for _ in range(3):   # iterate, objective, constraint
        s.execute("undo")
    s.execute("undo")    # the linkage block is one step
    assert "arm" not in s.scene.linkages and not s.scene.derived
    s.execute("undo")   # ARM's const and time lines
    s.execute("undo")
    assert state(s.scene) == empty
    while s.history.redo_steps:
        s.execute("redo")
    assert np.array_equal(s.scene.coefficient_vector(), solved)


def test_solve_after_undo_is_the_solve_without_the_undone_command():
    """The warm start comes back too, so the next solve gives the same numbers."""
    a = run_lines(Session(), TWO_D + "iterate 2\nconstraint mid: y = 1 @ 1\niterate 2\n")
    b = run_lines(Session(), TWO_D + "iterate 2\nconstraint mid: y = 1 @ 1\niterate 2\n")
    a.execute("iterate 2")
    a.execute("undo")
    a.execute("iterate 3")
    b.execute("iterate 3")
    assert np.array_equal(a.scene.coefficient_vector(), b.scene.coefficient_vector())
    assert [r.objective for r in a.runs[-1].reports] == [r.objective for r in b.runs[-1].reports]


def test_nothing_to_undo_or_redo_is_a_clear_error_and_changes_nothing():
    s = Session()
    with pytest.raises(StwError, match="nothing to undo"):
        s.execute("undo")
    run_lines(s, TWO_D)
    before = state(s.scene)
    with pytest.raises(StwError, match="nothing to redo"):
        s.execute("redo")
    assert state(s.scene) == before
    assert s.journal.entries[-1].ok is False


def test_failed_and_read_only_commands_are_not_steps():
    s = run_lines(Session(), TWO_D)
    before = state(s.scene)
    s.execute("dof w")
    with pytest.raises(StwError):
        s.execute("constraint bad: nosuch = 1 @ 0")
    s.execute("print x @ 1")
    s.execute("help undo")
    s.execute("undo")   # undoes `dof w`, not the print, help or the failed constraint
    assert state(s.scene) == before


def test_a_new_command_drops_the_redo_steps():
    s = run_lines(Session(), TWO_D)
    s.execute("const m = 3")
    s.execute("undo")
    s.execute("const g = 1")
    with pytest.raises(StwError, match="nothing to redo"):
        s.execute("redo")
    assert s.scene.constants == {"m": 1, "g": 1}


def test_history_is_bounded():
    s = run_lines(Session(), TWO_D)
    s.history.limit = 3
    for k in range(6):
        s.execute(f"const m = {k + 2}")
    for _ in range(3):
        s.execute("undo")
    assert s.scene.constants["m"] == 4
    with pytest.raises(StwError, match="nothing to undo"):
        s.execute("undo")


def test_undo_and_redo_are_journalled_and_replay_to_the_same_scene():
    s = run_lines(Session(), TWO_D + "iterate 3\n")
    for line in ["constraint mid: y = 1 @ 1", "iterate 3", "undo", "undo", "weight goal 5", "iterate 2",
                 "undo", "redo", "shake y amplitude=0.02", "undo"]:
        s.execute(line)
    text = s.journal.text()
    assert "\nundo\n" in text and "\nredo\n" in text
    replay = run_lines(Session(), text)
    assert np.array_equal(replay.scene.coefficient_vector(), s.scene.coefficient_vector())
    assert state(replay.scene) == state(s.scene)
    assert warm_bytes(replay) == warm_bytes(s)


def test_undo_message_names_the_command():
    s = run_lines(Session(), TWO_D)
    s.execute("weight goal 3")
    assert "`weight goal 3`" in s.execute("undo").message
    assert "`weight goal 3`" in s.execute("redo").message
    assert History.describe("iterate 3 adapt=0\ninstances x add 0.5") == "`iterate 3 adapt=0` …"
