"""Commands of the session language: one frozen dataclass per command, and the line parser.

Numeric arguments written as expressions (times, values, weights) are kept as sympy expressions;
the interpreter evaluates them with the constants' values. Counts (knots, samples, passes, N,
seed) are ints.
"""

from __future__ import annotations

import difflib
from dataclasses import dataclass, field

import sympy as sp

from stw_tui.sym import limits
from stw_tui.sym.errors import printable
from stw_tui.sym.language.expressions import FUNCTIONS, DictScope, ExpressionParser, NameKind, Scope
from stw_tui.sym.language.tokens import END, NAME, NUMBER, Token, strip_comment, tokenize

Interval = tuple[sp.Expr, sp.Expr]


@dataclass(frozen=True)
class TimeCmd:
    """`time START END [knots=N] [samples=K]`: the animation span and how densely it is sampled."""

    start: sp.Expr
    end: sp.Expr
    knots: int | None
    samples: int | None
    text: str = ""


@dataclass(frozen=True)
class ConstCmd:
    """`const NAME = VALUE[, …]`: declare constants, or change their values."""

    items: tuple[tuple[str, sp.Expr], ...]
    text: str = ""


@dataclass(frozen=True)
class DofCmd:
    """`dof NAME[, …] [= EXPR] [knots=N] [lo=A] [hi=B]`: declare DOF curves, or refit them."""

    names: tuple[str, ...]
    init: sp.Expr | None
    knots: int | None
    lo: sp.Expr | None
    hi: sp.Expr | None
    text: str = ""


@dataclass(frozen=True)
class LetCmd:
    """`let NAME = EXPR`: a subexpression, substituted wherever it is named."""

    name: str
    expr: sp.Expr
    text: str = ""


@dataclass(frozen=True)
class Relation:
    """One relation of a `constraint` line as parsed: ``lhs - rhs`` with "eq", "ge" or "le"."""

    expr: sp.Expr        # lhs - rhs
    kind: str            # "eq", "ge" or "le"
    column: int


@dataclass(frozen=True)
class ConstraintCmd:
    """`constraint NAME: REL[, …] (@ T | on [A, B]) [when COND] [OPTION=VALUE…]`."""

    name: str
    relations: tuple[Relation, ...]
    at: sp.Expr | None
    interval: Interval | None
    when: sp.Basic | None
    weight: sp.Expr | None
    text: str = ""
    samples: int | None = None      # instances per animation span, overriding `time … samples=`
    dense_tol: sp.Expr | None = None   # its own continuous-time tolerance, overriding `set dense_tol`


@dataclass(frozen=True)
class ObjectiveCmd:
    """`objective NAME: [minimize|maximize] EXPR[, …] [on [A, B] | @ T] [weight=W]`: expressions
    to minimize."""

    name: str
    exprs: tuple[sp.Expr, ...]
    interval: Interval | None
    weight: sp.Expr | None
    text: str = ""
    at: sp.Expr | None = None      # a terminal (Mayer) cost: the squares at one instant
    sense: str | None = None       # "minimize" / "maximize": the expression signed, not squared


@dataclass(frozen=True)
class KeyCmd:
    """`key T DOF=V[, …]`: a keyframe that bends DOF curves through values (not a constraint)."""

    time: sp.Expr
    assignments: tuple[tuple[str, sp.Expr], ...]
    text: str = ""


@dataclass(frozen=True)
class WindowCmd:
    """`window NAME [dofs=a,b|all] [[A, B]]`: define a spacetime window and use it."""

    name: str
    dofs: tuple[str, ...] | None
    interval: Interval | None
    text: str = ""


@dataclass(frozen=True)
class UseCmd:
    """`use NAME`: iterate on a defined window."""

    name: str
    text: str = ""


@dataclass(frozen=True)
class WeightCmd:
    """`weight NAME W`: set the weight of a constraint or objective."""

    name: str
    weight: sp.Expr
    text: str = ""


@dataclass(frozen=True)
class DampCmd:
    """`damp DOF D`: damp the change of a DOF's control points per iteration."""

    dof: str
    amount: sp.Expr
    text: str = ""


