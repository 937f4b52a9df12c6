"""Applying parsed commands to a scene. Each handler works on a scene copy owned by the caller.

Handlers validate everything before they change anything they cannot undo, and raise StwError
with a message naming what is wrong; :class:`~stw_tui.session.session.Session` discards the copy then.
"""

from __future__ import annotations

from dataclasses import dataclass, replace


import numpy as np
import sympy as sp

from stw_tui.session.midsolve import Trail, hook_for
from stw_tui.session.outcome import Outcome, PrintResult
from stw_tui.session.protocol import SessionLike
from stw_tui.session.verbs import owned_by_verb
from stw_tui.sos.backend import (RunResult, SolverState, Status, WarmStart, create_backend, load_backend,
                                 run_iterations)
from stw_tui.sos.batch import joined_backend
from stw_tui.sos import refinement
from stw_tui.sos.attachments import pieces
from stw_tui.sos.continuous import DenseReport, check_scene, survey_failures
from stw_tui.sos.instances import dofs_used
from stw_tui.sos.scene import DEFAULT_SETTINGS, Constraint, Dof, Objective, Relation, Scene, Window
from stw_tui.sos.spline import DofCurve
from stw_tui.sos.window import WindowProblem
from stw_tui.sym import language as lang
from stw_tui.sym import limits
from stw_tui.sym.compiler import compile_term, free_symbols
from stw_tui.sym.errors import LimitError, SolveError, SourceError, StwError
from stw_tui.sym.kinds import Capability, TermKind
from stw_tui.sym.symbols import dof_symbol, dof_symbols, named_symbol


_KINDS = {"dof": lang.NameKind.DOF, "const": lang.NameKind.CONST, "let": lang.NameKind.LET}


class SceneScope:
    """The parser's view of which names a scene defines."""

    def __init__(self, scene: Scene):
        self.scene = scene

    def kind_of(self, name: str):
        """What ``name`` is in the scene (DOF, constant, subexpression…), as the parser's kinds."""
        return _KINDS.get(self.scene.kind_of(name))

    def names(self) -> list[str]:
        """Every name an expression may use: DOF, constants, subexpressions and linkage quantities."""
        s = self.scene
        return [*s.dofs, *s.constants, *s.lets, *s.derived]


def apply_line(session: SessionLike, scene: Scene, text: str, line: int | None, on_report,
               session_handlers: dict | None = None) -> Outcome:
    """Apply one command line to ``scene`` (a copy the caller keeps or drops). Commands that act on
    the session itself (undo, export, survey...) go to ``session_handlers``, by command type: the
    session hands its table in, so this module never imports the modules above it."""

    command = lang.parse_command(text, SceneScope(scene), line=line)
    if command is None:
        return Outcome()
    session_handler = (session_handlers or {}).get(type(command))
    if session_handler is not None:
        if getattr(session_handler, "reports_progress", False):   # survey, adopt
            return session_handler(session, scene, command, on_report)
        return session_handler(session, scene, command)
    handler = _HANDLERS[type(command)]
    if handler in (_iterate, _slide):    # solves: they need the session and report progress
        return handler(session, scene, command, on_report)
    message = handler(scene, command)
    if isinstance(command, lang.PrintCmd):
        return Outcome(message=message[0], prints=[message[1]])
    return Outcome(message=message or "")


def apply_linkage(session: SessionLike, scene: Scene, block) -> Outcome:
    """Add a linkage: its joint (and base) variables become DOF, its kinematics and generalized
    forces become derived subexpressions."""
    from stw_tui.sym.linkage import curve_dofs, derive, dof_names, parse_linkage

    (header_line, header), rows = block[0], block[1:]
    spec = parse_linkage(header, [(ln, text) for ln, text in rows], header_line=header_line)
    if spec.name in scene.linkages or scene.kind_of(spec.name) is not None:
        raise StwError(f"'{spec.name}' is already defined; choose another linkage name")
    if spec.gravity_axis is not None and "g" not in scene.constants:
        raise StwError("the linkage feels gravity g: declare it first, e.g. `const g = 9.81`")
    names = curve_dofs(spec)
    limits.check("dofs", len(scene.dofs) + len(names), "the DOF count")
    taken = [n for n in names + [b.dof for b in spec.base] if scene.kind_of(n) is not None]
    if taken:
        raise StwError(f"linkage DOF {', '.join(taken)} already exist; rename the joints")
    derived = derive(spec)
    derived.update(_base_from_com(spec, derived))
    clash = [n for n in derived if scene.kind_of(n) is not None]
    if clash:
        raise StwError(f"linkage quantities {', '.join(clash[:4])} clash with existing names")
    for name in names:
        scene.dofs[name] = Dof(name, DofCurve.uniform(scene.t0, scene.t1, scene.knots))
    scene.derived.update(derived)
    scene.linkages[spec.name] = spec
    forces = ", ".join(f"tau_{n}" for n in dof_names(spec))
    tree = _branches(spec)
    ends = f"{spec.name}.JOINT.end.* (branched: {tree}), " if tree else ""
    return Outcome(message=f"linkage {spec.name}: DOF {', '.join(names)}; forces {forces}; "
                           f"positions {spec.name}.JOINT.x|y|z, {ends}{spec.name}.tip.*, {spec.name}.com.*")


def _branches(spec) -> str:
    """``HIP -> SHIN, THIGH2; ...``: the joints with more than one child (empty for a chain)."""
    from stw_tui.sym.linkage.spec import child_indices

    names = {i: j.name for i, j in enumerate(spec.joints)} | {-1: "base"}
    return "; ".join(f"{names[up]} -> {', '.join(names[k] for k in kids)}"
                     for up, kids in child_indices(spec).items() if len(kids) > 1)


def _base_from_com(spec, derived: dict) -> dict:
    """With ``com=CX,CY``: each base variable as a subexpression, the centroidal DOF minus where
    the centre of mass sits relative to the base (which depends on the joints only); and each base
    force as what it is, the total outside force along its axis, M·(C'' - gravity), the base's
    own mass in M (``NAME.com`` places it too). That equals the Newton–Euler expression with the
    base substituted, which only cancels to it numerically and grows with every link (a
    three-link lamp's tau_Y: 68k nodes); this one is linear."""
    out = {}
    total = sum(sp.nsimplify(m) for m in [j.mass for j in spec.joints] + [spec.base_mass] if m)
    for axis, com in zip(spec.base, spec.com):
        base = dof_symbol(axis.dof)
        # the weights m_i/M sum to 1 only up to rounding: drop the base's 1e-16 leftover
        offset = sp.expand(derived[f"{spec.name}.com.{'xyz'[axis.index]}"] - base)
        offset = offset.xreplace({base: 0})
        out[axis.dof] = dof_symbol(com) - offset
        gravity = spec.gravity_sign * named_symbol("g") if spec.gravity_axis == axis.index else 0
        out[f"tau_{axis.dof}"] = total * (dof_symbol(com, 2) - gravity)
    return out


