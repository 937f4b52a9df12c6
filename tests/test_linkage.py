"""Linkage kinematics and Newton–Euler equations of motion, checked against independent derivations.

Tolerances: closed-form double pendulum 1e-9, independent Lagrangians 1e-8, energy balance 1e-8
(all absolute on O(1..100) torques, states drawn from a seeded generator).
"""

from __future__ import annotations

import math
import pathlib
import re

import numpy as np
import pytest
import sympy as sp
import symengine as se

from stw_tui.sym.errors import StwError
from stw_tui.sym.linkage import derive, dof_names, parse_linkage, segments, time_derivative
from stw_tui.sym.linkage.kinematics import chain, link_com_world, world_frames
from stw_tui.sym.linkage.spec import link_com, link_inertia
from stw_tui.sym.symbols import dof_symbol, named_symbol

G = named_symbol("g")
GVAL = 9.81


def make(text: str):
    lines = [ln for ln in text.strip().splitlines()]
    assert lines[-1].strip() == "end"
    return parse_linkage(lines[0], [(i + 2, ln) for i, ln in enumerate(lines[1:-1])], header_line=1)


def state_symbols(names):
    return ([dof_symbol(n) for n in names] + [dof_symbol(n, 1) for n in names]
            + [dof_symbol(n, 2) for n in names] + [G])


def evaluator(exprs, names):
    fn = sp.lambdify(state_symbols(names), list(exprs), modules="numpy", cse=True)
    return lambda q, qd, qdd, g=GVAL: np.array(fn(*q, *qd, *qdd, g), dtype=float)


def taus(spec):
    d = derive(spec)
    return [d[f"tau_{n}"] for n in dof_names(spec)]


ARM3 = """
linkage arm base=fixed
  SHOULDER revolute a=0.35 mass=2.0
  ELBOW    revolute a=0.30 mass=1.5
  WRIST    revolute a=0.15 mass=0.5
end
"""

# 3-D: moving, turning base (the basketball player's), twisted links, a prismatic joint, full
# inertia tensors, off-axis centres of mass
SPATIAL = """
linkage bb base=tx:BX,tz:BZ,ry:BROT gravity=-y
  TURN    revolute  d=0.8 alpha=pi/2 mass=3 inertia=0.05:0.04:0.03 com=0:-0.3:0.02
  REACH   prismatic a=0.1 alpha=-90deg theta=0.3 d=0.2 mass=1.5
  HAND    revolute  a=0.4 alpha=0.7 d=0.05 mass=0.8 com=-0.2:0.03:-0.01 inertia=0.01:0.02:0.025
end
"""


# ------------------------------------------------------------------------------ forward kinematics


def test_arm_straight_and_raised():
    spec = make(ARM3)
    d = derive(spec)
    pos = ["arm.tip.x", "arm.tip.y", "arm.tip.z", "arm.ELBOW.x", "arm.ELBOW.y", "arm.WRIST.x",
           "arm.SHOULDER.x", "arm.SHOULDER.y", "arm.com.x", "arm.com.y"]
    f = sp.lambdify([dof_symbol(n) for n in dof_names(spec)], [d[p] for p in pos])
    tip_x, tip_y, tip_z, ex, ey, wx, sx, sy, cx, cy = f(0.0, 0.0, 0.0)
    assert (tip_x, tip_y, tip_z) == pytest.approx((0.8, 0.0, 0.0), abs=1e-12)
    assert (ex, ey, wx, sx, sy) == pytest.approx((0.35, 0.0, 0.65, 0.0, 0.0), abs=1e-12)
    # rods: com of each link at its middle
    com = (2.0 * 0.175 + 1.5 * 0.5 + 0.5 * 0.725) / 4.0
    assert (cx, cy) == pytest.approx((com, 0.0), abs=1e-12)
    tip_x, tip_y, tip_z, ex, ey, *_ = f(math.pi / 2, 0.0, 0.0)
    assert (tip_x, tip_y, tip_z) == pytest.approx((0.0, 0.8, 0.0), abs=1e-12)
    assert (ex, ey) == pytest.approx((0.0, 0.35), abs=1e-12)
    tip_x, tip_y, *_ = f(0.0, math.pi / 2, -math.pi / 2)
    assert (tip_x, tip_y) == pytest.approx((0.5, 0.3), abs=1e-12)


