"""The symbolic console: `show NAME`, `show EXPR [@ T]` and `cse NAME|EXPR`.

`show` prints what a name is, as the compiler sees it: a constraint's relations (as written and
with every subexpression substituted), its scope, instance count and weight; an objective's
terms; a DOF's knots, control points and bounds; a subexpression's definition; a motion verb's
line and the constraints it expanded into. `show EXPR` prints any expression's expanded form (and
its value at T), `show diff(EXPR, VAR)` its partial derivative by a DOF quantity (x, x', x''), t
or a constant; `cse` the common subexpressions the compiler shares when it compiles a term.

These commands only read the scene (never a step of the history) and never evaluate text as
code: expressions come from the language's parser.
"""

from __future__ import annotations

import numpy as np
import symengine as se
import sympy as sp

from stw_tui.session.outcome import Outcome, PrintResult
from stw_tui.session.protocol import SessionLike
from stw_tui.session.verbs import verb_of
from stw_tui.sos.instances import relation_times
from stw_tui.sos.scene import Scene
from stw_tui.sym.compiler import _to_symengine
from stw_tui.sym.errors import StwError
from stw_tui.sym.kinds import TermKind
from stw_tui.sym.linkage.kinematics import to_sympy


WIDTH = 100           # wider pretty forms are printed on one line
MAX_CHARS = 4000      # longer one-line forms are cut (`cse` shows their parts)
SIMPLIFY_OPS = 60     # sympy's simplify on larger expressions may take minutes: shown as they are
MAX_CSE_LINES = 80


def simplified(expr: sp.Basic) -> sp.Basic:
    """``expr`` simplified when it is small enough for that to be quick, else as it is."""
    if sp.count_ops(expr) > SIMPLIFY_OPS:
        return expr
    return sp.simplify(expr)


def render(expr: sp.Basic, indent: str = "  ") -> str:
    """Sympy's (ASCII) pretty form, indented; one line when that is wider than the terminal."""
    pretty = sp.pretty(expr, use_unicode=False, wrap_line=False)
    lines = pretty.splitlines()
    if max((len(line) for line in lines), default=0) <= WIDTH and len(lines) <= 12:
        return "\n".join(indent + line.rstrip() for line in lines)
    flat = sp.sstr(expr)
    if len(flat) > MAX_CHARS:
        flat = flat[:MAX_CHARS] + f"… ({len(flat)} characters; `cse` shows its parts)"
    return indent + flat


def _relation_text(expr: sp.Basic, kind: TermKind) -> str:
    return f"{sp.sstr(expr)} {'=' if kind is TermKind.EQ else '>='} 0"


def _forms(scene: Scene, written: sp.Basic, suffix: str = "", scope=None) -> list[str]:
    """The forms of an expression below its written one: as compiled (every subexpression
    substituted; read on ``scope``, see Scene.expand), when that differs, and simplified, when
    that is quick and differs."""
    expanded = scene.expand(written, scope)
    lines = []
    if expanded != written:
        lines += ["  as compiled:", render(expanded, "    ") + suffix]
    simple = simplified(expanded)
    if simple != expanded:
        lines += ["  simplified:", render(simple, "    ") + suffix]
    return lines


def _show_constraint(scene: Scene, name: str) -> list[str]:
    c = scene.constraints[name]
    counts = [relation_times(scene, c, rel.expr, rel.kind).size for rel in c.relations]
    head = (f"constraint {name} {c.scope_text}" + (f" when {sp.sstr(c.when)}" if c.when is not None else "")
            + f", weight {c.weight:g}, {sum(counts)} instance(s)"
            + (f" ({', '.join(map(str, counts))} per relation)" if len(set(counts)) > 1 else ""))
    lines = [head]
    for rel in c.relations:
        lines.append(f"  {_relation_text(rel.expr, rel.kind)}")
        lines += _forms(scene, rel.expr, "  = 0" if rel.kind is TermKind.EQ else "  >= 0",
                        c.span)
    return lines