# --- helpers ---------------------------------------------------------------------------------
def _evaluate_curve_expr(scene: Scene, expr: sp.Expr):
    """A function of t from an expression of t and constants (compiled, never eval'd)."""
    expr = scene.expand(expr)
    term = compile_term(expr, set(), set(scene.constants))
    params = scene.constant_values(term.parameters)

    def curve(times):
        times = np.asarray(times, float)
        values = term.value(np.zeros((len(times), 0)), times, params)
        bad = np.flatnonzero(~np.isfinite(values))
        if bad.size:   # exp(1000*t), log(t - 1): a curve must be finite everywhere
            what = "not a real number" if np.isnan(values[bad[0]]) else "infinite"
            raise StwError(f"the curve {sp.sstr(expr)[:60]} is {what} at t={times[bad[0]]:.6g}")
        return values
    return curve


def _option(scene: Scene, expr, what: str) -> float | None:
    """An optional number of a command (None when not given)."""
    return scene.numeric(expr, what) if expr is not None else None


def _time_in_span(scene: Scene, value: float, what: str) -> float:
    if not scene.t0 - 1e-12 <= value <= scene.t1 + 1e-12:
        raise StwError(f"{what} {value:g} is outside the animation span [{scene.t0:g}, {scene.t1:g}]")
    return min(max(value, scene.t0), scene.t1)


def _interval(scene: Scene, pair, what: str) -> tuple[float, float]:
    a, b = (scene.numeric(v, f"{what} bound") for v in pair)
    if not a < b:
        raise StwError(f"{what} [{a:g}, {b:g}] is empty: the start must be before the end")
    return _time_in_span(scene, a, f"{what} start"), _time_in_span(scene, b, f"{what} end")


def _check_new_name(scene: Scene, name: str, allowed: tuple[str, ...]) -> None:
    kind = scene.kind_of(name)
    if kind is not None and kind not in allowed:
        raise StwError(f"'{name}' is already a {kind}; choose another name")
    if name in scene.derived:
        raise StwError(f"'{name}' is derived from a linkage and cannot be redefined")
    equations = {**scene.constraints, **scene.objectives}
    if "equation" not in allowed and name in equations:
        raise StwError(f"'{name}' is already a constraint or objective; choose another name")
    owner = owned_by_verb(scene, name)
    if owner:
        raise StwError(owner)
    if name in scene.verbs:
        raise StwError(f"'{name}' names the verb `{scene.verbs[name][0]}`; choose another name")


def _uses_dof(scene: Scene, expr: sp.Basic) -> bool:
    dof_syms = {s for d in scene.dofs for s in dof_symbols(d)}
    # compiler.free_symbols keeps the walk, which compile_term then asks of the same expansion
    return bool(free_symbols(scene.expand(expr)) & dof_syms)


# --- handlers --------------------------------------------------------------------------------
def _time(scene: Scene, cmd) -> str:
    t0, t1 = scene.numeric(cmd.start, "start time"), scene.numeric(cmd.end, "end time")
    if not t0 < t1:
        raise StwError(f"the animation span [{t0:g}, {t1:g}] is empty")
    knots = cmd.knots if cmd.knots is not None else scene.knots
    if max(abs(t0), abs(t1)) > 1e15 or not (t1 - t0) / max(knots, 1) > 1e-9 * max(1.0, abs(t0), abs(t1)):
        raise StwError(f"the animation span [{t0:g}, {t1:g}] cannot hold {knots} knot spans in "
                       "double precision; use times within ±1e15 and spans longer than 1e-9 of them")
    if knots < 1:
        raise StwError("knots must be at least 1")
    if cmd.samples is not None and cmd.samples < 1:
        raise StwError("samples must be at least 1")
    outside = _outside_span(scene, t0, t1)
    if outside:
        raise StwError(f"{', '.join(outside[:3])}{' and more' if len(outside) > 3 else ''} would lie "
                       f"outside the span [{t0:g}, {t1:g}]; change or delete them first")
    for dof in scene.dofs.values():
        old = dof.curve
        dof.curve = DofCurve.fit(t0, t1, knots, lambda t, c=old: c.evaluate(np.clip(t, c.t0, c.t1)))
    scene.t0, scene.t1, scene.knots = t0, t1, knots
    scene.extra_instances.clear()   # they were placed for the old span and knots
    if cmd.samples is not None:
        scene.samples = cmd.samples
    return f"time [{t0:g}, {t1:g}], {knots} knot spans, {scene.sample_count} samples"


def _outside_span(scene: Scene, t0: float, t1: float) -> list[str]:
    """What would no longer fit a new span: constraints, objectives, windows and keys."""
    def out(a: float, b: float) -> bool:
        return a < t0 - 1e-12 or b > t1 + 1e-12

    found = [f"constraint {c.name} {c.scope_text}" for c in scene.constraints.values()
             if out(*c.span)]
    found += [f"objective {o.name}" for o in scene.objectives.values()
              if (o.interval and out(*o.interval)) or (o.at is not None and out(o.at, o.at))]
    found += [f"window {w.name}" for w in scene.windows.values() if w.interval and out(*w.interval)]
    found += [f"a key of {d.name}" for d in scene.dofs.values() if d.keys and out(d.keys[0][0], d.keys[-1][0])]
    return found


REPLACED = " (replaced the old definition; `undo` brings it back)"


def _replaced(previous) -> str:
    """What a command that redefines a name adds to its message: it says so, and how to go back."""
    return REPLACED if previous is not None else ""


def _const(scene: Scene, cmd) -> str:
    was = {}
    for name, expr in cmd.items:
        _check_new_name(scene, name, ("const",))
        if name in scene.constants and name not in was:
            was[name] = scene.constants[name]
        scene.constants[name] = scene.numeric(expr, f"constant {name}")
    changed = [f"{n} was {v:g}" for n, v in was.items() if v != scene.constants[n]]
    return ", ".join(f"{n} = {scene.constants[n]:g}" for n, _ in cmd.items) + (
        f" ({', '.join(changed)}; `undo` brings it back)" if changed else "")


