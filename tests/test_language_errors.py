"""Hostile and malformed input to the session language: every failure is a positioned SourceError,
never a hang, a RecursionError or a stray sympy/Python exception."""

from __future__ import annotations

import time

import pytest
import sympy as sp

from stw_tui.sym.errors import SourceError
from stw_tui.sym.language import DictScope, NameKind, parse_command, parse_condition, parse_expression
from stw_tui.sym.language.commands import ConstCmd, IterateCmd, KeyCmd, ShakeCmd
from stw_tui.sym.language.expressions import MAX_DEPTH
from stw_tui.sym.symbols import TIME, dof_symbol, named_symbol

SCOPE = DictScope({"x": NameKind.DOF, "y": NameKind.DOF, "m": NameKind.CONST, "g": NameKind.CONST,
                   "f": NameKind.LET})
X = dof_symbol("x")


def expr_error(text: str) -> SourceError:
    with pytest.raises(SourceError) as info:
        parse_expression(text, SCOPE, line=1)
    return info.value


def cmd_error(text: str, scope=SCOPE) -> SourceError:
    with pytest.raises(SourceError) as info:
        parse_command(text, scope, line=5)
    return info.value


# --- numbers that would hang or crash ---------------------------------------------------------------

@pytest.mark.parametrize("text, column, message", [
    ("9^9^9", 2, "number too large"),                 # 9^387420489 would never finish
    ("2**10000000", 2, "number too large"),
    ("(1/2)^-100000", 6, "number too large"),
    ("sqrt(2)^100000000", 8, "number too large"),
    ("1" * 400, 1, "number too long"),                # Python refuses to convert > 4300 digits
    ("1e999", 1, "number out of range"),              # float('1e999') is inf
])
def test_huge_numbers_are_refused_quickly(text, column, message):
    start = time.perf_counter()
    err = expr_error(text)
    assert time.perf_counter() - start < 1.0
    assert (err.line, err.column) == (1, column)
    assert err.message == message
    assert err.expected


def test_moderate_powers_still_fold():
    assert parse_expression("10^300", SCOPE) == sp.Integer(10) ** 300
    assert parse_expression("2^-10", SCOPE) == sp.Rational(1, 1024)
    assert parse_expression("1.5^1000", SCOPE).is_Float         # floats are cheap to raise
    assert expr_error("1.5^1000000").message == "number out of range"   # but no double holds 1e176091
    assert parse_expression("pi^2", SCOPE) == sp.pi ** 2


@pytest.mark.parametrize("text", ["(" * 500 + "x" + ")" * 500, "-" * 2000 + "x",
                                  "sin(" * 300 + "x" + ")" * 300, "2^" * 300 + "2"])
def test_deep_nesting_is_an_error_not_a_recursion_error(text):
    err = expr_error(text)
    assert "nested too deeply" in err.message
    assert err.column is not None


def test_nesting_within_the_limit_parses():
    depth = MAX_DEPTH - 5
    assert parse_expression("(" * depth + "x" + ")" * depth, SCOPE) == X


def test_deeply_nested_condition_is_an_error():
    with pytest.raises(SourceError, match="nested too deeply"):
        parse_condition("not " * 300 + "x > 0", SCOPE)
    with pytest.raises(SourceError, match="nested too deeply"):
        parse_condition("(" * 200 + "x > 0" + ")" * 200, SCOPE)


# atan2(0, 0) is 0, as in C, mpmath and on the curves (tests/test_real_domains.py)
@pytest.mark.parametrize("text, column", [("1/0", 2), ("x/(m - m)", 2), ("log(0)", 1),
                                          ("0^-1", 2), ("2 + 3*(1/0)", 9)])
def test_undefined_values_are_errors_at_the_operation(text, column):
    err = expr_error(text)
    assert err.column == column
    assert "undefined or infinite" in err.message
    assert err.expected == "a finite expression"


def test_non_real_values_are_source_errors_where_they_arise():
    err = expr_error("min(sqrt(-1), 1)")
    assert err.column == 5                    # at sqrt, where the value stops being real
    assert err.expected == "a real expression"
    with pytest.raises(SourceError) as info:
        parse_condition("x > 0 and sqrt(-1) > 0", SCOPE, line=2)
    assert (info.value.line, info.value.column) == (2, 11)
    assert "not a real number" in info.value.message


@pytest.mark.parametrize("text, column", [("sqrt(-1)", 1), ("2*log(-2)", 3), ("(-4)^(1/2)", 5)])
def test_constant_non_real_values_are_refused(text, column):
    err = expr_error(text)
    assert err.column == column and "not a real number" in err.message


