"""Every bundled session that holds an object: held, it is the hand at every 1 ms; it leaves and
is caught with the hand's velocity; it flies a parabola from the release. The hand is derived
here from the joint samples (planar forward kinematics, turned and carried by a base where there
is one), not through stw's linkage or compiler."""

import numpy as np
import pytest

from conftest import SESSIONS
from stw_tui.session.session import Session
from test_creatures import _planar_tip, _player_tip

G = 9.81
JOINTS = ("SHOULDER", "ELBOW", "WRIST")
STEP = 1e-3


def hand(scene, t: np.ndarray) -> np.ndarray:
    """(n, 3): the tip of the planar arm (test_creatures' kinematics, written apart from stw's), in
    a vertical plane that a base (PX, PZ, TURN about y) carries and turns when the scene has one."""
    angles = [scene.dofs[joint].curve.evaluate(t) for joint in JOINTS]
    if "TURN" not in scene.dofs:
        x, y = _planar_tip(angles)
        return np.stack([x, y, np.zeros_like(t)], axis=1)
    return _player_tip(angles, [scene.dofs[n].curve.evaluate(t) for n in ("PX", "PZ", "TURN")]).T


def hand_velocity(scene, t: np.ndarray, h: float = 1e-6) -> np.ndarray:
    """A central difference of :func:`hand` (error ~h^2 |p'''| plus rounding ~eps |p| / h:
    about 1e-10, below the 1e-8 asked)."""
    return (hand(scene, t + h) - hand(scene, t - h)) / (2 * h)


def ball(scene, t: np.ndarray, order: int = 0, own: bool = False) -> np.ndarray:
    """(n, 3): the ball as the motion has it (own: its own curve, used outside its holds)."""
    names = [n for n in ("BX", "BY", "BZ") if n in scene.dofs]
    cols = [scene.dofs[n].curve.evaluate(t, order) if own else scene.dof_values(n, t, order) for n in names]
    cols += [np.zeros_like(t)] * (3 - len(cols))
    return np.stack(cols, axis=1)


@pytest.fixture(scope="module", params=["arm_throw", "arm_overhand", "basketball"])
def thrower(request):
    s = Session()
    s.run_file(SESSIONS / f"{request.param}.stw")
    return s


def holds(scene) -> list[tuple[float, float]]:
    return sorted({(p.a, p.b) for parts in scene.attachments.values() for p in parts if p.target == "BX"})


def test_a_held_ball_is_in_the_hand_at_every_millisecond(thrower):
    scene = thrower.scene
    assert holds(scene), "the session holds its ball"
    for a, b in holds(scene):
        t = np.arange(a, b, STEP)
        gap = np.linalg.norm(ball(scene, t) - hand(scene, t), axis=1)
        # The target is 0.1 mm; held, the ball is the hand's point by construction, so the gap
        # is rounding: measured 2.3e-16 (arm_throw, arm_overhand), 1.6e-15 (basketball). 1e-13
        # leaves room for another evaluation order (60x the worst).
        assert gap.max() <= 1e-13, (a, b, gap.max())


def test_the_ball_leaves_and_is_caught_with_the_hands_velocity_and_flies_a_parabola(thrower):
    scene = thrower.scene
    times = sorted({t for a, b in holds(scene) for t in (a, b) if scene.t0 < t < scene.t1})
    assert times
    for t in times:                        # its own curve meets the hand at a release and a catch
        at = np.array([t])
        # measured: 7.1e-13 m (arm_overhand; 3e-15 the others), to the solve's violation there
        assert np.linalg.norm(ball(scene, at, own=True) - hand(scene, at)) <= 5e-11
        # measured: 9.3e-10 m/s at worst, the central difference's rounding (eps |p| / h ~ 1e-10)
        assert np.linalg.norm(ball(scene, at, 1, own=True) - hand_velocity(scene, at)) <= 1e-8
    for a, b in holds(scene):              # after each release: a parabola from the hand's state
        if b >= scene.t1:
            continue
        catch = min([t for t in times if t > b] + [scene.t1])
        t = np.arange(b, catch, STEP)
        p0, v0 = hand(scene, np.array([b]))[0], hand_velocity(scene, np.array([b]))[0]
        dt = (t - b)[:, None]
        parabola = p0 + v0 * dt + np.array([0, -G / 2, 0]) * dt ** 2
        # the residual is the hand's velocity difference times the flight (<= 1e-8 m/s * 1 s)
        # plus rounding: measured 9.6e-10 m at worst (basketball); the ball's own curve against
        # its own release state is exact (measured 3.0e-15; 1e-12 allows for rounding):
        assert np.abs(ball(scene, t) - parabola).max() <= 2e-8
        own = ball(scene, np.array([b]), own=True)[0], ball(scene, np.array([b]), 1, own=True)[0]
        exact = own[0] + own[1] * dt + np.array([0, -G / 2, 0]) * dt ** 2
        assert np.abs(ball(scene, t) - exact).max() <= 1e-12