def _dof(scene: Scene, cmd) -> str:
    f = _evaluate_curve_expr(scene, cmd.init) if cmd.init is not None else None
    lo, hi = _bounds(scene, cmd.lo, cmd.hi)
    if cmd.knots is not None and cmd.knots < 1:
        raise StwError("knots must be at least 1")
    limits.check("dofs", len(scene.dofs) + len(set(cmd.names) - set(scene.dofs)), "the DOF count")
    for name in cmd.names:
        _check_new_name(scene, name, ("dof",))
        dof = scene.dofs.get(name)
        spans = cmd.knots or (dof.curve.spans if dof else scene.knots)
        if dof is None:
            curve = DofCurve.fit(scene.t0, scene.t1, spans, f) if f else DofCurve.uniform(
                scene.t0, scene.t1, spans)
            dof = scene.dofs[name] = Dof(name, curve)
        elif f is not None or cmd.knots is not None:
            old = dof.curve
            source = f or (lambda t, c=old: c.evaluate(t))
            dof.curve = DofCurve.fit(scene.t0, scene.t1, spans, source)
        if cmd.lo is not None:
            dof.lo = lo
        if cmd.hi is not None:
            dof.hi = hi
    return f"dof {', '.join(cmd.names)}"


def _bounds(scene: Scene, lo_expr, hi_expr) -> tuple[float | None, float | None]:
    """A DOF's lower and upper bound, as `dof … lo= hi=` and `limit DOF LO HI` give them (None:
    not given); an empty range is refused."""
    lo, hi = _option(scene, lo_expr, "lo"), _option(scene, hi_expr, "hi")
    if lo is not None and hi is not None and not lo < hi:
        raise StwError(f"bounds lo={lo:g} hi={hi:g} are empty: the lower limit must be below the upper")
    return lo, hi


def _let(scene: Scene, cmd) -> str:
    _check_new_name(scene, cmd.name, ("let",))
    previous = scene.lets.get(cmd.name)
    scene.lets[cmd.name] = cmd.expr
    if _refers_to_itself(scene, cmd.name):   # also through a derivative: let f = f'
        raise StwError(f"'{cmd.name}' would be defined in terms of itself")
    try:
        expanded = scene.expand(sp.Symbol(cmd.name, real=True))
    except LimitError:
        raise
    except StwError:
        raise StwError(f"'{cmd.name}' would be defined in terms of itself") from None
    if sp.Symbol(cmd.name, real=True) in expanded.free_symbols:
        raise StwError(f"'{cmd.name}' would be defined in terms of itself")
    return f"let {cmd.name}" + _replaced(previous)


def _refers_to_itself(scene: Scene, name: str) -> bool:
    """Whether subexpression ``name`` uses itself, directly, through other subexpressions or
    through their time derivatives (f', which expansion would differentiate for ever)."""
    definitions = {**scene.derived, **scene.lets}
    seen, todo = set(), [name]
    while todo:
        current = todo.pop()
        for symbol in definitions[current].free_symbols:
            base = symbol.name.rstrip("'")
            if base == name:
                return True
            if base in definitions and base not in seen:
                seen.add(base)
                todo.append(base)
    return False


def _weight_value(scene: Scene, expr, allow_zero: bool) -> float:
    if expr is None:
        return 1.0
    w = scene.numeric(expr, "weight")
    if w < 0 or (w == 0 and not allow_zero):
        raise StwError(f"weight must be {'>= 0' if allow_zero else '> 0'}, not {w:g}")
    return w


def _constraint(scene: Scene, cmd) -> str:
    _check_new_name(scene, cmd.name, ("equation",))
    if cmd.name in scene.objectives:
        raise StwError(f"'{cmd.name}' is already an objective; choose another name")
    relations = []
    at = _time_in_span(scene, scene.numeric(cmd.at, "time"), "time") if cmd.at is not None else None
    interval = _interval(scene, cmd.interval, "interval") if cmd.interval is not None else None
    for rel in cmd.relations:
        if not _uses_dof(scene, rel.expr):
            raise StwError(f"a relation of '{cmd.name}' does not depend on any DOF")
        expr = -rel.expr if rel.kind == "le" else rel.expr
        relations.append(Relation(expr, TermKind.EQ if rel.kind == "eq" else TermKind.GE))
        # compiled as the window will read it (an attached DOF's one branch there, not both)
        compile_term(scene.expand(expr, (at, at) if at is not None else interval), set(scene.dofs),
                     set(scene.constants))
    if cmd.samples is not None and cmd.samples < 1:
        raise StwError("samples must be at least 1")
    dense_tol = _option(scene, cmd.dense_tol, "dense_tol")
    if dense_tol is not None and dense_tol <= 0:
        raise StwError(f"dense_tol must be > 0, not {dense_tol:g}")
    scene.extra_instances.pop(cmd.name, None)   # placed for the old definition
    previous = scene.constraints.get(cmd.name)
    scene.constraints[cmd.name] = Constraint(cmd.name, tuple(relations), at, interval, cmd.when,
                                             _weight_value(scene, cmd.weight, False), cmd.text,
                                             cmd.samples, dense_tol)
    return (f"constraint {cmd.name}: {len(relations)} relation(s) {scene.constraints[cmd.name].scope_text}"
            + _replaced(previous))


def _objective(scene: Scene, cmd) -> str:
    _check_new_name(scene, cmd.name, ("equation",))
    if cmd.name in scene.constraints:
        raise StwError(f"'{cmd.name}' is already a constraint; choose another name")
    interval = _interval(scene, cmd.interval, "interval") if cmd.interval is not None else None
    at = _time_in_span(scene, scene.numeric(cmd.at, "objective time"), "objective time") \
        if cmd.at is not None else None
    # compiled as the window will read it: at its instant, or piece by piece between attachments
    scopes = [(at, at)] if at is not None else pieces(scene, *(interval or (scene.t0, scene.t1)))
    for expr in cmd.exprs:
        if not _uses_dof(scene, expr):
            raise StwError(f"a term of objective '{cmd.name}' does not depend on any DOF")
        for scope in scopes:
            compile_term(scene.expand(expr, scope), set(scene.dofs), set(scene.constants))
    previous = scene.objectives.get(cmd.name)
    scene.objectives[cmd.name] = Objective(cmd.name, tuple(cmd.exprs), interval,
                                           _weight_value(scene, cmd.weight, True), cmd.text, at, cmd.sense)
    what = f"{cmd.sense} its term" if cmd.sense else f"{len(cmd.exprs)} term(s)"
    return (f"objective {cmd.name}: {what}" + (f" at t={at:g}" if at is not None else "")
            + _replaced(previous))


