"""A linkage base with a body of its own (``base_mass=``, ``base_inertia=``), against derivations
written apart from stw's compiler: the cart-pole's textbook equations of motion, a turning base's
Lagrangian by hand, and Newton's second law on the centre of mass of base and links; then the
bundled cart-pole swing-up, its passive pivot checked at 1 ms by the textbook formula.

Tolerances: 1e-9 absolute on O(1..100) forces at seeded random states (the expressions are
evaluated in double precision, so only rounding separates them).
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import sympy as sp

from conftest import SESSIONS
from stw_tui.session.session import Session
from stw_tui.sym.errors import SourceError
from stw_tui.sym.linkage import derive, dof_names, parse_linkage
from stw_tui.sym.symbols import dof_symbol, named_symbol

G = named_symbol("g")


def make(text: str):
    lines = text.strip().splitlines()
    return parse_linkage(lines[0], [(i + 2, ln) for i, ln in enumerate(lines[1:-1])], header_line=1)


def forces(spec):
    """stw's generalized forces as one numpy function of (q, q', q'', g), DOF in dof_names order."""
    names = dof_names(spec)
    derived = derive(spec)
    symbols = [dof_symbol(n, k) for k in range(3) for n in names] + [G]
    fn = sp.lambdify(symbols, [derived[f"tau_{n}"] for n in names], modules="numpy", cse=True)
    return lambda q, qd, qdd, g: np.array(fn(*q, *qd, *qdd, g), dtype=float)


def textbook_cart_pole(x_dd, phi, phi_d, phi_dd, cart, pole, lc, inertia, g):
    """(cart force F, pivot torque tau_phi) of a cart-pole as the textbooks write it, the pole
    angle phi from upright, positive toward +x (the pole's centre of mass at x + lc sin phi,
    lc cos phi), inertia about the pole's centre of mass:

        (M + m) x'' + m lc cos(phi) phi'' - m lc sin(phi) phi'^2 = F
        m lc cos(phi) x'' + (I + m lc^2) phi'' - m g lc sin(phi) = tau_phi
    """
    c, s = math.cos(phi), math.sin(phi)
    force = (cart + pole) * x_dd + pole * lc * c * phi_dd - pole * lc * s * phi_d**2
    torque = pole * lc * c * x_dd + (inertia + pole * lc**2) * phi_dd - pole * g * lc * s
    return force, torque


def cart_pole_in_stw_angles(x_dd, th, th_d, th_dd, cart, pole, lc, inertia, g):
    """The textbook cart-pole with stw's angle: th from +x, counterclockwise (y up), so
    phi = pi/2 - th and the pivot torque on th is minus the torque on phi."""
    force, torque = textbook_cart_pole(x_dd, math.pi / 2 - th, -th_d, -th_dd, cart, pole, lc, inertia, g)
    return force, -torque


@pytest.mark.parametrize("pole_row, lc, inertia", [
    ("POLE revolute a=0.5 mass=0.3", 0.25, 0.3 * 0.5**2 / 12),      # the default: a uniform rod
    ("POLE revolute a=0.8 mass=0.2 com=0:0:0 inertia=0:0:0", 0.8, 0.0),   # a bob at the tip
])
def test_cart_pole_forces_match_the_textbook(pole_row, lc, inertia):
    spec = make(f"linkage cp base=tx:X base_mass=1.3\n  {pole_row}\nend")
    mass = spec.joints[0].mass
    f = forces(spec)
    rng = np.random.default_rng(50)
    for _ in range(20):
        q, qd, qdd = rng.uniform(-3, 3, 2), rng.uniform(-4, 4, 2), rng.uniform(-10, 10, 2)
        g = rng.uniform(0, 20)
        expected = cart_pole_in_stw_angles(qdd[0], q[1], qd[1], qdd[1], 1.3, mass, lc, inertia, g)
        np.testing.assert_allclose(f(q, qd, qdd, g), expected, rtol=0, atol=1e-9)


def test_base_mass_zero_is_a_bare_base():
    # base_mass=0 and no base_mass give the same expressions, tree for tree
    bare = derive(make("linkage cp base=tx:X\n  POLE revolute a=0.5 mass=0.3\nend"))
    zero = derive(make("linkage cp base=tx:X base_mass=0 base_inertia=0\n  POLE revolute a=0.5 mass=0.3\nend"))
    assert {k: sp.srepr(v) for k, v in bare.items()} == {k: sp.srepr(v) for k, v in zero.items()}


TORSO = """
linkage torso base=tx:X,ty:Y,rz:R {body}
  HIP  revolute a=0.4 mass=2
  KNEE revolute a=0.3 mass=1 com=-0.1:0.05:0
