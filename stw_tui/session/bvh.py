"""BVH export of a linkage's motion (`export bvh FILE [fps=N] [what=LINKAGE]`), for Blender and
other motion-capture tools.

The skeleton comes from the linkage's Denavit–Hartenberg rows. DH row i is
``Rz(theta_i + q_i) Tz(d_i + q_i) Tx(a_i) Rx(alpha_i)`` (q_i on theta for a revolute joint, on d
for a prismatic one). A BVH joint is a translation (its OFFSET, and position channels) followed
by a rotation (its rotation channels, multiplied in the order listed). So BVH joint i sits where
stw's joint i sits (the origin of DH frame i-1), its OFFSET is the previous row's ``(a, 0, d)``,
and its channels are ``Xrotation Zrotation Yrotation``: the previous row's constant twist alpha,
then theta_i (+ q_i), and a Y of 0 (three rotation channels, as importers expect). After a
prismatic row the next joint also has ``Xposition Yposition Zposition`` = ``(0, 0, q)``: the slide
along the previous joint's z. The End Site is the tip (a joint ``tip`` with the slide, when the
last row is prismatic). The ROOT is the linkage's base: its translations are the position
channels (0 for a fixed base) and its rotations the first rotation channels, in base= order.

Angles are written in degrees, positions in the scene's units, with 17 significant digits, so
that joint positions from the file match stw's forward kinematics to rounding.

Written by hand rather than with a BVH library: the writer is this one function of text, and the
libraries (bvhio, pybvh) would be a dependency for it; the tests read the file back with their
own independent parser and forward kinematics.
"""

from __future__ import annotations

import math

import numpy as np

from stw_tui.sos.scene import Scene
from stw_tui.sym.errors import StwError
from stw_tui.sym.linkage.spec import child_indices, parent_indices
from stw_tui.sym.symbols import named_symbol

ROTATION_ORDER = ("Xrotation", "Zrotation", "Yrotation")
POSITIONS = ("Xposition", "Yposition", "Zposition")


def pick_linkage(scene: Scene, what=()):
    """The linkage to export: the only one, or the one named in ``what=``.

    Raises:
        StwError: no linkage, several and none chosen, or a name that is not one.
    """
    if not scene.linkages:
        raise StwError("bvh exports a linkage's skeleton, and the scene has none: add a `linkage` block")
    if what:
        if len(what) > 1 or what[0] not in scene.linkages:
            raise StwError(f"bvh: what= names one linkage ({', '.join(scene.linkages)}), not {','.join(what)}")
        return scene.linkages[what[0]]
    if len(scene.linkages) > 1:
        raise StwError(f"a BVH file holds one skeleton: choose a linkage with what=NAME "
                       f"({', '.join(scene.linkages)})")
    return next(iter(scene.linkages.values()))


def _root_channels(spec) -> tuple[list[str], list[tuple[str, float | None]]]:
    """(channel names, [(base DOF or None for 0, scale)]) of the ROOT: positions, then rotations."""
    translations = {a.axis[1]: a.dof for a in spec.base if a.kind == "prismatic"}
    rotations = [a for a in spec.base if a.kind == "revolute"]
    seen_rotation = False
    for axis in spec.base:
        seen_rotation |= axis.kind == "revolute"
        if seen_rotation and axis.kind == "prismatic":
            raise StwError(f"bvh: linkage {spec.name} translates its base ({axis.axis}) after rotating it; "
                           "a BVH root translates first (write the base's translations first)")
    if len({a.axis for a in rotations}) < len(rotations):
        raise StwError(f"bvh: linkage {spec.name} rotates its base twice about one axis; a BVH root cannot")
    order = [f"{a.axis[1].upper()}rotation" for a in rotations]
    order += [r for r in ("Zrotation", "Xrotation", "Yrotation") if r not in order]
    by_channel = {f"{a.axis[1].upper()}rotation": a.dof for a in rotations}
    sources = [(translations.get(axis), 1.0) for axis in "xyz"]
    sources += [(by_channel.get(name), math.degrees(1.0)) for name in order]
    return [*POSITIONS, *order], sources


