"""Plots (textual-plotext): DOF curves, equation values, the stick figure, solver convergence.

Every plot keeps the data it draws and redraws at most ~10 times a second (plotext costs ~30 ms a
draw). They are touched only on the UI thread: the app feeds them from message handlers.
"""

from __future__ import annotations

import math
import time
from typing import TYPE_CHECKING

from textual.binding import Binding
from textual_plotext import PlotextPlot

from stw_tui.app.axes import fit_title, nice_ticks, title_room, value_limits
from stw_tui.app.messages import ItemChosen
from stw_tui.app.values import QUANTITIES, SceneInfo, dof_series, equation_names, equation_series

if TYPE_CHECKING:
    from stw_tui.sos.backend import StepReport
    from stw_tui.sos.scene import Scene

REDRAW_INTERVAL = 0.1   # seconds: at most ~10 redraws a second


class ScenePlot(PlotextPlot, can_focus=True):
    """A plot of some aspect of the scene; subclasses implement :meth:`draw`."""

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self.scene: "Scene | None" = None
        self.info = SceneInfo()
        self._last_draw = 0.0
        self._pending = None

    def set_scene(self, scene: "Scene", info: SceneInfo | None = None) -> None:
        self.scene = scene
        if info is not None:
            self.info = info
        self.request_draw()

    @property
    def redraw_pending(self) -> bool:
        return self._pending is not None

    def request_draw(self) -> None:
        """Redraw now, or once the 0.1 s since the last redraw have passed."""
        wait = REDRAW_INTERVAL - (time.monotonic() - self._last_draw)
        if wait <= 0:
            self._redraw()
        elif self._pending is None:
            self._pending = self.set_timer(wait, self._redraw)

    def _redraw(self) -> None:
        self._pending = None
        self._last_draw = time.monotonic()
        plt = self.plt
        plt.clear_figure()
        try:
            self.draw(plt)
        except Exception as exc:  # a plot must never take the app down; say what went wrong
            plt.clear_figure()
            plt.title(f"cannot draw: {exc}")
        self.refresh()

    def draw(self, plt) -> None:
        raise NotImplementedError

    _label_width = 5   # of the y tick labels of the last draw (the title's room depends on it)

    def set_axes(self, plt, xlim: tuple[float, float], ylim: tuple[float, float], xinteger: bool = False) -> None:
        """Limits and round tick labels for both axes, as many as the plot's size allows."""
        width, height = self.size
        xticks, xlabels = nice_ticks(*xlim, count=max(2, min(9, width // 8)), integer=xinteger)
        yticks, ylabels = nice_ticks(*ylim, count=max(3, min(8, (height - 2) // 2)))
        plt.xlim(*xlim)
        plt.ylim(*ylim)
        if xticks:
            plt.xticks(xticks, xlabels)
        if yticks:
            plt.yticks(yticks, ylabels)
        self._label_width = max(map(len, ylabels), default=5)

    def set_title(self, plt, *variants: str) -> None:
        """The most detailed of ``variants`` that fits (plotext would drop one that does not)."""
        width = self.size.width
        room = title_room(width, self._label_width) if width else len(variants[0])
        plt.title(fit_title(variants, room))

    @staticmethod
    def mark_interval(plt, interval: tuple[float, float] | None, color: str = "gray") -> None:
        if interval is not None:
            for t in sorted(set(interval)):
                plt.vline(t, color)


class DofPlot(ScenePlot):
    """Value, velocity or acceleration of one DOF, with the active window and keyframes marked."""

    BINDINGS = [
        Binding("left_square_bracket", "cycle(-1)", "Prev DOF"),
        Binding("right_square_bracket", "cycle(1)", "Next DOF"),
        Binding("v", "quantity", "Value/vel/acc"),
    ]

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self.dof: str | None = None
        self.order = 0

    def action_cycle(self, step: int) -> None:
        names = list(self.scene.dofs) if self.scene else []
        if names:
            index = names.index(self.dof) if self.dof in names else 0
            self.post_message(ItemChosen("dof", names[(index + step) % len(names)]))

    def action_quantity(self) -> None:
        self.order = (self.order + 1) % 3
        self.request_draw()

    def draw(self, plt) -> None:
        scene = self.scene
        if scene is None or not scene.dofs:
            plt.title("no DOF yet: `dof x`")
            return
        if self.dof not in scene.dofs:
            self.dof = next(iter(scene.dofs))
        series = dof_series(scene, self.dof, self.order)
        plt.plot(series.times, series.values, label=series.label, color="cyan")
        window = scene.window
        inside = window.dofs is None or self.dof in window.dofs
        self.mark_interval(plt, window.interval, "orange")
        keys = scene.dofs[self.dof].keys if self.order == 0 else []
        if keys:
            plt.scatter([k[0] for k in keys], [k[1] for k in keys], marker="dot", color="red", label="keys")
        self.set_axes(plt, (scene.t0, scene.t1), value_limits([*series.values, *(k[1] for k in keys)]))
        name, quantity = self.dof, QUANTITIES[self.order]
        note, short = ("", "") if inside else (" (outside window)", " (out)")
        self.set_title(plt, f"{name} {quantity} · window {window.name}{note}  [ ] v",
                       f"{name} {quantity} · window {window.name}{short}", f"{name} {quantity}{short}",
                       f"{name}{chr(39) * self.order}{short}")


class ExpressionPlot(ScenePlot):
    """Values over the span of the relations of a constraint, the terms of an objective, or a let."""

    BINDINGS = [
        Binding("left_square_bracket", "cycle(-1)", "Prev term"),
        Binding("right_square_bracket", "cycle(1)", "Next term"),
    ]

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self.name_shown: str | None = None

    def action_cycle(self, step: int) -> None:
        names = equation_names(self.scene) if self.scene else []
        if names:
            index = names.index(self.name_shown) if self.name_shown in names else 0
            self.post_message(ItemChosen("equation", names[(index + step) % len(names)]))

    def draw(self, plt) -> None:
        scene = self.scene
        names = equation_names(scene) if scene else []
        if not names:
            plt.title("no constraints, objectives or lets yet")
            return
        if self.name_shown not in names:
            self.name_shown = names[0]
        series, scope = equation_series(scene, self.name_shown)
        for s in series:
            plt.plot(s.times, s.values, label=s.label)
        self.mark_interval(plt, scope, "orange")
        self.set_axes(plt, (scene.t0, scene.t1), value_limits(v for one in series for v in one.values))
        name, violation = self.name_shown, self.info.violations.get(self.name_shown)
        if violation is None:
            self.set_title(plt, f"{name}  [ ]", name)
        else:
            self.set_title(plt, f"{name} · max violation {violation:.2e}  [ ]",
                           f"{name} · viol {violation:.1e}", name)


class FigurePlot(ScenePlot):
    """The creature as a stick figure at the frame time; space plays, arrows scrub."""

    BINDINGS = [
        Binding("space", "play", "Play/pause"),
        Binding("left", "scrub(-1)", "Back"),
        Binding("right", "scrub(1)", "Forward"),
        Binding("home", "jump(0)", "Start", show=False),
        Binding("end", "jump(1)", "End", show=False),
    ]
    FRAMES = 40     # scrub steps per span

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self.t: float | None = None
        self._timer = None

    @property
    def playing(self) -> bool:
        return self._timer is not None

    def action_play(self) -> None:
        if self._timer is not None:
            self._timer.stop()
            self._timer = None
        else:
            self._timer = self.set_interval(REDRAW_INTERVAL, lambda: self.action_scrub(1, wrap=True))

    def action_scrub(self, steps: int, wrap: bool = False) -> None:
        scene = self.scene
        if scene is None:
            return
        span = scene.t1 - scene.t0
        t = (self.t if self.t is not None else scene.t0) + steps * span / self.FRAMES
        if wrap and t > scene.t1 + 1e-9:
            t = scene.t0
        self.t = min(max(t, scene.t0), scene.t1)
        self.request_draw()

    def action_jump(self, end: int) -> None:
        if self.scene is not None:
            self.t = self.scene.t1 if end else self.scene.t0
            self.request_draw()

    def draw(self, plt) -> None:
        from stw_tui.session.figure import scene_figure

        scene = self.scene
        if scene is None or not scene.dofs:
            plt.title("no creature yet")
            return
        if self.t is None:
            self.t = scene.settings.get("frame", scene.t0)
        t = min(max(self.t, scene.t0), scene.t1)
        ghost = self.info.proposal      # `set preview on`: the proposal beside the scene's motion, dimmed
        line, dot = ("gray", "gray") if ghost is not None else ("cyan", "red")
        figure = scene_figure(scene, t)
        for (x0, y0), (x1, y1) in figure.segments:
            plt.plot([x0, x1], [y0, y1], color=line, marker="braille")
        points = figure.points
        if not figure.segments and not points:
            # A lone DOF (the jet particle) is drawn as a dot at its height.
            name = next(iter(scene.dofs))
            points = [(name, (0.0, float(scene.dofs[name].curve.evaluate([t])[0])))]
            values = dof_series(scene, name, 0).values
            pad = 0.1 * max(max(values) - min(values), 0.2)
            bounds = (-1.0, 1.0, min(values) - pad, max(values) + pad)
        else:
            bounds = self.info.figure_bounds
        for label, (x, y) in points:
            plt.scatter([x], [y], marker="●", color=dot)
            plt.text(label, x, y, color="white")
        if ghost is not None:
            proposed = ghost.figure(t)
            for (x0, y0), (x1, y1) in proposed.segments:
                plt.plot([x0, x1], [y0, y1], color="cyan", marker="braille")
            for label, (x, y) in proposed.points:
                plt.scatter([x], [y], marker="●", color="red")
            bounds = self.info.figure_bounds           # both motions fit
        if bounds is not None and all(map(math.isfinite, bounds)):
            self.set_axes(plt, (bounds[0], bounds[1]), (bounds[2], bounds[3]))
        if ghost is not None:
            self.set_title(plt, *ghost.captions(t))
            return
        state = "playing" if self.playing else "space plays"
        self.set_title(plt, f"t = {t:.3f} of [{scene.t0:g}, {scene.t1:g}] · {state} · ← →",
                       f"t = {t:.3f} of [{scene.t0:g}, {scene.t1:g}] · {state}",
                       f"t = {t:.3f} of [{scene.t0:g}, {scene.t1:g}]", f"t = {t:.3f}", f"t={t:.2f}")


class ConvergencePlot(ScenePlot):
    """log10 of objective and max violation per iteration of the running (or last) solve."""

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self.reports: list["StepReport"] = []

    def set_reports(self, reports: list["StepReport"]) -> None:
        self.reports = list(reports)
        self.request_draw()

    def draw(self, plt) -> None:
        if not self.reports:
            plt.title("no solve yet: F5 or `iterate N`")
            return
        its = [r.iteration for r in self.reports]
        objective = [math.log10(max(abs(r.objective), 1e-300)) for r in self.reports]
        violation = [math.log10(max(r.max_violation, 1e-16)) for r in self.reports]
        plt.plot(its, objective, label="log10 objective", color="cyan")
        plt.plot(its, violation, label="log10 violation", color="orange")
        self.set_axes(plt, (its[0], max(its[-1], its[0] + 1)), value_limits(objective + violation),
                      xinteger=True)
        n = len(self.reports)
        self.set_title(plt, f"convergence: {n} iteration(s)", f"{n} iteration(s)", f"{n} it")
