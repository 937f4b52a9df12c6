"""Two feet on the ground (issue 53): a second foot planted through its leg's joints, with the
ground's force on it as curves of its own (stw_tui.session.planted_branch).

The physics is derived here from the DOF samples alone, with planar kinematics and Newton-Euler
written apart from stw (rods between the joints, each link's angle the sum of the joint angles
on its way from the first foot): both feet stay where they are planted, the ground does no work
on either, each foot only pushes, inside its friction cone, and the body's angular momentum
about its centre of mass changes by exactly the two feet's moments (point feet: the first foot
passes no moment, the second none by construction). That last one is what ties the force curves
to the equations of motion: a load with a wrong sign or a missing term breaks it.
"""

import math

import numpy as np
import pytest

from planar_tree import G, rebuild
from stw_tui.session.session import Session
from stw_tui.sym.errors import StwError
from stw_tui.sym.symbols import named_symbol

# (joint, parent, theta, length, mass): the stance's linkage
ROWS = [("LSHIN", None, 0.0, 0.5, 4.0), ("LTHIGH", "LSHIN", 0.0, 0.5, 8.0), ("TRUNK", "LTHIGH", 0.0, 0.6, 30.0),
        ("RTHIGH", "LTHIGH", math.pi, 0.5, 8.0), ("RSHIN", "RTHIGH", 0.0, 0.5, 4.0)]
MASS = sum(r[4] for r in ROWS)
SIZE = sum(r[3] for r in ROWS)
RIGHT_X = -0.3

STANCE = f"""
time 0 1 knots=8
const g = 9.81
set limit expression_size 2000000
linkage st base=tx:X,ty:Y
  LSHIN  revolute a=0.5 mass=4
  LTHIGH revolute a=0.5 mass=8
  TRUNK  revolute a=0.6 mass=30
  RTHIGH revolute a=0.5 mass=8 theta=pi parent=LTHIGH
  RSHIN  revolute a=0.5 mass=4
end
dof LSHIN = 1.1
dof LTHIGH = 1.0
dof TRUNK = -0.5
dof RTHIGH = -0.94
dof RSHIN = 0.6
dof FX, FY
contact st.LSHIN on ground on [0, 1] x=0
contact st.RSHIN.end on ground on [0, 1] x={RIGHT_X} force=F
"""
SQUAT = """
constraint still: LSHIN' = 0, LTHIGH' = 0, TRUNK' = 0 @ 0
constraint still2: LSHIN' = 0, LTHIGH' = 0, TRUNK' = 0 @ 1
constraint low: st.TRUNK.y = 0.8 @ 0.5
objective effort: tau_LTHIGH, tau_TRUNK, tau_RTHIGH, tau_RSHIN
iterate 60
"""


@pytest.fixture(scope="module")
def squat():
    session = Session()
    session.run_text(STANCE + SQUAT)
    return session


def physics(samples: dict, rows=ROWS) -> dict:
    """The first foot (the base point), the second (the last row's end), the centre of mass, the
    ground's total force and the rate of angular momentum about the centre of mass."""
    body = rebuild(samples, rows)
    return {"t": body["t"], "left": body["base"], "right": body["end"][rows[-1][0]], "com": body["com"],
            "force": body["force"], "spin": body["spin"]}


def test_both_feet_stay_planted_and_the_ground_does_no_work(squat):
    assert squat.runs[-1].converged
    s = squat.sample(1001)                       # 1 ms
    p = physics(s)
    right_force = np.stack([np.asarray(s["FX"]["value"]), np.asarray(s["FY"]["value"])])
    left_force = p["force"] - right_force
    for (x0, (pos, vel, _)), force in ((0.0, p["left"]), left_force), ((RIGHT_X, p["right"]), right_force):
        assert np.abs(pos[0] - x0).max() <= 1e-9 and np.abs(pos[1]).max() <= 1e-9   # measured 1.2e-15 m
        assert np.hypot(*vel).max() <= 1e-9                                         # measured 1.8e-15 m/s
        power = force[0] * vel[0] + force[1] * vel[1]
        assert np.abs(np.trapezoid(power, p["t"])) <= 1e-9                          # J
        # each foot only pushes, inside the cone (mu = 1), to the contacts' 1% of the weight
        assert force[1].min() >= -0.01 * MASS * G
        assert (np.abs(force[0]) - force[1]).max() <= 0.01 * MASS * G
    # the two feet share the weight: neither carries it all
    assert 0.2 < np.mean(right_force[1]) / (MASS * G) < 0.8


