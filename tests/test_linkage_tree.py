"""Branched linkages (rows with ``parent=``): kinematics and equations of motion of a tree,
checked against sympy.physics.mechanics (its own frames, points and Lagrange's equations), not
against stw's kinematics.

Tolerance: 1e-9 absolute on torques of O(1..100) N·m at seeded random states (issue 53).
"""

from __future__ import annotations

import numpy as np
import pytest
import sympy as sp
from sympy.physics import mechanics as me

from stw_tui.sym.errors import SourceError
from stw_tui.sym.linkage import derive, dof_names, parse_linkage, segments
from stw_tui.sym.linkage.spec import parent_indices
from stw_tui.sym.symbols import dof_symbol, named_symbol

GVAL = 9.81


def make(text: str):
    lines = text.strip().splitlines()
    assert lines[-1].strip() == "end"
    return parse_linkage(lines[0], [(i + 2, ln) for i, ln in enumerate(lines[1:-1])], header_line=1)


# A planar figure on a free base: a leg of two links, and from the base a trunk whose end carries
# two arms and a head (branches at the base and at a link's end; one link with its own centre of
# mass and inertia, one with an angle offset).
FIGURE = """
linkage fig base=tx:X,ty:Y
  SHIN  revolute a=0.45 mass=3.5
  THIGH revolute a=0.42 mass=7
  TRUNK revolute a=0.55 mass=30 parent=base com=-0.3:0.02:0 inertia=0:0:1.4
  LARM  revolute a=0.6 mass=3 parent=TRUNK
  RARM  revolute a=0.55 mass=2.5 parent=TRUNK theta=0.3
  HEAD  revolute a=0.25 mass=5 parent=TRUNK
end
"""

# (row, parent row or None for the base, a, mass, theta offset, com along the link or None for
# the midpoint, inertia about the com or None for a rod): the same figure, written out for the
# independent derivation
ROWS = [("SHIN", None, 0.45, 3.5, 0.0, None, None),
        ("THIGH", "SHIN", 0.42, 7.0, 0.0, None, None),
        ("TRUNK", None, 0.55, 30.0, 0.0, (-0.3, 0.02), 1.4),
        ("LARM", "TRUNK", 0.6, 3.0, 0.0, None, None),
        ("RARM", "TRUNK", 0.55, 2.5, 0.3, None, None),
        ("HEAD", "TRUNK", 0.25, 5.0, 0.0, None, None)]


def mechanics_taus():
    """The generalized forces of FIGURE by sympy.physics.mechanics: each link a rigid body in its
    own frame turned about N.z by its absolute angle (the parent's frame plus its joint), Lagrange's
    equations with no applied forces but gravity. Returns (expressions, q, q', q'', g)."""
    names = ["X", "Y"] + [r[0] for r in ROWS]
    q = me.dynamicsymbols(" ".join(names))
    t = me.dynamicsymbols._t
    g = sp.Symbol("g")
    N = me.ReferenceFrame("N")
    O = me.Point("O")
    O.set_vel(N, 0)
    base = O.locatenew("B", q[0] * N.x + q[1] * N.y)
    base.set_vel(N, base.pos_from(O).dt(N))
    frames, ends, bodies = {}, {}, []
    for i, (name, parent, a, mass, theta, com, inertia) in enumerate(ROWS):
        up_frame = N if parent is None else frames[parent]
        start = base if parent is None else ends[parent]
        F = up_frame.orientnew(name, "Axis", (q[2 + i] + theta, up_frame.z))
        frames[name] = F
        end = start.locatenew(f"{name}_end", a * F.x)
        end.v2pt_theory(start, N, F)
        ends[name] = end
        # com given in the link frame, which sits at the link's end (DH frame i)
        cx, cy = com if com is not None else (-a / 2, 0.0)
        c = end.locatenew(f"{name}_c", cx * F.x + cy * F.y)
        c.v2pt_theory(end, N, F)
        izz = inertia if inertia is not None else mass * a * a / 12
        body = me.RigidBody(name, c, F, mass, (me.inertia(F, 0, 0, izz), c))
        body.potential_energy = mass * g * c.pos_from(O).dot(N.y)
        bodies.append(body)
    lagrangian = me.Lagrangian(N, *bodies)
    lm = me.LagrangesMethod(lagrangian, q)
    eqs = lm.form_lagranges_equations()
    qd = [s.diff(t) for s in q]
    qdd = [s.diff(t, 2) for s in q]
    return list(eqs), q, qd, qdd, g


