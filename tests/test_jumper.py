"""sessions/jumper.stw (issue 53): a seven-link figure's standing broad jump, its physics derived
here at 1 ms from the DOF samples with planar kinematics and Newton–Euler written apart from stw
(rods between the joints, the tree as the session states it), not through stw's compiler.

Its first run compiles large equations of motion (about two minutes on these machines; the term
cache keeps them), which is why the catalogue's every-session-on-every-backend tests leave it to
this file (catalogue.HEAVY).
"""

import numpy as np
import pytest

import catalogue
from planar_tree import G, rebuild
from stw_tui.session.session import Session

# (joint, parent, length, mass): sessions/jumper.stw's linkage
ROWS = [("FOOT", None, 0.17, 2.0), ("SHIN", "FOOT", 0.44, 6.6), ("THIGH", "SHIN", 0.44, 14.0),
        ("TRUNK", "THIGH", 0.52, 34.8), ("HEAD", "TRUNK", 0.33, 5.7), ("UARM", "TRUNK", 0.33, 4.0),
        ("FARM", "UARM", 0.46, 3.0)]
MASS = sum(r[3] for r in ROWS)
WEIGHT = MASS * G
SIZE = sum(r[2] for r in ROWS)
STANCES = (((0.0, 0.6), 0.0), ((0.95, 1.8), 0.7))
FLIGHT = (0.6, 0.95)
SOLE = (-0.22, 0.0)


@pytest.fixture(scope="module")
def jump():
    session = Session()
    session.run_text(catalogue.problem("jumper").text)
    return session


def physics(samples: dict) -> dict:
    """Root (the planted ball of the foot), every joint and link end, the centre of mass and the
    external force and moment (about the centre of mass), from the DOF samples."""
    body = rebuild(samples, [(name, parent, 0.0, length, mass) for name, parent, length, mass in ROWS])
    points = [body["base"][0]] + [body["end"][name][0] for name, *_ in ROWS]
    return {"t": body["t"], "root": body["base"], "com": body["com"], "force": body["force"],
            "spin": body["spin"], "points": points}


def test_the_jumper_jumps_on_planted_feet_inside_the_cone_and_flies_free(jump):
    assert jump.runs[-1].converged
    p = physics(jump.sample(1801))          # 1 ms
    t, (root, root_v, _), (fx, fy) = p["t"], p["root"], p["force"]
    for (a, b), x0 in STANCES:
        on = (t >= a - 1e-9) & (t <= b + 1e-9)
        assert np.abs(root[0, on] - x0).max() <= 1e-3 and np.abs(root[1, on]).max() <= 1e-3   # measured < 1e-10 mm
        assert np.hypot(*root_v[:, on]).max() <= 1e-2                                          # < 1e-12 cm/s
        work = np.trapezoid(np.maximum(fx[on] * root_v[0, on] + fy[on] * root_v[1, on], 0.0), t[on])
        assert work <= 1e-3                                                                    # 0
        # forces from one side of a switch: the sample at it mixes the phases' accelerations
        inside = (t > a + 1e-9) & (t < b - 1e-9)
        assert fy[inside].min() > 0 and fy[inside].max() <= 10 * WEIGHT                        # 0.61-4.8 BW
        assert (np.abs(fx[inside]) - fy[inside]).max() <= 0.01 * WEIGHT                        # far inside
        r = p["com"][0][:, inside] - root[:, inside]
        moment = p["spin"][inside] + r[0] * fy[inside] - r[1] * fx[inside]   # the ground's, about the root
        beyond = np.maximum(SOLE[0] * fy[inside] - moment, moment - SOLE[1] * fy[inside])
        assert beyond.max() <= 0.01 * WEIGHT * SIZE     # on the sole to the contact's tolerance: 13.6 N m of 18.5
    air = (t > FLIGHT[0] + 1e-9) & (t < FLIGHT[1] - 1e-9)
    assert np.hypot(fx[air], fy[air]).max() <= 0.01 * WEIGHT        # measured 4.0 N of 6.9
    assert np.abs(p["spin"][air]).max() <= 0.01 * WEIGHT * SIZE     # measured 2.7 N m of 18.5


def test_the_jumper_stands_at_rest_over_its_sole_and_lands_half_a_metre_on(jump):
    p = physics(jump.sample(1801))
    com, root = p["com"], p["root"][0]
    for i in (0, -1):
        assert np.hypot(*com[1][:, i]) <= 1e-2                              # measured < 1e-6 cm/s
        assert np.hypot(*com[2][:, i]) <= 1e-2                              # and no acceleration (< 1e-7)
        assert SOLE[0] <= com[0][0, i] - root[0, i] <= SOLE[1]             # -0.141 m: over the sole
    assert com[0][0, -1] - com[0][0, 0] >= 0.5                              # measured 0.70 m
    assert min(point[1].min() for point in p["points"]) >= -1e-3           # no joint under the ground