def _key(scene: Scene, cmd) -> str:
    t = _time_in_span(scene, scene.numeric(cmd.time, "key time"), "key time")
    for name, expr in cmd.assignments:
        value = scene.numeric(expr, f"key value of {name}")
        dof = scene.dofs[name]
        dof.keys = [k for k in dof.keys if abs(k[0] - t) > 1e-12] + [(t, value)]
        dof.keys.sort()
        dof.curve = dof.curve.sketched(dof.keys)   # all keys: each new one keeps the earlier ones
    return f"key at t={t:g}: " + ", ".join(n for n, _ in cmd.assignments)


def _window(scene: Scene, cmd) -> str:
    if cmd.name == "all":
        raise StwError("'all' is the built-in window of everything; choose another name")
    _check_new_name(scene, cmd.name, ())
    interval = _interval(scene, cmd.interval, "window") if cmd.interval is not None else None
    scene.windows[cmd.name] = Window(cmd.name, tuple(cmd.dofs) if cmd.dofs else None, interval)
    scene.active_window = cmd.name
    return f"window {cmd.name} is now in use"


def _use(scene: Scene, cmd) -> str:
    if cmd.name not in scene.windows:
        raise StwError(f"no window named '{cmd.name}' (windows: {', '.join(scene.windows)})")
    scene.active_window = cmd.name
    return f"using window {cmd.name}"


def _weight(scene: Scene, cmd) -> str:
    if cmd.name in scene.constraints:
        scene.constraints[cmd.name].weight = _weight_value(scene, cmd.weight, False)
    elif cmd.name in scene.objectives:
        scene.objectives[cmd.name].weight = _weight_value(scene, cmd.weight, True)
    else:
        raise StwError(f"no constraint or objective named '{cmd.name}'")
    return f"weight {cmd.name} = {scene.numeric(cmd.weight):g}"


def _damp(scene: Scene, cmd) -> str:
    amount = scene.numeric(cmd.amount, "damping")
    if amount < 0:
        raise StwError(f"damping must be >= 0, not {amount:g}")
    scene.dofs[cmd.dof].damp = amount
    return f"damp {cmd.dof} = {amount:g}" + _unsupported_note(scene, None, {Capability.DAMPING})


def _filter(scene: Scene, cmd) -> str:
    if cmd.passes < 1:
        raise StwError("filter passes must be at least 1")
    dof = scene.dofs[cmd.dof]
    dof.curve = dof.curve.filtered(cmd.passes)
    return f"filtered {cmd.dof} ({cmd.passes} pass{'es' if cmd.passes > 1 else ''})"


def _shake(scene: Scene, cmd) -> str:
    amplitude = scene.numeric(cmd.amplitude, "amplitude")
    if amplitude <= 0:
        raise StwError("amplitude must be > 0")
    names = list(cmd.dofs) or list(scene.window.dofs or scene.dofs)
    seed = cmd.seed if cmd.seed is not None else scene.shake_count
    rng = np.random.default_rng(seed)
    interval = scene.window.interval
    for name in names:
        dof = scene.dofs[name]
        # Only the control points the window frees (its solve could not bring the others back,
        # and the motion outside the window would stay broken); the same draws either way
        moved = None if interval is None else dof.curve.touching(*interval)
        dof.curve = dof.curve.shaken(amplitude, rng, moved)
    scene.shake_count += 1
    where = "" if interval is None else f", where window {scene.window.name} frees them"
    return f"shook {', '.join(names)} (amplitude {amplitude:g}, seed {seed}{where})"


def _refine(scene: Scene, cmd) -> str:
    if cmd.at is not None:
        t = _time_in_span(scene, scene.numeric(cmd.at, "knot time"), "knot time")
        if not 1 <= cmd.multiplicity <= 3:
            raise StwError(f"multiplicity must be 1, 2 or 3 (a cubic), not {cmd.multiplicity}")
        if not scene.t0 < t < scene.t1:
            raise StwError(f"a knot at {t:g} must lie inside the animation span, not at its end")
        dof = scene.dofs[cmd.dof]
        dof.curve = dof.curve.with_knot(t, cmd.multiplicity)
        limits.check("knots", dof.curve.n_coef - 3, f"the knot spans of {cmd.dof} after refining,")
        return f"refined {cmd.dof}: a knot at {t:g} {cmd.multiplicity} time(s), {dof.curve.n_coef} control points"
    if cmd.interval is not None:
        a, b = _interval(scene, cmd.interval, "refinement interval")
    else:
        a, b = scene.window.interval or (scene.t0, scene.t1)
    dof = scene.dofs[cmd.dof]
    before = dof.curve.n_coef
    dof.curve = dof.curve.refined(a, b)
    limits.check("knots", dof.curve.n_coef - 3, f"the knot spans of {cmd.dof} after refining,")
    return f"refined {cmd.dof} on [{a:g}, {b:g}]: {before} -> {dof.curve.n_coef} control points"


def _backend(scene: Scene, cmd) -> str:
    cls = load_backend(cmd.name)
    options = dict(cmd.options)
    if cmd.name == scene.backend:
        options = {**scene.backend_options, **options}
    create_backend(cls, options)  # validates names and values
    scene.backend, scene.backend_options = cmd.name, options
    shown = " ".join(f"{k}={v}" for k, v in options.items())
    return f"backend {cmd.name} {shown}".rstrip() + _unsupported_note(scene, cls)


def _capabilities_asked(scene: Scene) -> dict[Capability, str]:
    """The capabilities the scene's settings ask of a backend, each with what asks for it."""
    def some(names: list[str]) -> str:
        return ", ".join(names[:3]) + (f" and {len(names) - 3} more" if len(names) > 3 else "")

    constraints = scene.constraints.values()
    asked = {
        Capability.DAMPING: [d.name for d in scene.dofs.values() if d.damp > 0],
        Capability.CONDITIONAL: [c.name for c in constraints if c.when is not None],
        Capability.INEQUALITIES: [c.name for c in constraints if any(r.kind is TermKind.GE for r in c.relations)]
        + [f"{d.name}.bounds" for d in scene.dofs.values() if d.lo is not None or d.hi is not None],
        Capability.WEIGHTS: [e.name for e in (*constraints, *scene.objectives.values()) if e.weight != 1.0],
    }
    return {capability: some(names) for capability, names in asked.items() if names}


def _unsupported_note(scene: Scene, cls, only: set[Capability] | None = None) -> str:
    """A warning line for each setting of the scene that backend ``cls`` (None: the scene's) does
    not declare it honours (its ``capabilities``), e.g. `damp` under IPOPT; empty when it honours
    them all, or when the scene's backend no longer loads (the next solve says so)."""
    if cls is None:
        try:
            cls = load_backend(scene.backend)
        except StwError:
            return ""
    missing = {capability: what for capability, what in _capabilities_asked(scene).items()
               if capability not in cls.capabilities and (only is None or capability in only)}
    return "".join(f"\nwarning: backend {cls.name} does not support {capability} ({what}); "
                   "the solve ignores it" for capability, what in missing.items())