def test_the_feet_forces_turn_the_body_as_newton_euler_says(squat):
    s = squat.sample(1001)
    p = physics(s)
    right_force = np.stack([np.asarray(s["FX"]["value"]), np.asarray(s["FY"]["value"])])
    left_force = p["force"] - right_force
    (cx, cy), moments = p["com"][0], 0.0
    for (pos, _, _), f in ((p["left"], left_force), (p["right"], right_force)):
        moments = moments + (pos[0] - cx) * f[1] - (pos[1] - cy) * f[0]
    # What is left is the moment the first foot passes: a point foot's is 0 at the contact's
    # instances and, between them, within the contact's tolerance (1% of weight x size). It must
    # be the torque stw reports at that joint, the ground's force on the second foot loaded.
    left_moment = p["spin"] - moments
    reported = squat.scene.evaluate(named_symbol("tau_LSHIN"), p["t"])
    assert np.abs(left_moment - reported).max() <= 1e-9                 # N m; measured 4.4e-13
    assert np.abs(left_moment).max() <= 0.01 * MASS * G * SIZE           # measured 3.1 of 13.8
    knots = np.isin(np.round(p["t"], 9), np.round(np.linspace(0, 1, 17), 9))
    assert np.abs(left_moment[knots]).max() <= 1e-8                      # at the instances: 1.2e-10


def test_the_body_squats(squat):
    com = physics(squat.sample(101))["com"][0]
    assert com[1][50] < com[1][0] - 0.04      # the centre of mass follows the hip down


def test_a_second_foot_says_what_it_needs():
    base = STANCE.split("contact st.RSHIN.end")[0]
    for line, why in (
            ("contact st.RSHIN.end on ground on [0, 1] x=-0.3", "force=F for DOF FX, FY"),
            ("contact st.RSHIN.end on ground on [0, 1] x=-0.3 force=Q", "declare QX, QY first"),
            ("contact st.RSHIN.end on ground on [0, 1] x=3 force=F", "out of reach of its two links"),
            ("contact st.LSHIN.end on ground on [0, 1] x=0 force=F", "plant st.LSHIN, the first joint.*st has 1 link"),
            ("contact st.RSHIN.end on ground on [0, 1] force=F", "x=X0 says where"),
            ("contact st.RSHIN.end on ground on [0, 1] x=-0.3 force=F angle=1", "no sole")):
        session = Session()
        session.run_text(base)
        before = dict(session.scene.constraints)
        with pytest.raises(StwError, match=why):
            session.run_text(line + "\n")
        assert session.scene.constraints == before and not session.scene.attachments.get("RSHIN_contact")


# Soles: a first foot, one leg, a trunk, and a second leg of thigh, shin and foot whose sole is
# planted 25 cm ahead and keeps its angle; the figure leans forward and back.
SOLE_ROWS = [("LFOOT", None, 0.0, 0.15, 1.0), ("LLEG", "LFOOT", 0.0, 0.9, 10.0), ("TRUNK", "LLEG", 0.0, 0.6, 30.0),
             ("RTHIGH", "LLEG", math.pi, 0.5, 7.0), ("RSHIN", "RTHIGH", 0.0, 0.5, 3.0),
             ("RFOOT", "RSHIN", 0.0, 0.15, 1.0)]
