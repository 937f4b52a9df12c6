"""The panels of the paper's interface (Cohen 1992, section 4), each emitting command lines.

DOF · Equations · Constants · Windows · Time · Optimization. Keys act on the row under the
cursor; the key hints line lists them while a panel has the focus.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from rich.text import Text
from textual.binding import Binding

from stw_tui.app.messages import ItemChosen
from stw_tui.app.panel_base import ScenePanel, SettingRow, SettingsPanel, num, short, show
from stw_tui.session.queries import SceneInfo
from stw_tui.session.verbs import verb_of

if TYPE_CHECKING:
    from stw_tui.sos.scene import Scene


class DofPanel(ScenePanel):
    """Degrees of freedom: in the window or not, bounds, knots, damping, keyframes."""

    # Short enough for the 40 columns a panel has at 80x24; the help's Panels section says them in full
    COLUMNS = ("DOF", "win", "lo", "hi", "sp", "cp", "damp", "keys")
    COLUMN_HELP = {"win": "in the active window (✓) or not (·)", "lo": "lower bound", "hi": "upper bound",
                   "sp": "knot spans", "cp": "control points", "damp": "damping of its change per iteration",
                   "keys": "keyframes"}
    BINDINGS = [
        Binding("i", "include", "In/out", tooltip="put the DOF in or out of the active window"),
        Binding("b", "bounds", "Bounds"),
        Binding("k", "knots", "Knots", tooltip="knot spans (refits the curve)"),
        Binding("d", "damp", "Damp"),
        Binding("f", "filter", "Filter", tooltip="smooth the curve"),
        Binding("r", "refine", "Refine", tooltip="double its knots"),
        Binding("s", "shake", "Shake", tooltip="a seeded random change of the curve"),
    ]

    def table_rows(self, scene: "Scene", info: SceneInfo):
        """One row per DOF: in the window or not, bounds, spans, control points, damping, keys."""
        window = scene.window
        for name, dof in scene.dofs.items():
            inside = window.dofs is None or name in window.dofs
            yield name, (name, "✓" if inside else "·", short(dof.lo), short(dof.hi), str(dof.curve.spans),
                         str(dof.curve.n_coef), short(dof.damp), str(len(dof.keys)))

    def activate(self, key: str) -> None:
        """Choose the DOF for the curve plot."""
        self.post_message(ItemChosen("dof", key))

    def action_include(self) -> None:
        """Put the DOF in or out of the active window (a new window when the active one is `all`)."""
        name, scene = self.selected, self.scene
        if name is None:
            return
        window = scene.window
        current = list(window.dofs) if window.dofs else list(scene.dofs)
        wanted = {d for d in current if d != name} if name in current else {*current, name}
        if not wanted:
            self.app.notify("a window needs at least one DOF", severity="warning")
            return
        dofs = "all" if wanted == set(scene.dofs) else ",".join(d for d in scene.dofs if d in wanted)
        target = window.name
        if target == "all":   # `all` is built in; make a named window instead
            k = 1
            while f"w{k}" in scene.windows:
                k += 1
            target = f"w{k}"
        interval = f" [{num(window.interval[0])}, {num(window.interval[1])}]" if window.interval else ""
        self.emit(f"window {target} dofs={dofs}{interval}")

    def action_bounds(self) -> None:
        name = self.selected
        if name is not None:
            dof = self.scene.dofs[name]
            current = " ".join(f"{k}={num(v)}" for k, v in (("lo", dof.lo), ("hi", dof.hi)) if v is not None)
            self.ask(f"Bounds of {name} (lo=A hi=B)", current or "lo=-1 hi=1", lambda v: f"dof {name} {v}")

    def action_knots(self) -> None:
        name = self.selected
        if name is not None:
            spans = str(self.scene.dofs[name].curve.spans)
            self.ask(f"Knot spans of {name} (refits the curve)", spans, lambda v: f"dof {name} knots={v}")

    def action_damp(self) -> None:
        name = self.selected
        if name is not None:
            self.ask(f"Damping of {name}", num(self.scene.dofs[name].damp), lambda v: f"damp {name} {v}")

    def action_filter(self) -> None:
        if self.selected is not None:
            self.emit(f"filter {self.selected}")

    def action_refine(self) -> None:
        if self.selected is not None:
            self.emit(f"refine {self.selected}")

    def action_shake(self) -> None:
        name = self.selected
        if name is not None:
            self.ask(f"Shake {name}: amplitude", "0.05", lambda v: f"shake {name} amplitude={v}")


VERB_KEY = "verb:"   # row key of a verb's heading: a group may share its name with one of its parts


class EquationsPanel(ScenePanel):
    """Constraints, objectives and subexpressions with weight, time scope and current violation.
    What a motion verb made is grouped under a heading row with the verb's line (and the worst
    violation of its parts): the verb is the unit the animator wrote, and the one `delete` removes."""

    # The violation next to the name: at 80x24 (a panel 40 columns wide) it shows the name, the
    # violation and the scope; the definition, last, is cut to what is left
    COLUMNS = ("name", "max viol", "scope", "kind", "weight", "definition")
    KEEP_IN_VIEW = 3
    COLUMN_HELP = {"max viol": "largest violation over the constraint's whole scope (dense check)",
                   "scope": "the instant or interval it holds at",
                   "kind": "con(straint), obj(ective), let, or the verb whose parts follow",
                   "definition": "as written (`show NAME` prints it whole)"}
    BINDINGS = [
        Binding("w", "weight", "Weight"),
        Binding("x", "delete", "Delete"),
    ]

    def table_rows(self, scene: "Scene", info: SceneInfo):
        """Constraints and objectives, a verb's parts grouped under a heading row for the verb."""
        shown: set[str] = set()
        for name in [*scene.constraints, *scene.objectives]:
            if name in shown:
                continue
            group = verb_of(scene, name)
            if group is None:
                yield name, self._cells(scene, info, name, name)
                continue
            members = [m for m in scene.verbs[group][1] if m in scene.constraints or m in scene.objectives]
            shown.update(members)     # the group sits where its first part would have
            yield VERB_KEY + group, self._heading(scene, info, group, members)
            for i, member in enumerate(members):
                yield member, self._cells(scene, info, member, ("└ " if i == len(members) - 1 else "├ ") + member)
        for group, (_, members) in scene.verbs.items():   # a verb that made no row (a hold over the span)
            if not members:
                yield VERB_KEY + group, self._heading(scene, info, group, [])
        for name, expr in scene.lets.items():
            yield name, (name, "", "", "let", "", str(expr))

    @staticmethod
    def _cells(scene: "Scene", info: SceneInfo, name: str, label: str) -> tuple:
        if name in scene.constraints:
            c = scene.constraints[name]
            scope = c.scope_text + (" when…" if c.when is not None else "")
            viol = info.violations.get(name)
            return (label, "n/a" if viol is None else f"{viol:.2e}", scope, "con", show(c.weight),
                    c.text.split(":", 1)[-1].strip())
        o = scene.objectives[name]
        scope = f"@ {o.at:g}" if o.at is not None else f"on [{o.interval[0]:g}, {o.interval[1]:g}]" \
            if o.interval else "span"
        return label, "", scope, "obj", show(o.weight), o.text.split(":", 1)[-1].strip()

    @staticmethod
    def _heading(scene: "Scene", info: SceneInfo, group: str, members: list[str]) -> tuple:
        """The verb's row: its word, the time its parts cover, their worst violation, its line."""
        line = scene.verbs[group][0]
        spans = [scene.constraints[m].span for m in members if m in scene.constraints]
        spans += [scene.objectives[m].interval for m in members if m in scene.objectives]
        spans += [(p.a, p.b) for p in scene.attachments.get(group, ())]    # a hold's time in the hand
        if not spans or None in spans:
            scope = "span"
        else:
            a, b = min(s[0] for s in spans), max(s[1] for s in spans)
            scope = f"@ {a:g}" if a == b else f"on [{a:g}, {b:g}]"
        viols = [info.violations[m] for m in members if m in scene.constraints and m in info.violations]
        worst = f"{max(viols):.2e}" if viols else ("n/a" if any(m in scene.constraints for m in members) else "")
        return Text(group, style="bold"), worst, scope, Text(line.split()[0], style="bold"), "", line

    def activate(self, key: str) -> None:
        """Enter on a verb shows its expansion; on a constraint or objective, plots its values."""
        if key.startswith(VERB_KEY):     # a verb: its line and expansion, in the console
            self.emit(f"show {key[len(VERB_KEY):]}")
        else:
            self.post_message(ItemChosen("equation", key))

    def action_weight(self) -> None:
        name, scene = self.selected, self.scene
        if name is None:
            return
        if name.startswith(VERB_KEY):
            self.app.notify("a verb has no weight of its own: choose one of its parts below it",
                            severity="warning")
            return
        item = scene.constraints.get(name) or scene.objectives.get(name)
        if item is None:
            self.app.notify("subexpressions have no weight", severity="warning")
            return
        self.ask(f"Weight of {name}", num(item.weight), lambda v: f"weight {name} {v}")

    def action_delete(self) -> None:
        name = self.selected
        if name is None:
            return
        heading = name.startswith(VERB_KEY)
        group = name[len(VERB_KEY):] if heading else verb_of(self.scene, name)
        title = f"Delete {name}?"
        if group is not None:   # a verb's parts go together (`delete` refuses one part alone)
            title = ("" if heading else f"{name} is part of verb {group}. ") + \
                f"Delete {group} and the {len(self.scene.verbs[group][1])} item(s) it made?"
        target = group or name
        self.ask(f"{title} (Enter runs the command)", f"delete {target}",
                 lambda v: v if v.startswith("delete ") else f"delete {target}")


