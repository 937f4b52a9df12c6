"""The session language: expressions (precedence, names, functions), errors with line/column/expected,
rejection of code injection, every command form, DOF-name checks and help."""

from __future__ import annotations

import builtins
import inspect

import pytest
import sympy as sp

from stw_tui.session.session import Session
from stw_tui.sym.errors import SourceError, StwError
from stw_tui.sym.language import (COMMAND_HELP, COMMAND_NAMES, DictScope, NameKind, parse_command,
                              parse_condition, parse_expression)
from stw_tui.sym.language import commands as commands_module
from stw_tui.sym.language import expressions as expressions_module
from stw_tui.sym.language import tokens as tokens_module
from stw_tui.sym.language.commands import (BackendCmd, ConstCmd, ConstraintCmd, DampCmd, DeleteCmd,
                                       DofCmd, FilterCmd, HelpCmd, IterateCmd, KeyCmd, LetCmd,
                                       ObjectiveCmd, PrintCmd, RefineCmd, Relation, SetCmd, ShakeCmd,
                                       TimeCmd, UseCmd, WeightCmd, WindowCmd)
from stw_tui.sym.language.help import help_text
from stw_tui.sym.symbols import TIME, dof_symbol, named_symbol

SCOPE = DictScope({"x": NameKind.DOF, "y": NameKind.DOF, "m": NameKind.CONST, "g": NameKind.CONST,
                   "f": NameKind.LET})

X, X1, X2 = dof_symbol("x"), dof_symbol("x", 1), dof_symbol("x", 2)
Y = dof_symbol("y")
M, G, F = named_symbol("m"), named_symbol("g"), named_symbol("f")


def expr(text: str, **kw) -> sp.Expr:
    return parse_expression(text, SCOPE, **kw)


def cmd(text: str, scope=SCOPE, line: int | None = None):
    return parse_command(text, scope, line=line)


def expr_error(text: str, **kw) -> SourceError:
    with pytest.raises(SourceError) as info:
        parse_expression(text, SCOPE, **kw)
    return info.value


def cmd_error(text: str, scope=SCOPE, line: int | None = 1) -> SourceError:
    with pytest.raises(SourceError) as info:
        parse_command(text, scope, line=line)
    return info.value


# --- expressions: precedence and associativity ------------------------------------------------------

def test_unary_minus_binds_looser_than_power():
    result = expr("-x^2")
    assert result == -(X**2)
    assert result != (-X) ** 2


def test_power_is_right_associative():
    assert expr("2^3^2") == 512
    assert expr("2**3**2") == 512
    assert expr("(2^3)^2") == 64


def test_power_exponent_may_be_negated():
    assert expr("x^-2") == X**-2
    assert expr("2^-1") == sp.Rational(1, 2)


def test_subtraction_is_left_associative():
    assert expr("x - y - m") == (X - Y) - M
    assert expr("x - y - m") != X - (Y - M)


def test_division_is_left_associative():
    assert expr("x / y / m") == (X / Y) / M
    assert expr("x / y / m") != X / (Y / M)


def test_product_binds_tighter_than_sum():
    assert expr("x + y * m") == X + Y * M
    assert expr("(x + y) * m") == (X + Y) * M
    assert expr("x*y + m/g - 1") == X * Y + M / G - 1


def test_unary_plus_and_double_minus():
    assert expr("+x") == X
    assert expr("--x") == X
    assert expr("-(-x)") == X


def test_primes_make_velocity_and_acceleration_symbols():
    assert expr("x' * 2") == 2 * dof_symbol("x", 1)
    assert expr("x''") == dof_symbol("x", 2)
    assert expr("x'' + y'") == X2 + dof_symbol("y", 1)
    # the three are distinct symbols, not derivatives of one another
    assert len({X, X1, X2}) == 3


def test_dof_constant_and_let_symbols():
    assert expr("x") == dof_symbol("x")
    assert expr("m") == named_symbol("m")
    assert expr("f") == named_symbol("f")
    assert expr("m*x'' + m*g") == M * X2 + M * G


def test_time_and_pi():
    assert expr("t") == TIME
    assert expr("t") is TIME
    assert expr("pi") == sp.pi
    assert expr("2*pi*t") == 2 * sp.pi * TIME