@dataclass(frozen=True)
class FilterCmd:
    """`filter DOF [PASSES]`: smooth a DOF curve's control points."""

    dof: str
    passes: int = 1
    text: str = ""


@dataclass(frozen=True)
class ShakeCmd:
    """`shake [DOF…] amplitude=A [seed=S]`: perturb control points to leave a local minimum."""

    dofs: tuple[str, ...]
    amplitude: sp.Expr
    seed: int | None
    text: str = ""


@dataclass(frozen=True)
class RefineCmd:
    """`refine DOF [[A, B]]` or `refine DOF @ T [multiplicity=M]`: insert knots in a DOF."""

    dof: str
    interval: Interval | None
    text: str = ""
    at: sp.Expr | None = None           # `refine DOF @ T`: a knot at T ...
    multiplicity: int | None = None     # ... repeated this many times (2: acceleration may jump)


@dataclass(frozen=True)
class BackendCmd:
    """`backend NAME [OPTION=VALUE…]`: choose the solver backend and its options."""

    name: str
    options: tuple[tuple[str, str], ...]
    text: str = ""


@dataclass(frozen=True)
class SetCmd:
    """`set OPTION VALUE` (or `set limit NAME VALUE`): change a setting or a limit."""

    option: str
    value: str
    text: str = ""


@dataclass(frozen=True)
class InstancesCmd:
    """`instances NAME add T[, …]` or `instances NAME clear`: instances added by hand."""

    name: str                       # a constraint, or "DOF.bounds"
    action: str                     # "add" or "clear"
    times: tuple[sp.Expr, ...] = ()
    text: str = ""


@dataclass(frozen=True)
class IterateCmd:
    """`iterate [N] [adapt=R]`: run up to N SQP iterations on the current window."""

    n: int = 1
    text: str = ""
    adapt: int | None = None        # at most this many adaptive re-solves (None: the settings')


@dataclass(frozen=True)
class HoldCmd:
    """`hold P at POINT on [A, B] [mass=M]`: an object carried by a linkage point."""

    point: str                      # the held object: DOF PX, PY (, PZ) for point P
    at: str                         # a linkage point, e.g. arm.tip (arm.tip.x, arm.tip.y, …)
    interval: Interval
    weight: sp.Expr | None          # accepted and unused (it weighed a tracking objective once)
    text: str = ""
    mass: sp.Expr | None = None     # loads the holder's generalized forces while held


@dataclass(frozen=True)
class BallisticCmd:
    """`ballistic P on [A, B]`: free flight of the object P under gravity."""

    point: str
    interval: Interval
    text: str = ""


@dataclass(frozen=True)
class ContactCmd:
    """`contact POINT on ground [y=H] on [A, B] x=X0 [friction=MU] [support=[L, R]] [dense_tol=D]`:
    a point planted on the ground."""

    point: str                      # a linkage point, e.g. acro.FOOT
    height: sp.Expr | None          # the ground's height (None: 0)
    interval: Interval
    friction: sp.Expr | None        # Coulomb coefficient (None: 1)
    x: sp.Expr | None               # where the point is planted
    text: str = ""
    dense_tol: sp.Expr | None = None   # the ground force's own continuous-time tolerance (N)
    support: Interval | None = None    # the foot's sole along the ground, about the point (None: [0, 0])
    force: str | None = None           # a second foot's ground force: DOF FX, FY (FM)
    angle: sp.Expr | None = None       # a second foot's angle while planted (None: at the touchdown)


@dataclass(frozen=True)
class FlightCmd:
    """`flight LINKAGE on [A, B] [dense_tol=D]`: nothing outside acts on the creature."""

    linkage: str
    interval: Interval
    text: str = ""
    dense_tol: sp.Expr | None = None   # its own continuous-time tolerance


@dataclass(frozen=True)
class AvoidCmd:
    """`avoid LINK (LINK | ground [y=H]) [by=D] [on [A, B]] [dense_tol=E]`: two links, or a link and
    the ground, kept at least D apart."""

    first: str                      # a link, named by its joint: fig.LARM
    second: str                     # another link, or "ground"
    height: sp.Expr | None          # the ground's height (None: 0)
    by: sp.Expr | None              # the least distance (None: the default)
    interval: Interval | None       # when (None: the whole animation)
    text: str = ""
    dense_tol: sp.Expr | None = None


