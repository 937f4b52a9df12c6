"""Undo, redo and named snapshots: exact, journalled, and replayable."""

import dataclasses

import numpy as np
import pytest

import catalogue
from conftest import run_lines
from stw_tui.session.history import History
from stw_tui.session.session import Session
from stw_tui.sym.errors import StwError

TWO_D = catalogue.problem("analytic_point_mass").text
ARM = catalogue.problem("analytic_arm2").text + """constraint reach: arm.tip.x = 0.4, arm.tip.y = 0.3 @ 1
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


# --- named snapshots -----------------------------------------------------------------------------

def test_restore_brings_back_the_snapshot_exactly_and_is_undoable():
    s = run_lines(Session(), TWO_D + "iterate 2\n")
    s.execute("snapshot start")
    kept, warm = state(s.scene), warm_bytes(s)
    for line in ["constraint mid: y = 1 @ 1", "refine y [0.5, 1]", "const m = 2", "iterate 3"]:
        s.execute(line)
    changed = state(s.scene)
    s.execute("restore start")
    assert state(s.scene) == kept and warm_bytes(s) == warm
    s.execute("undo")
    assert state(s.scene) == changed


def test_snapshot_is_not_a_step():
    s = run_lines(Session(), TWO_D)
    before = state(s.scene)
    s.execute("const m = 5")
    s.execute("snapshot a")
    s.execute("snapshots")
    s.execute("diff a")
    s.execute("undo")    # takes back `const m = 5`
    assert state(s.scene) == before
    assert "replaced" in s.execute("snapshot a").message


def test_unknown_snapshot_is_an_error_that_names_the_known_ones():
    s = run_lines(Session(), TWO_D)
    s.execute("snapshot first")
    before = state(s.scene)
    for line in ("restore nosuch", "diff nosuch"):
        with pytest.raises(StwError, match="no snapshot named 'nosuch' .*first"):
            s.execute(line)
    assert state(s.scene) == before


def test_snapshots_lists_objective_and_violation_of_each():
    s = run_lines(Session(), TWO_D)
    s.execute("snapshot raw")
    s.execute("iterate 10")
    s.execute("snapshot solved")
    last = s.runs[-1].reports[-1]
    from stw_tui.session.snapshots import measure
    m = measure(s.history.snapshots["solved"].scene)
    assert m.objective == pytest.approx(last.objective, rel=1e-12)
    assert m.violation < 1e-8 and m.dense < 1e-8
    raw = measure(s.history.snapshots["raw"].scene)
    assert raw.violation == pytest.approx(3.0)      # y' = -3 at the start, the curve's is 0
    text = s.execute("snapshots").message
    assert "raw" in text and "solved" in text and f"{last.objective:.6g}" in text and "3.00e+00" in text


def test_diff_names_the_changed_dof_and_how_much():
    s = run_lines(Session(), TWO_D + "iterate 5\n")
    s.execute("snapshot a")
    old_y = s.scene.dofs["y"].curve
    s.execute("shake y amplitude=0.05 seed=1")
    s.execute("const g = 9.8")
    from stw_tui.session.snapshots import diff_scenes
    d = diff_scenes(s.history.snapshots["a"].scene, s.scene)
    changes = {c.name: c for c in d.dofs}
    assert changes["x"].max_abs == 0 and changes["y"].max_abs > 0
    t = np.linspace(0, 2, 20001)
    fine = np.max(np.abs(s.scene.dofs["y"].curve.evaluate(t) - old_y.evaluate(t)))
    assert fine * (1 - 1e-3) <= changes["y"].max_abs <= fine * (1 + 1e-9)   # the grid finds the peak
    assert d.changed == {"constants": ["~g"]}
    text = s.execute("diff a").message
    assert "y: max |change|" in text and "unchanged: x" in text and "constants: ~g" in text
    assert "before: objective" in text and "now:    objective" in text


def test_snapshots_replay_from_the_journal():
    s = run_lines(Session(), TWO_D + "iterate 2\n")
    for line in ["snapshot a", "constraint mid: y = 1 @ 1", "iterate 3", "snapshot b", "restore a",
                 "iterate 1", "restore b", "undo"]:
        s.execute(line)
    replay = run_lines(Session(), s.journal.text())
    assert state(replay.scene) == state(s.scene)
    assert list(replay.history.snapshots) == ["a", "b"]


def test_a_stopped_solve_is_one_step():
    s = run_lines(Session(), TWO_D)
    before, warm = state(s.scene), warm_bytes(s)
    before_coef = s.scene.coefficient_vector().copy()
    s.execute("iterate 10", on_report=lambda report: False)    # stopped after its first iteration
    assert s.runs[-1].status.name == "STOPPED" and not np.array_equal(s.scene.coefficient_vector(),
                                                                       before_coef)
    s.execute("undo")
    assert state(s.scene) == before and warm_bytes(s) == warm


def test_a_failed_solve_leaves_the_warm_start_as_it_was(monkeypatch):
    """A command that fails after its solve ran keeps neither the scene nor the multipliers, so a
    replay (where it is a comment) goes on from the same warm start."""
    import stw_tui.session.interpreter as interpreter

    s = run_lines(Session(), TWO_D + "iterate 2\nconstraint mid: y = 1 @ 1\n")
    before, warm = state(s.scene), warm_bytes(s)

    def broken(*args, **kwargs):
        raise StwError("the dense check broke")
    monkeypatch.setattr(interpreter, "survey_failures", broken)
    with pytest.raises(StwError, match="dense check broke"):
        s.execute("iterate 5")
    assert state(s.scene) == before and warm_bytes(s) == warm


def test_a_replaced_snapshot_is_measured_again():
    s = run_lines(Session(), TWO_D)
    s.execute("snapshot a")
    first = s.history.measured("a")
    assert s.history.measured("a") is first        # kept: the snapshot's scene never changes
    s.execute("iterate 10")
    s.execute("snapshot a")
    assert s.history.measured("a").violation < 1e-8 < first.violation


@pytest.mark.parametrize("first, second, kind", [
    ("constraint c: x = 0 @ 0", "constraint c: x = 1 @ 0", "constraints"),
    ("objective e: x''", "objective e: x'", "objectives"),
    ("let u = x + 1", "let u = x + 2", "lets"),
])
def test_redefining_a_name_says_so_and_undo_brings_the_old_one_back(first, second, kind):
    s = run_lines(Session(), f"time 0 1 knots=8\ndof x\n{first}\n")
    assert "replaced" not in s.execute("constraint other: x = 0 @ 1").message   # a new name: nothing to say
    before = state(s.scene)[kind]
    message = s.execute(second).message
    assert "replaced the old definition; `undo` brings it back" in message
    assert state(s.scene)[kind] != before
    s.execute("undo")
    assert state(s.scene)[kind] == before


def test_a_constant_given_a_new_value_says_what_it_was():
    s = run_lines(Session(), "const k = 1\n")
    assert s.execute("const k = 2").message == "k = 2 (k was 1; `undo` brings it back)"
    assert s.execute("const k = 2").message == "k = 2"     # the same value: nothing replaced
    s.execute("undo")
    s.execute("undo")
    assert s.scene.constants["k"] == 1
