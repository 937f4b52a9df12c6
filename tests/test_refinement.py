"""Adaptive refinement refines the curves (issue 50 part 3): knots where an equation fails between
its instances, journalled as the `refine` and `instances` lines a replay applies, within the
control-point budget `adaptive_points`; and a window with more equality instances than free
control points says so."""

import numpy as np
import pytest

import catalogue
from conftest import run_lines
from stw_tui.session.checkpoint_record import restored_scene, scene_record
from stw_tui.session.session import Session
from stw_tui.sos.continuous import check_scene

# Y must follow sin(3 X) while X sweeps 0 -> 3: no cubic on 8 spans can, between its instances.
TRACK = """time 0 1 knots=8 samples=8
dof X, Y
constraint ends: X = 0, X' = 0 @ 0
constraint goal: X = 3, X' = 0 @ 1
constraint track: Y - sin(3*X) = 0 on [0, 1]
objective smooth: X'', Y''
"""


def curves(scene) -> dict:
    return {n: (d.curve.knots.tobytes(), d.curve.coef.tobytes()) for n, d in scene.dofs.items()}


def test_refinement_inserts_knots_in_the_dof_the_failing_equation_reads_and_says_so():
    s = run_lines(Session(), TRACK)
    before = {n: d.curve.n_coef for n, d in s.scene.dofs.items()}
    outcome = s.execute("iterate 60")
    after = {n: d.curve.n_coef for n, d in s.scene.dofs.items()}
    assert after["X"] > before["X"] and after["Y"] > before["Y"]
    assert "refined X, Y over [" in outcome.message and "for track" in outcome.message
    assert f"({sum(before.values())} -> {sum(after.values())} control points)" in outcome.message
    # the new freedom is constrained: the equation has instances on the new knots
    assert len(s.scene.extra_instances["track"]) >= after["Y"] - before["Y"]
    assert outcome.run.converged


def test_the_journal_replays_the_refined_curves_bit_for_bit_and_undo_restores_the_scene():
    s = run_lines(Session(), TRACK)
    start = curves(s.scene), dict(s.scene.extra_instances)
    s.execute("iterate 60")
    replay = run_lines(Session(), "\n".join(s.journal.replayable()))
    assert curves(replay.scene) == curves(s.scene)
    assert replay.scene.extra_instances == s.scene.extra_instances
    s.execute("undo")
    assert (curves(s.scene), dict(s.scene.extra_instances)) == start
    s.execute("redo")
    assert curves(s.scene) == curves(replay.scene)


def test_a_stopped_refining_solve_is_journalled_as_refine_and_instances_lines(monkeypatch):
    from dataclasses import replace

    from stw_tui.session import interpreter
    from stw_tui.sos.backend import Status

    s = run_lines(Session(), TRACK)
    real, calls = interpreter.run_iterations, []

    def stop_the_third(backend, problem, start, n, settings, on_report=None, **hooks):
        calls.append(n)
        if len(calls) < 3:
            return real(backend, problem, start, n, settings, on_report, **hooks)
        return replace(real(backend, problem, start, 1, settings, on_report, **hooks), status=Status.STOPPED)
    monkeypatch.setattr(interpreter, "run_iterations", stop_the_third)
    s.execute("iterate 60")
    lines = "\n".join(s.journal.replayable()).splitlines()
    assert any(line.startswith("refine X [") for line in lines)
    assert any(line.startswith("instances track add ") for line in lines)
    monkeypatch.undo()
    replay = run_lines(Session(), "\n".join(lines))
    assert curves(replay.scene) == curves(s.scene)


def test_the_control_point_budget_stops_refinement_with_a_clear_message():
    s = run_lines(Session(), TRACK + "set adaptive_points 24\n")
    outcome = s.execute("iterate 60")
    assert sum(d.curve.n_coef for d in s.scene.dofs.values()) <= 24
    assert "the control-point budget stopped refinement for track (adaptive_points 24" in outcome.message
    assert "`set adaptive_points N` allows more" in outcome.message
    with pytest.raises(Exception, match="whole number"):
        s.execute("set adaptive_points lots")


