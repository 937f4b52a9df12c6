"""The ``linkage`` block of the session language, parsed into a frozen :class:`LinkageSpec`.

::

    linkage arm base=fixed gravity=-y
      SHOULDER revolute a=0.35 mass=2.0
      ELBOW    revolute a=0.30 mass=1.5
      WRIST    revolute a=0.15 mass=0.5
    end

Header options
    ``base=fixed`` (the default) or a comma list ``axis:DOF`` with ``axis`` one of ``tx ty tz rx ry rz``,
    applied in the order given, each in the frame left by the previous one (``base=tx:BX,tz:BZ,ry:BROT``).
    ``gravity=-y`` (the default): the axis gravity pulls along, ``[+|-]x|y|z``, or ``none``. Its
    magnitude is the constant ``g``.
    ``com=CX,CY`` (only with a base of translations, one name per base axis): centroidal coordinates.
    The DOF ``CX, CY`` are where the linkage's centre of mass is, and the base DOF (``X, Y``) become
    subexpressions that follow from it and the joints. Free flight is then linear in the DOF
    (``CX'' = 0``, ``CY'' + g = 0``), so it can hold exactly between the samples.
    ``base_mass=M`` (default 0, only with a base that translates): the base's own mass, a point at
    the base frame origin (after all base axes); it counts in ``NAME.com`` and in the base forces.
    ``base_inertia=I`` (default 0, only with exactly one rotation ``rx|ry|rz`` in the base): the
    base's moment of inertia about that axis, so ``tau_R`` gains ``I R''``.

Rows: ``JOINT revolute|prismatic key=value ...``
    ``a alpha d theta`` standard Denavit–Hartenberg offsets (default 0). The joint variable (a DOF named
    after the joint) adds to ``theta`` (revolute) or to ``d`` (prismatic). ``mass`` (default 1),
    ``com=x:y:z`` centre of mass in the link frame (default: the middle of the link, the rod from the
    joint to the next joint frame origin), ``inertia=Ixx:Iyy:Izz`` about the centre of mass, link frame
    axes (default: a uniform thin rod along the link). Numbers are plain decimals; angles may also be
    written ``pi``, ``-pi/2``, ``3pi/4``, ``90deg``. Bare numbers after the joint type fill
    ``a alpha d theta mass`` in that order. ``#`` starts a comment.

Only regular expressions and ``float()`` touch the user's text: nothing is evaluated.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass

from stw_tui.sym.errors import SourceError

JOINT_TYPES = ("revolute", "prismatic")
BASE_AXES = ("tx", "ty", "tz", "rx", "ry", "rz")
ROW_KEYS = ("a", "alpha", "d", "theta", "mass", "com", "inertia", "parent")
POSITIONAL_KEYS = ("a", "alpha", "d", "theta", "mass")
ANGLE_KEYS = ("alpha", "theta")
HEADER_KEYS = ("base", "gravity", "com", "base_mass", "base_inertia")
RESERVED_NAMES = ("tip", "com", "base", "end", "g", "t")

_IDENT = re.compile(r"[A-Za-z_][A-Za-z0-9_]*\Z")
_NUMBER = re.compile(r"[+-]?(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?\Z")
_PI = re.compile(r"(?P<sign>[+-]?)(?P<num>(?:\d+\.?\d*|\.\d+)\*?)?pi(?:/(?P<den>\d+\.?\d*|\.\d+))?\Z")
_DEG = re.compile(r"(?P<num>[+-]?(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?)deg\Z")
_TOKEN = re.compile(r"(?P<key>[A-Za-z_][A-Za-z0-9_]*)\s*=\s*(?P<val>[^\s#]*)|(?P<word>[^\s#]+)")


@dataclass(frozen=True)
class JointSpec:
    """One Denavit–Hartenberg row: the joint and the link it moves.

    ``com`` and ``inertia`` are ``None`` for the defaults (see :func:`link_com`, :func:`link_inertia`).
    ``inertia`` as given by the user is the diagonal ``(Ixx, Iyy, Izz)``.
    """

    name: str
    kind: str  # "revolute" | "prismatic"
    a: float = 0.0
    alpha: float = 0.0
    d: float = 0.0
    theta: float = 0.0
    mass: float = 1.0
    com: tuple[float, float, float] | None = None
    inertia: tuple[float, float, float] | None = None
    line: int | None = None
    parent: str | None = None  # the joint whose link this one hangs from; None: the row above


@dataclass(frozen=True)
class BaseAxis:
    """One base DOF: ``axis`` in tx ty tz rx ry rz, moved by DOF ``dof``."""

    axis: str
    dof: str

    @property
    def kind(self) -> str:
        """``prismatic`` for a translation (``t…``), ``revolute`` for a rotation (``r…``)."""
        return "prismatic" if self.axis[0] == "t" else "revolute"

    @property
    def index(self) -> int:
        """The axis moved along or about: 0, 1, 2 for x, y, z."""
        return "xyz".index(self.axis[1])


@dataclass(frozen=True)
class LinkageSpec:
    """A parsed `linkage` block: its joints, base axes, gravity, centroidal DOF and base body."""

    name: str
    joints: tuple[JointSpec, ...]
    base: tuple[BaseAxis, ...] = ()
    gravity_axis: int | None = 1  # 0, 1, 2 for x, y, z; None: no gravity
    gravity_sign: int = -1
    line: int | None = None
    com: tuple[str, ...] = ()  # centroidal DOF, one per base axis (``com=CX,CY``), or none
    base_mass: float = 0.0  # a point mass at the base frame origin
    base_inertia: float = 0.0  # about the base's one rotation axis

    @property
    def total_mass(self) -> float:
        """The links' masses and the base's."""
        return sum(j.mass for j in self.joints) + self.base_mass

    @property
    def base_body(self) -> bool:
        """Whether the base has a mass or an inertia of its own (without, it is a bare frame)."""
        return self.base_mass > 0.0 or self.base_inertia > 0.0


def base_rotation_axis(spec: LinkageSpec) -> int:
    """The axis (0, 1, 2) of the base's one rotation, about which ``base_inertia`` turns it.

    With a single rotation the frame after all base axes keeps that axis (translations do not
    turn it), so the inertia sits on the same local axis of the base frame.
    """
    (axis,) = [b.index for b in spec.base if b.kind == "revolute"]
    return axis


def parent_indices(spec: LinkageSpec) -> tuple[int, ...]:
    """For each joint, the index of the joint whose link it hangs from (-1: the base frame).

    A row without ``parent=`` hangs from the row above (the first row from the base), so a linkage
    without any ``parent=`` is the serial chain it always was.
    """
    index = {j.name: i for i, j in enumerate(spec.joints)}
    return tuple(i - 1 if j.parent is None else -1 if j.parent == "base" else index[j.parent]
                 for i, j in enumerate(spec.joints))


def child_indices(spec: LinkageSpec) -> dict[int, list[int]]:
    """For the base (-1) and each joint, the joints that hang from it, in row order."""
    children: dict[int, list[int]] = {i: [] for i in range(-1, len(spec.joints))}
    for index, up in enumerate(parent_indices(spec)):
        children[up].append(index)
    return children


def base_children(spec: LinkageSpec) -> list[str]:
    """The joints that hang from the base frame itself: the first row, and any with ``parent=base``.
    The moment the world exerts on a base that cannot turn is the sum of their torques."""
    return [spec.joints[i].name for i in child_indices(spec)[-1]]


def dof_names(spec: LinkageSpec) -> list[str]:
    """The variables of the linkage's kinematics: base variables in order, then the joints."""
    return [b.dof for b in spec.base] + [j.name for j in spec.joints]