@pytest.mark.parametrize("text, value", [
    ("1", sp.Integer(1)),
    ("42", sp.Integer(42)),
    ("1.5", sp.Float(1.5)),
    (".5", sp.Float(0.5)),
    ("1e-3", sp.Float(0.001)),
    ("2.5E2", sp.Float(250.0)),
])
def test_numbers(text, value):
    result = expr(text)
    assert result == value
    assert isinstance(result, type(value))


def test_integer_division_is_exact_rational():
    assert expr("1/9") == sp.Rational(1, 9)


@pytest.mark.parametrize("text, expected", [
    ("sin(x)", sp.sin(X)), ("cos(x)", sp.cos(X)), ("tan(x)", sp.tan(X)),
    ("asin(x)", sp.asin(X)), ("acos(x)", sp.acos(X)), ("atan(x)", sp.atan(X)),
    ("sinh(x)", sp.sinh(X)), ("cosh(x)", sp.cosh(X)), ("tanh(x)", sp.tanh(X)),
    ("exp(x)", sp.exp(X)), ("log(x)", sp.log(X)), ("sqrt(x)", sp.sqrt(X)),
    ("atan2(y, x)", sp.atan2(Y, X)),
    ("abs(x - 1)", sp.Abs(X - 1)),
    ("sign(x'')", sp.sign(X2)),
    ("min(x, y, m)", sp.Min(X, Y, M)),
    ("max(x, 0)", sp.Max(X, 0)),
    ("min(x)", X),
    ("sin(x)^2 + cos(2*t)", sp.sin(X) ** 2 + sp.cos(2 * TIME)),
])
def test_functions(text, expected):
    assert expr(text) == expected


@pytest.mark.parametrize("text, message", [
    ("atan2(x)", "atan2 takes 2 argument(s), not 1"),
    ("atan2(x, y, m)", "atan2 takes 2 argument(s), not 3"),
    ("sin(x, y)", "sin takes 1 argument(s), not 2"),
    ("abs(x, y)", "abs takes 1 argument(s), not 2"),
])
def test_function_arity_errors(text, message):
    err = expr_error(text, line=2)
    assert err.message == message
    assert (err.line, err.column) == (2, 1)


def test_function_with_no_arguments_is_an_error():
    err = expr_error("min()")
    assert err.column == 5
    assert err.expected == "a number, name, function or '('"


def test_function_name_without_call_is_an_error():
    err = expr_error("1 + sin")
    assert err.column == 5
    assert err.expected == "'sin(...)'"


def test_condition_parses_to_sympy_logic():
    cond = parse_condition("x > 1 and not y < 0 or x'' == 0", SCOPE)
    assert cond == sp.Or(sp.And(sp.StrictGreaterThan(X, 1), sp.Not(sp.StrictLessThan(Y, 0))),
                         sp.Eq(X2, 0))


def test_condition_parenthesised_sum_and_group():
    cond = parse_condition("(x + 1) > 2 or (y < 0 and x != 1)", SCOPE)
    assert cond == sp.Or(sp.StrictGreaterThan(X + 1, 2), sp.And(sp.StrictLessThan(Y, 0), sp.Ne(X, 1)))


# --- errors: line, column, expected -----------------------------------------------------------------

def test_unknown_name_with_suggestion():
    err = expr_error("x + gg", line=7)
    assert (err.line, err.column) == (7, 5)
    assert "unknown name 'gg'" in err.message
    assert "did you mean 'g'" in err.message
    assert err.expected == "a DOF, constant, subexpression or function"


def test_an_unknown_name_in_the_wrong_case_suggests_the_right_one():
    s = Session()
    s.run_text("time 0 1\nconst g = 9.81\nlinkage arm base=fixed\n  SHOULDER revolute a=0.35\nend\n")
    with pytest.raises(SourceError) as err:
        s.execute("objective e: tau_shoulder")
    assert "unknown name 'tau_shoulder' (did you mean 'tau_SHOULDER'" in err.value.message


def test_unknown_name_never_becomes_a_symbol():
    err = expr_error("zzz_unlikely")
    assert "unknown name 'zzz_unlikely'" in err.message
    assert "did you mean" not in err.message