def _set(scene: Scene, cmd) -> str:
    if cmd.option == "limit":   # the parser checked the name and the ceiling
        name, value = cmd.value.split()
        scene.limits[name] = limits.validated(name, int(value))
        return f"limit {name} = {value}"
    if cmd.option == "samples":
        try:
            value = int(cmd.value)
        except ValueError:
            raise StwError(f"samples must be a whole number, not '{cmd.value}'") from None
        if value < 1:
            raise StwError("samples must be at least 1")
        scene.samples = value
        return f"samples = {value}"
    if cmd.option in ("adaptive", "preview"):
        words = {"on": 1.0, "off": 0.0, "1": 1.0, "0": 0.0, "yes": 1.0, "no": 0.0}
        if cmd.value.lower() not in words:
            raise StwError(f"{cmd.option} is on or off, not '{cmd.value}'")
        scene.settings[cmd.option] = words[cmd.value.lower()]
        return f"{cmd.option} {'on' if scene.settings[cmd.option] else 'off'}"
    if cmd.option in ("adaptive_rounds", "adaptive_points") and not cmd.value.isdigit():
        raise StwError(f"{cmd.option} must be a whole number, not '{cmd.value}'")
    if cmd.option not in DEFAULT_SETTINGS:
        raise StwError(f"unknown setting '{cmd.option}' (settings: samples, {', '.join(DEFAULT_SETTINGS)})")
    try:
        value = float(cmd.value)
    except ValueError:
        raise StwError(f"setting {cmd.option} needs a number, not '{cmd.value}'") from None
    if not np.isfinite(value) or value < 0:
        raise StwError(f"setting {cmd.option} must be a finite number >= 0")
    if cmd.option == "quadrature" and not 1 <= value <= 10:
        raise StwError("quadrature must be between 1 and 10 points per span")
    scene.settings[cmd.option] = value
    return f"{cmd.option} = {value:g}"


def _delete(scene: Scene, cmd) -> str:
    name = cmd.name
    if name == "all":
        raise StwError("the window 'all' cannot be deleted")
    users = scene.names_used_by(name) if name in scene.dofs or name in scene.constants or name in scene.lets else []
    users = [u for u in users if u != name]
    if users:
        raise StwError(f"'{name}' is used by {', '.join(users)}; delete or change those first")
    if name in scene.verbs:
        _, members = scene.verbs.pop(name)
        scene.attachments.pop(name, None)
        for member in members:
            scene.constraints.pop(member, None)
            scene.objectives.pop(member, None)
            scene.extra_instances.pop(member, None)
        return f"deleted {name} ({', '.join(members)})"
    owner = owned_by_verb(scene, name)
    if owner:       # refused, not widened to the group: delete removes only what it names
        raise StwError(owner)
    for table in (scene.constraints, scene.objectives, scene.lets, scene.dofs, scene.constants, scene.windows):
        if name in table:
            del table[name]
            scene.extra_instances.pop(name, None)
            scene.extra_instances.pop(f"{name}.bounds", None)
            if scene.active_window not in scene.windows:
                scene.active_window = "all"
            return f"deleted {name}"
    raise StwError(f"nothing named '{name}' to delete")


def _print_check(scene: Scene, name: str):

    report = check_scene(scene)
    if name not in report.checks:
        known = ", ".join(report.checks) or "none"
        raise StwError(f"'{name}' is neither defined nor a constraint (constraints: {known})")
    c = report.checks[name]
    where = f", worst at t={c.worst_t:.6g}" if c.worst_t is not None and c.dense > 0 else ""
    text = f"{name}: violation {c.instances:.2e} at its instances, {c.dense:.2e} densely{where}"
    return text, PrintResult(name, c.worst_t, c.as_dict())


def _print(scene: Scene, cmd):

    if cmd.expr is None:
        return _print_check(scene, cmd.expr_text)
    if cmd.at is not None:
        times = np.array([_time_in_span(scene, scene.numeric(cmd.at, "time"), "time")])
    else:
        a, b = _interval(scene, cmd.interval, "interval") if cmd.interval else (scene.t0, scene.t1)
        times = np.linspace(a, b, 201)
    result = scene.evaluate(cmd.expr, times)
    bad = np.flatnonzero(~np.isfinite(result))
    if bad.size:   # x^(1/3) of a negative x, log(0): say where, never print nan
        t = times[bad[0]]
        what = "not a real number" if np.isnan(result[bad[0]]) else "infinite"
        raise SourceError(f"{cmd.expr_text} is {what} at t={t:.6g}" +
                          (f" (and at {bad.size - 1} more of {times.size} times)" if bad.size > 1 else ""),
                          column=cmd.column, expected="an expression defined on the curves")
    if cmd.at is not None:
        value = float(result[0])
        return f"{cmd.expr_text} @ {times[0]:g} = {value:.10g}", PrintResult(cmd.expr_text, float(times[0]), value)
    with np.errstate(over="ignore"):
        mean = result.mean()
    if not np.isfinite(mean):   # sinh(710) at 201 times: their sum overflows, their mean does not
        mean = (result / result.size).sum()
    summary = {"min": float(result.min()), "max": float(result.max()), "mean": float(mean),
               "start": float(result[0]), "end": float(result[-1])}
    text = (f"{cmd.expr_text} on [{times[0]:g}, {times[-1]:g}]: min {summary['min']:.6g}, "
            f"max {summary['max']:.6g}, mean {summary['mean']:.6g}, "
            f"start {summary['start']:.6g}, end {summary['end']:.6g}")
    return text, PrintResult(cmd.expr_text, None, summary)


def _help(scene: Scene, cmd) -> str:
    return lang.help_text(cmd.topic)


def _instances(scene: Scene, cmd) -> str:
    name = cmd.name
    bounded = name.endswith(".bounds") and name[:-len(".bounds")] in scene.dofs
    if name not in scene.constraints and not bounded:
        raise StwError(f"no constraint named '{name}' (for a DOF's bounds write DOF.bounds)")
    if cmd.action == "clear":
        dropped = len(scene.extra_instances.pop(name, ()))
        return f"{name}: {dropped} added instance(s) dropped"
    constraint = scene.constraints.get(name)
    if constraint is not None and constraint.at is not None:
        raise StwError(f"'{name}' holds at an instant ({constraint.scope_text}); instances are for intervals")
    a, b = constraint.interval if constraint is not None else (scene.t0, scene.t1)
    times = [scene.numeric(t, "instance time") for t in cmd.times]
    outside = [t for t in times if not a - 1e-12 <= t <= b + 1e-12]
    if outside:
        raise StwError(f"instance time {outside[0]:g} is outside {name}'s interval [{a:g}, {b:g}]")
    merged = sorted(set(scene.extra_instances.get(name, ())) | set(times))
    scene.extra_instances[name] = tuple(merged)
    return f"{name}: {len(merged)} added instance(s)"