def curve_dofs(spec: LinkageSpec) -> list[str]:
    """The DOF the linkage adds to a scene: the centroidal DOF in place of the base variables when
    ``com=`` is given (the base variables are then subexpressions), then the joints."""
    return list(spec.com) + [j.name for j in spec.joints] if spec.com else dof_names(spec)


def link_com(joint: JointSpec) -> tuple[float, float, float]:
    """Centre of mass in the link frame: given, or the midpoint of the link rod.

    Under standard DH the link runs from the origin of frame i-1 to the origin of frame i; seen from
    frame i, frame i-1's origin is Rx(-alpha) Tx(-a) Tz(-d) 0 = (-a, -d sin(alpha), -d cos(alpha)).
    For a prismatic joint ``d`` here is the constant offset (the link is rigid; the joint variable
    slides it), so the default centre of mass of a prismatic link with d=0, a=0 is its frame origin.
    """
    if joint.com is not None:
        return joint.com
    x, y, z = _link_vector(joint)
    return (x / 2, y / 2, z / 2)


def link_inertia(joint: JointSpec) -> tuple[tuple[float, float, float], ...]:
    """3x3 inertia tensor about the centre of mass in link frame axes.

    Given: ``diag(Ixx, Iyy, Izz)``. Default: a uniform thin rod of length L along the link,
    ``m L^2 / 12 (I - u u^T)`` with u the unit rod direction (0 about the rod, m L^2/12 about the two
    axes perpendicular to it).
    """
    if joint.inertia is not None:
        ixx, iyy, izz = joint.inertia
        return ((ixx, 0.0, 0.0), (0.0, iyy, 0.0), (0.0, 0.0, izz))
    v = _link_vector(joint)
    length2 = sum(c * c for c in v)
    if length2 == 0.0:
        return ((0.0, 0.0, 0.0),) * 3
    k = joint.mass * length2 / 12.0
    return tuple(tuple(k * ((1.0 if r == c else 0.0) - v[r] * v[c] / length2) for c in range(3))
                 for r in range(3))


