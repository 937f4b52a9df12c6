"""Motion verbs: `hold`, `ballistic` and `limit` expand into the constraints one would write by
hand, solve to the same motion, and are removed as one group."""

import numpy as np
import pytest

import catalogue
from conftest import run_lines
from stw_tui.session.session import Session
from stw_tui.sym.errors import SourceError, StwError

ARM = catalogue.problem("analytic_arm3").text + """dof BX, BY
limit SHOULDER -2.6 3.2
limit ELBOW 0 2.5
limit WRIST -1.2 1.2
dof SHOULDER = -pi/2
dof BY = -0.8
constraint hang: SHOULDER = -pi/2, ELBOW = 0, WRIST = 0, SHOULDER' = 0, ELBOW' = 0, WRIST' = 0 @ 0
"""
TAIL = """constraint goal: BX = 1.5, BY = 0.5 @ 1.5
constraint rest: SHOULDER' = 0, ELBOW' = 0, WRIST' = 0 @ 1.5
objective effort: tau_SHOULDER, tau_ELBOW, tau_WRIST
iterate 40
"""
BY_HAND = """constraint B_released: BX = arm.tip.x, BY = arm.tip.y, BX' = arm.tip.x', BY' = arm.tip.y' @ 0.55
constraint B_flight: BX'' = 0, BY'' + g = 0 on [0.55, 1.5]
"""
VERBS = "hold B at arm.tip on [0, 0.55]\nballistic B on [0.55, 1.5]\n"
LINKS = (0.35, 0.30, 0.15)


def hand(session, times, order=0):
    """The arm's tip and its time derivatives from the joint samples, by planar kinematics
    written here (angles relative, from +x, y up), not through stw's linkage or compiler."""
    q = [np.array(session.scene.dofs[j].curve.evaluate(times, 0)) for j in ("SHOULDER", "ELBOW", "WRIST")]
    qd = [np.array(session.scene.dofs[j].curve.evaluate(times, 1)) for j in ("SHOULDER", "ELBOW", "WRIST")]
    qdd = [np.array(session.scene.dofs[j].curve.evaluate(times, 2)) for j in ("SHOULDER", "ELBOW", "WRIST")]
    x, y, vx, vy, ax, ay = (np.zeros_like(times) for _ in range(6))
    phi, w, al = np.zeros_like(times), np.zeros_like(times), np.zeros_like(times)
    for a, th, thd, thdd in zip(LINKS, q, qd, qdd):
        phi, w, al = phi + th, w + thd, al + thdd
        c, s_ = np.cos(phi), np.sin(phi)
        x, y = x + a * c, y + a * s_
        vx, vy = vx - a * s_ * w, vy + a * c * w
        ax, ay = ax - a * (c * w ** 2 + s_ * al), ay + a * (c * al - s_ * w ** 2)
    return [(x, y), (vx, vy), (ax, ay)][order]