@dataclass
class SolveReport:
    """What one `iterate` did, as data: the merged run, the last window problem, and the dense
    check of the motion it left, with what the adaptive rounds refined and added."""

    run: RunResult
    problem: WindowProblem
    backend: str
    dense: DenseReport
    tol: float                       # the scene's dense_tol
    adapted: refinement.RefinementLog   # the curves refined and instances added by adaptive re-solves
    resolves: int
    journal_text: str | None         # what replays it, when it was stopped

    def dense_lines(self) -> list[str]:
        """The lines after the solve's own: the dense check, what was refined and added, what to try."""
        lines = [f"dense violation {self.dense.dense_violation:.2e} over the whole animation"]
        done = self.adapted.describe()
        if done:
            lines[0] += done + f", {self.resolves} re-solve(s)"
        lines[0] += self.adapted.undone
        # (constraints in conflict fail at their instances too: refining would not help)
        failing = self.dense.failing(self.tol)
        if failing and self.run.status is not Status.INFEASIBLE:
            outside = beyond_window(self.problem, failing)
            stop = self.adapted.stop_note()
            hint = f" — {stop}" if stop else " — refine the knots there, or `set dense_tol`"
            if len(outside) == len(failing):   # refining would not help: the window cannot reach them
                hint = ""
            lines.append(f"between the instances it fails dense_tol {self.tol:.0e} (or its own): "
                         f"{self.dense.describe_failures(self.tol)}{hint}")
            if outside:
                lines.append(outside_note(self.problem, outside))
        last = self.run.reports[-1] if self.run.reports else None
        if self.run.status is Status.INFEASIBLE and last is not None and last.message:
            lines.append(last.message)    # names the constraints in conflict
        elif self.run.status is Status.STALLED:
            lines.append("— try `shake`, a keyframe, damping, or a smaller window")
        elif self.run.status is Status.MAX_ITERATIONS and self._runs_away():
            lines.append(f"— the objective is still falling ({last.objective:.3g}): a `maximize` or "
                         "`minimize` term is unbounded unless something bounds it (an effort objective, "
                         "constraints, DOF bounds)")
        return lines

    def _runs_away(self) -> bool:
        """Whether a signed objective fell without bound: it fell at each of the last steps, to
        over 1000 times its first size (a sum of squares cannot: it stays >= 0)."""
        objectives = [r.objective for r in self.run.reports[-5:]]
        first = self.run.reports[0].objective if self.run.reports else 0.0
        return (self.problem.linear_objective is not None and len(objectives) >= 2
                and all(b < a for a, b in zip(objectives, objectives[1:]))
                and objectives[-1] < first - 1e3 * max(1.0, abs(first)))

    def message(self) -> str:
        """The console message of the `iterate`. A window's objective and violation are its own
        (the terms its free control points change, over the times they reach), not the whole
        animation's: the line says so."""
        last = self.run.reports[-1] if self.run.reports else None
        text = f"{self.problem.summary()}\n{len(self.run.reports)} iteration(s) with {self.backend}: {self.run.status.value}"
        if last is not None:
            whose = "" if _is_everything(self.problem) else f" (window '{self.problem.window.name}')"
            text += (f"; objective{whose} {last.objective:.6g}, max violation {last.max_violation:.2e}, "
                     f"KKT {last.kkt_residual:.2e}")
        return "\n".join([text, *self.dense_lines()])


def _is_everything(problem: WindowProblem) -> bool:
    """Whether a window problem frees every control point (the window `all`, or one as large)."""
    return problem.n_free == problem.n_total


def beyond_window(problem: WindowProblem, failing: list) -> list:
    """The failing checks that a solve on ``problem``'s window cannot repair: worst where none of
    its free control points reach, or on DOF it does not free."""
    if _is_everything(problem):
        return []
    scene, (a, b) = problem.scene, problem.reach
    out = []
    for check in failing:
        if check.worst_t is not None and not a - 1e-12 <= check.worst_t <= b + 1e-12:
            out.append(check)
            continue
        constraint = scene.constraints.get(check.name)
        dofs = [check.name[:-len(".bounds")]] if check.name.endswith(".bounds") else None
        try:
            if constraint is not None:
                dofs = dofs_used(scene, [rel.expr for rel in constraint.relations], constraint.span)
        except Exception:  # a constraint that no longer compiles: say nothing of it
            continue
        if dofs is not None and not set(dofs) & problem.free_dofs:
            out.append(check)
    return out


def outside_note(problem: WindowProblem, outside: list) -> str:
    """The console line that says which failures lie outside the window and what to do instead."""
    window = problem.window
    names = ", ".join(c.name for c in outside[:3]) + (f" and {len(outside) - 3} more" if len(outside) > 3 else "")
    where = f"[{window.interval[0]:g}, {window.interval[1]:g}]" if window.interval is not None else "the whole span"
    dofs = f", DOF {', '.join(window.dofs)}" if window.dofs else ""
    a, b = problem.reach
    return (f"{names} {'fails' if len(outside) == 1 else 'fail'} outside window '{window.name}' ({where}{dofs}; "
            f"its control points reach t={a:.4g}..{b:.4g}): its solve cannot repair "
            f"{'it' if len(outside) == 1 else 'them'} — `use all` (or a window that covers "
            f"{'it' if len(outside) == 1 else 'them'}), then `iterate`")


def _iterate(session: SessionLike, scene: Scene, cmd, on_report) -> Outcome:
    if cmd.n < 1:
        raise StwError("iterate needs a positive number of iterations")
    solved = _solve_adaptive(session, scene, cmd.n, cmd.adapt, on_report, Trail(cmd.text))
    return Outcome(message=solved.message(), run=solved.run, journal_text=solved.journal_text,
                   dense=solved.dense)