def hierarchy(spec) -> tuple[str, list[tuple]]:
    """The HIERARCHY text, and per channel in file order a source: (DOF name or None, scale,
    constant offset) meaning ``scale * DOF + offset``.

    A branched linkage (rows with ``parent=``) is written as the tree it is: each joint is a
    child of the joint whose link it hangs from (of the ROOT for the base's children), and every
    link without children ends in an End Site."""
    lines = ["HIERARCHY", f"ROOT {spec.name}", "{", "  OFFSET 0 0 0"]
    root_names, root_sources = _root_channels(spec)
    lines.append(f"  CHANNELS {len(root_names)} {' '.join(root_names)}")
    sources = [(dof, scale, 0.0) for dof, scale in root_sources]
    parents = parent_indices(spec)
    children = child_indices(spec)
    deg = math.degrees(1.0)

    def write(index: int, depth: int) -> None:
        joint = spec.joints[index]
        previous = spec.joints[parents[index]] if parents[index] >= 0 else None
        pad = "  " * depth
        offset = (previous.a, 0.0, previous.d) if previous else (0.0, 0.0, 0.0)
        lines.extend([f"{pad}JOINT {joint.name}", f"{pad}{{", f"{pad}  OFFSET {_numbers(offset)}"])
        names = []
        if previous is not None and previous.kind == "prismatic":
            names += POSITIONS
            sources.extend([(None, 0.0, 0.0), (None, 0.0, 0.0), (previous.name, 1.0, 0.0)])
        names += ROTATION_ORDER
        sources.extend([(None, 0.0, math.degrees(previous.alpha) if previous else 0.0),
                        (joint.name if joint.kind == "revolute" else None, deg, math.degrees(joint.theta)),
                        (None, 0.0, 0.0)])
        lines.append(f"{pad}  CHANNELS {len(names)} {' '.join(names)}")
        for child in children[index]:
            write(child, depth + 1)
        if not children[index]:
            _end_site(joint, depth + 1)
        lines.append(f"{pad}}}")

    def _end_site(last, depth: int) -> None:
        pad = "  " * depth
        if last.kind == "prismatic":    # the tip slides with the last joint: a joint, not an End Site
            lines.extend([f"{pad}JOINT {_tip_name(last)}", f"{pad}{{",
                          f"{pad}  OFFSET {_numbers((last.a, 0.0, last.d))}",
                          f"{pad}  CHANNELS 3 {' '.join(POSITIONS)}",
                          f"{pad}  End Site", f"{pad}  {{", f"{pad}    OFFSET 0 0 0", f"{pad}  }}", f"{pad}}}"])
            sources.extend([(None, 0.0, 0.0), (None, 0.0, 0.0), (last.name, 1.0, 0.0)])
        else:
            lines.extend([f"{pad}End Site", f"{pad}{{", f"{pad}  OFFSET {_numbers((last.a, 0.0, last.d))}",
                          f"{pad}}}"])

    def _tip_name(last) -> str:
        # a chain's one sliding end keeps the name it always had; a tree's ends are told apart
        leaves = sum(1 for i in range(len(spec.joints)) if not children[i])
        return "tip" if leaves == 1 else f"{last.name}_tip"

    for root_child in children[-1]:
        write(root_child, 1)
    lines.append("}")
    return "\n".join(lines), sources


def _numbers(values) -> str:
    return " ".join(repr(float(v)) if v else "0" for v in values)


def bvh_text(scene: Scene, times: np.ndarray, fps: int, what=()) -> str:
    """The whole BVH file of one linkage sampled at ``times``."""
    spec = pick_linkage(scene, what)
    text, sources = hierarchy(spec)
    values = {}
    for dof in {d for d, _, _ in sources if d is not None}:
        values[dof] = np.broadcast_to(scene.evaluate(named_symbol(dof), times), times.shape)
    columns = [scale * values[dof] + offset if dof is not None else np.full(times.shape, offset)
               for dof, scale, offset in sources]
    rows = np.column_stack(columns) if columns else np.zeros((times.size, 0))
    if not np.all(np.isfinite(rows)):
        raise StwError("bvh: the motion is not finite at some frame")
    motion = ["MOTION", f"Frames: {times.size}", f"Frame Time: {1.0 / fps!r}"]
    motion += [" ".join(repr(float(v)) for v in row) for row in rows]
    return text + "\n" + "\n".join(motion) + "\n"