def test_column_offset_shifts_columns():
    err = expr_error("x + gg", line=3, column_offset=10)
    assert (err.line, err.column) == (3, 15)


def test_primes_on_a_constant_are_an_error():
    err = expr_error("2 * m'", line=1)
    assert err.column == 5
    assert "only DOF and subexpressions can be differentiated" in err.message


def test_primes_on_time_are_errors_and_on_a_let_its_derivative():
    assert "not one" in expr_error("t''").message
    assert expr("f'") == sp.Symbol("f'", real=True)   # the scene differentiates f when it expands it


def test_three_primes_are_an_error():
    err = expr_error("y + x'''", line=4)
    assert (err.line, err.column) == (4, 5)
    assert "at most two primes" in err.message


def test_detached_prime_is_not_a_derivative():
    err = expr_error("x '")
    assert err.column == 3
    assert err.expected == "an operator or end of line"


def test_unknown_function_with_suggestion():
    err = expr_error("1 + sinn(x)", line=2)
    assert (err.line, err.column) == (2, 5)
    assert "unknown function 'sinn'" in err.message
    assert "did you mean 'sin'" in err.message
    assert err.expected == "a known function"


def test_missing_closing_parenthesis():
    err = expr_error("(x + 1", line=1)
    assert err.column == 7
    assert err.expected == "')'"
    assert err.message == "missing ')'"


def test_missing_closing_parenthesis_in_call():
    err = expr_error("sin(x + 1")
    assert err.column == 10
    assert err.expected == "',' or ')'"


def test_unexpected_trailing_tokens():
    err = expr_error("x + 1 )", line=5)
    assert (err.line, err.column) == (5, 7)
    assert err.expected == "an operator or end of line"
    err = expr_error("x y")
    assert err.column == 3


def test_unknown_command_with_suggestion():
    err = cmd_error("constrant a: x = 0 @ 0", line=12)
    assert (err.line, err.column) == (12, 1)
    assert "unknown command 'constrant'" in err.message
    assert "did you mean 'constraint'" in err.message
    assert err.expected == "a command; `help` lists them"


def test_command_error_columns_are_absolute_in_the_line():
    err = cmd_error("constraint c: x = 0, y = zz @ 1", line=3)
    assert (err.line, err.column) == (3, 26)
    assert "unknown name 'zz'" in err.message


def test_constraint_without_time_scope():
    err = cmd_error("constraint c: x = 0")
    assert err.column == 20
    assert err.expected == "'@ TIME' or 'on [A, B]'"


def test_constraint_without_relation_operator():
    err = cmd_error("constraint c: x @ 0")
    assert err.column == 17
    assert err.expected == "'=', '>=' or '<='"


def test_trailing_tokens_after_command():
    err = cmd_error("iterate 20 30")
    assert err.column == 12
    assert err.expected == "end of line"


def test_option_given_twice():
    err = cmd_error("time 0 1 knots=4 knots=5")
    assert err.column == 18
    assert "given twice" in err.message


def test_dof_initial_curve_may_not_use_dofs():
    err = cmd_error("dof z = 2*x", scope=SCOPE)
    assert err.column == 11
    assert "initial curve may use only t and constants" in err.message
    assert err.expected is not None


def test_source_error_caret_points_at_column():
    err = cmd_error("damp m 1")
    assert err.caret() == "damp m 1\n     ^"
    # What the command line prints: where, then the caret lines; without a column, one line.
    assert err.report("s.stw") == f"s.stw: {err}\ndamp m 1\n     ^"
    from stw_tui.sym.errors import SourceError

    assert SourceError("no time", line=3).report("s.stw") == "s.stw: line 3: no time"


# --- code injection is rejected -----------------------------------------------------------------------

INJECTIONS = ["__import__('os')", "x.__class__", "lambda: 1", '"str"', "x[0]", "1; import os",
              "().__class__.__bases__", "exec('1')", "eval('1')", "open('/etc/passwd')",
              "x.real", "`ls`", "sin.__globals__"]


@pytest.mark.parametrize("text", INJECTIONS)
def test_injection_rejected_as_expression(text):
    with pytest.raises(SourceError) as info:
        parse_expression(text, SCOPE, line=1)
    assert info.value.line == 1
    assert info.value.column is not None