def test_segments_stick_figure():
    spec = make(ARM3)
    segs = segments(spec, {"SHOULDER": math.pi / 2, "ELBOW": -math.pi / 2, "WRIST": 0.0}, {"g": 9.81})
    assert len(segs) == 3
    expected = [(0, 0, 0), (0, 0.35, 0), (0.30, 0.35, 0), (0.45, 0.35, 0)]
    for (a, b), p, q in zip(segs, expected, expected[1:]):
        np.testing.assert_allclose(a, p, atol=1e-12)
        np.testing.assert_allclose(b, q, atol=1e-12)
    assert segments(spec, {"SHOULDER": 0, "ELBOW": 0, "WRIST": 0}, {})[-1][1] == pytest.approx(
        [0.8, 0, 0])
    with pytest.raises(StwError, match="WRIST"):
        segments(spec, {"SHOULDER": 0, "ELBOW": 0}, {})


def test_exact_right_angle_offsets():
    """theta=pi/2 and alpha=90deg fold to exact cos/sin values: no 6e-17 residue in the expressions."""
    spec = make("""
linkage s
  A revolute a=1 theta=pi/2
  B revolute a=1 alpha=90deg
end
""")
    d = derive(spec)
    tip = [d[f"s.tip.{a}"] for a in "xyz"]
    assert not any(e.atoms(sp.Float) for e in tip)
    at_zero = [e.xreplace({dof_symbol("A"): 0, dof_symbol("B"): 0}) for e in tip]
    assert [sp.nsimplify(e) for e in at_zero] == [0, 2, 0]
    np.testing.assert_allclose(segments(spec, {"A": 0, "B": 0}, {})[1][1], [0, 2, 0], atol=0)
    np.testing.assert_allclose(segments(spec, {"A": 0, "B": math.pi / 2}, {})[1][1], [-1, 1, 0],
                               atol=1e-15)


def test_spatial_kinematics_known_pose():
    spec = make("""
linkage s base=tx:X,ty:Y,rz:R
  A revolute d=0.5 alpha=pi/2
  B prismatic
end
""")
    # base moves to (1, 2), turns R about z; A rotates about z by q_A and lifts d=0.5, then alpha=90
    # deg turns the frame so that its z (the slide of B) is horizontal, perpendicular to the arm plane
    vals = {"X": 1.0, "Y": 2.0, "R": 0.0, "A": 0.0, "B": 0.7}
    segs = segments(spec, vals, {})
    np.testing.assert_allclose(segs[0][0], [1, 2, 0], atol=1e-12)  # A sits at the base
    np.testing.assert_allclose(segs[0][1], [1, 2, 0.5], atol=1e-12)  # B sits at frame 1
    np.testing.assert_allclose(segs[1][1], [1, 2 - 0.7, 0.5], atol=1e-12)  # z1 = -y0
    vals.update(R=math.pi / 2)
    np.testing.assert_allclose(segments(spec, vals, {})[1][1], [1 + 0.7, 2, 0.5], atol=1e-12)


def test_default_com_is_link_midpoint_and_rod_inertia():
    """The brief's default com (-a/2, -d sin(alpha)/2, -d cos(alpha)/2) in frame i is the midpoint of
    the DH origins of frames i-1 and i; the default inertia is a thin rod along that segment."""
    spec = make("""
linkage s base=fixed
  A revolute a=0.3 d=0.4 alpha=0.6 theta=0.2 mass=2
  B revolute a=0.5 d=-0.2 alpha=1.1 mass=1
end
""")
    ch = chain(spec)
    frames = world_frames(spec, ch)
    coms = link_com_world(spec, frames, ch)
    names = dof_names(spec)
    f = sp.lambdify([dof_symbol(n) for n in names],
                    [list(c) for c in coms] + [list(frames[k][1]) for k in ch.joint_frames]
                    + [list(frames[-1][1])] + [[e for row in frames[k][0] for e in row]
                                               for k in ch.link_frames])
    rng = np.random.default_rng(1)
    for _ in range(5):
        c1, c2, p1, p2, tip, r1, r2 = f(*rng.uniform(-3, 3, len(names)))
        np.testing.assert_allclose(c1, (np.array(p1) + p2) / 2, atol=1e-12)
        np.testing.assert_allclose(c2, (np.array(p2) + tip) / 2, atol=1e-12)
        for joint, r, start, end in ((spec.joints[0], r1, p1, p2), (spec.joints[1], r2, p2, tip)):
            u = np.array(end, float) - start
            length = np.linalg.norm(u)
            u_local = np.array(r, float).reshape(3, 3).T @ (u / length)
            inertia = np.array(link_inertia(joint))
            np.testing.assert_allclose(inertia @ u_local, 0, atol=1e-12)
            assert np.trace(inertia) == pytest.approx(2 * joint.mass * length**2 / 12, abs=1e-12)
    assert link_com(spec.joints[0]) == pytest.approx(
        (-0.15, -0.2 * math.sin(0.6), -0.2 * math.cos(0.6)))