def test_a_held_object_is_the_hand_at_every_time_and_leaves_it_with_the_hands_velocity():
    s = run_lines(Session(), ARM + VERBS + TAIL)
    assert s.runs[-1].converged
    # While held: at 1 ms, the object (as the motion has it) is the hand, derived apart.
    times = np.arange(0, 0.55, 1e-3)
    for order in (0, 1, 2):
        bx, by = s.scene.dof_values("BX", times, order), s.scene.dof_values("BY", times, order)
        hx, hy = hand(s, times, order)
        assert np.max(np.hypot(bx - hx, by - hy)) < 1e-10, order
    # At the release its own curve leaves with the hand's position and velocity ...
    t = np.array([0.55])
    for order in (0, 1):
        own = [s.scene.dofs[d].curve.evaluate(t, order)[0] for d in ("BX", "BY")]
        assert np.allclose(own, [h[0] for h in hand(s, t, order)], atol=1e-9)
    # ... and flies ballistically: its acceleration is (0, -g) at every 1 ms after it.
    after = np.arange(0.55, 1.5, 1e-3)
    assert np.max(np.abs(s.scene.dofs["BX"].curve.evaluate(after, 2))) < 1e-9
    assert np.max(np.abs(s.scene.dofs["BY"].curve.evaluate(after, 2) + 9.81)) < 1e-9
    # `stw run --json` samples the object as the motion has it, the hand's point while held.
    sampled = s.sample(12)["BX"]
    t12 = np.array(sampled["t"])
    held = t12 < 0.55
    assert np.allclose(np.array(sampled["value"])[held], hand(s, t12)[0][held], atol=1e-10)
    # The constraints the verbs made are the ones written by hand; the hold itself is no line.
    hand_made = run_lines(Session(), ARM + BY_HAND)
    for name, c in hand_made.scene.constraints.items():
        mine = s.scene.constraints[name]
        assert [(r.expr, r.kind) for r in mine.relations] == [(r.expr, r.kind) for r in c.relations]
    assert s.scene.verbs == {"B_held": ("hold B at arm.tip on [0, 0.55]", ("B_released",)),
                             "B_flight": ("ballistic B on [0.55, 1.5]", ("B_flight",))}
    assert [p.target for p in s.scene.attachments["B_held"]] == ["BX", "BY"]
    # The journal keeps the verbs, and replays to the same scene.
    assert "hold B at arm.tip on [0, 0.55]" in s.journal.replayable()
    replay = run_lines(Session(), "\n".join(s.journal.replayable()) + "\n")
    assert np.array_equal(replay.scene.coefficient_vector(), s.scene.coefficient_vector())


def test_a_held_mass_loads_the_joints_as_newton_euler_derived_apart_says():
    """A point mass m at the tip of a planar two-link arm adds J^T m (p'' + g y) to the joint
    torques: written here from the tip's Jacobian, compared with stw's tau at random states."""
    text = """time 0 1 knots=6
const g = 9.81
linkage arm base=fixed
  SHOULDER revolute a=0.4 mass=1.2
  ELBOW    revolute a=0.3 mass=0.8
end
dof BX, BY
"""
    bare = run_lines(Session(), text)
    held = run_lines(Session(), text + "hold B at arm.tip on [0, 0.5] mass=0.6\n")
    rng = np.random.default_rng(3)
    for name in ("SHOULDER", "ELBOW"):
        for s in (bare, held):
            s.scene.dofs[name].curve = s.scene.dofs[name].curve.with_coef(rng.standard_normal(9))
        held.scene.dofs[name].curve = bare.scene.dofs[name].curve
    times = np.array([0.05, 0.2, 0.45, 0.7])
    q = [bare.scene.dofs[j].curve.evaluate(times, k) for j in ("SHOULDER", "ELBOW") for k in (0,)]
    qd = [bare.scene.dofs[j].curve.evaluate(times, 1) for j in ("SHOULDER", "ELBOW")]
    qdd = [bare.scene.dofs[j].curve.evaluate(times, 2) for j in ("SHOULDER", "ELBOW")]
    a1, a2, m, g = 0.4, 0.3, 0.6, 9.81
    p1, p12 = q[0], q[0] + q[1]
    w1, w12, al1, al12 = qd[0], qd[0] + qd[1], qdd[0], qdd[0] + qdd[1]
    ax = -a1 * (np.cos(p1) * w1 ** 2 + np.sin(p1) * al1) - a2 * (np.cos(p12) * w12 ** 2 + np.sin(p12) * al12)
    ay = a1 * (np.cos(p1) * al1 - np.sin(p1) * w1 ** 2) + a2 * (np.cos(p12) * al12 - np.sin(p12) * w12 ** 2)
    fx, fy = m * ax, m * (ay + g)                              # what the hand must push on the mass
    jac = {"SHOULDER": (-a1 * np.sin(p1) - a2 * np.sin(p12), a1 * np.cos(p1) + a2 * np.cos(p12)),
           "ELBOW": (-a2 * np.sin(p12), a2 * np.cos(p12))}
    from stw_tui.sym.symbols import named_symbol
    for name, (jx, jy) in jac.items():
        extra = held.scene.evaluate(named_symbol(f"tau_{name}"), times) - \
            bare.scene.evaluate(named_symbol(f"tau_{name}"), times)
        inside = times < 0.5
        np.testing.assert_allclose(extra[inside], (jx * fx + jy * fy)[inside], rtol=1e-9, atol=1e-9)
        assert np.max(np.abs(extra[~inside])) < 1e-12          # let go: no load (rounding aside)