@pytest.mark.parametrize("text", INJECTIONS)
def test_injection_rejected_in_commands(text):
    for line in (f"print {text}", f"let h = {text}", f"constraint c: {text} = 0 @ 0"):
        with pytest.raises(SourceError):
            parse_command(line, SCOPE, line=1)


def test_dunder_names_rejected_by_tokenizer():
    err = expr_error("1 + __import__('os')")
    assert err.column == 5
    assert "'__'" in err.message


def test_parsing_never_calls_eval_or_parse_expr(monkeypatch):
    import sympy.parsing.sympy_parser as sympy_parser

    def forbidden(*args, **kwargs):
        raise AssertionError("the language must not evaluate text")

    monkeypatch.setattr(builtins, "eval", forbidden)
    monkeypatch.setattr(sympy_parser, "parse_expr", forbidden)
    monkeypatch.setattr(sympy_parser, "eval_expr", forbidden)
    result = expr("-x^2 + atan2(y, x)*min(m, g, 1.5)/abs(x'') + sign(f) - pi*t")
    assert result == (-X**2 + sp.atan2(Y, X) * sp.Min(M, G, sp.Float(1.5)) / sp.Abs(X2) + sp.sign(F)
                      - sp.pi * TIME)
    assert isinstance(cmd("constraint floor: y >= 0 on [0, 1.5] when x > 1 weight=3"), ConstraintCmd)
    assert isinstance(cmd("dof z = 0.5*t^2 knots=10"), DofCmd)


def test_language_sources_do_not_mention_eval():
    for module in (tokens_module, expressions_module, commands_module):
        code = inspect.getsource(module)
        for word in ("eval(", "exec(", "sympify(", "parse_expr(", "lambdify("):
            assert word not in code, (module.__name__, word)


# --- commands ---------------------------------------------------------------------------------------

def test_blank_and_comment_lines():
    assert cmd("") is None
    assert cmd("   \t ") is None
    assert cmd("# just a comment") is None
    assert cmd("    # indented comment") is None


def test_time():
    text = "time 0 1.5 knots=24 samples=48"
    assert cmd(text) == TimeCmd(sp.Integer(0), sp.Float(1.5), 24, 48, text)
    assert cmd("time 0 1") == TimeCmd(sp.Integer(0), sp.Integer(1), None, None, "time 0 1")


def test_time_knots_must_be_whole():
    err = cmd_error("time 0 1 knots=2.5")
    assert err.column == 16
    assert err.expected == "a whole number for knots"


def test_const():
    text = "const m = 1, g = 9.81"
    assert cmd(text) == ConstCmd((("m", sp.Integer(1)), ("g", sp.Float(9.81))), text)


def test_const_cannot_rename_a_dof():
    err = cmd_error("const x = 1")
    assert err.column == 7
    assert "already a DOF" in err.message


def test_dof_with_new_names():
    text = "dof x, y = 0.5*t^2 knots=10 lo=-1 hi=2"
    result = cmd(text, scope=DictScope())
    assert result == DofCmd(("x", "y"), sp.Float(0.5) * TIME**2, 10, sp.Integer(-1), sp.Integer(2), text)


def test_dof_plain_and_in_scope():
    assert cmd("dof a") == DofCmd(("a",), None, None, None, None, "dof a")
    # redeclaring an existing DOF is how its curve is refit
    assert cmd("dof x = g*t").init == G * TIME


def test_let():
    text = "let f = m*x'' + m*g"
    assert cmd(text) == LetCmd("f", M * X2 + M * G, text)


def test_constraint_at_instant():
    text = "constraint start: x = 0, x' = 0 @ 0"
    assert cmd(text) == ConstraintCmd(
        "start", (Relation(X, "eq", 19), Relation(X1, "eq", 26)), sp.Integer(0), None, None, None, text)


def test_constraint_on_interval_with_when_and_weight():
    text = "constraint floor: y >= 0 on [0, 1.5] when x > 1 and not y < 0 weight=3"
    expected_when = sp.And(sp.StrictGreaterThan(X, 1), sp.Not(sp.StrictLessThan(Y, 0)))
    assert cmd(text) == ConstraintCmd("floor", (Relation(Y, "ge", 19),), None,
                                      (sp.Integer(0), sp.Float(1.5)), expected_when, sp.Integer(3), text)