# ------------------------------------------------------------------------------------------ dynamics


def double_pendulum_closed_form(q, qd, qdd, l1, lc1, lc2, m1, m2, i1, i2, g):
    """Spong, Hutchinson & Vidyasagar, Robot Modeling and Control, sec. 7.4 (planar elbow manipulator),
    relative angle q2, gravity -y, angles from the x axis; I1, I2 about the centres of mass."""
    c2, s2 = math.cos(q[1]), math.sin(q[1])
    m11 = m1 * lc1**2 + m2 * (l1**2 + lc2**2 + 2 * l1 * lc2 * c2) + i1 + i2
    m12 = m2 * (lc2**2 + l1 * lc2 * c2) + i2
    m22 = m2 * lc2**2 + i2
    h = -m2 * l1 * lc2 * s2
    g1 = (m1 * lc1 + m2 * l1) * g * math.cos(q[0]) + m2 * lc2 * g * math.cos(q[0] + q[1])
    g2 = m2 * lc2 * g * math.cos(q[0] + q[1])
    tau1 = m11 * qdd[0] + m12 * qdd[1] + h * qd[1] * qd[1] + 2 * h * qd[0] * qd[1] + g1
    tau2 = m12 * qdd[0] + m22 * qdd[1] - h * qd[0] * qd[0] + g2
    return np.array([tau1, tau2])


@pytest.mark.parametrize("kind", ["point masses", "rods"])
def test_double_pendulum_closed_form(kind):
    l1, l2, m1, m2 = 0.7, 0.45, 1.3, 0.8
    if kind == "point masses":
        extra = " com=0:0:0 inertia=0:0:0"
        lc1, lc2, i1, i2 = l1, l2, 0.0, 0.0
    else:
        extra = ""
        lc1, lc2, i1, i2 = l1 / 2, l2 / 2, m1 * l1**2 / 12, m2 * l2**2 / 12
    spec = make(f"""
linkage dp
  ONE revolute a={l1} mass={m1}{extra}
  TWO revolute a={l2} mass={m2}{extra}
end
""")
    f = evaluator(taus(spec), dof_names(spec))
    rng = np.random.default_rng(7)
    for _ in range(20):
        q, qd, qdd = rng.uniform(-3, 3, 2), rng.uniform(-4, 4, 2), rng.uniform(-10, 10, 2)
        g = rng.uniform(0, 20)
        expected = double_pendulum_closed_form(q, qd, qdd, l1, lc1, lc2, m1, m2, i1, i2, g)
        np.testing.assert_allclose(f(q, qd, qdd, g), expected, rtol=0, atol=1e-9)


def lagrange_taus(lagrangian, names, diff=sp.diff):
    """tau_j = d/dt dL/dq'_j - dL/dq_j, the time derivative by the chain rule written out here."""
    out = []
    for n in names:
        dl_dqd = diff(lagrangian, dof_symbol(n, 1))
        ddt = 0
        for m in names:
            ddt += diff(dl_dqd, dof_symbol(m)) * dof_symbol(m, 1)
            ddt += diff(dl_dqd, dof_symbol(m, 1)) * dof_symbol(m, 2)
        out.append(ddt - diff(lagrangian, dof_symbol(n)))
    return out