def test_hold_inside_the_animation_catches_and_releases_and_delete_removes_the_group():
    s = run_lines(Session(), ARM + "hold B at arm.tip on [0.3, 0.9] mass=0.2\n")
    assert s.scene.verbs["B_held"][1] == ("B_caught", "B_released")
    assert s.scene.constraints["B_caught"].at == 0.3 and s.scene.constraints["B_released"].at == 0.9
    assert {p.target for p in s.scene.attachments["B_held"] if p.adds} == {"tau_SHOULDER", "tau_ELBOW", "tau_WRIST"}
    s.execute("hold B at arm.tip on [1, 1.2]")             # a second hold gets fresh names
    assert s.scene.verbs["B_held2"][1] == ("B_caught2", "B_released2")
    with pytest.raises(StwError, match="already held on"):   # one object, one hand at a time
        s.execute("hold B at arm.tip on [0.8, 1]")
    s.execute("delete B_held")
    assert not {"B_caught", "B_released"} & set(s.scene.constraints)
    assert "B_held" not in s.scene.verbs and "B_held" not in s.scene.attachments
    assert "B_released2" in s.scene.constraints and "B_held2" in s.scene.attachments
    assert s.scene.verbs["B_held2"][1] == ("B_caught2", "B_released2")


@pytest.mark.parametrize("line, message", [
    # One part of a verb: refused, naming the group and how to delete it (never widened to it).
    ("delete B_caught", r"'B_caught' is part of the verb `hold B at arm.tip on \[0.3, 0.9\]` "
                        r"\(group B_held\): `delete B_held` removes the whole group"),
    ("delete B_released", "part of the verb `hold B"),
    # Redefining a part, or naming something else like a group, would make the group lie.
    ("constraint B_released: BX = 0 @ 0.9", "part of the verb `hold B"),
    ("objective B_held: BX", "'B_held' names the verb `hold B"),
    ("let B_flight = BX + 1", "already a constraint or objective"),
    ("window B_flight dofs=BX", "already a constraint or objective"),
])
def test_a_part_of_a_verb_is_neither_deleted_nor_redefined_alone(line, message):
    s = run_lines(Session(), ARM + "hold B at arm.tip on [0.3, 0.9]\nballistic B on [0.9, 1.5]\n")
    before = ({n: c.text for n, c in s.scene.constraints.items()}, set(s.scene.objectives),
              set(s.scene.lets), set(s.scene.windows), dict(s.scene.verbs))
    with pytest.raises(StwError, match=message):
        s.execute(line)
    assert ({n: c.text for n, c in s.scene.constraints.items()}, set(s.scene.objectives),
            set(s.scene.lets), set(s.scene.windows), dict(s.scene.verbs)) == before
    s.execute("weight B_caught 5")                             # reweighing one part is allowed
    assert s.scene.constraints["B_caught"].weight == 5