def _show_objective(scene: Scene, name: str) -> list[str]:
    o = scene.objectives[name]
    if o.sense is not None:
        where = f"at t={o.at:g} (a terminal cost)" if o.at is not None else "integrated over " + (
            f"[{o.interval[0]:g}, {o.interval[1]:g}]" if o.interval else f"[{scene.t0:g}, {scene.t1:g}]")
        lines = [f"objective {name}: {o.sense} its term, weight {o.weight:g}, {where}; it enters the merit "
                 f"as {'-' if o.sense == 'maximize' else ''}{o.weight:g} times its value, not squared"]
        for expr in o.exprs:
            lines.append(f"  {sp.sstr(expr)}")
            lines += _forms(scene, expr, scope=(o.at, o.at) if o.at is not None else o.interval)
        return lines
    if o.at is not None:
        lines = [f"objective {name}: minimize weight {o.weight:g} times the square of "
                 f"{'each term' if len(o.exprs) > 1 else 'its term'} at t={o.at:g} (a terminal cost)"]
        for expr in o.exprs:
            lines.append(f"  {sp.sstr(expr)}")
            lines += _forms(scene, expr, scope=(o.at, o.at))
        return lines
    where = f"[{o.interval[0]:g}, {o.interval[1]:g}]" if o.interval else f"[{scene.t0:g}, {scene.t1:g}]"
    lines = [f"objective {name}: minimize weight {o.weight:g} times the integral over {where} of the "
             f"square of {'each term' if len(o.exprs) > 1 else 'its term'}"]
    for expr in o.exprs:
        lines.append(f"  {sp.sstr(expr)}")
        lines += _forms(scene, expr, scope=o.interval)
    return lines


def _show_dof(scene: Scene, name: str) -> list[str]:
    dof = scene.dofs[name]
    curve = dof.curve
    distinct, counts = np.unique(curve.knots, return_counts=True)
    knots = ", ".join(f"{k:g}" + (f" (x{n})" if n > 1 else "") for k, n in zip(distinct, counts))
    bounds = [f"lo={dof.lo:g}" if dof.lo is not None else "", f"hi={dof.hi:g}" if dof.hi is not None else ""]
    lines = [f"dof {name}: cubic B-spline on [{curve.t0:g}, {curve.t1:g}], {curve.spans} span(s), "
             f"{curve.n_coef} control points" + "".join(f", {b}" for b in bounds if b)
             + (" (on its control points, so everywhere)" if any(bounds) else "")
             + (f", damp {dof.damp:g}" if dof.damp else ""),
             f"  knots: {knots}",
             "  control points: " + ", ".join(f"{c:.6g}" for c in curve.coef)]
    if dof.keys:
        lines.append("  keys: " + ", ".join(f"{v:g} @ {t:g}" for t, v in dof.keys))
    for group, parts in scene.attachments.items():
        lines += [f"  is {p.expr} on [{p.a:g}, {p.b:g}] (`{scene.verbs[group][0]}`): its curve is read "
                  f"outside that only" for p in parts if p.target == name]
    return lines


def _show_definition(scene: Scene, name: str) -> list[str]:
    if name in scene.constants:
        return [f"const {name} = {scene.constants[name]!r}"]
    definition = scene.lets.get(name, scene.derived.get(name))
    origin = "let" if name in scene.lets else "derived from linkage " + next(
        (link for link in scene.linkages if name.startswith(link + ".")
         or any(name == f"tau_{d}" for d in _linkage_dofs(scene.linkages[link]))), "?")
    return [f"{name} ({origin}) = {sp.sstr(definition)}"[:MAX_CHARS], *_forms(scene, definition)]


def _linkage_dofs(spec) -> list[str]:
    return [j.name for j in spec.joints] + [a.dof for a in spec.base]


def _show_verb(scene: Scene, name: str) -> list[str]:
    line, members = scene.verbs[name]
    parts = scene.attachments.get(name, ())
    lines = [line] + [f"  {d}" for d in dict.fromkeys(p.describe() for p in parts if not p.adds)]
    loads = [p.target for p in parts if p.adds]
    if loads:
        lines.append(f"  its mass loads {', '.join(loads)} there")
    lines.append(f"  expands into {len(members)} named constraint(s) and objective(s):")
    for member in members:
        item = scene.constraints.get(member) or scene.objectives.get(member)
        if item is not None:
            lines.append(f"  {item.text}")
    return lines


def _show_window(scene: Scene, name: str) -> list[str]:
    w = scene.windows[name]
    dofs = ", ".join(w.dofs) if w.dofs else "all DOF"
    interval = f"[{w.interval[0]:g}, {w.interval[1]:g}]" if w.interval else "the whole animation"
    return [f"window {name}: {dofs} over {interval}" + (" (in use)" if scene.active_window == name else "")]