def _solve_adaptive(session: SessionLike, scene: Scene, n: int, adapt: int | None, on_report,
                    trail: Trail) -> SolveReport:
    """Solve, check every constraint densely over the whole animation, and (adaptive) where the
    check fails, refine the curves there and add instances (stw_tui/sos/refinement.py decides
    which), and solve again from where the last solve ended, at most ``rounds`` times and within
    the control-point budget ``adaptive_points``. A re-solve that does not converge (a stop, or
    constraints it cannot meet) is undone: adaptive refinement never leaves a motion worse than
    the plain solve. Its changes are applied as the `refine` and `instances` lines that replay
    them. ``trail``: the lines that replay what the command kept before this call (for the
    running solve's checkpoints)."""
    settings = scene.settings
    rounds = adapt if adapt is not None else (int(settings["adaptive_rounds"]) if settings["adaptive"] else 0)
    backend = joined_backend(scene.backend, scene.backend_options)   # a batch job's member backend
    tol = settings["dense_tol"]
    problem = WindowProblem.of(scene)
    result = _solve(session, scene, problem, backend, n, on_report, trail)
    runs = [result]
    journal = [f"iterate {len(result.reports) if result.status is Status.STOPPED else n} adapt=0"]
    adapted = refinement.RefinementLog(sum(d.curve.n_coef for d in scene.dofs.values()),
                                       int(settings["adaptive_points"]))
    stopped = result.status is Status.STOPPED
    report = None   # the dense check of the scene as it is now (None: not made yet)
    while result.status is Status.CONVERGED and report is None:
        last = len(runs) > rounds   # no round left: the check alone (where it fails, to say so)
        report, wanted, failing = survey_failures(scene, tol if rounds else None)
        if last:
            adapted.rounds_out = bool(report.failing(tol) and (wanted or failing) and rounds > 0)
            break
        plan = refinement.plan_round(scene, failing, wanted, problem.free_dofs, problem.interval,
                                     problem.reach, adapted.budget)
        adapted.over_budget |= set(plan.over_budget)
        if not plan:
            break
        saved = ({name: dof.curve for name, dof in scene.dofs.items()}, dict(scene.extra_instances), session.warm)
        lines = plan.lines()
        for line in lines:   # as the journal replays them
            command = lang.parse_command(line, SceneScope(scene))
            _HANDLERS[type(command)](scene, command)
        trial_problem = WindowProblem.of(scene)
        trial = _solve(session, scene, trial_problem, backend, n, on_report, trail.then(journal + lines))
        if trial.status is not Status.CONVERGED:
            for name, curve in saved[0].items():
                scene.dofs[name].curve = curve
            scene.extra_instances, session.warm = saved[1], saved[2]
            stopped |= trial.status is Status.STOPPED
            adapted.undo(plan, trial.status.value, len(trial.reports))
            break
        problem, result, report = trial_problem, trial, None
        runs.append(trial)
        journal += lines + [f"iterate {n} adapt=0"]
        adapted.keep(plan)
    report = report or check_scene(scene)   # an undone round restored the surveyed scene
    adapted.points = sum(d.curve.n_coef for d in scene.dofs.values())
    # A stopped solve is journalled as what it kept, so a replay reaches the same scene.
    return SolveReport(_merged(runs), problem, backend.name, report, tol, adapted, len(runs) - 1,
                       "\n".join(journal) if stopped else None)


def _verb(scene: Scene, cmd) -> str:
    """A motion verb: expand it into named constraints and objectives (stw_tui.session.verbs), applied as
    their own lines would be, and remember them as one group that `delete` removes."""
    from stw_tui.session import verbs

    a, b = (scene.t0, scene.t1) if cmd.interval is None else _interval(scene, cmd.interval, "interval")
    parts, note = (), ""
    if isinstance(cmd, lang.HoldCmd):
        group, lines, parts = verbs.hold_lines(scene, cmd.point, cmd.at, a, b, _option(scene, cmd.mass, "mass"))
        if cmd.weight is not None:    # sessions written when a tracking objective carried it
            note = " (weight= is not used: the object is the holding point while held)"
    elif isinstance(cmd, lang.ContactCmd):
        support = None if cmd.support is None else tuple(_option(scene, v, "support") for v in cmd.support)
        group, lines, parts = verbs.contact_lines(
            scene, cmd.point, _option(scene, cmd.height, "ground height") or 0.0, a, b,
            _option(scene, cmd.friction, "friction coefficient"), _option(scene, cmd.x, "x"),
            _option(scene, cmd.dense_tol, "dense_tol"), support, cmd.force, _option(scene, cmd.angle, "angle"))
    elif isinstance(cmd, lang.AvoidCmd):
        group, lines = verbs.avoid_lines(scene, cmd.first, cmd.second, a, b, _option(scene, cmd.by, "by"),
                                         _option(scene, cmd.height, "ground height"),
                                         _option(scene, cmd.dense_tol, "dense_tol"))
    elif isinstance(cmd, lang.FlightCmd):
        group, lines = verbs.flight_lines(scene, cmd.linkage, a, b, _option(scene, cmd.dense_tol, "dense_tol"))
    else:
        group, lines = verbs.ballistic_lines(scene, cmd.point, a, b)
    members = []
    for line in lines:
        command = lang.parse_command(line, SceneScope(scene))
        _HANDLERS[type(command)](scene, command)
        members.append(command.name)
    scene.verbs[group] = (cmd.text, tuple(members))
    if parts:
        scene.attachments[group] = parts
        lines = list(dict.fromkeys(p.describe() for p in parts if not p.adds)) + lines
        if any(p.adds for p in parts):
            whose = "the ground's force on it" if isinstance(cmd, lang.ContactCmd) else "its mass"
            lines.append(f"{whose} loads {', '.join(p.target for p in parts if p.adds)}")
    return f"{lang.classify_line(cmd.text).verb} {group}: " + "; ".join(lines) + note


def _limit(scene: Scene, cmd) -> str:
    lo, hi = _bounds(scene, cmd.lo, cmd.hi)
    dof = scene.dofs[cmd.dof]
    dof.lo, dof.hi = lo, hi
    values = dof.curve.evaluate(np.linspace(scene.t0, scene.t1, 2001))
    outside = (f"; it is outside now ({values.min():.4g} to {values.max():.4g}): the next solve brings it in"
               if values.min() < lo or values.max() > hi else "")
    return f"{cmd.dof} limited to [{lo:g}, {hi:g}] everywhere (on its control points){outside}"


MAX_SLIDE_POSITIONS = 1000


