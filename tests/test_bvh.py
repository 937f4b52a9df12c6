"""BVH export, read back with this file's own parser and forward kinematics: the hierarchy names,
the channel and frame counts, the angles (the DOF curves at the frame times, in degrees), and the
joint and tip positions against stw's symbolic forward kinematics to 1e-6."""

import math
import subprocess
import sys

import numpy as np
import pytest

from conftest import run_lines
from stw_tui.session.export import frame_times
from stw_tui.session.session import Session
from stw_tui.sym.errors import StwError
from stw_tui.sym.symbols import named_symbol

# A 3-D creature that uses every part of the mapping: a base that translates then rotates, a twist
# (alpha) between rows, a prismatic joint, offsets theta and d.
ROBOT = """time 0 1.2 knots=8
const g = 9.81
linkage rob base=tx:X,ty:Y,rz:R
  A revolute a=0.3 alpha=pi/2 mass=1
  B prismatic a=0.1 d=0.2 alpha=-pi/2 mass=1
  C revolute a=0.25 theta=0.3 d=0.05 mass=1
end
dof X = 0.4*t
dof Y = 0.1*sin(3*t)
dof R = 0.5*t^2
dof A = sin(2*t)
dof B = 0.1 + 0.05*t
dof C = -1 + t
"""
LAST_PRISMATIC = """time 0 1 knots=6
const g = 9.81
linkage arm base=fixed
  S revolute a=0.4 mass=1
  P prismatic alpha=-pi/2 mass=1
end
dof S = t
dof P = 0.2*t
"""


def parse_bvh(text: str):
    """(joints [(name, parent index, offset, channels, is_end_site)], frame time, frames array)."""
    tokens = text.split()
    i, joints, stack = 0, [], []
    assert tokens[i] == "HIERARCHY"
    i += 1
    while tokens[i] != "MOTION":
        word = tokens[i]
        if word in ("ROOT", "JOINT"):
            joints.append([tokens[i + 1], stack[-1] if stack else -1, None, [], False])
            i += 2
        elif word == "End":
            assert tokens[i + 1] == "Site"
            joints.append(["End Site", stack[-1], None, [], True])
            i += 2
        elif word == "{":
            stack.append(len(joints) - 1)
            i += 1
        elif word == "}":
            stack.pop()
            i += 1
        elif word == "OFFSET":
            joints[stack[-1]][2] = np.array([float(v) for v in tokens[i + 1:i + 4]])
            i += 4
        elif word == "CHANNELS":
            n = int(tokens[i + 1])
            joints[stack[-1]][3] = tokens[i + 2:i + 2 + n]
            i += 2 + n
        else:
            raise AssertionError(f"unexpected {word}")
    assert not stack
    assert tokens[i + 1] == "Frames:" and tokens[i + 3:i + 5] == ["Frame", "Time:"]
    frames, frame_time = int(tokens[i + 2]), float(tokens[i + 5])
    values = np.array([float(v) for v in tokens[i + 6:]]).reshape(frames, -1)
    return joints, frame_time, values


def _rotation(axis: str, degrees: float) -> np.ndarray:
    c, s = math.cos(math.radians(degrees)), math.sin(math.radians(degrees))
    return {"X": np.array([[1, 0, 0], [0, c, -s], [0, s, c]]),
            "Y": np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]]),
            "Z": np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])}[axis]


def world_positions(joints, row) -> list[np.ndarray]:
    """Each joint's (and End Site's) world position in one frame: T(offset + positions) then the
    rotation channels multiplied in the order listed."""
    frames, out, k = [], [], 0
    for name, parent, offset, channels, _ in joints:
        translation, rotation = offset.astype(float).copy(), np.eye(3)
        for channel in channels:
            value = row[k]
            k += 1
            if channel.endswith("position"):
                translation["XYZ".index(channel[0])] += value
            else:
                rotation = rotation @ _rotation(channel[0], value)
        if parent < 0:
            rot, pos = rotation, translation
        else:
            prot, ppos = frames[parent]
            rot, pos = prot @ rotation, ppos + prot @ translation
        frames.append((rot, pos))
        out.append(pos)
    assert k == len(row)
    return out