def test_three_link_arm_vs_hand_lagrangian():
    """A planar 3-link arm with one off-axis centre of mass and given inertias, against a Lagrangian
    written by hand from planar geometry (no DH, no Newton–Euler)."""
    spec = make("""
linkage arm3
  S revolute a=0.35 mass=2.0
  E revolute a=0.30 mass=1.5 com=-0.1:0.04:0 inertia=0.01:0.02:0.015
  W revolute a=0.15 mass=0.5 com=0:0:0 inertia=0:0:0.002
end
""")
    names = dof_names(spec)
    q = [dof_symbol(n) for n in names]
    qd = [dof_symbol(n, 1) for n in names]
    lengths = [0.35, 0.30, 0.15]
    masses = [2.0, 1.5, 0.5]
    com_local = [(-0.175, 0.0), (-0.1, 0.04), (0.0, 0.0)]  # in each link's frame, x along the link
    izz = [2.0 * 0.35**2 / 12, 0.015, 0.002]
    lagrangian = 0
    phi, phid = 0, 0
    ox, oy = 0, 0
    for i in range(3):
        phi, phid = phi + q[i], phid + qd[i]
        ox, oy = ox + lengths[i] * sp.cos(phi), oy + lengths[i] * sp.sin(phi)
        cx = ox + com_local[i][0] * sp.cos(phi) - com_local[i][1] * sp.sin(phi)
        cy = oy + com_local[i][0] * sp.sin(phi) + com_local[i][1] * sp.cos(phi)
        vx = sum(sp.diff(cx, qj) * qdj for qj, qdj in zip(q, qd))
        vy = sum(sp.diff(cy, qj) * qdj for qj, qdj in zip(q, qd))
        lagrangian += masses[i] * (vx**2 + vy**2) / 2 + izz[i] * phid**2 / 2 - masses[i] * G * cy
    ref = evaluator(lagrange_taus(lagrangian, names), names)
    f = evaluator(taus(spec), names)
    rng = np.random.default_rng(11)
    for _ in range(20):
        state = rng.uniform(-3, 3, 3), rng.uniform(-4, 4, 3), rng.uniform(-10, 10, 3)
        np.testing.assert_allclose(f(*state), ref(*state), rtol=0, atol=1e-8)


def kinetic_and_potential(spec):
    """T and V of the linkage from link velocities: v_c by the chain rule on the world centre of mass,
    world angular velocity from the skew matrix R' R^T; independent of the Newton–Euler recursion."""
    names = dof_names(spec)
    ch = chain(spec)
    frames = world_frames(spec, ch)
    coms = link_com_world(spec, frames, ch)
    gvec = np.zeros(3)
    gvec[spec.gravity_axis] = spec.gravity_sign
    T, V = 0, 0
    for joint, k, c in zip(spec.joints, ch.link_frames, coms):
        R = sp.Matrix(frames[k][0])
        Rd = R.applyfunc(lambda e: time_derivative(e, names))
        W = Rd * R.T
        w = sp.Matrix([W[2, 1], W[0, 2], W[1, 0]])
        v = sp.Matrix([time_derivative(e, names) for e in c])
        inertia_world = R * sp.Matrix(link_inertia(joint)) * R.T
        T += joint.mass * (v.T * v)[0] / 2 + (w.T * inertia_world * w)[0] / 2
        V += -joint.mass * G * sum(gvec[i] * c[i] for i in range(3))
    return T, V