def test_tree_equations_of_motion_match_sympy_mechanics():
    spec = make(FIGURE)
    names = dof_names(spec)
    assert names == ["X", "Y", "SHIN", "THIGH", "TRUNK", "LARM", "RARM", "HEAD"]
    derived = derive(spec)
    ours = sp.lambdify([dof_symbol(n, k) for k in range(3) for n in names] + [named_symbol("g")],
                       [derived[f"tau_{n}"] for n in names], modules="numpy", cse=True)
    eqs, q, qd, qdd, g = mechanics_taus()
    # the dynamic symbols replaced by plain ones (highest derivative first) for lambdify
    plain = [sp.Symbol(f"s{k}_{i}") for k in range(3) for i in range(len(q))]
    subs = dict(zip(qdd + qd + q, plain[2 * len(q):] + plain[len(q):2 * len(q)] + plain[:len(q)]))
    theirs = sp.lambdify(plain + [g], [e.subs(subs) for e in eqs], modules="numpy")
    rng = np.random.default_rng(53)
    for _ in range(20):
        state = rng.uniform(-2.0, 2.0, 3 * len(names))
        a = np.asarray(ours(*state, GVAL), dtype=float)
        b = np.asarray(theirs(*state, GVAL), dtype=float)
        np.testing.assert_allclose(a, b, rtol=0, atol=1e-9)
        assert np.max(np.abs(b)) > 1.0   # the states exercise the dynamics, not a zero


def test_tree_points_and_stick_figure():
    """Joints sit at the end of their parent's link; every link ends where the figure says; the
    stick figure has one segment per link, each from its joint to its end."""
    spec = make(FIGURE)
    assert parent_indices(spec) == (-1, 0, -1, 2, 2, 2)
    values = dict(X=1.0, Y=0.5, SHIN=np.pi / 2, THIGH=0.0, TRUNK=np.pi / 2, LARM=np.pi / 2,
                  RARM=-np.pi / 2, HEAD=0.0)
    derived = derive(spec)
    subs = {dof_symbol(n): v for n, v in values.items()}

    def point(name):
        return np.array([float(derived[f"{name}.{ax}"].subs(subs)) for ax in "xy"])

    np.testing.assert_allclose(point("fig.SHIN"), [1.0, 0.5], atol=1e-12)
    np.testing.assert_allclose(point("fig.SHIN.end"), [1.0, 0.95], atol=1e-12)
    np.testing.assert_allclose(point("fig.THIGH.end"), [1.0, 1.37], atol=1e-12)
    np.testing.assert_allclose(point("fig.TRUNK.end"), [1.0, 1.05], atol=1e-12)
    np.testing.assert_allclose(point("fig.LARM"), [1.0, 1.05], atol=1e-12)
    np.testing.assert_allclose(point("fig.LARM.end"), [0.4, 1.05], atol=1e-12)   # turned left
    np.testing.assert_allclose(point("fig.RARM.end"),
                               [1.0 + 0.55 * np.cos(0.3), 1.05 + 0.55 * np.sin(0.3)], atol=1e-12)
    np.testing.assert_allclose(point("fig.HEAD.end"), [1.0, 1.30], atol=1e-12)
    np.testing.assert_allclose(point("fig.tip"), point("fig.HEAD.end"), atol=1e-15)
    segs = segments(spec, values)
    assert len(segs) == 6
    for (start, end), row in zip(segs, [r[0] for r in ROWS]):
        np.testing.assert_allclose(start[:2], point(f"fig.{row}"), atol=1e-12)
        np.testing.assert_allclose(end[:2], point(f"fig.{row}.end"), atol=1e-12)