def _link_vector(joint: JointSpec) -> tuple[float, float, float]:
    ca, sa = snapped_cos_sin(joint.alpha)
    return (-joint.a, -joint.d * sa, -joint.d * ca)


def snapped_cos_sin(angle: float) -> tuple[float, float]:
    """cos, sin of a constant angle, exact (0, ±1) at multiples of pi/2 (alpha=1.5708 means pi/2)."""
    quarter = angle / (math.pi / 2)
    k = round(quarter)
    if abs(quarter - k) < 1e-9:
        return ((1.0, 0.0), (0.0, 1.0), (-1.0, 0.0), (0.0, -1.0))[k % 4]
    return math.cos(angle), math.sin(angle)


# ---------------------------------------------------------------------------------------- parsing


@dataclass
class _Tok:
    key: str | None
    value: str
    col: int  # 1-based column of the token start
    vcol: int  # 1-based column of the value


def _tokens(text: str) -> list[_Tok]:
    code = text.split("#", 1)[0]
    toks = []
    for m in _TOKEN.finditer(code):
        if m.group("key") is not None:
            toks.append(_Tok(m.group("key"), m.group("val"), m.start() + 1, m.start("val") + 1))
        else:
            toks.append(_Tok(None, m.group("word"), m.start() + 1, m.start() + 1))
    return toks


def _err(message, line, col, source, expected=None):
    return SourceError(message, line=line, column=col, source=source, expected=expected)


def _number(text: str, *, angle: bool, line, col, source) -> float:
    if _NUMBER.match(text):
        value = float(text)
    elif angle and (m := _PI.match(text)):
        num = float(m.group("num").rstrip("*")) if m.group("num") else 1.0
        den = float(m.group("den")) if m.group("den") else 1.0
        if den == 0.0:
            raise _err("division by zero", line, col, source, "a number")
        value = (-1.0 if m.group("sign") == "-" else 1.0) * num * math.pi / den
    elif angle and (m := _DEG.match(text)):
        value = math.radians(float(m.group("num")))
    else:
        expected = "a number, pi/2 or 90deg" if angle else "a number"
        raise _err(f"bad number {text!r}", line, col, source, expected)
    if not math.isfinite(value):
        raise _err(f"number {text!r} is not finite", line, col, source, "a finite number")
    return value