@pytest.mark.parametrize("text", [ARM3, SPATIAL], ids=["planar arm", "3-D base + prismatic"])
def test_energy_balance_along_trajectory(text):
    """Sum_j tau_j q_j' = dE/dt along q_j(t) = sums of sines (E = T + V), at several times.

    Blind, by physics, to the gyroscopic moment w x (I w) of the Newton-Euler recursion: it does no
    work (w . (w x I w) = 0 for every inertia tensor), so a recursion that drops it balances the
    energy just as well, even on the 3-D creature, whose unequal inertias make it nonzero (checked:
    with that term deleted from dynamics.py this test passes on both creatures). The torques
    themselves are compared with a Lagrangian in test_spatial_vs_lagrangian_symengine, which
    fails with it deleted."""
    spec = make(text)
    names = dof_names(spec)
    T, V = kinetic_and_potential(spec)
    energy = se.S(T + V)  # differentiated by symengine: sympy takes seconds on the 3-D energy
    dedt = sum(energy.diff(se.Symbol(n)) * se.Symbol(n + "'")
               + energy.diff(se.Symbol(n + "'")) * se.Symbol(n + "''") for n in names)
    power = sum(tau * dof_symbol(n, 1) for tau, n in zip(taus(spec), names))
    power_f = evaluator([power, T], names)
    dedt_f = se.Lambdify([se.Symbol(s.name) for s in state_symbols(names)], [dedt])
    rng = np.random.default_rng(3)
    amp, om, ph = (rng.uniform(0.2, 1.5, (len(names), 3)), rng.uniform(0.5, 4, (len(names), 3)),
                   rng.uniform(0, 6, (len(names), 3)))
    for t in np.linspace(0.0, 2.0, 9):
        q = (amp * np.sin(om * t + ph)).sum(1)
        qd = (amp * om * np.cos(om * t + ph)).sum(1)
        qdd = (-amp * om**2 * np.sin(om * t + ph)).sum(1)
        p, kinetic = power_f(q, qd, qdd)
        de = float(np.asarray(dedt_f(np.concatenate([q, qd, qdd, [GVAL]]))).ravel()[0])
        assert kinetic > 0
        assert abs(p - de) < 1e-8, (t, p, de)


def test_spatial_vs_lagrangian_symengine():
    """The 3-D creature's full torques (not only their power) against a Lagrangian built from world
    frames and differentiated by symengine."""
    spec = make(SPATIAL)
    names = dof_names(spec)
    T, V = kinetic_and_potential(spec)
    L = se.S(T - V)
    to_se = {}

    def diff(expr, sym):
        s = to_se.setdefault(sym, se.Symbol(sym.name))
        return expr.diff(s)

    ref_se = lagrange_taus(L, names, diff=diff)
    syms = [se.Symbol(s.name) for s in state_symbols(names)]
    ref = se.Lambdify(syms, ref_se)
    f = evaluator(taus(spec), names)
    rng = np.random.default_rng(5)
    for _ in range(10):
        state = rng.uniform(-2, 2, len(names)), rng.uniform(-3, 3, len(names)), rng.uniform(-8, 8, len(
            names))
        expected = np.asarray(ref(np.concatenate([*state, [GVAL]])), dtype=float).ravel()
        np.testing.assert_allclose(f(*state), expected, rtol=0, atol=1e-8)


def test_symengine_build_equals_sympy_build():
    """The same recursion run in pure sympy gives the same numbers and the same tree sizes."""
    from stw_tui.sym.linkage.dynamics import generalized_forces_raw
    from stw_tui.sym.linkage.kinematics import SYMPY

    spec = make(SPATIAL)
    names = dof_names(spec)
    fast = taus(spec)
    slow = list(generalized_forces_raw(spec, None, SYMPY).values())
    rng = np.random.default_rng(2)
    state = [rng.uniform(-2, 2, len(names)) for _ in range(3)]
    np.testing.assert_allclose(evaluator(fast, names)(*state), evaluator(slow, names)(*state),
                               rtol=0, atol=1e-10)

    def nodes(e):
        return 1 + sum(nodes(a) for a in e.args)

    assert sum(nodes(e) for e in fast) <= 1.05 * sum(nodes(e) for e in slow)


def test_free_base_statics_and_gravity_axis():
    """A resting creature on a free base: base forces carry its weight; gravity=none removes it."""
    spec = make("""
linkage hop base=tx:X,ty:Y
  FOOT  revolute a=0.5 mass=2
  WAIST revolute a=0.4 mass=1
end
""")
    f = evaluator(taus(spec), dof_names(spec))
    tx, ty, *_ = f(np.zeros(4), np.zeros(4), np.zeros(4))
    assert tx == pytest.approx(0, abs=1e-12)
    assert ty == pytest.approx(3 * GVAL, abs=1e-12)
    # base accelerating up at a: total force m (a + g)
    tx, ty, *_ = f(np.zeros(4), np.zeros(4), np.array([0, 2.0, 0, 0]))
    assert ty == pytest.approx(3 * (GVAL + 2.0), abs=1e-12)
    spec_up = make("""
linkage hop base=tx:X,ty:Y,tz:Z gravity=+z
  FOOT revolute a=0.5 mass=2
end
""")
    d = derive(spec_up)
    assert sp.simplify(d["tau_Z"] - (2 * dof_symbol("Z", 2) - 2 * G)) == 0
    none = make("""
linkage float base=tx:X gravity=none
  FOOT revolute a=0.5 mass=2
end
""")
    assert G not in derive(none)["tau_FOOT"].free_symbols


