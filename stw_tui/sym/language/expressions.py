"""Expressions of the session language, parsed by recursive descent straight into sympy objects.

There is no ``eval`` and no ``sympify`` here: every sympy object is built by a constructor call
chosen from a fixed table, so a session file from a stranger can never run code. Unknown names
are errors, never new symbols.

Grammar (lowest precedence first)::

    condition  := disjunct ("or" disjunct)*
    disjunct   := conjunct ("and" conjunct)*
    conjunct   := "not" conjunct | comparison | "(" condition ")"
    comparison := sum (">" | ">=" | "<" | "<=" | "==" | "!=") sum
    sum        := product (("+" | "-") product)*
    product    := unary (("*" | "/") unary)*
    unary      := ("-" | "+") unary | power
    power      := atom (("^" | "**") unary)?          # right-associative, binds tighter than unary minus
    atom       := NUMBER | NAME primes? | FUNCTION "(" sum ("," sum)* ")" | "(" sum ")"

A stranger's file must not hang or crash the parser either: nesting depth, literal sizes and exact
powers are bounded, and undefined values (1/0, log(0)) are errors at the operation that made them.
"""

from __future__ import annotations

import difflib
import enum
import math
from contextlib import contextmanager
from typing import Protocol

import sympy as sp

from stw_tui.sym import limits
from stw_tui.sym.compiler import double_finite
from stw_tui.sym.errors import SourceError
from stw_tui.sym.language.tokens import END, NAME, NUMBER, Token, tokenize
from stw_tui.sym.symbols import TIME, dof_symbol, named_symbol


class NameKind(enum.Enum):
    """What a name in an expression stands for; the value is what messages call it."""

    DOF = "DOF"
    CONST = "constant"
    LET = "subexpression"


class Scope(Protocol):
    """What the parser asks of the world: the kind of a name, None if unknown. A scope may also
    offer ``names() -> list[str]``, used only to suggest close matches."""

    def kind_of(self, name: str) -> NameKind | None:
        """The kind of ``name``, or None if it is not defined."""


class DictScope:
    """A scope from a plain mapping (tests, and callers with a fixed set of names), optionally
    layered over a ``parent`` scope that answers for the names it lacks."""

    def __init__(self, kinds: dict[str, NameKind] | None = None, parent: Scope | None = None):
        self.kinds = dict(kinds or {})
        self.parent = parent

    def kind_of(self, name: str) -> NameKind | None:
        """The kind of ``name``, or None if neither this scope nor its parent defines it."""
        if name in self.kinds:
            return self.kinds[name]
        return self.parent.kind_of(name) if self.parent is not None else None

    def names(self) -> list[str]:
        """Every name defined here or in the parent (for suggestions)."""
        inherited = getattr(self.parent, "names", lambda: [])() if self.parent is not None else []
        return list(self.kinds) + [n for n in inherited if n not in self.kinds]


def _min(*args):
    return sp.Min(*args)


def _max(*args):
    return sp.Max(*args)


# name -> (constructor, allowed argument counts; None = one or more)
FUNCTIONS: dict[str, tuple[object, tuple[int, ...] | None]] = {
    "sin": (sp.sin, (1,)), "cos": (sp.cos, (1,)), "tan": (sp.tan, (1,)),
    "asin": (sp.asin, (1,)), "acos": (sp.acos, (1,)), "atan": (sp.atan, (1,)),
    "atan2": (sp.atan2, (2,)), "sinh": (sp.sinh, (1,)), "cosh": (sp.cosh, (1,)),
    "tanh": (sp.tanh, (1,)), "exp": (sp.exp, (1,)), "log": (sp.log, (1,)),
    "sqrt": (sp.sqrt, (1,)), "abs": (sp.Abs, (1,)), "sign": (sp.sign, (1,)),
    "min": (_min, None), "max": (_max, None),
}
CONSTANT_NAMES = {"pi": sp.pi}
CONDITION_WORDS = ("and", "or", "not")
# The defaults of the limits the parser checks (stw_tui.sym.limits; `set limit` changes them).
MAX_DEPTH = limits.LIMITS["nesting"].default           # parentheses, calls, signs and powers
MAX_DIGITS = limits.LIMITS["digits"].default           # digits of an integer literal
MAX_BITS = limits.LIMITS["number_bits"].default        # size of an exact number
MAX_FLOAT = 1.7976931348623157e308                     # a Float beyond this is no double: refused
_UNDEFINED = (sp.zoo, sp.nan, sp.oo, -sp.oo)
_COMPARISONS = {">": sp.StrictGreaterThan, ">=": sp.GreaterThan, "<": sp.StrictLessThan,
                "<=": sp.LessThan, "==": sp.Eq, "!=": sp.Ne}