def test_a_chain_keeps_its_names_and_segments():
    """Without parent= nothing changes: no .end names, and segments run joint to joint to tip."""
    spec = make("""
linkage arm base=fixed
  SHOULDER revolute a=0.35 mass=2.0
  ELBOW    revolute a=0.30 mass=1.5 parent=SHOULDER
end
""")
    names = set(derive(spec))
    assert "arm.SHOULDER.end.x" not in names and "arm.tip.x" in names
    (s0, e0), (s1, e1) = segments(spec, {"SHOULDER": 0.0, "ELBOW": np.pi / 2})
    np.testing.assert_allclose([s0, e0, s1, e1], [[0, 0, 0], [0.35, 0, 0], [0.35, 0, 0], [0.35, 0.3, 0]],
                               atol=1e-12)


@pytest.mark.parametrize("row, message, expected", [
    ("  B revolute a=1 parent=C", "parent 'C' is not a joint above this row", "A, base"),
    ("  B revolute a=1 parent=a", "parent 'a' is not a joint above this row", "did you mean 'A'"),
    ("  B revolute a=1 parent=", "parent= needs a value", "a joint name"),
    ("  B revolute a=1 parent=B", "parent 'B' is not a joint above this row", ""),
])
def test_bad_parent_is_refused_with_where_and_why(row, message, expected):
    with pytest.raises(SourceError) as err:
        make(f"linkage L base=fixed\n  A revolute a=1\n{row}\nend")
    text = str(err.value)
    assert message in text and expected in text
    assert err.value.line == 3 and err.value.column == row.index("parent=") + len("parent=") + 1


SWING = """time 0 1 knots=8
const g = 9.81
linkage tee base=fixed
  POLE  revolute a=0.5 mass=1
  LEFT  revolute a=0.3 mass=0.5
  RIGHT revolute a=0.3 mass=0.5 parent=POLE
end
dof POLE = pi/2
constraint start: POLE = pi/2, LEFT = pi/2, RIGHT = -pi/2, POLE' = 0, LEFT' = 0, RIGHT' = 0 @ 0
constraint reach: tee.LEFT.end.x = -0.2, tee.LEFT.end.y = 0.3, tee.RIGHT.end.y = 0.7 @ 1
objective effort: tau_POLE, tau_LEFT, tau_RIGHT
iterate 40
"""


def test_a_branched_linkage_in_a_session_reaches_with_each_branch():
    """A T on a fixed pivot: both arms hang from the pole's end. Constraints on each branch's end
    are met, as planar kinematics written here confirms, and the figure player draws three links
    that meet at the pole's end."""
    from stw_tui.session.figure import scene_figure
    from stw_tui.session.session import Session

    s = Session()
    s.run_text(SWING)
    assert s.runs[-1].converged
    pole, left, right = (float(s.scene.dofs[n].curve.evaluate(np.array([1.0]), 0)[0])
                         for n in ("POLE", "LEFT", "RIGHT"))
    top = 0.5 * np.array([np.cos(pole), np.sin(pole)])
    left_end = top + 0.3 * np.array([np.cos(pole + left), np.sin(pole + left)])
    right_end = top + 0.3 * np.array([np.cos(pole + right), np.sin(pole + right)])
    np.testing.assert_allclose(left_end, [-0.2, 0.3], atol=1e-8)
    assert abs(right_end[1] - 0.7) < 1e-8
    figure = scene_figure(s.scene, 1.0)
    assert len(figure.segments) == 3
    np.testing.assert_allclose(figure.segments[1][0], top, atol=1e-12)
    np.testing.assert_allclose(figure.segments[2][0], top, atol=1e-12)
    np.testing.assert_allclose(figure.segments[1][1], left_end, atol=1e-12)
    np.testing.assert_allclose(figure.segments[2][1], right_end, atol=1e-12)