class ConstantsPanel(SettingsPanel):
    """Constants; Enter edits a value (`const NAME = VALUE`), n declares a new one."""

    BINDINGS = [Binding("n", "new", "New constant")]

    def settings(self, scene: "Scene", info: SceneInfo) -> list[SettingRow]:
        """One editable row per constant (`const NAME = VALUE`)."""
        return [SettingRow(name, name, num(value), lambda v, n=name: f"const {n} = {v}")
                for name, value in scene.constants.items()]

    def action_new(self) -> None:
        self.ask("New constant (NAME = VALUE)", "c = 1", lambda v: f"const {v}")


class WindowsPanel(ScenePanel):
    """Spacetime windows; Enter uses one, n defines a new one."""

    COLUMNS = ("", "window", "DOF", "interval")
    BINDINGS = [Binding("n", "new", "New window")]

    def table_rows(self, scene: "Scene", info: SceneInfo):
        """One row per window: in use or not, its name, its DOF and its interval."""
        for w in scene.windows.values():
            interval = f"[{w.interval[0]:g}, {w.interval[1]:g}]" if w.interval else "span"
            yield w.name, ("▶" if w.name == scene.active_window else "", w.name,
                           ",".join(w.dofs) if w.dofs else "all", interval)

    def activate(self, key: str) -> None:
        """Make the window under the cursor the active one (`use NAME`)."""
        self.emit(f"use {key}")

    def action_new(self) -> None:
        scene = self.scene
        k = 1
        while f"w{k}" in scene.windows:
            k += 1
        template = f"w{k} dofs=all [{num(scene.t0)}, {num(scene.t1)}]"
        self.ask("New window: NAME [dofs=a,b|all] [[A, B]]", template, lambda v: f"window {v}")