def _slide(session: SessionLike, scene: Scene, cmd, on_report) -> Outcome:
    """Move a window along the time axis by ``by``, solving (an `iterate`) at each position, from
    where it is until its end reaches ``to`` (the last step is shortened to land there). Each
    solve sees only its window: the paper's cat that chases where the mouse is now."""

    window = scene.windows.get(cmd.window)
    if window is None:
        raise StwError(f"no window named '{cmd.window}' (windows: {', '.join(scene.windows)})")
    if window.interval is None:
        raise StwError(f"window '{cmd.window}' covers the whole animation; give it an interval to slide, "
                       f"e.g. `window {cmd.window} [0, 0.5]`")
    by = scene.numeric(cmd.by, "slide step")
    if not by > 0:
        raise StwError(f"slide step {by:g} must be positive")
    a, b = window.interval
    end = _time_in_span(scene, scene.numeric(cmd.to, "slide end"), "slide end") if cmd.to is not None else scene.t1
    if not end > b + 1e-12 * (scene.t1 - scene.t0):
        raise StwError(f"window '{cmd.window}' already ends at {b:g}; slide it `to` a later time than that")
    if cmd.n < 1:
        raise StwError("slide needs a positive number of iterations at each position")
    steps = (end - b) / by   # counted before the list is built: `by 1e-300` asked for 1e300 of them
    if not steps < MAX_SLIDE_POSITIONS:
        many = (f"{int(steps) + 1}" if steps < 1e15 else f"about {steps:.3g}" if np.isfinite(steps)
                else "more than 1e308")
        raise StwError(f"slide would solve at {many} positions (at most {MAX_SLIDE_POSITIONS}); take a larger step")
    count = int(np.floor(steps + 1e-9))
    ends = [b + k * by for k in range(count + 1)]
    if end - ends[-1] > 1e-9 * (scene.t1 - scene.t0):
        ends.append(end)
    if len(ends) > MAX_SLIDE_POSITIONS:
        raise StwError(f"slide would solve at {len(ends)} positions (at most {MAX_SLIDE_POSITIONS}); "
                       "take a larger step")
    width, lines, runs, journal = b - a, [], [], []
    for e in ends:
        interval = (e - width, e)
        scene.windows[cmd.window] = replace(window, interval=interval)
        scene.active_window = cmd.window
        moved = (f"window {cmd.window}" + (f" dofs={','.join(window.dofs)}" if window.dofs else "")
                 + f" [{interval[0]!r}, {interval[1]!r}]")
        solved = _solve_adaptive(session, scene, cmd.n, None, on_report, Trail(cmd.text, journal + [moved]))
        runs.append(solved.run)
        journal += [moved, solved.journal_text or f"iterate {cmd.n}"]
        last = solved.run.reports[-1] if solved.run.reports else None
        lines.append(f"[{interval[0]:.4g}, {interval[1]:.4g}]: {len(solved.run.reports)} iteration(s), "
                     f"{solved.run.status.value}" + (f", objective {last.objective:.6g}" if last else ""))
        if solved.run.status is Status.STOPPED:
            break
    done = sum(r.converged for r in runs)
    stopped = runs[-1].status is Status.STOPPED
    head = (f"slid window {cmd.window} over {len(runs)} of {len(ends)} position(s) by {by:g}; "
            f"converged at {done} of {len(runs)}" + (" (stopped)" if stopped else ""))
    text = "\n".join([head, *lines, *solved.dense_lines()])
    # A stopped slide is journalled as the positions it solved, so a replay reaches the same scene.
    return Outcome(message=text, run=_merged(runs), journal_text="\n".join(journal) if stopped else None)


def _check_start(problem: WindowProblem) -> None:
    """Refuse to solve from curves where a term or its derivatives is not a finite real number
    (sqrt or log of a negative value, x^(1/3) of a negative x): name the term and the time,
    instead of letting the backend fail on NaN with a misleading message."""
    found = problem.first_undefined(problem.initial())
    if found is not None:
        group, i, what = found
        kind = "objective" if group.kind is TermKind.OBJ else "constraint"
        raise SolveError(f"{kind} {group.label}: {what} is not a finite real number at t={group.times[i]:.6g} "
                         f"on the current curves ({sp.sstr(group.term.expr)[:80]}); the scene is unchanged — "
                         "a keyframe, bounds (lo=, hi=) or a different start can keep it defined")


def _solve(session: SessionLike, scene: Scene, problem: WindowProblem, backend, n: int, on_report,
           trail: Trail | None = None) -> RunResult:
    """Run the backend on one window problem from the scene's curves (and the last solve's
    multipliers when its rows are the same), and put the result in the scene. A journalled
    session checkpoints the running solve every few seconds (stw_tui/session/midsolve.py)."""
    _check_start(problem)
    signature = (scene.active_window, tuple(problem.free), tuple(g.label for g in problem.groups),
                 tuple(g.n for g in problem.groups))
    start = SolverState.start(problem)
    if session.warm is not None and session.warm.signature == signature:
        start = SolverState(s=start.s, lam_eq=session.warm.state.lam_eq, lam_ge=session.warm.state.lam_ge,
                            working_set=session.warm.state.working_set,
                            merit_weight=session.warm.state.merit_weight)
    checkpoint = hook_for(session, scene, problem, lambda state: WarmStart(signature, state), trail)
    result = run_iterations(backend, problem, start, n, scene.settings, on_report, on_state=checkpoint)
    scene.with_coefficients(problem.scatter(result.state.s))
    session.warm = WarmStart(signature, result.state)
    return result


def _merged(runs: list[RunResult]) -> RunResult:
    """One result for the rounds of an adaptive `iterate`: their reports numbered on, the last status."""
    if len(runs) == 1:
        return runs[0]
    reports, offset = [], 0
    for run in runs:
        reports += [replace(r, iteration=r.iteration + offset) for r in run.reports]
        offset += len(run.reports)
    return RunResult(runs[-1].status, runs[-1].state, reports, sum(r.seconds for r in runs))


_HANDLERS = {
    lang.TimeCmd: _time, lang.ConstCmd: _const, lang.DofCmd: _dof, lang.LetCmd: _let,
    lang.ConstraintCmd: _constraint, lang.ObjectiveCmd: _objective, lang.KeyCmd: _key,
    lang.WindowCmd: _window, lang.UseCmd: _use, lang.WeightCmd: _weight, lang.DampCmd: _damp,
    lang.FilterCmd: _filter, lang.ShakeCmd: _shake, lang.RefineCmd: _refine, lang.BackendCmd: _backend,
    lang.SetCmd: _set, lang.IterateCmd: _iterate, lang.DeleteCmd: _delete, lang.PrintCmd: _print,
    lang.HelpCmd: _help, lang.InstancesCmd: _instances, lang.SlideCmd: _slide,
    lang.HoldCmd: _verb, lang.BallisticCmd: _verb, lang.ContactCmd: _verb,
    lang.FlightCmd: _verb, lang.AvoidCmd: _verb, lang.LimitCmd: _limit,
}