end
"""


def test_turning_base_adds_its_mass_and_inertia():
    """The base body is a point mass at (X, Y) turning with R: its own Newton–Euler is M X'',
    M (Y'' + g), I R'', and it pushes on nothing else, so the joints' torques stay as they were."""
    bare = forces(make(TORSO.format(body="")))
    body = forces(make(TORSO.format(body="base_mass=4.5 base_inertia=0.35")))
    rng = np.random.default_rng(51)
    for _ in range(20):
        q, qd, qdd = rng.uniform(-3, 3, 5), rng.uniform(-4, 4, 5), rng.uniform(-10, 10, 5)
        g = rng.uniform(0, 20)
        extra = [4.5 * qdd[0], 4.5 * (qdd[1] + g), 0.35 * qdd[2], 0.0, 0.0]
        np.testing.assert_allclose(body(q, qd, qdd, g) - bare(q, qd, qdd, g), extra, rtol=0, atol=1e-9)


def test_base_mass_sits_after_all_base_axes():
    """base=rz:R,tx:X turns, then slides along the turned x: the base's mass rides at
    (X cos R, X sin R). By hand, T = M (X'^2 + X^2 R'^2)/2 + I R'^2/2 and V = M g X sin R give
    tau_R = M (X^2 R'' + 2 X X' R') + I R'' + M g X cos R and tau_X = M (X'' - X R'^2) + M g sin R."""
    text = "linkage arm base=rz:R,tx:X {body}\n  A revolute a=0.5 mass=1.2\nend"
    bare, body = (forces(make(text.format(body=b))) for b in ("", "base_mass=2.5 base_inertia=0.4"))
    rng = np.random.default_rng(52)
    for _ in range(20):
        q, qd, qdd = rng.uniform(-3, 3, 3), rng.uniform(-4, 4, 3), rng.uniform(-10, 10, 3)
        g = rng.uniform(0, 20)
        (r, x), (rd, xd), (rdd, xdd) = q[:2], qd[:2], qdd[:2]
        tau_r = 2.5 * (x * x * rdd + 2 * x * xd * rd) + 0.4 * rdd + 2.5 * g * x * math.cos(r)
        tau_x = 2.5 * (xdd - x * rd * rd) + 2.5 * g * math.sin(r)
        np.testing.assert_allclose(body(q, qd, qdd, g) - bare(q, qd, qdd, g), [tau_r, tau_x, 0.0],
                                   rtol=0, atol=1e-9)


def test_spatial_base_inertia_is_about_its_rotation_axis():
    """A 3-D base that slides in x, z and turns about y (gravity -y): its inertia adds I BROT''."""
    text = ("linkage bb base=tx:BX,tz:BZ,ry:BROT gravity=-y {body}\n"
            "  TURN revolute d=0.8 alpha=pi/2 mass=3\n  HAND revolute a=0.4 mass=0.8\nend")
    bare, body = (forces(make(text.format(body=b))) for b in ("", "base_mass=6 base_inertia=0.9"))
    rng = np.random.default_rng(53)
    for _ in range(10):
        q, qd, qdd = rng.uniform(-3, 3, 5), rng.uniform(-4, 4, 5), rng.uniform(-10, 10, 5)
        g = rng.uniform(0, 20)
        extra = [6 * qdd[0], 6 * qdd[1], 0.9 * qdd[2], 0.0, 0.0]
        np.testing.assert_allclose(body(q, qd, qdd, g) - bare(q, qd, qdd, g), extra, rtol=0, atol=1e-9)


def test_centroidal_dof_count_the_base_mass():
    # Two rods of 0.5 m and 1 kg on a 0.7 kg base: the centre of mass sits (0.75 u1 + 0.25 u2) / 2.7
    # from the foot (u1, u2 the links' directions), and the ground force is 2.7 (C'' - gravity).
    s = Session()
    s.run_text("""time 0 1 knots=8
const g = 9.81
linkage acro base=tx:X,ty:Y com=CX,CY base_mass=0.7
  FOOT  revolute a=0.5 mass=1.0
  WAIST revolute a=0.5 mass=1.0
end
dof FOOT = 1 + 2*t^2
dof WAIST = 0.5*sin(3*t)
dof CX = 0.3 + t - t^3
dof CY = 0.5 + 2*t - 4.9*t^2
""")
    sc = s.scene
    times = np.linspace(0.05, 0.95, 7)
    val = {n: sc.dofs[n].curve.evaluate(times) for n in sc.dofs}
    acc = {n: sc.dofs[n].curve.evaluate(times, 2) for n in sc.dofs}
    f, w = val["FOOT"], val["FOOT"] + val["WAIST"]
    at = lambda name: sc.evaluate(named_symbol(name), times)
    np.testing.assert_allclose(at("X"), val["CX"] - (0.75 * np.cos(f) + 0.25 * np.cos(w)) / 2.7, atol=1e-12)
    np.testing.assert_allclose(at("Y"), val["CY"] - (0.75 * np.sin(f) + 0.25 * np.sin(w)) / 2.7, atol=1e-12)
    np.testing.assert_allclose(at("acro.com.x"), val["CX"], atol=1e-12)
    np.testing.assert_allclose(at("tau_X"), 2.7 * acc["CX"], atol=1e-9)
    np.testing.assert_allclose(at("tau_Y"), 2.7 * (acc["CY"] + 9.81), atol=1e-9)
    assert dof_symbol("X") not in sc.derived["X"].free_symbols     # the 1e-16 leftover is dropped


