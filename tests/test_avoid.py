"""`avoid`: links kept apart, checked at 1 ms samples with planar kinematics and point-to-segment
distances written here (not through stw's compiler or its continuous-time check).

Tolerance: the distance may fall short of `by` by at most the verb's dense tolerance, 1 mm (1e-3 rad
for links that share a joint, which is 1 mm at the tip of a 1 m link)."""

import numpy as np
import pytest

from stw_tui.session.session import Session
from stw_tui.sym.errors import StwError

SWING = """time 0 2 knots=16
const g = 9.81
linkage dp base=fixed
  UPPER revolute a=1 mass=1
  FORE  revolute a=1 mass=1
end
dof UPPER = -pi/2 + pi*t/2
constraint hang: UPPER = -pi/2, FORE = 0, UPPER' = 0, FORE' = 0 @ 0
constraint up: UPPER = pi/2, FORE = 0, UPPER' = 0, FORE' = 0 @ 2
objective effort: tau_UPPER, tau_FORE
set adaptive on
"""


def samples(session, names, t0=0.0, t1=2.0):
    times = np.arange(t0, t1 + 1e-12, 1e-3)
    return times, [session.scene.dofs[n].curve.evaluate(times, 0) for n in names]


def segment_distance(p, q1, q2):
    """Distance from points p (n x 2) to segments q1 q2 (n x 2 each)."""
    u, w = q2 - q1, p - q1
    s = np.clip(np.sum(w * u, axis=1) / np.sum(u * u, axis=1), 0.0, 1.0)
    return np.linalg.norm(w - s[:, None] * u, axis=1)


def arm_points(angles, lengths):
    """Joint and tip positions of a planar chain on a fixed pivot (relative angles, from +x)."""
    points, phi, p = [np.zeros((angles[0].size, 2))], 0.0, np.zeros((angles[0].size, 2))
    for q, a in zip(angles, lengths):
        phi = phi + q
        p = p + a * np.stack([np.cos(phi), np.sin(phi)], axis=1)
        points.append(p)
    return points


def test_a_double_pendulum_swing_up_folds_through_itself_unless_told_to_avoid():
    free = Session()
    free.run_text(SWING + "iterate 100\n")
    _, (upper, fore) = samples(free, ["UPPER", "FORE"])
    shoulder, elbow, tip = arm_points([upper, fore], [1.0, 1.0])
    assert free.runs[-1].converged
    assert segment_distance(tip, shoulder, elbow).min() < 0.05      # the forearm passes the upper arm

    kept = Session()
    kept.run_text(SWING + "avoid dp.FORE dp.UPPER by=0.1\niterate 100\n")
    assert kept.runs[-1].converged
    _, (upper, fore) = samples(kept, ["UPPER", "FORE"])
    shoulder, elbow, tip = arm_points([upper, fore], [1.0, 1.0])
    least = min(segment_distance(tip, shoulder, elbow).min(), segment_distance(shoulder, elbow, tip).min())
    assert least >= 0.1 - 1e-3                        # measured 0.09956
    assert np.abs(fore).max() < np.pi                 # never folded through (measured 3.0419 = pi - 0.0997)


REACH = """time 0 1 knots=12
const g = 9.81
linkage arm base=fixed
  S revolute a=0.5 mass=1
  E revolute a=0.5 mass=1
  W revolute a=0.3 mass=0.5
end
dof S = 0.3
dof E = 2*t
constraint start: S = 0.3, E = 0, W = 0, S' = 0, E' = 0, W' = 0 @ 0
constraint reach: arm.tip.x = 0.35, arm.tip.y = 0.45 @ 1
objective effort: tau_S, tau_E, tau_W
set adaptive on
"""


def reach_distances(session):
    _, angles = samples(session, ["S", "E", "W"], 0.0, 1.0)
    base, elbow, wrist, tip = arm_points(angles, [0.5, 0.5, 0.3])
    np.testing.assert_allclose(tip[-1], [0.35, 0.45], atol=1e-8)
    least = min(segment_distance(wrist, base, elbow).min(), segment_distance(tip, base, elbow).min(),
                segment_distance(base, wrist, tip).min(), segment_distance(elbow, wrist, tip).min())
    return least, min(wrist[:, 1].min(), tip[:, 1].min())


def test_links_that_share_no_joint_and_the_ground_are_kept_apart_by_distance():
    """A three-link arm reaching back over its own upper arm: left free, it whirls and its hand
    link passes through the upper arm; told to avoid, the hand link keeps 0.1 from the upper arm
    (distances: they share no joint) and stays 0.05 above a ground at y = -0.2."""
    free = Session()
    free.run_text(REACH + "iterate 150\n")
    assert free.runs[-1].converged
    assert reach_distances(free)[0] < 0.05

    s = Session()
    s.run_text(REACH + "avoid arm.W arm.S by=0.1\navoid arm.W ground y=-0.2 by=0.05\niterate 150\n")
    assert s.runs[-1].converged
    least, lowest = reach_distances(s)
    assert least >= 0.1 - 1e-3          # measured 0.0996 (the dense check's 3.7e-4 below 0.1)
    assert lowest >= -0.2 + 0.05 - 1e-3
    assert "W_S_avoid" in s.scene.verbs and "W_ground_avoid" in s.scene.verbs


@pytest.mark.parametrize("line, message", [
    ("avoid dp.ELBOW dp.UPPER", "'dp.ELBOW' is not a link (a link is named by its joint: dp.UPPER, dp.FORE)"),
    ("avoid dp.FORE dp.FORE", "two different links"),
    ("avoid dp.FORE dp.UPPER by=0", "must be more than 0"),
    ("avoid dp.FORE dp.UPPER by=1.5", "not less than the shorter link"),
    ("avoid dp.FORE dp.UPPER on [0, 3]", "outside the animation span"),
])
def test_bad_avoid_lines_say_why_and_change_nothing(line, message):
    s = Session()
    s.run_text(SWING)
    before = dict(s.scene.constraints)
    with pytest.raises(StwError, match=None) as err:
        s.execute(line)
    assert message in str(err.value)
    assert s.scene.constraints.keys() == before.keys() and not s.scene.verbs


def test_avoid_refuses_links_already_folded_together_and_delete_removes_it():
    s = Session()
    s.run_text(SWING + "dof FORE = 3.1\n")
    with pytest.raises(StwError, match="already closer than 0.1"):
        s.execute("avoid dp.FORE dp.UPPER by=0.1")
    s.execute("dof FORE = 0")
    s.execute("avoid dp.FORE dp.UPPER by=0.1")
    assert set(s.scene.verbs) == {"FORE_UPPER_avoid"}
    s.execute("delete FORE_UPPER_avoid")
    assert not s.scene.verbs and "FORE_UPPER_apart" not in s.scene.constraints