class TimePanel(SettingsPanel):
    """Span, knot spans, constraint samples, frame time, quadrature."""

    def settings(self, scene: "Scene", info: SceneInfo) -> list[SettingRow]:
        """Span, knot spans, samples, frame time and quadrature, each editable."""
        span = f"{num(scene.t0)} {num(scene.t1)}"
        return [
            SettingRow("span", "span", span, lambda v: f"time {v}", "start end"),
            SettingRow("knots", "knot spans", str(scene.knots), lambda v: f"time {span} knots={v}",
                       "of new DOF; refits all"),
            SettingRow("samples", "samples", str(scene.sample_count), lambda v: f"set samples {v}",
                       "constraint instances"),
            SettingRow("frame", "frame time", num(scene.settings["frame"]), lambda v: f"set frame {v}"),
            SettingRow("quadrature", "quadrature", num(scene.settings["quadrature"]),
                       lambda v: f"set quadrature {v}", "points per span"),
        ]


class OptimizationPanel(SettingsPanel):
    """Backend and its options, iterations per run, merit weight and tolerances; c compares the
    installed backends on the scene (iterate N each) in a table."""

    BINDINGS = [
        Binding("i", "iterate", "Iterate"),
        Binding("s", "shake", "Shake", tooltip="shake the window's DOF (a seeded random change)"),
        Binding("c", "compare", "Compare", tooltip="solve copies of the scene with each backend, side by side"),
    ]

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self.iterations = 10    # what F5 / i runs

    def settings(self, scene: "Scene", info: SceneInfo) -> list[SettingRow]:
        """The backend, its declared options, iterations per run, merit weight and tolerances."""
        rows = [SettingRow("backend", "backend", scene.backend, lambda v: f"backend {v}", "name")]
        for opt in info.backend_options:
            value = scene.backend_options.get(opt.name, opt.default)
            choices = "|".join(map(str, opt.choices)) if opt.choices else opt.type.__name__
            rows.append(SettingRow(f"opt:{opt.name}", f"  {opt.name}", str(value),
                                   lambda v, o=opt.name: f"backend {scene.backend} {o}={v}", choices))
        if info.backend_error:
            rows.append(SettingRow("error", "  error", info.backend_error))
        rows.append(SettingRow("iterate", "iterate N", str(self.iterations), self._iterate_line, "runs now"))
        for key in ("merit", "tol_violation", "tol_kkt", "tol_step"):
            rows.append(SettingRow(key, key, num(scene.settings[key]), lambda v, k=key: f"set {k} {v}"))
        return rows

    def _iterate_line(self, value: str) -> str:
        if value.isdigit() and int(value) > 0:
            self.iterations = int(value)
        return f"iterate {value}"

    def action_iterate(self) -> None:
        self.emit(f"iterate {self.iterations}")

    def action_compare(self) -> None:
        self.app.action_compare()

    def action_shake(self) -> None:
        self.ask("Shake the window's DOF: amplitude", "0.05", lambda v: f"shake amplitude={v}")