@dataclass(frozen=True)
class LimitCmd:
    """`limit DOF A B`: a range for a DOF (a joint's limits)."""

    dof: str
    lo: sp.Expr
    hi: sp.Expr
    text: str = ""


@dataclass(frozen=True)
class SlideCmd:
    """`slide WINDOW by DT [to T] [iterate N]`: solve a window moved step by step along time."""

    window: str
    by: sp.Expr                     # how far the window moves each time
    to: sp.Expr | None              # where its end stops (None: the end of the animation)
    n: int = 10                     # iterations at each position
    text: str = ""


@dataclass(frozen=True)
class DeleteCmd:
    """`delete NAME`: delete a definition that nothing else uses."""

    name: str
    text: str = ""


@dataclass(frozen=True)
class PrintCmd:
    """`print EXPR [@ T | on [A, B]]` or `print CONSTRAINT`: a value, a summary or a check."""

    expr: sp.Expr | None            # None: `print NAME` of a constraint (its continuous-time check)
    at: sp.Expr | None
    expr_text: str
    text: str = ""
    interval: Interval | None = None   # summary over [A, B] instead of the whole span
    column: int | None = field(default=None, compare=False)   # where the expression starts (errors)


@dataclass(frozen=True)
class HelpCmd:
    """`help [COMMAND]`: list the commands, or document one."""

    topic: str | None
    text: str = ""


Command = (TimeCmd | ConstCmd | DofCmd | LetCmd | ConstraintCmd | ObjectiveCmd | KeyCmd | WindowCmd
           | UseCmd | WeightCmd | DampCmd | FilterCmd | ShakeCmd | RefineCmd | BackendCmd | SetCmd
           | IterateCmd | DeleteCmd | PrintCmd | HelpCmd | InstancesCmd | SlideCmd | HoldCmd
           | BallisticCmd | ContactCmd | FlightCmd | AvoidCmd | LimitCmd)

COMMAND_NAMES = ("time", "const", "dof", "let", "constraint", "objective", "key", "window", "use",
                 "weight", "damp", "filter", "shake", "refine", "backend", "set", "iterate", "delete",
                 "print", "help", "linkage", "instances", "slide", "hold", "ballistic", "contact", "flight", "avoid", "limit")
# `contact`, `flight` and `avoid` became verbs after sessions had named constraints so; a line's
# first word is its command, so they stay free as names.
RESERVED = (set(COMMAND_NAMES) - {"contact", "flight", "avoid"}) | set(FUNCTIONS) | {"t", "pi", "all", "on", "when",
                                                                          "and", "or", "not"}


MAX_COUNT = 100_000_000    # other counts (multiplicity): larger is surely a typo
MAX_SEED = 2**63 - 1
# Counts bounded by a limit of stw_tui.sym.limits, by option or setting name.
_COUNT_LIMITS = {"knots": "knots", "samples": "samples", "adapt": "adapt_rounds",
                 "adaptive_rounds": "adapt_rounds"}
_NUMERIC_RULE = "a time, value or weight may use only numbers and constants"