SOLE_MASS = sum(r[4] for r in SOLE_ROWS)
SOLE = (-0.2, 0.0)
LEAN = f"""
time 0 1 knots=8
const g = 9.81
set limit expression_size 200000
linkage so base=tx:X,ty:Y
  LFOOT  revolute a=0.15 mass=1
  LLEG   revolute a=0.9 mass=10
  TRUNK  revolute a=0.6 mass=30
  RTHIGH revolute a=0.5 mass=7 theta=pi parent=LLEG
  RSHIN  revolute a=0.5 mass=3
  RFOOT  revolute a=0.15 mass=1
end
dof LFOOT = 2.8
dof LLEG = -1.35
dof TRUNK = 0.12
dof RTHIGH = 0.39
dof RSHIN = -0.6
dof RFOOT = 1.56
dof FX, FY, FM
contact so.LFOOT on ground on [0, 1] x=0 support=[{SOLE[0]}, {SOLE[1]}]
constraint flat: LFOOT = 2.8 on [0, 1]
contact so.RFOOT.end on ground on [0, 1] x=0.25 support=[{SOLE[0]}, {SOLE[1]}] force=F
constraint still: LLEG' = 0, TRUNK' = 0 @ 0
constraint still2: LLEG' = 0, TRUNK' = 0 @ 1
constraint lean: so.TRUNK.x = 0.1 @ 0.5
objective effort: tau_LLEG, tau_TRUNK, tau_RTHIGH, tau_RSHIN, tau_RFOOT
iterate 60
"""


@pytest.fixture(scope="module")
def lean():
    session = Session()
    session.run_text(LEAN)
    return session


def test_a_sole_stays_flat_where_it_is_planted_and_both_pressures_stay_on_the_soles(lean):
    assert lean.runs[-1].converged
    s = lean.sample(1001)
    p = physics(s, SOLE_ROWS)
    q = {n: np.asarray(s[n]["value"]) for n in s}
    foot_angle = q["LFOOT"] + q["LLEG"] + math.pi + q["RTHIGH"] + q["RSHIN"] + q["RFOOT"]
    assert np.ptp(foot_angle) <= 1e-9                                  # the second sole does not turn: 4.4e-15
    ball = p["right"]
    assert np.abs(ball[0][0] - 0.25).max() <= 1e-9 and np.abs(ball[0][1]).max() <= 1e-9
    assert np.hypot(*ball[1]).max() <= 1e-9
    right = np.stack([q["FX"], q["FY"]])
    left = p["force"] - right
    weight = SOLE_MASS * G
    for force in (left, right):
        assert force[1].min() >= -0.01 * weight and (np.abs(force[0]) - force[1]).max() <= 0.01 * weight
    # the second sole's moment FM is its centre of pressure times its push, on the sole
    assert (np.maximum(SOLE[0] * q["FY"] - q["FM"], q["FM"] - SOLE[1] * q["FY"])).max() <= 0.01 * weight * 2.8
    # the first foot's moment from Newton-Euler, with the second's force and moment, is the
    # torque stw reports at the first joint
    (cx, cy) = p["com"][0]
    moments = q["FM"].copy()
    for pos, f in ((p["left"][0], left), (ball[0], right)):
        moments += (pos[0] - cx) * f[1] - (pos[1] - cy) * f[0]
    reported = lean.scene.evaluate(named_symbol("tau_LFOOT"), p["t"])
    assert np.abs(p["spin"] - moments - reported).max() <= 1e-9          # N m; measured 2.8e-13


def test_a_planted_legs_joint_keeps_its_range_on_its_own_curve():
    # the range holds on the joint's control points (its own curve, read outside the stance);
    # the window built it from the inverse kinematics the joint is over the stance, and the
    # build failed (a bound row of one variable, a term of six)
    session = Session()
    session.run_text(STANCE.replace("[0, 1] x=-0.3", "[0, 0.5] x=-0.3") + "limit RSHIN -3 3\niterate 2\n")
    assert session.scene.dofs["RSHIN"].lo == -3 and session.runs[-1].reports


def test_the_figure_player_draws_the_feet_not_the_force(squat):
    from stw_tui.session.figure import player_figure, point_pairs

    assert [label for label, *_ in point_pairs(squat.scene)] == ["•"]      # the base X, Y: the first foot
    figure = player_figure(squat.scene, 0.5)
    low = min(min(a[1], b[1]) for a, b in figure.segments)
    assert abs(low) <= 1e-9 and max(abs(p[1][1]) for p in figure.points) <= 1e-9   # feet on the ground