def test_inequalities_keep_adding_instances_only():
    floor = """time 0 2 knots=16 samples=64
dof y = 0.5
constraint start: y = 0.5, y' = -3 @ 0
constraint goal:  y = 0.5, y' = 0 @ 2
constraint floor: y >= 0 on [0, 2]
objective thrust: y'' + 9.81
"""
    s = run_lines(Session(), floor)
    outcome = s.execute("iterate 30")
    assert "refined" not in outcome.message and "added" in outcome.message
    assert s.scene.dofs["y"].curve.n_coef == 19
    assert check_scene(s.scene).checks["floor"].dense <= 1e-6


def test_a_checkpoint_carries_the_refined_knots():
    s = run_lines(Session(), TRACK)
    s.execute("iterate 60")
    record = scene_record(s.scene, s.warm, 0)
    fresh = run_lines(Session(), TRACK)
    assert curves(restored_scene(fresh, record)) == curves(s.scene)


def test_an_over_determined_window_says_so_and_suggests_refine():
    s = run_lines(Session(), """time 0 1 knots=4 samples=40
dof X
constraint wig: X - sin(20*t) = 0 on [0, 1]
set adaptive off
""")
    outcome = s.execute("iterate 30")
    assert "41 equality instances on only 7 free control points" in outcome.message
    assert "`refine`" in outcome.message and "shake" not in outcome.message


# The raw grasp: a three-link arm and a ball, tied by a constraint, not by `hold`.
IN_HAND = catalogue.problem("analytic_arm3").text + """dof BX, BY
limit SHOULDER -2.6 3.2
limit ELBOW 0 2.5
limit WRIST -1.2 1.2
dof SHOULDER = -pi/2
dof BY = -0.8
constraint hang: SHOULDER = -pi/2, ELBOW = 0, WRIST = 0, SHOULDER' = 0, ELBOW' = 0, WRIST' = 0, BX' = 0, BY' = 0 @ 0
constraint in_hand: arm.tip.x - BX = 0, arm.tip.y - BY = 0 on [0, 0.6]
constraint flight: BX'' = 0, BY'' + g = 0 on [0.6, 1.5]
constraint goal: BX = 1.5, BY = 0.5 @ 1.5
constraint rest: SHOULDER' = 0, ELBOW' = 0, WRIST' = 0 @ 1.5
objective effort: tau_SHOULDER, tau_ELBOW, tau_WRIST
set adaptive on
"""


def hand(scene, t):
    """The arm's tip by planar forward kinematics, apart from stw's compiler."""
    angle, x, y = 0.0, 0.0, 0.0
    for name, a in (("SHOULDER", 0.35), ("ELBOW", 0.30), ("WRIST", 0.15)):
        angle = angle + scene.dofs[name].curve.evaluate(t)
        x, y = x + a * np.cos(angle), y + a * np.sin(angle)
    return x, y


def test_the_raw_in_hand_constraint_converges_with_the_ball_in_the_hand_by_refinement():
    # Measured: one round refines every DOF over [0.125, 0.6875] (135 -> 180 control points) and
    # leaves the ball 0.91 mm from the hand; a second round's re-solve reaches its limit and is
    # undone. Without unit rows in the curvature test the first re-solve crawled under a false
    # shift (40 against a least eigenvalue of -0.2) and was undone too, at 28 mm.
    s = run_lines(Session(), IN_HAND)
    outcome = s.execute("iterate 150")
    assert outcome.run.converged
    t = np.arange(0, 0.6 + 1e-12, 1e-3)
    x, y = hand(s.scene, t)
    gap = np.hypot(x - s.scene.dofs["BX"].curve.evaluate(t), y - s.scene.dofs["BY"].curve.evaluate(t))
    assert gap.max() <= 5e-3
    assert "refined" in outcome.message and "BX" in outcome.message and "for in_hand" in outcome.message
