"""Linkage blocks in sessions, and the paper's arm throw (5.1)."""

import numpy as np
import pytest

from conftest import SESSIONS
from stw_tui.errors import SourceError, StwError
from stw_tui.figure import scene_figure
from stw_tui.session import Session

ARM = """time 0 1 knots=8
const g = 9.81
linkage arm base=fixed
  SHOULDER revolute a=0.35 mass=2.0
  ELBOW    revolute a=0.30 mass=1.5
end
"""


def test_linkage_block_defines_dof_and_subexpressions():
    s = Session()
    s.run_text(ARM + "print arm.tip.x @ 0\nprint tau_SHOULDER @ 0\n")
    assert list(s.scene.dofs) == ["SHOULDER", "ELBOW"]
    # All angles 0: the arm lies along x; tip at 0.65; static shoulder torque = moment of gravity
    # of two uniform rods: 2*g*0.175 + 1.5*g*(0.35 + 0.15).
    assert s.prints[0].value == pytest.approx(0.65, abs=1e-12)
    assert s.prints[1].value == pytest.approx(9.81 * (2 * 0.175 + 1.5 * 0.5), rel=1e-12)
    figure = scene_figure(s.scene, 0.5)
    assert figure.segments[-1][1] == pytest.approx((0.65, 0.0), abs=1e-12)


def test_bad_linkage_block_leaves_the_scene_unchanged():
    s = Session()
    s.run_text("time 0 1 knots=8\nconst g = 9.81\ndof x\n")
    before = (dict(s.scene.dofs), dict(s.scene.derived))
    s.execute("linkage arm base=fixed", line=4)
    s.execute("  SHOULDER revolute a=oops", line=5)
    with pytest.raises(SourceError) as err:
        s.execute("end", line=6)
    assert err.value.line == 5
    assert (dict(s.scene.dofs), dict(s.scene.derived)) == before
    with pytest.raises(StwError, match="already"):
        s.run_text("linkage x\n  J revolute a=1\nend\n")


def test_arm_throw_converges_to_an_underhand_toss():
    s = Session()
    s.run_file(SESSIONS / "arm_throw.stw")
    assert all(run.converged for run in s.runs)
    assert s.runs[-1].reports[-1].max_violation <= 1e-6
    prints = [(p.expr, p.t, p.value) for p in s.prints]
    shoulder = prints[0][2]
    assert -np.pi / 2 < shoulder < 0          # hand below the shoulder at release: underhand
    assert prints[1][2] > 0                   # ball rising as it leaves the hand
    before, after = prints[2][2], prints[4][2]           # hand-ball gap summaries near release
    assert after["mean"] < before["mean"] / 2 and after["max"] < before["max"]
    assert before["max"] < 0.02                          # held within 2 cm even before
    assert prints[3][2] == pytest.approx(1.5, abs=1e-6)


def test_acrobat_flips_with_physically_valid_flight():
    s = Session()
    s.run_file(SESSIONS / "acrobat.stw")
    assert s.runs[-1].converged and s.runs[-1].reports[-1].max_violation <= 1e-6
    values = [p.value for p in s.prints]
    assert values[0] == pytest.approx(np.pi / 2 + 2 * np.pi, abs=1e-9)
    assert values[1] > 0.5                      # airborne
    assert abs(values[2]) < 1e-8                # no vertical force at a flight instance
    assert abs(values[3]) < 0.1 * 2 * 9.81      # and little between instances (< 10% of weight)
    assert values[4] == pytest.approx(1.8, abs=1e-9)
    # Two plain jumps before the flip: the foot leaves the ground and FOOT makes no full turn.
    foot = s.scene.dofs["FOOT"].curve
    assert abs(foot.evaluate(np.array([1.5]))[0] - np.pi / 2) < np.pi / 2
    y = s.scene.dofs["Y"].curve.evaluate(np.array([0.75, 1.75]))
    assert np.all(y > 0.05)


def test_keyframes_turn_the_toss_overhand():
    s = Session()
    s.run_file(SESSIONS / "arm_overhand.stw")
    assert s.runs[-1].converged and s.runs[-1].reports[-1].max_violation <= 1e-6
    tip_y, ball_vx, goal_x = (p.value for p in s.prints)
    assert tip_y > 0 and ball_vx > 0            # released above the shoulder, moving forward
    assert goal_x == pytest.approx(1.5, abs=1e-6)


def test_basketball_player_catches_its_own_throw_and_scores():
    s = Session()
    s.run_file(SESSIONS / "basketball.stw")
    assert s.runs[-1].converged and s.runs[-1].reports[-1].max_violation <= 1e-6
    px, pz, turn, gap, bx = (p.value for p in s.prints)
    assert np.hypot(px, pz) > 0.5 and abs(turn) > 0.1   # it moved and turned to catch
    assert abs(gap) < 1e-6 and bx == pytest.approx(2.0, abs=1e-6)
    figure = scene_figure(s.scene, 1.7)
    assert len(figure.segments) == 3                   # the arm is drawn (a side view)