def describe(scene: Scene, name: str) -> list[str]:
    """The lines `show NAME` prints.

    Raises:
        StwError: nothing has that name.
    """
    if name in scene.verbs:
        return _show_verb(scene, name)
    if name in scene.constraints or name in scene.objectives:
        lines = _show_constraint(scene, name) if name in scene.constraints else _show_objective(scene, name)
        group = verb_of(scene, name)
        return lines + ([f"  made by the verb `{scene.verbs[group][0]}` (`delete {group}` removes the group)"]
                        if group is not None else [])
    if name in scene.dofs:
        return _show_dof(scene, name)
    if name in scene.constants or name in scene.lets or name in scene.derived:
        return _show_definition(scene, name)
    if name in scene.windows:
        return _show_window(scene, name)
    if name in scene.linkages:
        spec = scene.linkages[name]
        return [f"linkage {name}: joints {', '.join(j.name for j in spec.joints)}"
                + (f"; base {', '.join(f'{a.axis}:{a.dof}' for a in spec.base)}" if spec.base else "; fixed base")]
    known = list(dict.fromkeys([*scene.verbs, *scene.constraints, *scene.objectives]))[:8]
    raise StwError(f"nothing named '{name}' to show" + (f" (for example {', '.join(known)})" if known else ""))


def show(session: SessionLike, scene: Scene, cmd) -> Outcome:
    """`show NAME` or `show EXPR [@ T]`: read-only."""
    if cmd.name is not None:
        return Outcome(message="\n".join(describe(scene, cmd.name)))
    expr = scene.expand(cmd.expr)
    if cmd.wrt is not None:
        if cmd.wrt.name.rstrip("'") in scene.lets or cmd.wrt.name.rstrip("'") in scene.derived:
            raise StwError(f"diff by '{cmd.wrt.name}': differentiate by a DOF quantity, t or a constant, "
                           "not a subexpression")
        expr = sp.diff(expr, cmd.wrt)
    lines = [f"{cmd.expr_text} =", render(simplified(expr))]
    prints = []
    if cmd.at is not None:
        t = scene.numeric(cmd.at, "time")
        if not scene.t0 - 1e-12 <= t <= scene.t1 + 1e-12:
            raise StwError(f"time {t:g} is outside the animation span [{scene.t0:g}, {scene.t1:g}]")
        value = float(scene.evaluate(expr, np.array([min(max(t, scene.t0), scene.t1)]))[0])
        if not np.isfinite(value):
            raise StwError(f"{cmd.expr_text} is not a finite real number at t={t:g}")
        lines.append(f"  @ {t:g} = {value:.10g}")
        prints.append(PrintResult(cmd.expr_text, t, value))
    return Outcome(message="\n".join(lines), prints=prints)


def _terms(scene: Scene, cmd) -> list[tuple[str, sp.Basic]]:
    """(label, expanded expression) of each term `cse` looks at."""
    if cmd.name is None:
        return [(cmd.expr_text, scene.expand(cmd.expr))]
    name = cmd.name
    if name in scene.constraints:
        relations = scene.constraints[name].relations
        return [(name if len(relations) == 1 else f"{name}[{i + 1}]", scene.expand(r.expr))
                for i, r in enumerate(relations)]
    if name in scene.objectives:
        exprs = scene.objectives[name].exprs
        return [(name if len(exprs) == 1 else f"{name}[{i + 1}]", scene.expand(e)) for i, e in enumerate(exprs)]
    if scene.kind_of(name) is not None:
        return [(name, scene.expand(sp.Symbol(name, real=True)))]
    raise StwError(f"nothing named '{name}': cse takes a constraint, an objective, a subexpression "
                   "or an expression")


def common_subexpressions(exprs: list[sp.Basic]) -> tuple[list[tuple[sp.Symbol, sp.Basic]], list[sp.Basic]]:
    """symengine's CSE of the terms (what the compiler's Lambdify(cse=True) shares), as sympy."""
    replacements, reduced = se.cse([_to_symengine(e) for e in exprs])
    memo: dict = {}   # converted node by node (linkage.kinematics.to_sympy): no text is ever parsed
    return ([(to_sympy(s, memo), to_sympy(e, memo)) for s, e in replacements],
            [to_sympy(e, memo) for e in reduced])


def cse(session: SessionLike, scene: Scene, cmd) -> Outcome:
    """`cse NAME|EXPR`: the shared subexpressions x0, x1, … and each term in terms of them."""
    terms = _terms(scene, cmd)
    replacements, reduced = common_subexpressions([e for _, e in terms])
    lines = [f"{len(replacements)} common subexpression(s)"]
    for symbol, value in replacements[:MAX_CSE_LINES]:
        lines.append(f"  {symbol} = {sp.sstr(value)}"[:MAX_CHARS])
    if len(replacements) > MAX_CSE_LINES:
        lines.append(f"  … and {len(replacements) - MAX_CSE_LINES} more")
    for (label, _), expr in zip(terms, reduced):
        lines.append(f"  {label} = {sp.sstr(expr)}"[:MAX_CHARS])
    return Outcome(message="\n".join(lines))