def test_prismatic_point_mass_on_rotating_arm():
    """Bead on a spinning rod: tau_SLIDE = m (r'' - r w^2) with r = q + d (gravity off), and
    tau_SPIN = m (r^2 w' + 2 r r' w)."""
    spec = make("""
linkage bead gravity=none
  SPIN  revolute alpha=pi/2 mass=0
  SLIDE prismatic d=0.1 mass=2 com=0:0:0 inertia=0:0:0
end
""")
    f = evaluator(taus(spec), dof_names(spec))
    rng = np.random.default_rng(9)
    for _ in range(10):
        q, qd, qdd = rng.uniform(-2, 2, 2), rng.uniform(-2, 2, 2), rng.uniform(-2, 2, 2)
        r, rd, rdd = q[1] + 0.1, qd[1], qdd[1]
        w, wd = qd[0], qdd[0]
        expected = [2 * (r * r * wd + 2 * r * rd * w), 2 * (rdd - r * w * w)]
        np.testing.assert_allclose(f(q, qd, qdd), expected, rtol=0, atol=1e-12)


def test_time_derivative_chain_rule_and_error():
    x, xd, xdd = dof_symbol("x"), dof_symbol("x", 1), dof_symbol("x", 2)
    y, yd = dof_symbol("y"), dof_symbol("y", 1)
    expr = sp.sin(x) * y + xd * y
    got = time_derivative(expr, ["x", "y"])
    assert sp.expand(got - (sp.cos(x) * xd * y + sp.sin(x) * yd + xdd * y + xd * yd)) == 0
    assert time_derivative(3.0, ["x"]) == 0
    with pytest.raises(StwError, match="x''"):
        time_derivative(xdd + x, ["x"])


def test_time_derivative_of_a_linkage_position_agrees_with_sympy_and_keeps_other_forms():
    """Sums of products of sines and cosines are differentiated in symengine (fast); the result
    must be sympy's chain rule, value for value; anything else (abs here) stays sympy's."""
    spec = make(SPATIAL)
    names = dof_names(spec)
    tip = derive(spec)["bb.tip.x"]
    t = sp.Symbol("t", real=True)
    got = time_derivative(tip + t * tip, names)                # the explicit time term too
    reference = sp.diff(tip + t * tip, t)
    for name in names:
        q, qd, qdd = (dof_symbol(name, k) for k in range(3))
        reference += sp.diff(tip + t * tip, q) * qd + sp.diff(tip + t * tip, qd) * qdd
    assert got.free_symbols <= reference.free_symbols | {t}
    rng = np.random.default_rng(3)
    for _ in range(5):
        point = {s: rng.uniform(-2, 2) for s in reference.free_symbols | got.free_symbols}
        assert abs(float(got.xreplace(point)) - float(reference.xreplace(point))) < 1e-10
    x = dof_symbol(names[0])
    assert time_derivative(sp.Abs(x), names) == sp.sign(x) * dof_symbol(names[0], 1)


def test_derive_names_and_symbols():
    spec = make(SPATIAL)
    d = derive(spec)
    expected = {f"bb.{p}.{a}" for p in ("TURN", "REACH", "HAND", "tip", "com") for a in "xyz"}
    expected |= {f"tau_{n}" for n in ("BX", "BZ", "BROT", "TURN", "REACH", "HAND")}
    assert set(d) == expected
    allowed = set(state_symbols(dof_names(spec)))
    for name, e in d.items():
        assert e.free_symbols <= allowed, name
        assert all(s.is_real for s in e.free_symbols)


def test_no_evaluation_of_text_in_package():
    root = pathlib.Path(__file__).resolve().parents[1] / "stw_tui" / "linkage"
    for path in root.glob("*.py"):
        code = path.read_text()
        assert not re.search(r"\b(eval|exec|sympify|parse_expr)\s*\(", code), path