def export_bvh(session, tmp_path, line):
    session.execute(line.replace("FILE", str(tmp_path / "out.bvh")))
    return (tmp_path / "out.bvh").read_text()


def check_positions(session, text, linkage, fps):
    scene = session.scene
    spec = scene.linkages[linkage]
    joints, frame_time, values = parse_bvh(text)
    times = frame_times(scene, fps)
    assert frame_time == pytest.approx(1 / fps, rel=1e-15)
    assert values.shape == (times.size, sum(len(j[3]) for j in joints))
    names = [j[0] for j in joints if not j[4]]
    points = [f"{linkage}.{j.name}" for j in spec.joints] + [f"{linkage}.tip"]
    index = {name: n for n, name in enumerate(j[0] for j in joints)}
    # stw's joint i is BVH joint i; the tip is the End Site (or the joint `tip` before it).
    where = [index[j.name] for j in spec.joints] + [len(joints) - 1]
    expected = np.stack([np.stack([np.broadcast_to(scene.evaluate(named_symbol(f"{p}.{axis}"), times), times.shape)
                                   for axis in "xyz"], axis=1) for p in points], axis=1)
    for f, row in enumerate(values):
        world = world_positions(joints, row)
        got = np.array([world[w] for w in where])
        np.testing.assert_allclose(got, expected[f], atol=1e-6, rtol=0)
    return names, joints, values, times


def test_bvh_hierarchy_angles_and_positions_match_stws_kinematics(tmp_path):
    s = run_lines(Session(), ROBOT)
    text = export_bvh(s, tmp_path, "export bvh FILE fps=25")
    names, joints, values, times = check_positions(s, text, "rob", 25)
    assert names == ["rob", "A", "B", "C"]
    assert [j[3] for j in joints[:4]] == [
        ["Xposition", "Yposition", "Zposition", "Zrotation", "Xrotation", "Yrotation"],
        ["Xrotation", "Zrotation", "Yrotation"], ["Xrotation", "Zrotation", "Yrotation"],
        ["Xposition", "Yposition", "Zposition", "Xrotation", "Zrotation", "Yrotation"]]
    assert joints[4][4] and joints[4][0] == "End Site"
    assert len(times) == 31 and values.shape == (31, 18)      # 1.2 s at 25 fps: frames 0..30
    curve = lambda name, order=0: s.scene.dofs[name].curve.evaluate(times, order)
    np.testing.assert_allclose(values[:, 0], curve("X"), atol=1e-12)          # base translation
    np.testing.assert_allclose(values[:, 1], curve("Y"), atol=1e-12)
    np.testing.assert_allclose(values[:, 3], np.degrees(curve("R")), atol=1e-10)
    np.testing.assert_allclose(values[:, 7], np.degrees(curve("A")), atol=1e-10)   # A's Zrotation
    np.testing.assert_allclose(values[:, 9], 90.0, atol=1e-12)                     # A's twist, on B
    np.testing.assert_allclose(values[:, 10], 0.0, atol=1e-12)                     # B slides, Z fixed
    np.testing.assert_allclose(values[:, 14], curve("B"), atol=1e-12)              # ... along z, on C
    np.testing.assert_allclose(values[:, 15], -90.0, atol=1e-12)                   # B's twist, on C
    np.testing.assert_allclose(values[:, 16], np.degrees(curve("C")) + np.degrees(0.3), atol=1e-10)


def test_bvh_with_a_prismatic_last_joint_ends_in_a_sliding_tip(tmp_path):
    s = run_lines(Session(), LAST_PRISMATIC)
    text = export_bvh(s, tmp_path, "export bvh FILE")
    names, joints, values, times = check_positions(s, text, "arm", 30)
    assert names == ["arm", "S", "P", "tip"] and len(times) == 31