def _magnitude(number: sp.Expr) -> float:
    """|number| as a float (inf when no float holds it), without exact arithmetic on huge values."""
    if number.is_Rational:
        if max(abs(number.p), number.q).bit_length() > 1000:
            return math.inf if abs(number.p) > number.q else 0.0
        return abs(float(number))
    try:
        return abs(complex(number.evalf(15)))
    except (TypeError, ValueError, OverflowError):
        return math.inf


class ExpressionParser:
    """Parses expressions from a token list, starting at any position.

    The command parser shares the token list and position: an expression ends at the first token
    that cannot continue it (a top-level ',', '@', ']', '=', a keyword…), which is left in place.
    Which names are allowed can be narrowed for a stretch with :meth:`restricted`.
    """

    def __init__(self, tokens: list[Token], scope: Scope, *, line: int | None = None,
                 source: str | None = None):
        self.tokens = tokens
        self.pos = 0
        self.scope = scope
        self.line = line
        self.source = source
        self.allowed: frozenset[NameKind] = frozenset(NameKind)
        self.time_allowed = True
        self.rule = ""          # why a known name is refused, e.g. "a time may use only constants"
        self.depth = 0

    # --- token helpers -----------------------------------------------------------------------
    @property
    def token(self) -> Token:
        """The current token, not consumed."""
        return self.tokens[self.pos]

    def advance(self) -> Token:
        """Consume the current token and return it (the end of line is never passed)."""
        token = self.tokens[self.pos]
        if token.kind != END:
            self.pos += 1
        return token

    def error(self, message: str, token: Token | None = None, expected: str | None = None) -> SourceError:
        """A SourceError at ``token`` (default: the current one), for the caller to raise."""
        token = token or self.token
        return SourceError(message, line=self.line, column=token.column, source=self.source,
                           expected=expected)

    def unexpected(self, expected: str) -> SourceError:
        """A SourceError for the current token, saying what was ``expected`` instead."""
        t = self.token
        what = "end of line" if t.kind == END else repr(t.text)
        return self.error(f"unexpected {what}", expected=expected)

    def expect_op(self, op: str, expected: str | None = None) -> Token:
        """Consume the operator ``op``, or raise an error saying it was expected."""
        if not self.token.is_op(op):
            if op in (")", "]") and self.token.kind == END:
                raise self.error(f"missing '{op}'", expected=expected or f"'{op}'")
            raise self.unexpected(expected or f"'{op}'")
        return self.advance()

    @contextmanager
    def restricted(self, kinds: tuple[NameKind, ...], *, time: bool, rule: str):
        """Allow only names of ``kinds`` (and ``t`` if ``time``) while parsing inside the block;
        ``rule`` ends the error message for a refused name."""
        saved = self.allowed, self.time_allowed, self.rule
        self.allowed, self.time_allowed, self.rule = frozenset(kinds), time, rule
        try:
            yield
        finally:
            self.allowed, self.time_allowed, self.rule = saved

    @contextmanager
    def _nested(self, token: Token):
        # Deep nesting would exhaust Python's stack (a RecursionError is not a user-facing error).
        self.depth += 1
        deepest = limits.value("nesting")
        if self.depth > deepest:
            raise self.error(f"expression nested too deeply (more than {deepest} levels, the limit "
                             f"nesting)", token)
        try:
            yield
        finally:
            self.depth -= 1

    def _text_since(self, start: int) -> str:
        """The source of the tokens from index ``start`` up to the last one consumed (for messages:
        ``log(-2) is not a real number``), spaced as typed."""
        text, end = "", None
        for token in self.tokens[start:self.pos]:
            if end is not None and token.column > end:
                text += " "
            text += token.text
            end = token.column + len(token.text)
        return text

    def _checked(self, value: sp.Expr, token: Token, start: int | None = None) -> sp.Expr:
        """``value`` unless it is undefined/infinite or an exact number too large to handle;
        ``start``, the index of its first token, names it in the message of a non-real value."""
        if value.has(*_UNDEFINED):
            raise self.error("the value is undefined or infinite here (division by zero?)", token,
                             expected="a finite expression")
        if value.is_number and not (value.is_Rational or value.is_Float) and not double_finite(value):
            # exp(exp(exp(100))): sympy would later evaluate it with ever more digits, for ever
            raise self.error("number out of range (or undefined)", token,
                             expected="a value a double can hold, below 1e308")
        if value.has(sp.I) or (value.is_number and value.is_extended_real is False):
            # sqrt(-1), log(-2), acos(2), (-8)^(1/3): stw's curves and values are real
            what = "the value" if start is None else self._text_since(start)[:60]
            raise self.error(f"{what} is not a real number", token, expected="a real expression")
        bits = limits.value("number_bits")
        if value.is_Rational and max(abs(value.p), value.q).bit_length() > bits:
            raise self.error("number too large", token, expected=f"numbers below 2^{bits} (limit number_bits)")
        if value.is_Float and not abs(value) <= MAX_FLOAT:   # 1.5^1e6, exp(1000.0): no double holds it
            raise self.error("number out of range", token, expected="a value below 1e308")
        return value

    # --- expressions -------------------------------------------------------------------------
    def expression(self) -> sp.Expr:
        """Parse an arithmetic expression (``sum`` in the grammar) into sympy."""
        return self._sum()

    def _sum(self) -> sp.Expr:
        left = self._product()
        while self.token.is_op("+", "-"):
            op = self.advance()
            right = self._product()
            left = left + right if op.text == "+" else left - right
            if left.is_Float and not abs(left) <= MAX_FLOAT:   # 1e308 + 1e308
                raise self.error("number out of range", op, expected="a value below 1e308")
        return left

    def _product(self) -> sp.Expr:
        start = self.pos
        left = self._unary()
        while self.token.is_op("*", "/"):
            op = self.advance()
            right = self._unary()
            try:
                value = left * right if op.text == "*" else left / right
            except ZeroDivisionError:   # a float zero (1e-400 underflows) divides in mpmath
                raise self.error("the value is undefined or infinite here (division by zero?)", op,
                                 expected="a finite expression") from None
            left = self._checked(value, op, start)
        return left

    def _unary(self) -> sp.Expr:
        if self.token.is_op("-", "+"):
            op = self.advance()
            with self._nested(op):
                operand = self._unary()
            return -operand if op.text == "-" else operand
        return self._power()

    def _power(self) -> sp.Expr:
        start = self.pos
        base = self._atom()
        if self.token.is_op("^", "**"):
            op = self.advance()
            with self._nested(op):
                exponent = self._unary()
            # sympy computes exact powers at once: 9^9^9 would never finish.
            if base.is_number and not base.is_Float and exponent.is_Rational:
                bits = max((max(abs(r.p), r.q).bit_length() for r in base.atoms(sp.Rational)), default=1)
                if abs(exponent) * bits > limits.value("number_bits"):
                    raise self.error("number too large", op, expected="a smaller exponent")
            # Float powers (9^9.81^…) take mpmath ever longer, and compiled code wraps integer
            # exponents of 2^31 and more: a numeric exponent is bounded, whatever its base.
            if exponent.is_number and _magnitude(exponent) > limits.value("exponent"):
                raise self.error("exponent too large", op,
                                 expected=f"an exponent of magnitude at most {limits.value('exponent')} "
                                          f"(limit exponent)")
            return self._checked(sp.Pow(base, exponent), op, start)
        return base

    def _atom(self) -> sp.Expr:
        token = self.token
        if token.kind == NUMBER:
            self.advance()
            return self._number(token)
        if token.is_op("("):
            self.advance()
            with self._nested(token):
                inner = self._sum()
            self.expect_op(")", "')'")
            return inner
        if token.kind == NAME:
            return self._name()
        numeric = not self.time_allowed and NameKind.DOF not in self.allowed
        if token.kind == END:
            raise self.error("expected a number" if numeric else "expected an expression",
                             expected="a number, name, function or '('")
        raise self.unexpected("a number, name, function or '('")

    def _number(self, token: Token) -> sp.Expr:
        text = token.text
        if text.isdigit():
            if len(text.lstrip("0")) > MAX_DIGITS:
                raise self.error("number too long", token, expected=f"at most {MAX_DIGITS} digits")
            return sp.Integer(int(text))
        value = float(text)
        if not math.isfinite(value):
            raise self.error("number out of range", token, expected="a number below 1e308")
        return sp.Float(value)

    def _name(self) -> sp.Expr:
        token = self.advance()
        name = token.text
        if self.token.is_op("("):
            return self._call(token)
        if name in FUNCTIONS:
            raise self.error(f"function '{name}' needs arguments", token, expected=f"'{name}(...)'")
        primes = 0
        while self.token.is_op("'", "''") and self.token.column == token.column + len(name) + primes:
            primes += len(self.advance().text)
        kind: NameKind | None = None
        if name == "t":
            if not self.time_allowed:
                raise self.error(f"'t' (time) is not allowed here; {self.rule}", token,
                                 expected=self._allowed_text())
            symbol = TIME
        elif name in CONSTANT_NAMES:
            symbol = CONSTANT_NAMES[name]
        else:
            kind = self.scope.kind_of(name)
            if kind is None:
                raise self._unknown(token)
            if kind not in self.allowed:
                raise self.error(f"'{name}' is a {kind.value}; {self.rule}", token,
                                 expected=self._allowed_text())
            symbol = dof_symbol(name, 0) if kind is NameKind.DOF else named_symbol(name)
        if primes:
            if kind not in (NameKind.DOF, NameKind.LET):
                raise self.error(f"only DOF and subexpressions can be differentiated with primes "
                                 f"('{name}' is not one)", token, expected="a DOF or subexpression before ' or ''")
            if primes > 2:
                raise self.error("at most two primes (acceleration) are allowed", token,
                                 expected="x, x' or x''")
            # A subexpression's time derivative (arm.tip.x' is the hand's velocity) is taken by
            # the scene when it substitutes definitions.
            symbol = dof_symbol(name, primes) if kind is NameKind.DOF else named_symbol(name + "'" * primes)
        return symbol

    def _allowed_text(self) -> str:
        words = [k.value for k in NameKind if k in self.allowed] + (["t"] if self.time_allowed else [])
        return "a number" + "".join(f", {w}" for w in words)

    def _unknown(self, token: Token) -> SourceError:
        names = [n for n in getattr(self.scope, "names", lambda: [])() if self.scope.kind_of(n) in self.allowed]
        candidates = names + list(FUNCTIONS) + ["pi"] + (["t"] if self.time_allowed else [])
        # compared without case too: joints are named in capitals (tau_shoulder is tau_SHOULDER)
        lowered = {c.lower(): c for c in candidates}
        close = list(dict.fromkeys(difflib.get_close_matches(token.text, candidates, n=3) + [
            lowered[c] for c in difflib.get_close_matches(token.text.lower(), list(lowered), n=3)]))[:3]
        hint = f" (did you mean {', '.join(repr(c) for c in close)}?)" if close else ""
        what = "a DOF, constant, subexpression or function" if self.allowed == frozenset(NameKind) \
            else self._allowed_text() + " or a function"
        return self.error(f"unknown name '{token.text}'{hint}", token, expected=what)

    def _call(self, token: Token) -> sp.Expr:
        name = token.text
        start = self.pos - 1
        if name not in FUNCTIONS:
            close = difflib.get_close_matches(name, list(FUNCTIONS), n=3)
            hint = f" (did you mean {', '.join(repr(c) for c in close)}?)" if close else ""
            raise self.error(f"unknown function '{name}'{hint}", token, expected="a known function")
        with self._nested(token):
            self.expect_op("(")
            args = [self._sum()]
            while self.token.is_op(","):
                self.advance()
                args.append(self._sum())
            self.expect_op(")", "',' or ')'")
        constructor, arities = FUNCTIONS[name]
        if arities is not None and len(args) not in arities:
            raise self.error(f"{name} takes {arities[0]} argument(s), not {len(args)}", token,
                             expected=f"{arities[0]} argument(s)")
        try:
            # atan2(0, 0) is 0, as in C, mpmath and on the curves (sympy's is nan)
            value = sp.Integer(0) if name == "atan2" and all(a.is_zero for a in args) else constructor(*args)
        except (TypeError, ValueError) as exc:   # e.g. min() of a non-real number
            raise self.error(f"{name}: {exc}", token, expected="real arguments") from None
        return self._checked(value, token, start)

    # --- conditions --------------------------------------------------------------------------
    def condition(self) -> sp.Basic:
        """Parse a condition (comparisons joined by and, or, not) into a sympy boolean."""
        left = self._conjunction()
        while self.token.is_word("or"):
            self.advance()
            left = sp.Or(left, self._conjunction())
        return left

    def _conjunction(self) -> sp.Basic:
        left = self._negation()
        while self.token.is_word("and"):
            self.advance()
            left = sp.And(left, self._negation())
        return left

    def _negation(self) -> sp.Basic:
        if self.token.is_word("not"):
            word = self.advance()
            with self._nested(word):
                return sp.Not(self._negation())
        if self.token.is_op("("):
            # A parenthesis may open a condition or an arithmetic sum: try the condition first.
            start = self.pos
            self.advance()
            try:
                with self._nested(self.token):
                    inner = self.condition()
                if self.token.is_op(")"):
                    self.advance()
                    if not self.token.is_op(*_COMPARISONS):
                        return inner
            except SourceError:
                pass
            self.pos = start
        return self._comparison()

    def _comparison(self) -> sp.Basic:
        left = self._sum()
        if not self.token.is_op(*_COMPARISONS):
            raise self.unexpected("a comparison (>, >=, <, <=, ==, !=)")
        op = self.advance()
        right = self._sum()
        try:
            return _COMPARISONS[op.text](left, right)
        except TypeError:   # sympy refuses to order non-real values such as sqrt(-1)
            raise self.error(f"cannot compare with '{op.text}': a side is not real", op,
                             expected="real-valued expressions") from None


def parse_expression(text: str, scope: Scope, *, line: int | None = None, column_offset: int = 0,
                     source: str | None = None) -> sp.Expr:
    """Parse a whole string as one expression.

    Raises:
        SourceError: with line, column (column_offset + position, 1-based) and what was expected.
    """
    parser = ExpressionParser(tokenize(text, line=line, column_offset=column_offset), scope,
                              line=line, source=source or text)
    expr = parser.expression()
    if parser.token.kind != END:
        raise parser.unexpected("an operator or end of line")
    return expr


def parse_condition(text: str, scope: Scope, *, line: int | None = None, column_offset: int = 0,
                    source: str | None = None) -> sp.Basic:
    """Parse a whole string as a condition (comparisons joined by and/or/not)."""
    parser = ExpressionParser(tokenize(text, line=line, column_offset=column_offset), scope,
                              line=line, source=source or text)
    cond = parser.condition()
    if parser.token.kind != END:
        raise parser.unexpected("'and', 'or' or end of line")
    return cond