def test_centroidal_base_places_the_centre_of_mass_and_keeps_the_base_forces():
    # `com=CX,CY`: the DOF are where the centre of mass is, the foot (X, Y) follows from it. For
    # two uniform rods of length 0.5 and mass 1 the centre of mass sits 0.375 along the first
    # link and 0.125 along the second from the foot; and by Newton's second law the force on the
    # free base (the ground reaction) is the total mass times the centre of mass's acceleration
    # plus its weight, whatever the joints do.
    from stw_tui.session.session import Session

    s = Session()
    s.run_text("""time 0 1 knots=8
const g = 9.81
linkage acro base=tx:X,ty:Y com=CX,CY
  FOOT  revolute a=0.5 mass=1.0
  WAIST revolute a=0.5 mass=1.0
end
dof FOOT = 1 + 2*t^2
dof WAIST = 0.5*sin(3*t)
dof CX = 0.3 + t - t^3
dof CY = 0.5 + 2*t - 4.9*t^2
""")
    sc = s.scene
    assert list(sc.dofs) == ["CX", "CY", "FOOT", "WAIST"]
    times = np.linspace(0.05, 0.95, 7)
    val = {n: sc.dofs[n].curve.evaluate(times) for n in sc.dofs}
    acc = {n: sc.dofs[n].curve.evaluate(times, 2) for n in sc.dofs}
    f, w = val["FOOT"], val["FOOT"] + val["WAIST"]
    foot_x = val["CX"] - 0.375 * np.cos(f) - 0.125 * np.cos(w)
    foot_y = val["CY"] - 0.375 * np.sin(f) - 0.125 * np.sin(w)
    at = lambda name: sc.evaluate(named_symbol(name), times)
    np.testing.assert_allclose(at("X"), foot_x, atol=1e-12)
    np.testing.assert_allclose(at("Y"), foot_y, atol=1e-12)
    np.testing.assert_allclose(at("acro.com.x"), val["CX"], atol=1e-12)
    np.testing.assert_allclose(at("tau_X"), 2.0 * acc["CX"], atol=1e-9)
    np.testing.assert_allclose(at("tau_Y"), 2.0 * (acc["CY"] + 9.81), atol=1e-9)
    # The scene states the base forces in that linear form; the recursive Newton–Euler forces of
    # the foot-based creature, with the foot substituted (differentiated twice), agree with it.
    from stw_tui.sym.linkage import derive, time_derivative

    spec = sc.linkages["acro"]
    names = ["CX", "CY", "FOOT", "WAIST"]
    foot = {n: sc.derived[n] for n in ("X", "Y")}
    subs = {}
    for n, e in foot.items():
        d1 = time_derivative(e, names)
        subs.update({dof_symbol(n): e, dof_symbol(n, 1): d1, dof_symbol(n, 2): time_derivative(d1, names)})
    vel = {n: sc.dofs[n].curve.evaluate(times, 1) for n in names}
    symbols = [dof_symbol(n, k) for n in names for k in range(3)] + [named_symbol("g")]
    for axis in ("X", "Y"):
        newton_euler = derive(spec)[f"tau_{axis}"].xreplace(subs)
        fn = sp.lambdify(symbols, newton_euler, "numpy")   # our own expression, not user text
        args = [v[n] for n in names for v in (val, vel, acc)] + [9.81]
        np.testing.assert_allclose(fn(*args), at(f"tau_{axis}"), atol=1e-9)
    assert sc.derived["tau_Y"].free_symbols == {dof_symbol("CY", 2), named_symbol("g")}
    s.execute("linkage twin base=tx:Q com=CX")        # CX is taken: refused at `end`, nothing added
    s.execute("A revolute a=0.5")
    with pytest.raises(StwError, match="already exist"):
        s.execute("end")
    assert "twin" not in s.scene.linkages and "Q" not in s.scene.derived


@pytest.mark.parametrize("header, message", [
    ("linkage a base=fixed com=CX", "base of translations"),
    ("linkage a base=tx:X,rz:R com=CX,CY", "base of translations"),
    ("linkage a base=tx:X,ty:Y com=CX", "1 DOF for 2 base axes"),
    ("linkage a base=tx:X,ty:Y com=CX,X", "given twice"),
])
def test_centroidal_base_errors(header, message):
    from stw_tui.sym.errors import SourceError

    with pytest.raises(SourceError, match=message):
        parse_linkage(header, [(2, "A revolute a=0.5")], header_line=1)