def _triple(text: str, *, line, col, source, what: str) -> tuple[float, float, float]:
    parts = text.split(":")
    if len(parts) != 3:
        raise _err(f"{what} needs three numbers separated by ':'", line, col, source, "x:y:z")
    values, offset = [], 0
    for part in parts:
        values.append(_number(part, angle=False, line=line, col=col + offset, source=source))
        offset += len(part) + 1
    return tuple(values)


def _check_name(name: str, *, line, col, source, what: str):
    if not _IDENT.match(name):
        raise _err(f"bad {what} name {name!r}", line, col, source,
                   "a name of letters, digits and '_', not starting with a digit")
    if "__" in name:   # the session language's rule: no name holds '__'
        raise _err(f"names with '__' are not allowed ({name!r})", line, col, source, "another name")
    if name in RESERVED_NAMES or name in _language_words():
        raise _err(f"{name!r} is reserved and cannot name a {what}", line, col, source,
                   "another name")


def _language_words() -> set[str]:
    """Commands, functions and keywords of the session language (a joint named `sin` would
    make `sin(...)` and the joint's DOF the same word)."""
    from stw_tui.sym.language.commands import RESERVED

    return RESERVED


def parse_linkage(header: str, rows: list[tuple[int, str]], *, header_line: int | None = None
                  ) -> LinkageSpec:
    """Parse a ``linkage NAME [base=...] [gravity=...] [com=...] [base_mass=...] [base_inertia=...]``
    header and its rows (``end`` excluded).

    ``rows`` are (line number, text) pairs. Raises :class:`SourceError` with the line and the
    1-based column of the offending token.
    """
    hl, hs = header_line, header
    toks = _tokens(header)
    if not toks or toks[0].key is not None or toks[0].value != "linkage":
        raise _err("a linkage block starts with 'linkage NAME'", hl, toks[0].col if toks else 1, hs,
                   "linkage")
    if len(toks) < 2 or toks[1].key is not None:
        col = toks[1].col if len(toks) > 1 else len(header.rstrip()) + 1
        raise _err("the linkage needs a name", hl, col, hs, "linkage NAME")
    name = toks[1].value
    _check_name(name, line=hl, col=toks[1].col, source=hs, what="linkage")

    base: tuple[BaseAxis, ...] = ()
    com_tok: _Tok | None = None
    body_toks: dict[str, _Tok] = {}
    gravity_axis, gravity_sign = 1, -1
    seen_keys: set[str] = set()
    for tok in toks[2:]:
        if tok.key is None:
            raise _err(f"unexpected {tok.value!r}", hl, tok.col, hs,
                       "base=..., gravity=..., com=..., base_mass=... or base_inertia=...")
        if tok.key not in HEADER_KEYS:
            raise _err(f"unknown linkage option {tok.key!r}", hl, tok.col, hs, ", ".join(HEADER_KEYS))
        if tok.key in seen_keys:
            raise _err(f"option {tok.key!r} given twice", hl, tok.col, hs)
        seen_keys.add(tok.key)
        if tok.key == "base":
            base = _parse_base(tok, hl, hs)
        elif tok.key == "com":
            com_tok = tok
        elif tok.key in ("base_mass", "base_inertia"):
            body_toks[tok.key] = tok
        else:
            gravity_axis, gravity_sign = _parse_gravity(tok, hl, hs)

    com = _parse_com(com_tok, base, hl, hs) if com_tok is not None else ()
    base_mass, base_inertia = _parse_base_body(body_toks, base, hl, hs)
    used = {n: None for n in [b.dof for b in base] + list(com)}
    joints: list[JointSpec] = []
    for line, text in rows:
        row_toks = _tokens(text)
        if not row_toks:
            continue
        joint, parent_col = _parse_row(row_toks, line, text)
        if joint.name in used:
            raise _err(f"name {joint.name!r} used twice in linkage {name!r}", line, row_toks[0].col,
                       text, "a new joint name")
        if joint.parent is not None and joint.parent != "base" and joint.parent not in {j.name for j in joints}:
            above = [j.name for j in joints] + ["base"]
            raise _err(f"parent {joint.parent!r} is not a joint above this row in linkage {name!r}"
                       f"{_did_you_mean(joint.parent, above)}", line, parent_col, text, ", ".join(above))
        used[joint.name] = None
        joints.append(joint)
    if not joints:
        raise _err(f"linkage {name!r} has no joints", hl, toks[1].col, hs,
                   "rows 'JOINT revolute|prismatic a=... mass=...' before 'end'")
    if sum(j.mass for j in joints) + base_mass <= 0.0:
        raise _err(f"linkage {name!r} has no mass", hl, toks[1].col, hs,
                   "at least one link with mass > 0, or base_mass > 0")
    return LinkageSpec(name=name, joints=tuple(joints), base=base, gravity_axis=gravity_axis,
                       gravity_sign=gravity_sign, line=hl, com=com, base_mass=base_mass,
                       base_inertia=base_inertia)