def test_the_base_childrens_torques_sum_to_the_worlds_moment():
    """Held still in a random pose, the joints on the base (SHIN and TRUNK) together hold the
    figure's weight about the base point: their torques sum to g * sum(m_i (x_i - X)), the centres
    of mass placed here by planar kinematics; the base forces carry the weight. That sum is what
    `flight` sets to zero and `contact … support=` bounds for a tree."""
    from stw_tui.sym.linkage import base_children

    spec = make(FIGURE)
    assert base_children(spec) == ["SHIN", "TRUNK"]
    derived = derive(spec)
    rng = np.random.default_rng(7)
    for _ in range(5):
        q = dict(zip(dof_names(spec), rng.uniform(-2, 2, len(dof_names(spec)))))
        subs = {dof_symbol(n): v for n, v in q.items()} | {named_symbol("g"): GVAL}
        subs |= {dof_symbol(n, k): 0.0 for n in q for k in (1, 2)}
        angle, end, moment, mass = {}, {}, 0.0, 0.0
        for name, parent, a, m, theta, com, _ in ROWS:
            start = np.array([q["X"], q["Y"]]) if parent is None else end[parent]
            angle[name] = (0.0 if parent is None else angle[parent]) + q[name] + theta
            u = np.array([np.cos(angle[name]), np.sin(angle[name])])
            end[name] = start + a * u
            cx, cy = com if com is not None else (-a / 2, 0.0)
            c = end[name] + cx * u + cy * np.array([-u[1], u[0]])
            moment += GVAL * m * (c[0] - q["X"])
            mass += m
        total = sum(float(derived[f"tau_{r}"].subs(subs)) for r in base_children(spec))
        assert abs(total - moment) < 1e-9
        assert abs(float(derived["tau_Y"].subs(subs)) - mass * GVAL) < 1e-9
        assert abs(float(derived["tau_X"].subs(subs))) < 1e-9


def test_flight_and_the_soles_moment_of_a_tree_sum_the_base_joints():
    """`flight` frees the figure's spin as the sum of the torques of the joints on its base (each
    alone is an internal torque, hip against leg), and `contact … support=` bounds that sum."""
    from stw_tui.session.session import Session

    s = Session()
    s.run_text("time 0 1 knots=8\nconst g = 9.81\nset limit expression_size 200000\n" + FIGURE.replace("base=tx:X,ty:Y", "base=tx:X,ty:Y com=CX,CY")
               + "flight fig on [0.5, 1]\ncontact fig.SHIN on ground on [0, 0.5] x=0 support=[-0.1, 0.2]\n")
    spin = s.scene.constraints["fig_spin"]
    assert [str(r.expr) for r in spin.relations] == ["tau_SHIN + tau_TRUNK"]
    pressure = s.scene.constraints["SHIN_pressure"]
    assert "tau_SHIN + tau_TRUNK" in pressure.text and "0.2*tau_Y" in pressure.text


def test_defining_a_tree_says_where_it_branches_and_what_it_names():
    from stw_tui.session.session import Session

    s = Session()
    outcomes = [s.execute(line) for line in ("time 0 1", "const g = 9.81", *FIGURE.strip().splitlines())]
    message = outcomes[-1].message
    assert "branched: base -> SHIN, TRUNK; TRUNK -> LARM, RARM, HEAD" in message
    assert "fig.JOINT.end.*" in message


def test_a_sole_that_ends_at_the_planted_point_reads_without_a_zero_term():
    """support=[-0.22, 0] (planted at the toe): the toe's bound is -tau >= 0, not 0.0*tau_Y - tau."""
    from stw_tui.session.session import Session

    s = Session()
    s.run_text("time 0 1 knots=8\nconst g = 9.81\nset limit expression_size 200000\n" + FIGURE
               + "contact fig.SHIN on ground on [0, 0.5] x=0 support=[-0.22, 0]\n")
    text = s.scene.constraints["SHIN_pressure"].text
    assert "(tau_SHIN + tau_TRUNK) + 0.22*tau_Y >= 0, -(tau_SHIN + tau_TRUNK) >= 0" in text and "0.0*" not in text


def test_help_linkage_draws_its_conventions_within_80_columns():
    """Issue 53 item 5: the angle convention and default masses, as a picture an 80-column console
    shows whole (the console indents nothing more; its panel is 80 wide at 80x24)."""
    from stw_tui.sym.language.help import help_text

    text = help_text("linkage")
    picture = text[text.index("picture:"):].splitlines()[1:]
    assert len(picture) >= 8 and all(len(line) <= 78 for line in picture)
    drawn = "\n".join(picture)
    for shown in ("SHOULDER = 0: from +x", "ELBOW = pi/2: counterclockwise", "ELBOW = 0: straight on",
                  "arm.tip", "m a^2/12", "gravity -y"):
        assert shown in drawn, shown