def test_constraint_le_relation_is_lhs_minus_rhs():
    result = cmd("constraint cap: x <= 1/9 @ 0.5")
    assert result.relations == (Relation(X - sp.Rational(1, 9), "le", 17),)
    assert result.at == sp.Float(0.5)
    result = cmd("constraint c: x'' + g = y @ 1")
    assert result.relations == (Relation(X2 + G - Y, "eq", 15),)


def test_objective():
    text = "objective fuel: f, x'' on [0, 1] weight=0.5"
    assert cmd(text) == ObjectiveCmd("fuel", (F, X2), (sp.Integer(0), sp.Integer(1)), sp.Float(0.5), text)
    assert cmd("objective fuel: f") == ObjectiveCmd("fuel", (F,), None, None, "objective fuel: f")


@pytest.mark.parametrize("text", ["key 0.75 x=2.5 y=0.5", "key 0.75 x=2.5, y=0.5"])
def test_key(text):
    assert cmd(text) == KeyCmd(sp.Float(0.75), (("x", sp.Float(2.5)), ("y", sp.Float(0.5))), text)


def test_key_needs_assignments_and_dofs():
    assert cmd_error("key 0.5").expected == "DOF=VALUE"
    err = cmd_error("key 0.5 m=1")
    assert err.column == 9
    assert err.expected == "a DOF name"


def test_window():
    text = "window release dofs=x,y [0.4, 0.8]"
    assert cmd(text) == WindowCmd("release", ("x", "y"), (sp.Float(0.4), sp.Float(0.8)), text)
    assert cmd("window w") == WindowCmd("w", None, None, "window w")


def test_use_weight_damp_filter():
    assert cmd("use w") == UseCmd("w", "use w")
    assert cmd("weight goal 10") == WeightCmd("goal", sp.Integer(10), "weight goal 10")
    assert cmd("damp x 0.2") == DampCmd("x", sp.Float(0.2), "damp x 0.2")
    assert cmd("filter x 2") == FilterCmd("x", 2, "filter x 2")
    assert cmd("filter y") == FilterCmd("y", 1, "filter y")


def test_shake():
    text = "shake x y amplitude=0.05 seed=3"
    assert cmd(text) == ShakeCmd(("x", "y"), sp.Float(0.05), 3, text)
    assert cmd("shake amplitude=1") == ShakeCmd((), sp.Integer(1), None, "shake amplitude=1")
    assert cmd_error("shake x").expected == "amplitude=A"


def test_refine():
    text = "refine x [0.4, 0.8]"
    assert cmd(text) == RefineCmd("x", (sp.Float(0.4), sp.Float(0.8)), text)
    assert cmd("refine y") == RefineCmd("y", None, "refine y")


def test_backend_and_set():
    text = "backend scipy solver=minres lin_tol=1e-9"
    assert cmd(text) == BackendCmd("scipy", (("solver", "minres"), ("lin_tol", "1e-9")), text)
    assert cmd("backend torch") == BackendCmd("torch", (), "backend torch")
    assert cmd("set tol_kkt 1e-8") == SetCmd("tol_kkt", "1e-8", "set tol_kkt 1e-8")
    assert cmd("set frame -1") == SetCmd("frame", "-1", "set frame -1")


def test_iterate_and_delete():
    assert cmd("iterate") == IterateCmd(1, "iterate")
    assert cmd("iterate 20") == IterateCmd(20, "iterate 20")
    assert cmd("delete catch") == DeleteCmd("catch", "delete catch")


def test_print():
    assert cmd("print x'' @ 0.5") == PrintCmd(X2, sp.Float(0.5), "x''", "print x'' @ 0.5")
    assert cmd("print f  # comment") == PrintCmd(F, None, "f", "print f")
    assert cmd("print m*x'' + g @ 1").expr_text == "m*x'' + g"


def test_help_command():
    assert cmd("help") == HelpCmd(None, "help")
    assert cmd("help constraint") == HelpCmd("constraint", "help constraint")


def test_command_text_strips_comment_and_whitespace():
    result = cmd("  iterate 20   # go")
    assert result == IterateCmd(20, "iterate 20")