def test_division_by_an_underflowing_float_is_a_positioned_error():
    err = expr_error("9.81/1e-400")              # 1e-400 is 0.0 as a float
    assert err.column == 5 and "division by zero" in err.message


def test_non_ascii_digits_and_letters_are_rejected():
    assert expr_error("\u0663").column == 1          # ARABIC-INDIC DIGIT THREE
    assert expr_error("x + \u00e9").column == 5
    assert "unexpected character" in expr_error("x + \u00e9").message


# --- counts ----------------------------------------------------------------------------------------

@pytest.mark.parametrize("text, column", [("iterate 99999999999999999999", 9),
                                          ("time 0 1 knots=" + "9" * 5000, 16),
                                          ("filter x 10000000", 10)])
def test_absurd_counts_are_refused(text, column):
    err = cmd_error(text)
    assert (err.line, err.column) == (5, column)
    assert err.message == "number too large"
    assert "up to" in err.expected


def test_large_seed_is_allowed():
    assert parse_command("shake amplitude=0.1 seed=123456789012", SCOPE) == ShakeCmd(
        (), sp.Float(0.1), 123456789012, "shake amplitude=0.1 seed=123456789012")
    assert parse_command("iterate 1000000", SCOPE) == IterateCmd(1_000_000, "iterate 1000000")


# --- what each place allows ----------------------------------------------------------------------

def test_const_items_may_use_earlier_items_of_the_same_line():
    c = parse_command("const a = 2, b = a*g", SCOPE)
    assert c == ConstCmd((("a", sp.Integer(2)), ("b", named_symbol("a") * named_symbol("g"))),
                         "const a = 2, b = a*g")


def test_const_items_may_not_use_later_items_or_repeat():
    assert "unknown name 'b'" in cmd_error("const a = b, b = 1").message
    err = cmd_error("const a = 1, a = 2")
    assert (err.column, err.message) == (14, "'a' given twice")


@pytest.mark.parametrize("text, column, start", [
    ("dof z = x + t", 9, "'x' is a DOF; an initial curve may use only t and constants"),
    ("dof z = f", 9, "'f' is a subexpression; an initial curve"),
    ("time 0 t", 8, "'t' (time) is not allowed here"),
    ("constraint c: x = 0 @ y", 23, "'y' is a DOF; a time, value or weight may use only"),
    ("weight c x'", 10, "'x' is a DOF"),
    ("key 0 x=f", 9, "'f' is a subexpression"),
])
def test_restricted_places_name_the_kind_they_refuse(text, column, start):
    err = cmd_error(text)
    assert err.column == column
    assert err.message.startswith(start)
    assert err.expected.startswith("a number")


def test_initial_curve_allows_t_constants_and_pi():
    c = parse_command("dof z = m*sin(pi*t)", SCOPE)
    assert c.init == named_symbol("m") * sp.sin(sp.pi * TIME)


def test_unknown_name_in_a_numeric_place_suggests_only_constants():
    err = cmd_error("time 0 gg")
    assert "did you mean 'g'" in err.message
    assert err.expected == "a number, constant or a function"
    assert "'y'" not in cmd_error("time 0 yy").message


@pytest.mark.parametrize("text, column, message", [
    ("time", 5, "expected a number"),
    ("time 0", 7, "expected a number"),
    ("constraint c: x = 0 on [0, 1", 29, "missing ']'"),
    ("print sin(x", 12, "missing ')'"),
    ("let q = ", 8, "expected an expression"),
    ("key 0 x=1,", 11, "unexpected end of line"),
    ("dof a, b, a", 11, "'a' given twice"),
    ("objective o: x )", 16, "unexpected ')'"),
])
def test_incomplete_lines(text, column, message):
    err = cmd_error(text)
    assert (err.line, err.column) == (5, column)
    assert err.message == message
    assert err.source == text


def test_key_with_commas_and_spaces_mixed():
    c = parse_command("key 1 x=1, y=-2", SCOPE)
    assert c == KeyCmd(sp.Integer(1), (("x", sp.Integer(1)), ("y", sp.Integer(-2))), "key 1 x=1, y=-2")


def test_layered_dict_scope():
    inner = DictScope({"a": NameKind.CONST}, parent=SCOPE)
    assert inner.kind_of("a") is NameKind.CONST
    assert inner.kind_of("x") is NameKind.DOF
    assert inner.kind_of("nope") is None
    assert inner.names()[:1] == ["a"] and "x" in inner.names()


def test_error_in_a_long_line_is_fast():
    text = " + ".join(f"{i}*x" for i in range(400)) + " + zz"
    start = time.perf_counter()
    err = expr_error(text)
    assert time.perf_counter() - start < 2.0
    assert err.column == len(text) - 1