def test_a_verb_group_name_that_is_no_part_is_not_taken_by_anything_else():
    s = run_lines(Session(), ACRO + "contact acro.FOOT on ground on [0, 0.5] x=0\n")
    assert "FOOT_contact" in s.scene.verbs and "FOOT_contact" not in s.scene.constraints
    for line in ("constraint FOOT_contact: CX = 0 @ 0", "let FOOT_contact = CX", "window FOOT_contact dofs=CX"):
        with pytest.raises(StwError, match="'FOOT_contact' names the verb `contact acro.FOOT on ground"):
            s.execute(line)
    assert s.execute("delete FOOT_contact").message == ("deleted FOOT_contact (FOOT_liftoff, FOOT_push, "
                                                         "FOOT_friction, FOOT_pressure)")
    assert not s.scene.verbs and not s.scene.constraints and not s.scene.attachments


@pytest.mark.parametrize("line, message", [
    ("hold Q at arm.tip on [0, 0.5]", "'Q' is not a point object"),
    ("hold B at arm.knee on [0, 0.5]", "'arm.knee' is not a linkage point"),
    ("hold B arm.tip on [0, 0.5]", "expected 'at POINT'"),
    ("hold B at arm.tip on [0.5, 0.2]", "is empty"),
    ("ballistic B on [0, 9]", "outside the animation span"),
    ("limit ELBOW 2 1", "lower limit must be below"),
    ("limit nothing 0 1", "not a DOF"),
])
def test_verb_errors_are_positioned_and_change_nothing(line, message):
    s = run_lines(Session(), ARM)
    before = (set(s.scene.constraints), set(s.scene.objectives), dict(s.scene.verbs))
    with pytest.raises((StwError, SourceError), match=message):
        s.execute(line)
    assert (set(s.scene.constraints), set(s.scene.objectives), dict(s.scene.verbs)) == before


def test_ballistic_needs_g_and_limit_is_a_dof_range():
    s = run_lines(Session(), "time 0 1 knots=8\ndof PX, PY\n")
    with pytest.raises(StwError, match="declare it first"):
        s.execute("ballistic P on [0, 1]")
    s.execute("dof PX = 2*t")
    message = s.execute("limit PX 0 1").message
    assert "outside now" in message and "to 2)" in message
    assert (s.scene.dofs["PX"].lo, s.scene.dofs["PX"].hi) == (0.0, 1.0)
    # two negative bounds: the second read as a subtraction is caught, and the fix is named
    with pytest.raises(SourceError) as err:
        s.execute("limit PX -2.9 -0.9")
    assert "a negative B after A reads as a subtraction" in str(err.value) and "(-0.9)" in str(err.value)
    assert (s.scene.dofs["PX"].lo, s.scene.dofs["PX"].hi) == (0.0, 1.0)
    s.execute("limit PX -2.9 (-0.9)")
    assert (s.scene.dofs["PX"].lo, s.scene.dofs["PX"].hi) == (-2.9, -0.9)


def test_a_verb_and_its_delete_are_each_one_undo_step():
    s = run_lines(Session(), ARM)
    s.execute("hold B at arm.tip on [0.3, 0.9]")
    s.execute("delete B_held")
    assert "B_caught" not in s.scene.constraints
    s.execute("undo")                                          # the group is back, whole
    assert s.scene.verbs["B_held"][1] == ("B_caught", "B_released")
    assert {"B_caught", "B_released"} <= set(s.scene.constraints) and "B_held" in s.scene.attachments
    s.execute("undo")                                          # and the verb is gone
    assert not s.scene.verbs and not s.scene.attachments