def test_cartpole_session_swings_up_with_a_passive_pivot():
    """The bundled swing-up converges; at 1 ms samples of its DOF the textbook pivot torque stays
    within the passive constraint's stated dense_tol, and the pole goes from hanging to upright."""
    s = Session()
    s.run_file(SESSIONS / "cartpole.stw")
    assert s.runs and s.runs[-1].converged
    tol = s.scene.constraints["passive"].dense_tol
    assert tol <= 0.01 * 0.3 * 9.81 * 0.5          # at most 1% of the pole's weight times length
    samples = s.sample(2001)                         # t = 0, 0.001, ..., 2
    x_dd = np.array(samples["X"]["acceleration"])
    th, th_d, th_dd = (np.array(samples["POLE"][k]) for k in ("value", "velocity", "acceleration"))
    torque = [cart_pole_in_stw_angles(*state, 1.0, 0.3, 0.25, 0.3 * 0.25 / 12, 9.81)[1]
              for state in zip(x_dd, th, th_d, th_dd)]
    assert np.abs(torque).max() <= tol
    assert (th[0], th[-1]) == pytest.approx((-math.pi / 2, math.pi / 2), abs=1e-9)
    assert np.abs(th_d[[0, -1]]).max() <= 1e-9
    x = np.array(samples["X"]["value"])
    assert np.abs(x[[0, -1]]).max() <= 1e-9 and x.max() > 0.3   # it has to run to swing the pole


@pytest.mark.parametrize("header, column, message", [
    ("linkage cp base=tx:X base_mass=-1", 32, "base_mass cannot be negative"),
    ("linkage cp base=tx:X base_mass=heavy", 32, "bad number 'heavy'"),
    ("linkage cp base=tx:X base_mass=", 32, "base_mass= needs a value"),
    ("linkage cp base=tx:X base_mass=1 base_mass=2", 34, "given twice"),
    ("linkage cp base_mass=1", 12, "base_mass needs a base that translates"),
    ("linkage cp base=rz:R base_mass=1", 22, "base_mass needs a base that translates"),
    ("linkage cp base=tx:X base_inertia=0.2", 22, "base_inertia needs a base that turns"),
    ("linkage cp base=rx:P,rz:R base_inertia=0.2", 27, "base_inertia needs one base rotation, not 2"),
    ("linkage cp base=tx:X,rz:R base_inertia=-0.2", 40, "base_inertia cannot be negative"),
    ("linkage cp base=tx:X base_weight=1", 22, "unknown linkage option 'base_weight'"),
])
def test_bad_base_body_is_refused_where_it_is_written(header, column, message):
    """In a session, the error names the header's line and the column of the bad option."""
    s = Session()
    with pytest.raises(SourceError) as info:
        s.run_text(f"time 0 1 knots=8\nconst g = 9.81\n{header}\n  POLE revolute a=0.5 mass=0.3\nend\n")
    err = info.value
    assert message in err.message
    assert (err.line, err.column) == (3, column)
    assert err.caret().splitlines()[1] == " " * (column - 1) + "^"
    assert "cp" not in s.scene.linkages


def test_a_massless_pole_on_a_massive_cart_is_a_linkage_with_mass():
    spec = make("linkage cp base=tx:X base_mass=2\n  POLE revolute a=0.5 mass=0\nend")
    assert spec.total_mass == 2.0
    with pytest.raises(SourceError, match="no mass"):
        make("linkage cp base=tx:X base_mass=0\n  POLE revolute a=0.5 mass=0\nend")


def test_help_states_the_options_and_conventions():
    from stw_tui.sym.language.help import help_text

    text = help_text("linkage")
    for words in ("base_mass=M", "base_inertia=I", "from +x", "y is up", "uniform rod", "mid-link",
                  "m a^2/12"):
        assert words in text, words


def test_flight_leaves_the_first_joint_to_push_on_a_base_with_inertia():
    """In the air a bare base (or a point mass) can take no torque, so the first joint's torque
    vanishes with the base forces; a base with an inertia of its own takes it (a torso's hip)."""
    def flight_of(body):
        s = Session()
        s.run_text(f"time 0 1 knots=8\nconst g = 9.81\n{TORSO.format(body=body).strip()}\n"
                   "flight torso on [0.2, 0.6]\n")
        c = s.scene.constraints
        return [sp.sstr(r.expr) for n in ("torso_flight", "torso_spin") if n in c for r in c[n].relations]

    assert flight_of("base_mass=4.5") == ["tau_X", "tau_Y", "tau_R", "tau_HIP"]
    assert flight_of("base_mass=4.5 base_inertia=0.35") == ["tau_X", "tau_Y", "tau_R"]