class CommandParser(ExpressionParser):
    """Parses one command line into a command dataclass."""

    def __init__(self, text: str, scope: Scope, line: int | None):
        super().__init__(tokenize(text, line=line), scope, line=line, source=text)
        self.text = strip_comment(text).strip()

    # --- small pieces ------------------------------------------------------------------------
    def name(self, what: str = "a name") -> Token:
        """The next token as a name; ``what`` says what was expected if it is not one."""
        if self.token.kind != NAME:
            raise self.unexpected(what)
        return self.advance()

    def new_name(self, what: str) -> str:
        """A name for a new definition: not reserved, without a dot."""
        token = self.name(what)
        if token.text in RESERVED or "." in token.text:
            raise self.error(f"'{token.text}' cannot be used as a name", token, expected=what)
        return token.text

    def dof_name(self) -> str:
        """The name of a declared DOF."""
        token = self.name("a DOF name")
        if self.scope.kind_of(token.text) is not NameKind.DOF:
            raise self.error(f"'{token.text}' is not a DOF", token, expected="a DOF name")
        return token.text

    def integer(self, what: str, limit: int = MAX_COUNT, limit_name: str | None = None) -> int:
        """A whole number up to ``limit``, or up to the limit ``limit_name`` (stw_tui.sym.limits)."""
        token = self.token
        if token.kind != NUMBER or not token.text.isdigit():
            raise self.unexpected(what)
        self.check_count(token, limit_name, what)
        if len(token.text) > len(str(limit)) or int(token.text) > limit:
            raise self.error("number too large", token, expected=f"{what} up to {limit}")
        self.advance()
        return int(token.text)

    def check_count(self, token: Token, limit_name: str | None, what: str = "a number") -> None:
        """Refuse a digits token over the limit ``limit_name`` (None: no limit), at its column."""
        if limit_name is None or not token.text.isdigit():
            return
        most, ceiling = limits.value(limit_name), limits.LIMITS[limit_name].ceiling
        if len(token.text.lstrip("0")) > len(str(most)) or int(token.text) > most:
            raise_it = f"; `set limit {limit_name} N` raises it up to {ceiling}" if most < ceiling else ""
            raise self.error("number too large", token,
                             expected=f"{what} up to {most}, the limit {limit_name}{raise_it}")

    def number_expr(self) -> sp.Expr:
        """An expression of numbers and constants (a time, a value, a weight)."""
        with self.restricted((NameKind.CONST,), time=False, rule=_NUMERIC_RULE):
            return self.expression()

    def interval(self) -> Interval:
        """An interval ``[A, B]`` of number expressions."""
        self.expect_op("[", "'['")
        a = self.number_expr()
        self.expect_op(",", "',' between the interval's ends")
        b = self.number_expr()
        self.expect_op("]", "']'")
        return a, b

    def finish(self) -> None:
        """Refuse anything left on the line after a complete command."""
        if self.token.kind != END:
            raise self.unexpected("end of line")

    def options(self, allowed: dict[str, str]) -> dict[str, object]:
        """`key=value` options in any order; ``allowed`` maps key to "int", "seed", "expr",
        "interval" (``[A, B]``) or "name" (a new name, such as a force's DOF prefix)."""
        found: dict[str, object] = {}
        while self.token.kind == NAME and self.token.text in allowed:
            key = self.advance()
            if key.text in found:
                raise self.error(f"'{key.text}' given twice", key)
            self.expect_op("=", f"'=' after {key.text}")
            kind = allowed[key.text]
            if kind == "name":
                found[key.text] = self.name(f"a name after {key.text}=").text
                continue
            found[key.text] = self.number_expr() if kind == "expr" else self.interval() if kind == "interval" else \
                self.integer(f"a whole number for {key.text}", MAX_SEED if kind == "seed" else MAX_COUNT,
                             _COUNT_LIMITS.get(key.text) if kind == "int" else None)
        return found

    # --- commands ----------------------------------------------------------------------------
    def parse(self):
        """The line as a command dataclass, or None when it is blank or only a comment."""
        if self.token.kind == END:
            return None
        word = self.token
        if word.kind != NAME or word.text not in _PARSERS:
            close = difflib.get_close_matches(word.text, COMMAND_NAMES, n=2)
            hint = f" (did you mean {' or '.join(repr(c) for c in close)}?)" if close else ""
            raise self.error(f"unknown command '{word.text}'{hint}", word,
                             expected="a command; `help` lists them")
        self.advance()
        command = _PARSERS[word.text](self)
        self.finish()
        return command

    def p_time(self):
        """`time START END [knots=N] [samples=K]`."""
        start = self.number_expr()
        end = self.number_expr()
        opts = self.options({"knots": "int", "samples": "int"})
        return TimeCmd(start, end, opts.get("knots"), opts.get("samples"), self.text)

    def p_const(self):
        """`const NAME = VALUE[, NAME = VALUE…]`; later values may use earlier names."""
        items: dict[str, sp.Expr] = {}
        outer = self.scope
        earlier = DictScope({}, parent=outer)   # the items so far, which later ones may use
        try:
            while True:
                token = self.name("a constant name")
                if token.text in RESERVED or "." in token.text:
                    raise self.error(f"'{token.text}' cannot be used as a name", token)
                kind = outer.kind_of(token.text)
                if kind not in (None, NameKind.CONST):
                    raise self.error(f"'{token.text}' is already a {kind.value}", token)
                if token.text in items:
                    raise self.error(f"'{token.text}' given twice", token)
                self.expect_op("=", f"'=' after {token.text}")
                items[token.text] = self.number_expr()
                # The interpreter applies the items in order, so later ones may use earlier ones.
                earlier.kinds[token.text] = NameKind.CONST
                self.scope = earlier
                if not self.token.is_op(","):
                    break
                self.advance()
        finally:
            self.scope = outer
        return ConstCmd(tuple(items.items()), self.text)

    def p_dof(self):
        """`dof NAME[, NAME…] [= EXPR] [knots=N] [lo=A] [hi=B]`."""
        names = [self.new_name("a DOF name")]
        while self.token.is_op(","):
            self.advance()
            token = self.token
            names.append(self.new_name("a DOF name"))
            if names[-1] in names[:-1]:
                raise self.error(f"'{names[-1]}' given twice", token)
        init = None
        if self.token.is_op("="):
            self.advance()
            with self.restricted((NameKind.CONST,), time=True,
                                 rule="an initial curve may use only t and constants"):
                init = self.expression()
        opts = self.options({"knots": "int", "lo": "expr", "hi": "expr"})
        return DofCmd(tuple(names), init, opts.get("knots"), opts.get("lo"), opts.get("hi"), self.text)

    def p_let(self):
        """`let NAME = EXPR`."""
        name = self.new_name("a subexpression name")
        self.expect_op("=", "'='")
        return LetCmd(name, self.expression(), self.text)

    def _scope_clause(self):
        at = interval = None
        if self.token.is_op("@"):
            self.advance()
            at = self.number_expr()
        elif self.token.is_word("on"):
            self.advance()
            interval = self.interval()
        return at, interval

    def p_constraint(self):
        """`constraint NAME: REL[, REL…] (@ T | on [A, B]) [when COND] [OPTION=VALUE…]`."""
        name = self.new_name("a constraint name")
        self.expect_op(":", "':' after the constraint name")
        relations = [self._relation()]
        while self.token.is_op(","):
            self.advance()
            relations.append(self._relation())
        at, interval = self._scope_clause()
        if at is None and interval is None:
            raise self.unexpected("'@ TIME' or 'on [A, B]'")
        when = None
        if self.token.is_word("when"):
            self.advance()
            when = self.condition()
        opts = self.options({"weight": "expr", "samples": "int", "dense_tol": "expr"})
        return ConstraintCmd(name, tuple(relations), at, interval, when, opts.get("weight"), self.text,
                             opts.get("samples"), opts.get("dense_tol"))

    def _relation(self) -> Relation:
        column = self.token.column
        left = self.expression()
        kinds = {"=": "eq", ">=": "ge", "<=": "le"}
        if not self.token.is_op(*kinds):
            raise self.unexpected("'=', '>=' or '<='")
        kind = kinds[self.advance().text]
        right = self.expression()
        return Relation(left - right, kind, column)

    def p_objective(self):
        """`objective NAME: [minimize|maximize] EXPR[, EXPR…] [on [A, B] | @ T] [weight=W]`."""
        name = self.new_name("an objective name")
        self.expect_op(":", "':' after the objective name")
        sense = None
        # a keyword when an expression follows it (a DOF may still be named `maximize`)
        if self.token.is_word("minimize", "maximize") and (
                self.tokens[self.pos + 1].kind in (NAME, NUMBER) or self.tokens[self.pos + 1].is_op("(", "-")):
            sense = self.advance().text
        exprs = [self.expression()]
        while self.token.is_op(","):
            if sense is not None:
                raise self.error(f"{sense} takes one expression (define one objective for each)", self.token)
            self.advance()
            exprs.append(self.expression())
        interval = at = None
        if self.token.is_word("on"):
            self.advance()
            interval = self.interval()
        elif self.token.is_op("@"):
            self.advance()
            at = self.number_expr()
        weight = self.options({"weight": "expr"}).get("weight")
        return ObjectiveCmd(name, tuple(exprs), interval, weight, self.text, at, sense)

    def p_key(self):
        """`key T DOF=V[, DOF=V…]`."""
        time = self.number_expr()
        assignments = []
        while self.token.kind == NAME:
            dof = self.dof_name()
            self.expect_op("=", f"'=' after {dof}")
            assignments.append((dof, self.number_expr()))
            if self.token.is_op(","):
                self.advance()
                if self.token.kind != NAME:
                    raise self.unexpected("DOF=VALUE after ','")
        if not assignments:
            raise self.unexpected("DOF=VALUE")
        return KeyCmd(time, tuple(assignments), self.text)

    def p_window(self):
        """`window NAME [dofs=a,b|all] [[A, B]]`."""
        name = self.new_name("a window name") if not self.token.is_word("all") else self.advance().text
        dofs: tuple[str, ...] | None = None
        if self.token.is_word("dofs"):
            self.advance()
            self.expect_op("=", "'=' after dofs")
            if self.token.is_word("all"):
                self.advance()
            else:
                names = [self.dof_name()]
                while self.token.is_op(","):
                    self.advance()
                    names.append(self.dof_name())
                dofs = tuple(names)
        interval = self.interval() if self.token.is_op("[") else None
        return WindowCmd(name, dofs, interval, self.text)

    def p_use(self):
        """`use NAME`."""
        return UseCmd(self.name("a window name").text, self.text)

    def p_weight(self):
        """`weight NAME W`."""
        return WeightCmd(self.name("a constraint or objective name").text, self.number_expr(), self.text)

    def p_damp(self):
        """`damp DOF D`."""
        return DampCmd(self.dof_name(), self.number_expr(), self.text)

    def p_filter(self):
        """`filter DOF [PASSES]`."""
        dof = self.dof_name()
        passes = self.integer("a number of passes", limit_name="filter_passes") \
            if self.token.kind == NUMBER else 1
        return FilterCmd(dof, passes, self.text)

    def p_shake(self):
        """`shake [DOF…] amplitude=A [seed=S]`."""
        names = []
        while self.token.kind == NAME and self.token.text not in ("amplitude", "seed"):
            names.append(self.dof_name())
            if self.token.is_op(","):
                self.advance()
        opts = self.options({"amplitude": "expr", "seed": "seed"})
        if "amplitude" not in opts:
            raise self.unexpected("amplitude=A")
        return ShakeCmd(tuple(names), opts["amplitude"], opts.get("seed"), self.text)

    def p_refine(self):
        """`refine DOF [[A, B]]` or `refine DOF @ T [multiplicity=M]`."""
        dof = self.dof_name()
        if self.token.is_op("@"):
            self.advance()
            at = self.number_expr()
            opts = self.options({"multiplicity": "int"})
            return RefineCmd(dof, None, self.text, at, opts.get("multiplicity", 1))
        interval = self.interval() if self.token.is_op("[") else None
        return RefineCmd(dof, interval, self.text)

    def p_backend(self):
        """`backend NAME [OPTION=VALUE…]`; a value is a name or a signed number."""
        name = self.name("a backend name").text
        options = []
        while self.token.kind == NAME:
            key = self.advance()
            self.expect_op("=", f"'=' after {key.text}")
            value = self.token
            if value.kind == END:
                raise self.unexpected(f"a value for {key.text}")
            sign = ""
            if value.is_op("-"):
                sign = self.advance().text
                value = self.token
            if value.kind not in (NAME, NUMBER):
                raise self.unexpected(f"a value for {key.text}")
            options.append((key.text, sign + self.advance().text))
        return BackendCmd(name, tuple(options), self.text)

    def p_set(self):
        """`set OPTION VALUE`, and `set limit NAME VALUE`."""
        option = self.name("a setting name").text
        if option == "limit":
            return self._set_limit()
        token = self.token
        self.check_count(token, _COUNT_LIMITS.get(option), f"a whole number for {option}")
        sign = ""
        if token.is_op("-"):
            sign = self.advance().text
            token = self.token
        if token.kind not in (NAME, NUMBER):
            raise self.unexpected("a value")
        return SetCmd(option, sign + self.advance().text, self.text)

    def _set_limit(self):
        """`set limit NAME VALUE`: a limit of stw_tui.sym.limits, within its floor and ceiling."""
        name = self.name("a limit name (`help limits` lists them)")
        if name.text not in limits.LIMITS:
            close = difflib.get_close_matches(name.text, list(limits.LIMITS), n=2)
            hint = f" (did you mean {' or '.join(repr(c) for c in close)}?)" if close else ""
            raise self.error(f"unknown limit '{name.text}'{hint}", name,
                             expected="a limit name; `help limits` lists them")
        limit = limits.LIMITS[name.text]
        value = self.integer(f"a whole number for limit {name.text}", limit.ceiling)
        if value < limit.floor:   # lower, and no line could raise it again (`set limit` itself)
            raise self.error(f"limit {name.text} must be at least {limit.floor}", self.tokens[self.pos - 1],
                             expected=f"{limit.floor} to {limit.ceiling}")
        return SetCmd("limit", f"{name.text} {value}", self.text)

    def p_iterate(self):
        """`iterate [N] [adapt=R]`."""
        n = self.integer("a number of iterations", limit_name="iterations") \
            if self.token.kind == NUMBER else 1
        opts = self.options({"adapt": "int"})
        return IterateCmd(n, self.text, opts.get("adapt"))

    def p_hold(self):
        """`hold P at POINT on [A, B] [mass=M]`."""
        point = self.new_name("the held object (P for DOF PX, PY)")
        if not self.token.is_word("at"):
            raise self.unexpected("'at POINT' (a linkage point such as arm.tip)")
        self.advance()
        at = self.name("a linkage point such as arm.tip").text
        if not self.token.is_word("on"):
            raise self.unexpected("'on [A, B]'")
        self.advance()
        interval = self.interval()
        opts = self.options({"mass": "expr", "weight": "expr"})
        return HoldCmd(point, at, interval, opts.get("weight"), self.text, opts.get("mass"))

    def p_ballistic(self):
        """`ballistic P on [A, B]`."""
        point = self.new_name("the flying object (P for DOF PX, PY)")
        if not self.token.is_word("on"):
            raise self.unexpected("'on [A, B]'")
        self.advance()
        return BallisticCmd(point, self.interval(), self.text)

    def p_contact(self):
        """`contact POINT on ground [y=H] on [A, B] [x=X0] [friction=MU] [support=[L, R]] [dense_tol=D]
        [force=F] [angle=PHI]`."""
        point = self.name("a linkage point such as acro.FOOT").text
        for word, expected in (("on", "'on ground'"), ("ground", "'ground' (the surface y = H)")):
            if not self.token.is_word(word):
                raise self.unexpected(expected)
            self.advance()
        height = self.options({"y": "expr"}).get("y")
        if not self.token.is_word("on"):
            raise self.unexpected("'on [A, B]'")
        self.advance()
        interval = self.interval()
        opts = self.options({"friction": "expr", "x": "expr", "dense_tol": "expr", "support": "interval",
                              "force": "name", "angle": "expr"})
        return ContactCmd(point, height, interval, opts.get("friction"), opts.get("x"), self.text,
                          opts.get("dense_tol"), opts.get("support"), opts.get("force"), opts.get("angle"))

    def p_flight(self):
        """`flight LINKAGE on [A, B] [dense_tol=D]`."""
        linkage = self.name("a linkage name").text
        if not self.token.is_word("on"):
            raise self.unexpected("'on [A, B]'")
        self.advance()
        interval = self.interval()
        opts = self.options({"dense_tol": "expr"})
        return FlightCmd(linkage, interval, self.text, opts.get("dense_tol"))

    def p_avoid(self):
        """`avoid LINK (LINK | ground [y=H]) [by=D] [on [A, B]] [dense_tol=E]`."""
        first = self.name("a link, named by its joint, such as fig.LARM").text
        second = self.name("another link (fig.TRUNK) or 'ground'").text
        height = self.options({"y": "expr"}).get("y") if second == "ground" else None
        opts = self.options({"by": "expr"})
        interval = None
        if self.token.is_word("on"):
            self.advance()
            interval = self.interval()
        opts |= self.options({"by": "expr", "dense_tol": "expr"} if "by" not in opts else {"dense_tol": "expr"})
        return AvoidCmd(first, second, height, opts.get("by"), interval, self.text, opts.get("dense_tol"))

    def p_limit(self):
        """`limit DOF A B`."""
        dof = self.dof_name()
        start = self.token
        lo = self.number_expr()
        if self.token.kind == END:   # `limit Q -2.9 -0.9` reads as one bound, -2.9 - 0.9
            raise self.error("limit needs two bounds, A and B; a negative B after A reads as a "
                             "subtraction (-2.9 -0.9 is -3.8): put it in parentheses", start,
                             expected=f"limit {dof} A B, e.g. limit {dof} -2.9 (-0.9)")
        hi = self.number_expr()
        return LimitCmd(dof, lo, hi, self.text)

    def p_slide(self):
        """`slide WINDOW by DT [to T] [iterate N]`."""
        window = self.name("a window name").text
        if not self.token.is_word("by"):
            raise self.unexpected("'by DT'")
        self.advance()
        by = self.number_expr()
        to = None
        if self.token.is_word("to"):
            self.advance()
            to = self.number_expr()
        n = 10
        if self.token.is_word("iterate"):
            self.advance()
            n = self.integer("a number of iterations")
        return SlideCmd(window, by, to, n, self.text)

    def p_instances(self):
        """`instances NAME add T[, T…]` or `instances NAME clear`."""
        name = self.name("a constraint name (or DOF.bounds)").text
        action = self.token
        if not (action.is_word("add") or action.is_word("clear")):
            raise self.unexpected("'add' or 'clear'")
        self.advance()
        times = []
        if action.text == "add":
            times.append(self.number_expr())
            while self.token.is_op(","):
                self.advance()
                times.append(self.number_expr())
        return InstancesCmd(name, action.text, tuple(times), self.text)

    def p_delete(self):
        """`delete NAME`."""
        return DeleteCmd(self.name("the name of something to delete").text, self.text)

    def p_print(self):
        """`print EXPR [@ T | on [A, B]]`, or `print NAME` of a constraint (its check)."""
        first = self.token
        if (first.kind == NAME and self.scope.kind_of(first.text) is None
                and ("." not in first.text or first.text.endswith(".bounds"))
                and self.tokens[self.pos + 1].kind == END):
            self.advance()   # `print NAME` of a constraint: its continuous-time check
            return PrintCmd(None, None, first.text, self.text)
        start = self.token.column
        expr = self.expression()
        end = self.token.column
        expr_text = printable(self.source[start - 1:end - 1].strip())   # echoed: no raw \r, \t
        at, interval = self._scope_clause()
        return PrintCmd(expr, at, expr_text, self.text, interval, start)

    def p_help(self):
        """`help [COMMAND]`."""
        topic = self.advance().text if self.token.kind == NAME else None
        return HelpCmd(topic, self.text)

    def p_linkage(self):
        """Refuse `linkage` as one line: the session reads the block over several lines."""
        raise self.error("a `linkage` block spans several lines; it is read by the session, "
                         "not as a single command")


_PARSERS = {name: getattr(CommandParser, f"p_{name}") for name in COMMAND_NAMES}

# Commands on the session rather than the scene: undo, redo, snapshots, export, save.
from stw_tui.sym.language.session_commands import *  # noqa: E402,F401,F403  (their dataclasses)
from stw_tui.sym.language.session_commands import SESSION_PARSERS, parse_file_command  # noqa: E402

_PARSERS.update(SESSION_PARSERS)
COMMAND_NAMES += tuple(SESSION_PARSERS)
RESERVED |= set(SESSION_PARSERS)


def parse_command(text: str, scope: Scope, *, line: int | None = None):
    """Parse one line of the session language.

    Returns:
        A command dataclass, or None for a blank or comment-only line.
    Raises:
        SourceError: with line, column and what was expected.
    """
    file_command = parse_file_command(text, line)   # export, save: a path is not a token
    if file_command is not None:
        return file_command
    return CommandParser(text, scope, line).parse()