def test_the_journal_save_and_autosave_keep_the_verb_line_and_replay_the_group(tmp_path):
    from stw_tui.session.autosave import Checkpoints
    from stw_tui.session.resume import resume

    def groups(session):
        scene = session.scene
        return dict(scene.verbs), {n: c.text for n, c in scene.constraints.items()}, \
            {n: (o.text, o.weight) for n, o in scene.objectives.items()}

    path = tmp_path / "journal.stw"
    s = Session(journal_path=path)
    s.checkpoints = Checkpoints(path)
    s.run_text(ARM + "hold B at arm.tip on [0.3, 0.9] weight=500\nballistic B on [0.9, 1.5]\n"
               "hold B at arm.tip on [1, 1.2]\ndelete B_held\nweight B_released2 3\n")
    assert set(s.scene.verbs) == {"B_flight", "B_held2"}
    # On disk: the verbs as typed, never their expansion (which a replay makes again).
    journal = path.read_text()
    assert "hold B at arm.tip on [0.3, 0.9] weight=500" in journal and "ballistic B on [0.9, 1.5]" in journal
    assert not any(line.startswith(("constraint B_", "objective B_")) for line in journal.splitlines())
    resumed, _, _ = resume(path)
    assert groups(resumed) == groups(s)
    saved = tmp_path / "saved.stw"
    s.execute(f"save {saved}")
    assert "hold B at arm.tip on [1, 1.2]" in saved.read_text()
    replay = Session()
    replay.run_file(saved)
    assert groups(replay) == groups(s)
    assert replay.scene.verbs["B_held2"][1] == ("B_caught2", "B_released2")
    assert replay.scene.attachments == s.scene.attachments


ACRO = """time 0 1.5 knots=30 samples=30
const g = 9.81
linkage acro base=tx:X,ty:Y com=CX,CY
  FOOT  revolute a=0.5 mass=1.0
  WAIST revolute a=0.5 mass=1.0
end
"""


def test_contact_and_flight_expand_into_named_constraints_grouped_under_the_verb():
    s = run_lines(Session(), ACRO + "contact acro.FOOT on ground y=0.1 on [0.5, 1] friction=0.8 x=0 "
                  "support=[-0.1, 0.2]\nflight acro on [0, 0.5]\nflight acro on [1, 1.5] dense_tol=0.5\n")
    c = s.scene.constraints
    assert s.scene.verbs["FOOT_contact"][1] == ("FOOT_touchdown", "FOOT_liftoff", "FOOT_push", "FOOT_friction",
                                                "FOOT_pressure")
    # The foot is planted by construction: over the stance the centre of mass hangs from (0, 0.1).
    parts = s.scene.attachments["FOOT_contact"]
    assert [(p.target, p.a, p.b, p.closed_a, p.closed_b) for p in parts] == [("CX", 0.5, 1.0, False, False),
                                                                             ("CY", 0.5, 1.0, False, False)]
    # The flights' own curves meet it at rest at the touchdown and the lift-off.
    for name, t in (("FOOT_touchdown", 0.5), ("FOOT_liftoff", 1.0)):
        assert c[name].text.endswith(f"acro.FOOT.x = 0.0, acro.FOOT.y = 0.1, acro.FOOT.x' = 0, acro.FOOT.y' = 0 @ {t}")
    assert [r.kind for r in c["FOOT_push"].relations] == ["ge"]
    assert len(c["FOOT_friction"].relations) == 2 and len(c["FOOT_pressure"].relations) == 2
    # The nonlinear relations hold to 1% of the body's weight (2 kg: 0.1962 N), and the centre of
    # pressure's moment to 1% of weight x size (1 m): physical units, not metres of slide.
    assert c["FOOT_push"].dense_tol == c["FOOT_friction"].dense_tol == pytest.approx(0.1962)
    assert c["FOOT_pressure"].dense_tol == pytest.approx(0.1962)
    # In the air: the base forces (exact with com=) and the torque hanging the first massive link.
    assert s.scene.verbs["acro_flight"][1] == ("acro_flight", "acro_spin")
    assert c["acro_flight"].dense_tol is None and len(c["acro_flight"].relations) == 2
    assert c["acro_spin"].dense_tol == pytest.approx(0.1962) and c["acro_spin2"].dense_tol == 0.5
    s.execute("delete FOOT_contact")
    assert not {"FOOT_liftoff", "FOOT_push", "FOOT_friction"} & set(s.scene.constraints)
    assert not s.scene.attachments and "acro_spin2" in s.scene.constraints


