"""Plots (textual-plotext): DOF curves, equation values, the stick figure, solver convergence.

Plots only render. What they show is computed from a scene snapshot in a background thread
(plot_data.py, through background.LatestOnly) and comes back in a :class:`PlotDataComputed`
message, so the UI thread never compiles or evaluates a term. Every plot redraws at most ~10
times a second. They are touched only on the UI thread: the app feeds them from message handlers.

Drawing is split the same way: the UI thread only states the figure (cheap plotext calls) into a
fresh plotext Plot; turning it into text (``build``, ~10-25 ms, several times that while a solve
holds the interpreter) happens in another background thread, and comes back in a
:class:`PlotBuilt` message. The widget keeps that text and renders it until the data, size or
theme change: textual-plotext's PlotextPlot rebuilds the figure at every render, and a tab switch
or focus change renders a plot again (on basketball at 80x24, half of an F3's UI time).
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any, Callable

from rich.text import Text
from textual.binding import Binding
from textual.geometry import Size
from textual_plotext import PlotextPlot
from textual_plotext.plot import Plot

from stw_tui.app.axes import fit_title, nice_ticks, title_room, value_limits
from stw_tui.app.background import LatestOnly
from stw_tui.app.messages import ItemChosen, PlotBuilt, PlotDataComputed
from stw_tui.app.plot_data import dof_plot_data, expression_plot_data, figure_data, live_scene
from stw_tui.session.queries import QUANTITIES, SceneInfo, equation_names
from stw_tui.session.throttle import ThrottledCall
from stw_tui.sym.errors import printable

if TYPE_CHECKING:
    import numpy as np

    from stw_tui.sos.backend import StepReport
    from stw_tui.sos.scene import Scene

REDRAW_INTERVAL = 0.1   # seconds: at most ~10 redraws a second


class ScenePlot(PlotextPlot, can_focus=True):
    """A plot of some aspect of the scene.

    Subclasses say what to compute in :meth:`data_request` (run in a background thread) and
    draw the result, ``self.data``, in :meth:`draw`.
    """

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self.scene: "Scene | None" = None
        self.coefficients: "np.ndarray | None" = None   # a running solve's, drawn over the scene
        self.info = SceneInfo()
        self.data: Any = None
        self.data_error: BaseException | None = None
        self._redraws = ThrottledCall(self._redraw, REDRAW_INTERVAL, self.set_timer)
        self._computer = LatestOnly(self._deliver, name=f"stw-{self.id or 'plot'}")
        self._builder = LatestOnly(self._deliver_built, name=f"stw-{self.id or 'plot'}-build")
        self._built: tuple[tuple, Text] | None = None   # (render key, text) of the newest figure

    def set_scene(self, scene: "Scene", info: SceneInfo | None = None, coefficients=None) -> None:
        """Show ``scene`` (a snapshot nobody changes), with a running solve's ``coefficients``."""
        self.scene = scene
        self.coefficients = coefficients
        if info is not None:
            self.info = info
        self.request_data()

    # --- data, computed in the background ----------------------------------------------------
    def data_request(self) -> "Callable[[Scene], Any] | None":
        """What to compute from the scene, as a function of it; None: nothing to compute (draw
        says why). Called on the UI thread: choose here, do the work in the function."""
        return None

    def request_data(self) -> None:
        """Compute the data for the current scene and choices, then redraw."""
        compute = self.data_request() if self.scene is not None else None
        if compute is None:
            self._computer.drop()
            self.data, self.data_error = None, None
            self.request_draw()
            return
        scene, coefficients = self.scene, self.coefficients
        self._computer.submit(lambda: compute(live_scene(scene, coefficients)))

    def _deliver(self, sequence: int, data: Any, error: BaseException | None) -> None:
        """In the background thread: hand the result to the UI thread."""
        self.post_message(PlotDataComputed(sequence, data, error))

    def on_plot_data_computed(self, message: PlotDataComputed) -> None:
        message.stop()
        if not self._computer.accept(message.sequence):   # older than what is shown
            return
        self.data, self.data_error = message.data, message.error
        self.request_draw()

    # --- drawing -----------------------------------------------------------------------------
    @property
    def redraw_pending(self) -> bool:
        """Data being computed, or a redraw waiting for its turn."""
        return self._redraws.pending or self._computer.pending or self.build_pending

    def request_draw(self) -> None:
        """Redraw now, or once the 0.1 s since the last redraw have passed."""
        self._redraws.request()

    @property
    def build_pending(self) -> bool:
        """The newest figure's text still being built in the background."""
        return self._builder.pending

    def _redraw(self) -> None:
        """State the figure now (on the UI thread: cheap); build its text in the background."""
        key = self._render_key(self._expected_size())
        plt = self._figure(key)
        if not all(key[:2]):   # in a tab never shown: built when first rendered
            self._builder.drop()
            self._built = None
            return
        self._builder.submit(lambda: (key, Text.from_ansi(plt.build())))

    def _figure(self, key: tuple) -> Plot:
        """A new plotext figure of ``self.data`` at the size and theme of ``key``."""
        width, height, theme = key
        plt = Plot()
        self._plot = plt    # `plt`: the newest figure (tests read it)
        self._draw_size = Size(width, height)
        try:
            if self.data_error is not None:
                raise self.data_error
            self.draw(plt)
        except Exception as exc:  # a plot must never take the app down; say what went wrong
            plt.clear_figure()
            plt.title(printable(f"cannot draw: {exc}"))
        plt.plotsize(width, height)
        plt._set_size(width, height)   # as PlotextPlot.render does (textual-plotext issue 5)
        plt.theme(theme)
        return plt

    def _deliver_built(self, sequence: int, built: Any, error: BaseException | None) -> None:
        """In the builder thread: hand the figure's text to the UI thread."""
        self.post_message(PlotBuilt(sequence, built, error))

    def on_plot_built(self, message: PlotBuilt) -> None:
        message.stop()
        if not self._builder.accept(message.sequence):   # older than what is shown
            return
        self._built = message.built if message.error is None else None
        self.refresh()

    def _expected_size(self):
        """The size the plot has, or will have when its tab is shown (the tab switcher's)."""
        for node in self.ancestors_with_self:
            if not getattr(node, "display", True):
                continue
            size = getattr(node, "content_size", None)
            if size is not None and size.width and size.height:
                return size
        return self.size

    def _render_key(self, size) -> tuple:
        return size.width, size.height, self._get_plotext_theme_name(self.app.theme)

    def render(self) -> Text:
        """The newest figure's text; built here only when the size or theme changed since."""
        key = self._render_key(self.size)
        if self._built is not None and self._built[0] == key:
            return self._built[1]
        # First shown, resized or a new theme: build now, and drop builds still under way.
        self._builder.drop()
        try:
            text = Text.from_ansi(self._figure(key).build())
        except Exception as exc:   # never take the app down
            text = Text(printable(f"cannot draw: {exc}"))
        self._built = (key, text)
        return text

    def draw(self, plt) -> None:
        """Render ``self.data`` (and the plot's own state) with plotext; compute nothing."""
        raise NotImplementedError

    _label_width = 5   # of the y tick labels of the last draw (the title's room depends on it)
    axes: tuple | None = None   # (xlim, ylim, x labels, y labels) set by the newest draw, if any
    _draw_size = Size(0, 0)   # of the figure being drawn

    def set_axes(self, plt, xlim: tuple[float, float], ylim: tuple[float, float], xinteger: bool = False) -> None:
        """Limits and round tick labels for both axes, as many as the plot's size allows."""
        width, height = self._draw_size
        xticks, xlabels = nice_ticks(*xlim, count=max(2, min(9, width // 8)), integer=xinteger)
        yticks, ylabels = nice_ticks(*ylim, count=max(3, min(8, (height - 2) // 2)))
        plt.xlim(*xlim)
        plt.ylim(*ylim)
        if xticks:
            plt.xticks(xticks, xlabels)
        if yticks:
            plt.yticks(yticks, ylabels)
        self._label_width = max(map(len, ylabels), default=5)
        self.axes = (xlim, ylim, xlabels, ylabels)   # of the newest figure (tests read them)

    def set_title(self, plt, *variants: str) -> None:
        """The most detailed of ``variants`` that fits (plotext would drop one that does not)."""
        width = self._draw_size.width
        room = title_room(width, self._label_width) if width else len(variants[0])
        plt.title(fit_title(variants, room))

    @staticmethod
    def mark_interval(plt, interval: tuple[float, float] | None, color: str = "gray") -> None:
        """Vertical lines at the ends of a time interval (a window, a constraint's scope)."""
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
        self.request_data()

    def data_request(self):
        if not self.scene.dofs:
            return None
        if self.dof not in self.scene.dofs:
            self.dof = next(iter(self.scene.dofs))
        name, order = self.dof, self.order
        return lambda live: dof_plot_data(live, name, order)

    def draw(self, plt) -> None:
        data = self.data
        if data is None:
            plt.title("no DOF yet: `dof x`")
            return
        series, keys = data.series, data.keys
        plt.plot(series.times, series.values, label=series.label, color="cyan")
        self.mark_interval(plt, data.interval, "orange")
        if keys:
            plt.scatter([k[0] for k in keys], [k[1] for k in keys], marker="dot", color="red", label="keys")
        self.set_axes(plt, data.span, value_limits([*series.values, *(k[1] for k in keys)]))
        name, quantity, window = data.name, QUANTITIES[data.order], data.window
        note, short = ("", "") if data.inside else (" (outside window)", " (out)")
        self.set_title(plt, f"{name} {quantity} · window {window}{note}  [ ] v",
                       f"{name} {quantity} · window {window}{short}", f"{name} {quantity}{short}",
                       f"{name}{chr(39) * data.order}{short}")


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

    def data_request(self):
        names = equation_names(self.scene)
        if not names:
            return None
        if self.name_shown not in names:
            self.name_shown = names[0]
        name = self.name_shown
        return lambda live: expression_plot_data(live, name)

    def draw(self, plt) -> None:
        data = self.data
        if data is None:
            plt.title("no constraints, objectives or lets yet")
            return
        for s in data.series:
            plt.plot(s.times, s.values, label=s.label)
        self.mark_interval(plt, data.scope, "orange")
        self.set_axes(plt, data.span, value_limits(v for one in data.series for v in one.values))
        name, violation = data.name, self.info.violations.get(data.name)
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
        """Whether the player is running through the frames."""
        return self._timer is not None

    def action_play(self) -> None:
        if self._timer is not None:
            self._timer.stop()
            self._timer = None
            self.request_draw()   # the title says so
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
        self.request_data()

    def action_jump(self, end: int) -> None:
        if self.scene is not None:
            self.t = self.scene.t1 if end else self.scene.t0
            self.request_data()

    def data_request(self):
        scene = self.scene
        if not scene.dofs:
            return None
        if self.t is None:
            self.t = scene.settings.get("frame", scene.t0)
        t, ghost = self.t, self.info.proposal    # `set preview on`: the proposal, beside the motion
        return lambda live: figure_data(live, t, ghost)

    def draw(self, plt) -> None:
        data = self.data
        if data is None:
            plt.title("no creature yet")
            return
        line, dot = ("gray", "gray") if data.ghost is not None else ("cyan", "red")   # dim the motion
        for (x0, y0), (x1, y1) in data.segments:
            plt.plot([x0, x1], [y0, y1], color=line, marker="braille")
        for label, (x, y) in data.points:
            plt.scatter([x], [y], marker="●", color=dot)
            plt.text(label, x, y, color="white")
        bounds = data.bounds if data.bounds is not None else self.info.figure_bounds
        if data.ghost is not None:
            for (x0, y0), (x1, y1) in data.ghost.segments:
                plt.plot([x0, x1], [y0, y1], color="cyan", marker="braille")
            for label, (x, y) in data.ghost.points:
                plt.scatter([x], [y], marker="●", color="red")
            bounds = self.info.figure_bounds           # the worker's: both motions fit
        if bounds is not None and all(map(math.isfinite, bounds)):
            self.set_axes(plt, (bounds[0], bounds[1]), (bounds[2], bounds[3]))
        if data.ghost is not None and self.info.proposal is not None:
            self.set_title(plt, *self.info.proposal.captions(data.t))
            return
        t, (t0, t1) = data.t, data.span
        state = "playing" if self.playing else "space plays"
        self.set_title(plt, f"t = {t:.3f} of [{t0:g}, {t1:g}] · {state} · ← →",
                       f"t = {t:.3f} of [{t0:g}, {t1:g}] · {state}",
                       f"t = {t:.3f} of [{t0:g}, {t1:g}]", f"t = {t:.3f}", f"t={t:.2f}")


class ConvergencePlot(ScenePlot):
    """log10 of objective and max violation per iteration of the running (or last) solve."""

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self.reports: list["StepReport"] = []

    def set_reports(self, reports: list["StepReport"]) -> None:
        """Show these iteration reports (the running or last solve's)."""
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