def _did_you_mean(word: str, names: list[str]) -> str:
    """`` (did you mean 'X'?)`` for the closest of ``names``, case aside (difflib), or nothing."""
    import difflib

    lowered = {n.lower(): n for n in names}
    close = difflib.get_close_matches(word.lower(), list(lowered), n=1)
    return f" (did you mean {lowered[close[0]]!r}?)" if close else ""


def _parse_base_body(toks: dict[str, _Tok], base: tuple[BaseAxis, ...], line, source
                     ) -> tuple[float, float]:
    """``base_mass=M``, ``base_inertia=I``: (M, I), each 0 when not given.

    A mass on a base that only turns about its own origin would never move, and an inertia needs
    one rotation to turn about (with two or more its axis would be a guess): both are refused
    (a zero, which does nothing, is not).
    """
    values = []
    for key, needs in (("base_mass", "base_mass >= 0"), ("base_inertia", "base_inertia >= 0")):
        tok = toks.get(key)
        if tok is None:
            values.append(0.0)
            continue
        if not tok.value:
            raise _err(f"{key}= needs a value", line, tok.vcol, source, "a number")
        value = _number(tok.value, angle=False, line=line, col=tok.vcol, source=source)
        if value < 0:
            raise _err(f"{key} cannot be negative", line, tok.vcol, source, needs)
        values.append(value)
    if values[0] > 0 and not any(b.kind == "prismatic" for b in base):
        raise _err("base_mass needs a base that translates", line, toks["base_mass"].col, source,
                   "base=tx:X,... base_mass=M")
    rotations = [b.axis for b in base if b.kind == "revolute"]
    if values[1] > 0 and len(rotations) != 1:
        why = "a base that turns" if not rotations else f"one base rotation, not {len(rotations)}"
        raise _err(f"base_inertia needs {why}", line, toks["base_inertia"].col, source,
                   "base=...,rz:R base_inertia=I (exactly one of rx, ry, rz)")
    return values[0], values[1]


def _parse_com(tok: _Tok, base: tuple[BaseAxis, ...], line, source) -> tuple[str, ...]:
    """``com=CX,CY``: one new DOF name per base axis, which must all be translations."""
    if not base or any(b.kind != "prismatic" for b in base):
        raise _err("com= needs a base of translations only", line, tok.col, source,
                   "base=tx:X,ty:Y com=CX,CY")
    names, offset = [], 0
    for item in tok.value.split(","):
        _check_name(item, line=line, col=tok.vcol + offset, source=source, what="DOF")
        if item in names or item in [b.dof for b in base]:
            raise _err(f"DOF {item!r} given twice", line, tok.vcol + offset, source, "a new DOF name")
        names.append(item)
        offset += len(item) + 1
    if len(names) != len(base):
        raise _err(f"com= names {len(names)} DOF for {len(base)} base axes", line, tok.vcol, source,
                   "one centroidal DOF per base axis")
    return tuple(names)