def test_contact_states_where_the_point_is_planted_and_one_stance_at_a_time():
    s = run_lines(Session(), ACRO + "contact acro.FOOT on ground on [0, 0.5] x=0\n")
    before = (set(s.scene.constraints), dict(s.scene.verbs))
    for bad, why in (("contact acro.FOOT on ground on [0.6, 1]", "x=X0 says where acro.FOOT is planted"),
                     ("contact acro.FOOT on ground on [0.4, 1] x=1", "already planted on \\[0, 0.5\\]"),
                     ("contact acro.FOOT on ground on [0.6, 1] x=1 support=[0.2, 0.1]", "support \\[0.2, 0.1\\] is empty"),
                     ("contact acro.WAIST on ground on [0.6, 1] x=1", "plant acro.FOOT, the first joint"),
                     ("contact acro.FOOT on ground on [0.6, 1] x=1 dense_tol=0", "dense_tol must be > 0"),
                     ("flight acro on [0.5, 1] dense_tol=-1", "dense_tol must be > 0")):
        with pytest.raises(StwError, match=why):
            s.execute(bad)
        assert (set(s.scene.constraints), dict(s.scene.verbs)) == before


def _values(scene, expr_text, times):
    from stw_tui.session.session import SceneScope
    from stw_tui.sym.language.commands import parse_command
    return scene.evaluate(parse_command(f"print {expr_text}", SceneScope(scene)).expr, times)


def test_a_planted_point_holds_by_construction_and_its_force_is_newton_for_the_whole_body():
    # Independent of the linkage's derivation: two uniform rods of mass 1 (total 2) put the centre
    # of mass 0.375 and 0.125 along the links from the foot. In the stance the centre of mass hangs
    # from the planted foot, so the ground's force is 2 (C'' + g y) of that hanging centre of mass,
    # whatever the centre of mass's own curve does; the foot stays exactly where it was planted.
    s = run_lines(Session(), ACRO + """dof FOOT = 1 + 2*t^2
dof WAIST = 0.5*sin(3*t)
dof CX = 0.3 + t - t^3
dof CY = 0.5 + 2*t - 4.9*t^2
contact acro.FOOT on ground on [0, 0.5] friction=0.8 x=0.25 support=[-0.1, 0.1]
flight acro on [0.5, 1]
""")
    sc = s.scene
    t = np.linspace(0.01, 0.49, 9)
    f, df, ddf = (sc.dofs["FOOT"].curve.evaluate(t, k) for k in range(3))
    w, dw, ddw = (a + b for a, b in zip((f, df, ddf), (sc.dofs["WAIST"].curve.evaluate(t, k) for k in range(3))))
    # C = foot + 0.375 u(f) + 0.125 u(w), u = (cos, sin): its second derivative, by hand
    cxx = -0.375 * (np.cos(f) * df ** 2 + np.sin(f) * ddf) - 0.125 * (np.cos(w) * dw ** 2 + np.sin(w) * ddw)
    cyy = -0.375 * (np.sin(f) * df ** 2 - np.cos(f) * ddf) - 0.125 * (np.sin(w) * dw ** 2 - np.cos(w) * ddw)
    push, friction = (sc.constraints[n] for n in ("FOOT_push", "FOOT_friction"))
    from stw_tui.sos.attachments import restrict
    from stw_tui.sym.symbols import named_symbol
    on = lambda e: restrict(sc.expand(e), 0.0, 0.5)
    for point, value in (("acro.FOOT.x", 0.25), ("acro.FOOT.y", 0.0), ("acro.FOOT.x'", 0.0), ("acro.FOOT.y'", 0.0)):
        np.testing.assert_allclose(sc.evaluate(on(named_symbol(point)), t), value, atol=1e-12)
    np.testing.assert_allclose(sc.evaluate(on(push.relations[0].expr), t), 2 * (cyy + 9.81), atol=1e-9)
    np.testing.assert_allclose(sc.evaluate(on(friction.relations[0].expr), t),
                               0.8 * 2 * (cyy + 9.81) - 2 * cxx, atol=1e-9)
    # In the air the centre of mass's own curve: force-free means C'' = -g y.
    t = np.linspace(0.51, 0.99, 9)
    flight = sc.constraints["acro_flight"].relations
    np.testing.assert_allclose(sc.evaluate(flight[0].expr, t), 2 * sc.dofs["CX"].curve.evaluate(t, 2),
                               atol=1e-9)