def test_linkage_is_not_a_single_line_command():
    err = cmd_error("linkage arm base=fixed")
    assert "block" in err.message


def test_design_examples_parse():
    scope = DictScope()
    lines = ["time 0 1 knots=12", "const m = 1, g = 9.81", "dof x", "let f = m*x'' + m*g",
             "constraint start: x = 0, x' = 0 @ 0", "constraint end:   x = 1, x' = 0 @ 1",
             "objective fuel: f                  # minimize the integral of f^2", "iterate 20"]
    kinds = {}
    for line in lines:
        scope = DictScope(kinds)
        result = parse_command(line, scope)
        assert result is not None
        if isinstance(result, ConstCmd):
            kinds.update({name: NameKind.CONST for name, _ in result.items})
        elif isinstance(result, DofCmd):
            kinds.update({name: NameKind.DOF for name in result.names})
        elif isinstance(result, LetCmd):
            kinds[result.name] = NameKind.LET
    assert result == IterateCmd(20, "iterate 20")


# --- DOF-name checks and reserved names ---------------------------------------------------------------

def test_damp_needs_a_dof_at_its_column():
    err = cmd_error("damp m 1", line=9)
    assert (err.line, err.column) == (9, 6)
    assert "'m' is not a DOF" in err.message
    assert err.expected == "a DOF name"


def test_window_dofs_must_be_dofs():
    err = cmd_error("window w dofs=x,g [0, 1]")
    assert err.column == 17
    assert err.expected == "a DOF name"


@pytest.mark.parametrize("text, column", [
    ("dof sin", 5), ("dof x, t", 8), ("let t = 1", 5), ("let pi = 3", 5), ("const on = 1", 7),
    ("constraint when: x = 0 @ 0", 12), ("window iterate", 8), ("dof arm.x", 5),
])
def test_reserved_names_rejected(text, column):
    err = cmd_error(text)
    assert err.column == column
    assert "cannot be used as a name" in err.message


# --- help ---------------------------------------------------------------------------------------------

@pytest.mark.parametrize("name", COMMAND_NAMES)
def test_every_command_has_help(name):
    assert name in COMMAND_HELP
    text = help_text(name)
    assert text.startswith(name)
    assert "example:" in text


def test_help_overview_mentions_every_command():
    overview = help_text(None)
    listed = {line.split()[0] for line in overview.splitlines()[1:] if line.startswith("  ")}
    assert listed == set(COMMAND_NAMES)
    assert "atan2" in overview and "pi" in overview


def test_help_examples_parse():
    scope = DictScope({"x": NameKind.DOF, "y": NameKind.DOF, "m": NameKind.CONST,
                       "g": NameKind.CONST, "f": NameKind.LET, "SHOULDER": NameKind.DOF,
                       "ELBOW": NameKind.DOF, "WRIST": NameKind.DOF, "BX": NameKind.DOF,
                       "BY": NameKind.DOF})
    for name, entry in COMMAND_HELP.items():
        if name == "linkage":
            continue
        result = parse_command(entry.example, scope)
        assert type(result).__name__ == name.capitalize() + "Cmd", name


def test_help_unknown_topic():
    with pytest.raises(StwError) as info:
        help_text("nosuch")
    assert "nosuch" in str(info.value)
    with pytest.raises(StwError, match="did you mean constraint"):
        help_text("constrant")


@pytest.mark.parametrize("text, verb, words", [
    ("iterate 20   # solve", "iterate", ("iterate", "20")),
    ("  linkage arm base=fixed", "linkage", ("linkage", "arm", "base=fixed")),
    ("end", "end", ("end",)),
    ("   # only a comment", None, ()),
    ("", None, ()),
    ("iterate# no space before the comment", "iterate", ("iterate",)),
    ('save "a file" # with a comment', "save", ("save", '"a', 'file"')),
    ("dof \u00e9 ?? unparsable", "dof", ("dof", "\u00e9", "??", "unparsable")),   # never raises
])
def test_classify_line_reads_the_words_before_a_comment(text, verb, words):
    from stw_tui.sym.language import classify_line

    line = classify_line(text)
    assert (line.verb, line.words, line.is_blank) == (verb, words, verb is None)