def test_bvh_is_refused_without_one_linkage_and_stw_export_writes_it(tmp_path):
    s = run_lines(Session(), "dof x\n")
    with pytest.raises(StwError, match="has none"):
        s.execute(f"export bvh {tmp_path / 'x.bvh'}")
    assert not (tmp_path / "x.bvh").exists()
    two = run_lines(Session(), LAST_PRISMATIC + "linkage leg base=fixed\n  K revolute a=0.2\nend\n")
    with pytest.raises(StwError, match="what=NAME"):
        two.execute(f"export bvh {tmp_path / 'x.bvh'}")
    text = export_bvh(two, tmp_path, "export bvh FILE what=leg")
    assert parse_bvh(text)[0][0][0] == "leg"
    session = tmp_path / "arm.stw"
    session.write_text(LAST_PRISMATIC)
    out = tmp_path / "cli.bvh"
    done = subprocess.run([sys.executable, "-m", "stw_tui.cli.main", "export", str(session), "--format", "bvh",
                           "-o", str(out), "--fps", "10"], capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    check_positions(run_lines(Session(), LAST_PRISMATIC), out.read_text(), "arm", 10)


# A branched planar figure on a free base: a leg, and from the base a trunk carrying two arms and
# a head (the base's children and a link's children), one arm with an angle offset.
TREE = """time 0 1 knots=6
const g = 9.81
linkage fig base=tx:X,ty:Y
  SHIN  revolute a=0.45 mass=3.5
  THIGH revolute a=0.42 mass=7
  TRUNK revolute a=0.55 mass=30 parent=base
  LARM  revolute a=0.6 mass=3 parent=TRUNK
  RARM  revolute a=0.55 mass=2.5 parent=TRUNK theta=0.3
  HEAD  revolute a=0.25 mass=5 parent=TRUNK
end
dof X = 0.5*t
dof Y = 0.1*sin(3*t)
dof SHIN = pi/2 - 0.3*t
dof THIGH = 0.6*t
dof TRUNK = pi/2 + 0.2*sin(2*t)
dof LARM = 2 + t
dof RARM = -2 + t^2
dof HEAD = -0.3*t
"""


def test_bvh_of_a_branched_linkage_is_its_tree_and_bvhio_reads_stws_positions(tmp_path):
    """The hierarchy nests each joint under the one it hangs from and ends every leaf in an End
    Site; this file's reader and bvhio (an independent BVH library) both put every joint and
    every link's end where stw's forward kinematics does, to 1e-6 at each frame."""
    bvhio = pytest.importorskip("bvhio")
    s = run_lines(Session(), TREE)
    text = export_bvh(s, tmp_path, "export bvh FILE fps=10")
    joints, frame_time, values = parse_bvh(text)
    parent = {j[0]: joints[j[1]][0] for j in joints if j[1] >= 0 and not j[4]}
    assert parent == {"SHIN": "fig", "THIGH": "SHIN", "TRUNK": "fig", "LARM": "TRUNK",
                      "RARM": "TRUNK", "HEAD": "TRUNK"}
    ends = [joints[j[1]][0] for j in joints if j[4]]
    assert ends == ["THIGH", "LARM", "RARM", "HEAD"]
    times = frame_times(s.scene, 10)

    def stw(point):
        return np.stack([np.broadcast_to(s.scene.evaluate(named_symbol(f"{point}.{ax}"), times), times.shape)
                         for ax in "xyz"], axis=1)

    expected = {name: stw(f"fig.{name}") for name in parent}
    expected_ends = {name: stw(f"fig.{name}.end") for name in ends}
    for f, row in enumerate(values):      # this file's own reader
        world = world_positions(joints, row)
        for n, j in enumerate(joints):
            if not j[4] and j[0] in expected:
                np.testing.assert_allclose(world[n], expected[j[0]][f], atol=1e-6, rtol=0)
            elif j[4]:
                np.testing.assert_allclose(world[n], expected_ends[joints[j[1]][0]][f], atol=1e-6, rtol=0)
    root = bvhio.readAsHierarchy(str(tmp_path / "out.bvh"))
    seen = set()
    for f in range(len(times)):
        root.loadPose(f)
        for joint, _, _ in root.layout():
            p = joint.PositionWorld
            got = np.array([p.x, p.y, p.z])
            if joint.Name in expected:
                np.testing.assert_allclose(got, expected[joint.Name][f], atol=1e-6, rtol=0)
                seen.add(joint.Name)
    assert seen == set(expected)