@pytest.mark.parametrize("line, message", [
    ("contact arm.tip on ground on [0, 0.5]", "fixed base"),
    ("contact acro.KNEE on ground on [0, 0.5]", "not a point of linkage acro"),
    ("contact acro.FOOT on ground on [0, 0.5] friction=-1 x=0", "must be at least 0"),
    ("contact acro.FOOT on floor on [0, 0.5]", "expected 'ground'"),
    ("contact acro.FOOT on ground [0, 0.5]", "expected 'on \\[A, B\\]'"),
    ("flight arm on [0, 0.5]", "fixed base"),
    ("flight bird on [0, 0.5]", "'bird' is not a linkage"),
])
def test_contact_and_flight_errors_change_nothing(line, message):
    s = run_lines(Session(), ACRO + "linkage arm base=fixed\n  S revolute a=0.5\nend\n")
    before = (set(s.scene.constraints), dict(s.scene.verbs))
    with pytest.raises((StwError, SourceError), match=message):
        s.execute(line)
    assert (set(s.scene.constraints), dict(s.scene.verbs)) == before


def test_flight_frees_every_joint_up_to_the_first_massive_link():
    # A massless hip hangs the leg on the base: in the air neither can take a torque.
    s = run_lines(Session(), """time 0 1 knots=8
const g = 9.81
linkage hopper base=tx:X,ty:Y
  HIP revolute a=0 mass=0
  LEG revolute a=0.8 mass=2
  ARM revolute a=0.3 mass=0.5
end
flight hopper on [0.2, 0.6]
""")
    c = s.scene.constraints
    assert [str(r.expr) for r in c["hopper_flight"].relations] == ["tau_X", "tau_Y"]
    assert [str(r.expr) for r in c["hopper_spin"].relations] == ["tau_HIP", "tau_LEG"]


def test_contact_and_flight_remain_usable_as_constraint_names():
    s = run_lines(Session(), "time 0 1 knots=8\ndof x\nconstraint flight: x = 1 @ 0.5\nconstraint contact: x' = 0 @ 0.5\n")
    assert {"flight", "contact"} <= set(s.scene.constraints)


@pytest.mark.parametrize("verb, made, deleted_by", [
    ("hold", {"B_held": ("B_released",)}, "`delete P_held`"),
    ("ballistic", {"B_flight": ("B_flight",)}, "`delete P_flight`"),
    ("contact", {"FOOT_contact": ("FOOT_liftoff", "FOOT_push", "FOOT_friction", "FOOT_pressure")},
     "`delete POINT_contact`"),
    ("flight", {"acro_flight": ("acro_flight", "acro_spin")}, "`delete LINKAGE_flight`"),
    ("limit", {}, "no group"),
])
def test_help_documents_every_verb_with_an_example_that_runs(verb, made, deleted_by):
    from stw_tui.sym.language.help import help_text

    text = help_text(verb)
    assert text.startswith(verb + " ") and f"\n  {verb} " in help_text(None) and deleted_by in text
    s = run_lines(Session(), ARM + ACRO.split("\n", 2)[2])     # the arm, and the acrobat beside it
    s.execute(text.split("example: ", 1)[1])
    assert {g: members for g, (_, members) in s.scene.verbs.items()} == made
    if verb == "limit":
        assert (s.scene.dofs["ELBOW"].lo, s.scene.dofs["ELBOW"].hi) == (0.0, 2.5)
