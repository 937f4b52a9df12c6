"""Parsing of ``linkage`` blocks: values, defaults, and errors with line and column."""

from __future__ import annotations

import math

import pytest

from stw_tui.sym.errors import SourceError
from stw_tui.sym.linkage import BaseAxis, dof_names, parse_linkage


def parse(header, *rows, start=2):
    return parse_linkage(header, [(start + i, r) for i, r in enumerate(rows)], header_line=start - 1)


def error(header, *rows) -> SourceError:
    with pytest.raises(SourceError) as info:
        parse(header, *rows)
    return info.value


def test_arm_block():
    spec = parse("linkage arm base=fixed",
                 "  SHOULDER revolute a=0.35 mass=2.0",
                 "  ELBOW    revolute a=0.30 mass=1.5   # the forearm",
                 "",
                 "  WRIST    revolute a=0.15 mass=0.5")
    assert spec.name == "arm" and spec.base == ()
    assert (spec.gravity_axis, spec.gravity_sign) == (1, -1)
    assert [j.name for j in spec.joints] == ["SHOULDER", "ELBOW", "WRIST"]
    assert [j.a for j in spec.joints] == [0.35, 0.30, 0.15]
    assert [j.mass for j in spec.joints] == [2.0, 1.5, 0.5]
    assert [j.line for j in spec.joints] == [2, 3, 5]
    assert spec.joints[0].kind == "revolute" and spec.joints[0].com is None
    assert dof_names(spec) == ["SHOULDER", "ELBOW", "WRIST"]


def test_base_gravity_keys_and_angles():
    spec = parse("linkage player base=tx:BX,tz:BZ,ry:BROT gravity=+z",
                 "TURN prismatic d=0.5 theta=pi/2 alpha=-90deg com=0:0.1:-0.2 inertia=1:2:3",
                 "ARM Revolute 0.3 3pi/4 0.1 -0.2 2.5")
    assert spec.base == (BaseAxis("tx", "BX"), BaseAxis("tz", "BZ"), BaseAxis("ry", "BROT"))
    assert [b.kind for b in spec.base] == ["prismatic", "prismatic", "revolute"]
    assert (spec.gravity_axis, spec.gravity_sign) == (2, 1)
    turn, arm = spec.joints
    assert turn.kind == "prismatic" and turn.d == 0.5
    assert turn.theta == pytest.approx(math.pi / 2) and turn.alpha == pytest.approx(-math.pi / 2)
    assert turn.com == (0.0, 0.1, -0.2) and turn.inertia == (1.0, 2.0, 3.0)
    # bare numbers fill a, alpha, d, theta, mass
    assert (arm.a, arm.alpha, arm.d, arm.theta, arm.mass) == pytest.approx(
        (0.3, 3 * math.pi / 4, 0.1, -0.2, 2.5))
    assert dof_names(spec) == ["BX", "BZ", "BROT", "TURN", "ARM"]
    assert parse("linkage s gravity=none", "A revolute").gravity_axis is None
    assert parse("linkage s", "A revolute a = 0.5").joints[0].a == 0.5


def test_base_body_options():
    spec = parse("linkage cart base=tx:X,ty:Y,rz:R base_inertia=0.25 base_mass=3", "A revolute a=1")
    assert (spec.base_mass, spec.base_inertia, spec.total_mass) == (3.0, 0.25, 4.0)
    bare = parse("linkage cart base=tx:X", "A revolute a=1")
    assert (bare.base_mass, bare.base_inertia, bare.base_body) == (0.0, 0.0, False)


def test_spec_is_hashable():
    a = parse("linkage s", "A revolute a=1")
    assert hash(a) == hash(parse("linkage s", "A revolute a=1"))


@pytest.mark.parametrize("row, column, message, expected", [
    ("ELBOW revolute a=0.3 lenght=2", 22, "unknown key 'lenght'", "a, alpha"),
    ("ELBOW revolute a=0.3x", 18, "bad number '0.3x'", "a number"),
    ("ELBOW revolute alpha=pie", 22, "bad number 'pie'", "pi/2"),
    ("ELBOW revolut a=0.3", 7, "unknown joint type 'revolut'", "revolute or prismatic"),
    ("ELBOW", 6, "needs a type", "revolute or prismatic"),
    ("ELBOW revolute a=", 18, "a= needs a value", "a number"),
    ("ELBOW revolute a=1 a=2", 20, "given twice", None),
    ("ELBOW revolute com=1:2", 20, "three numbers", "x:y:z"),
    ("ELBOW revolute com=1:2:zz", 24, "bad number 'zz'", "a number"),
    ("ELBOW revolute mass=-1", 21, "negative", "mass >= 0"),
    ("ELBOW revolute inertia=1:-2:3", 24, "negative", None),
    ("ELBOW revolute a=1 0.5", 20, "bare number", "key=value"),
    ("ELBOW revolute 1 2 3 4 5 6", 26, "unexpected '6'", "key=value"),
    ("2ELBOW revolute", 1, "bad joint name", "letters"),
    ("tip revolute", 1, "reserved", None),
    ("a=1 revolute", 1, "starts with the joint name", None),
])
def test_row_errors(row, column, message, expected):
    err = error("linkage arm", "SHOULDER revolute a=0.35", row)
    assert err.line == 3
    assert err.column == column
    assert message in err.message
    if expected is not None:
        assert expected in err.expected
    assert err.source == row
    assert err.caret().splitlines()[1] == " " * (column - 1) + "^"


def test_duplicate_joint_name():
    err = error("linkage arm", "SHOULDER revolute", "  SHOULDER prismatic")
    assert (err.line, err.column) == (3, 3)
    assert "used twice" in err.message
    err = error("linkage hop base=tx:X,ty:Y", "X revolute")
    assert (err.line, err.column) == (2, 1)


def test_no_joints():
    err = error("linkage arm base=fixed", "   ", "# only a comment")
    assert (err.line, err.column) == (1, 9)
    assert "no joints" in err.message
    err = error("linkage arm", "A revolute mass=0")
    assert "no mass" in err.message


@pytest.mark.parametrize("header, column, message", [
    ("linkage arm base=tx:X,tq:Y", 23, "unknown base axis 'tq'"),
    ("linkage arm base=tx:X,ty", 23, "bad base axis 'ty'"),
    ("linkage arm base=tx:X,ty:X", 26, "given twice"),
    ("linkage arm base=tx:1X", 21, "bad DOF name"),
    ("linkage arm base=", 18, "needs a value"),
    ("linkage arm gravity=down", 21, "bad gravity axis"),
    ("linkage arm colour=red", 13, "unknown linkage option 'colour'"),
    ("linkage arm base=fixed base=fixed", 24, "given twice"),
    ("linkage arm fixed", 13, "unexpected 'fixed'"),
    ("linkage", 8, "needs a name"),
    ("linkage 9arm", 9, "bad linkage name"),
    ("chain arm", 1, "starts with 'linkage NAME'"),
])
def test_header_errors(header, column, message):
    err = error(header, "A revolute")
    assert err.line == 1
    assert err.column == column
    assert message in err.message
    assert "line 1, column" in str(err)