def _parse_base(tok: _Tok, line, source) -> tuple[BaseAxis, ...]:
    if tok.value == "fixed":
        return ()
    if not tok.value:
        raise _err("base= needs a value", line, tok.vcol, source, "fixed or axis:DOF,...")
    axes, seen, offset = [], set(), 0
    for item in tok.value.split(","):
        col = tok.vcol + offset
        offset += len(item) + 1
        axis, colon, dof = item.partition(":")
        if not colon:
            raise _err(f"bad base axis {item!r}", line, col, source, "axis:DOF, e.g. tx:X")
        if axis not in BASE_AXES:
            raise _err(f"unknown base axis {axis!r}", line, col, source, " ".join(BASE_AXES))
        dcol = col + len(axis) + 1
        _check_name(dof, line=line, col=dcol, source=source, what="DOF")
        if dof in seen:
            raise _err(f"base DOF {dof!r} given twice", line, dcol, source, "a new DOF name")
        seen.add(dof)
        axes.append(BaseAxis(axis, dof))
    return tuple(axes)


def _parse_gravity(tok: _Tok, line, source) -> tuple[int | None, int]:
    value = tok.value
    if value in ("none", "0"):
        return None, 1
    m = re.fullmatch(r"([+-]?)([xyz])", value)
    if not m:
        raise _err(f"bad gravity axis {value!r}", line, tok.vcol, source, "-y, +z, x, ... or none")
    return "xyz".index(m.group(2)), (-1 if m.group(1) == "-" else 1)


def _parse_row(toks: list[_Tok], line, text) -> JointSpec:
    first = toks[0]
    if first.key is not None:
        raise _err(f"a joint row starts with the joint name, not {first.key}=", line, first.col, text,
                   "JOINT revolute|prismatic ...")
    _check_name(first.value, line=line, col=first.col, source=text, what="joint")
    if len(toks) < 2:
        raise _err(f"joint {first.value!r} needs a type", line, len(text.split("#")[0].rstrip()) + 1,
                   text, "revolute or prismatic")
    kind_tok = toks[1]
    kind = kind_tok.value.lower() if kind_tok.key is None else ""
    if kind not in JOINT_TYPES:
        raise _err(f"unknown joint type {kind_tok.value if kind_tok.key is None else kind_tok.key!r}",
                   line, kind_tok.col, text, "revolute or prismatic")
    fields: dict = {}
    positional = 0
    parent_col = [None]
    for tok in toks[2:]:
        if tok.key is None:
            if fields.keys() - set(POSITIONAL_KEYS[:positional]):
                raise _err(f"bare number {tok.value!r} after key=value", line, tok.col, text,
                           "key=value")
            if positional >= len(POSITIONAL_KEYS):
                raise _err(f"unexpected {tok.value!r}", line, tok.col, text, "key=value")
            key = POSITIONAL_KEYS[positional]
            positional += 1
            value, vcol = tok.value, tok.col
        else:
            key, value, vcol = tok.key, tok.value, tok.vcol
            if key not in ROW_KEYS:
                raise _err(f"unknown key {key!r}", line, tok.col, text, ", ".join(ROW_KEYS))
            if key in fields:
                raise _err(f"key {key!r} given twice", line, tok.col, text)
        if not value:
            raise _err(f"{key}= needs a value", line, vcol, text, "a joint name" if key == "parent" else "a number")
        if key == "parent":
            fields[key] = value
            parent_col[0] = vcol
        elif key == "com":
            fields[key] = _triple(value, line=line, col=vcol, source=text, what="com")
        elif key == "inertia":
            inertia = _triple(value, line=line, col=vcol, source=text, what="inertia")
            if min(inertia) < 0:
                raise _err("moments of inertia cannot be negative", line, vcol, text,
                           "Ixx:Iyy:Izz >= 0")
            fields[key] = inertia
        else:
            fields[key] = _number(value, angle=key in ANGLE_KEYS, line=line, col=vcol, source=text)
            if key == "mass" and fields[key] < 0:
                raise _err("mass cannot be negative", line, vcol, text, "mass >= 0")
    return JointSpec(name=first.value, kind=kind, line=line, **fields), parent_col[0]
