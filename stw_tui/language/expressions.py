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
"""

from __future__ import annotations

import difflib
import enum
from typing import Protocol

import sympy as sp

from ..errors import SourceError
from ..symbols import TIME, dof_symbol, named_symbol
from .tokens import END, NAME, NUMBER, Token, tokenize


class NameKind(enum.Enum):
    DOF = "dof"
    CONST = "constant"
    LET = "subexpression"


class Scope(Protocol):
    def kind_of(self, name: str) -> NameKind | None: ...


class DictScope:
    """A scope from a plain mapping (tests, and callers with a fixed set of names)."""

    def __init__(self, kinds: dict[str, NameKind] | None = None):
        self.kinds = dict(kinds or {})

    def kind_of(self, name: str) -> NameKind | None:
        return self.kinds.get(name)

    def names(self) -> list[str]:
        return list(self.kinds)


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
_COMPARISONS = {">": sp.StrictGreaterThan, ">=": sp.GreaterThan, "<": sp.StrictLessThan,
                "<=": sp.LessThan, "==": sp.Eq, "!=": sp.Ne}


class ExpressionParser:
    """Parses expressions from a token list, starting at any position.

    The command parser shares the token list and position: an expression ends at the first token
    that cannot continue it (a top-level ',', '@', ']', '=', a keyword…), which is left in place.
    """

    def __init__(self, tokens: list[Token], scope: Scope, *, line: int | None = None,
                 source: str | None = None, time_allowed: bool = True, dof_allowed: bool = True):
        self.tokens = tokens
        self.pos = 0
        self.scope = scope
        self.line = line
        self.source = source
        self.time_allowed = time_allowed
        self.dof_allowed = dof_allowed

    # --- token helpers -----------------------------------------------------------------------
    @property
    def token(self) -> Token:
        return self.tokens[self.pos]

    def advance(self) -> Token:
        token = self.tokens[self.pos]
        if token.kind != END:
            self.pos += 1
        return token

    def error(self, message: str, token: Token | None = None, expected: str | None = None) -> SourceError:
        token = token or self.token
        return SourceError(message, line=self.line, column=token.column, source=self.source,
                           expected=expected)

    def unexpected(self, expected: str) -> SourceError:
        t = self.token
        what = "end of line" if t.kind == END else repr(t.text)
        return self.error(f"unexpected {what}", expected=expected)

    def expect_op(self, op: str, expected: str | None = None) -> Token:
        if not self.token.is_op(op):
            raise self.unexpected(expected or f"'{op}'")
        return self.advance()

    # --- expressions -------------------------------------------------------------------------
    def expression(self) -> sp.Expr:
        return self._sum()

    def _sum(self) -> sp.Expr:
        left = self._product()
        while self.token.is_op("+", "-"):
            op = self.advance().text
            right = self._product()
            left = left + right if op == "+" else left - right
        return left

    def _product(self) -> sp.Expr:
        left = self._unary()
        while self.token.is_op("*", "/"):
            op = self.advance().text
            right = self._unary()
            left = left * right if op == "*" else left / right
        return left

    def _unary(self) -> sp.Expr:
        if self.token.is_op("-"):
            self.advance()
            return -self._unary()
        if self.token.is_op("+"):
            self.advance()
            return self._unary()
        return self._power()

    def _power(self) -> sp.Expr:
        base = self._atom()
        if self.token.is_op("^", "**"):
            self.advance()
            return sp.Pow(base, self._unary())
        return base

    def _atom(self) -> sp.Expr:
        token = self.token
        if token.kind == NUMBER:
            self.advance()
            text = token.text
            return sp.Integer(int(text)) if text.isdigit() else sp.Float(float(text))
        if token.is_op("("):
            self.advance()
            inner = self._sum()
            self.expect_op(")", "')'")
            return inner
        if token.kind == NAME:
            return self._name()
        raise self.unexpected("a number, name, function or '('")

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
        if name == "t" and self.time_allowed:
            symbol = TIME
            kind = "time"
        elif name in CONSTANT_NAMES:
            symbol, kind = CONSTANT_NAMES[name], "number"
        else:
            kind = self.scope.kind_of(name)
            if kind is None:
                raise self._unknown(token)
            if kind is NameKind.DOF and not self.dof_allowed:
                raise self.error(f"'{name}' is a DOF; only t and constants are allowed here", token)
            symbol = None
        if primes:
            if kind is not NameKind.DOF:
                raise self.error(f"only DOF can be differentiated with primes ('{name}' is not a DOF)",
                                 token)
            if primes > 2:
                raise self.error("at most two primes (acceleration) are allowed", token)
        if kind is NameKind.DOF:
            return dof_symbol(name, primes)
        if symbol is not None:
            return symbol
        return named_symbol(name)

    def _unknown(self, token: Token) -> SourceError:
        candidates = list(getattr(self.scope, "names", lambda: [])()) + list(FUNCTIONS) + ["t", "pi"]
        close = difflib.get_close_matches(token.text, candidates, n=3)
        hint = f" (did you mean {', '.join(close)}?)" if close else ""
        return self.error(f"unknown name '{token.text}'{hint}", token,
                          expected="a DOF, constant, subexpression or function")

    def _call(self, token: Token) -> sp.Expr:
        name = token.text
        if name not in FUNCTIONS:
            close = difflib.get_close_matches(name, list(FUNCTIONS), n=3)
            hint = f" (did you mean {', '.join(close)}?)" if close else ""
            raise self.error(f"unknown function '{name}'{hint}", token, expected="a known function")
        self.expect_op("(")
        args = [self._sum()]
        while self.token.is_op(","):
            self.advance()
            args.append(self._sum())
        self.expect_op(")", "',' or ')'")
        constructor, arities = FUNCTIONS[name]
        if arities is not None and len(args) not in arities:
            raise self.error(f"{name} takes {arities[0]} argument(s), not {len(args)}", token)
        return constructor(*args)

    # --- conditions --------------------------------------------------------------------------
    def condition(self) -> sp.Basic:
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
            self.advance()
            return sp.Not(self._negation())
        if self.token.is_op("("):
            # A parenthesis may open a condition or an arithmetic sum: try the condition first.
            start = self.pos
            self.advance()
            try:
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
        op = self.advance().text
        right = self._sum()
        return _COMPARISONS[op](left, right)


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
