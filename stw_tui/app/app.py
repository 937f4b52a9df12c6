"""The stw application: layout, keys, and the glue between widgets and the session worker.

Widgets post messages; the app turns each requested command into a :class:`Job` for the
:class:`Runner` and, when the worker reports back, refreshes the panels, plots and status line.
"""

from __future__ import annotations

import asyncio
import json
import os
import signal
import threading
from pathlib import Path
from typing import TYPE_CHECKING, Iterable

from textual import events
from textual.app import App, ComposeResult
from textual.binding import Binding
from textual.containers import Horizontal
from textual.css.query import NoMatches
from textual.reactive import Reactive
from textual.screen import Screen
from textual.widget import Widget

from stw_tui.app.console import Console
from stw_tui.app.deck import Deck
from stw_tui.app.dialogs import CompareScreen, TooSmallScreen, too_small
from stw_tui.app.gallery import GalleryScreen, OptimumChosen
from stw_tui.app.help_screen import HelpScreen, help_sections
from stw_tui.app.key_hints import KeyHints
from stw_tui.app.palette import SceneCommands, app_commands
from stw_tui.sym.language import classify_line
from stw_tui.app.messages import (CommandFinished, CommandRequested, CommandStarted, IterationReported, ItemChosen, Job,
                       Origin, SurveyProgressed, TaskFinished)
from stw_tui.app.panels import ConstantsPanel, DofPanel, EquationsPanel, OptimizationPanel, TimePanel, WindowsPanel
from stw_tui.app.plots import ConvergencePlot, DofPlot, ExpressionPlot, FigurePlot, ScenePlot
from stw_tui.app.runner import HANGUP_GRACE, Runner, Script, changes_scene
from stw_tui.app.status import StatusLine
from stw_tui.session.queries import SceneInfo
from stw_tui.session.throttle import ThrottledCall
from stw_tui.sym.errors import printable

if TYPE_CHECKING:
    from textual.app import SystemCommand

    from stw_tui.session.session import Session
    from stw_tui.sos.scene import Scene

PANELS = (("DOF", DofPanel), ("Eqns", EquationsPanel), ("Const", ConstantsPanel), ("Win", WindowsPanel),
          ("Time", TimePanel), ("Opt", OptimizationPanel))
VIEW_INTERVAL = 0.1   # seconds between refreshes of the panels and plots
# ... while a session replays (the console shows each line as it runs): each refresh samples the
# scene for the plots in background threads, which took the interpreter lock from the replay
# (arm_throw's replay in the app, 4 alternating runs: 6.6-7.2 s at 0.1, 5.1-5.7 s at 0.5)
REPLAY_VIEW_INTERVAL = 0.5
# Seconds between redraws from a running solve (status, curves, figure). Each redraw takes the
# interpreter lock from the solver: on basketball in tmux the solve took 21.6 and 22.5 s redrawn
# at every iteration, 18.1 and 18.5 s with the status line alone, 16.7 and 15.8 s undrawn;
# 20.0 and 14.5 s at this interval (headless, same minutes: 12.1 and 10.4 s).
LIVE_INTERVAL = 0.5
EXIT_HANGUP = 129     # 128 + SIGHUP, as a shell reports a process the signal ended
HANGUP_EXIT_S = 5.0   # seconds a hung-up TUI has to quit (HANGUP_GRACE of them its solve's) before it ends itself

class MainScreen(Screen):
    """The app's screen. A focus change repaints only what it restyles: Textual's Screen
    repaints itself whole when the focus moves (its ``focused`` reactive), and that full
    update was the largest part of an F2/F3/Esc (~40% of their UI time on basketball at 80x24)."""

    focused: Reactive[Widget | None] = Reactive(None, repaint=False)


PLOTS = (("Curves", DofPlot), ("Expr", ExpressionPlot), ("Figure", FigurePlot), ("Conv", ConvergencePlot))


class StwApp(App[int]):
    """Spacetime Windows in the terminal.

    The core (sympy, scipy) is imported by the worker's first job, not here, so the screen
    paints before it has loaded; commands typed meanwhile wait in the queue.

    Args:
        session: the session to drive (a new empty one by default).
        session_path: a .stw file to open and replay.
        step: step through that file line by line (F6) instead of replaying it to the end.
        show_timing: show ms per iteration (False for deterministic snapshots).
        blink: blink text cursors (False for deterministic snapshots).
        settings_path: a JSON file remembering the theme between runs (None: nothing is
            remembered, as in tests).
        notes: lines to show in the console when it opens (what `stw --resume` restored).
        quit_on_hangup: SIGHUP quits as Ctrl+Q does (the real process, `stw`; not a test's app).
    """

    CSS_PATH = "app.tcss"
    TITLE = "stw"
    COMMANDS = App.COMMANDS | {SceneCommands}
    # App keys first in the key hints (see KeyHints), short enough to fit 80 columns with room left
    # for the focused panel's or plot's own keys; F1 lists them all.
    BINDINGS = [
        Binding("f1", "help", "Help"),
        Binding("f2", "panels", "Panels"),
        Binding("f3", "plots", "Plots"),
        Binding("f4", "stop", "Stop"),
        Binding("f5", "iterate", "Iterate"),
        Binding("f6", "step", "Step"),
        Binding("f7", "run_rest", "Rest"),
        Binding("f8", "play", "Play", show=False),   # the Figure plot's title says `space plays`
        # Esc never stops anything: pressed to leave a panel, it must not cost a running solve.
        Binding("escape", "escape", "Console", show=False),
        Binding("ctrl+z", "undo", "Undo", show=False),
        Binding("ctrl+y", "redo", "Redo", show=False),
        Binding("f9", "accept", "Accept the proposal", show=False),    # `set preview on`
        Binding("f10", "reject", "Reject the proposal", show=False),
        Binding("ctrl+q", "quit", "Quit", priority=True),
    ]

    def __init__(self, session: "Session | None" = None, session_path: str | Path | None = None,
                 step: bool = False, show_timing: bool = True, blink: bool = True,
                 settings_path: str | Path | None = None, solver_process: bool = True,
                 journal: str | Path | None = None, notes: "list[str] | None" = None,
                 quit_on_hangup: bool = False, settle_heap: bool = False):
        super().__init__()
        self.notes = list(notes or ())
        self.quit_on_hangup = quit_on_hangup
        if "TEXTUAL_ANIMATIONS" not in os.environ:
            # The tab underline slides for 0.3 s after F2/F3: ~18 frames of the whole screen's
            # compositor, UI time that keys typed meanwhile wait for (and, during a solve, that
            # the solver loses). It jumps instead; TEXTUAL_ANIMATIONS=full brings it back.
            self.animation_level = "none"
        self.settings_path = Path(settings_path) if settings_path else None
        self.runner = Runner(self, session, solver_process=solver_process,
                             journal=Path(journal) if journal is not None and session is None else None,
                             settle_heap=settle_heap)
        self.session_path = Path(session_path) if session_path else None
        self.stepping = step
        self.show_timing = show_timing
        self.blink = blink
        self.script: Script | None = None
        self._info = SceneInfo()
        self._views = ThrottledCall(self._show_views, VIEW_INTERVAL, self.set_timer)
        self._stale: set[str] = set()     # ids of views in hidden tabs that missed a refresh
        # The plots open on the figure player once a scene has something to draw, unless a plot
        # was chosen before (F3, Enter on a row, F8, the gallery): see _open_on_figure
        self._plot_chosen = False
        self._figure_checked: "Scene | None" = None
        # What the views show: the worker's copy of the scene after the last command (the
        # session's own scene belongs to the worker), and a running solve's control points.
        self._shown: "Scene | None" = None
        self._coefficients = None
        self._latest_report = None       # of the running solve, not shown yet
        self._gallery_plan = None        # the plan of the survey whose gallery opened on its own
        self._live = ThrottledCall(self._show_latest_report, LIVE_INTERVAL, self.set_timer)

    def compose(self) -> ComposeResult:
        with Horizontal(id="main"):
            yield Deck([(title, cls(id=f"{title.lower()}-panel", classes="scene-view")) for title, cls in PANELS],
                       prepare=self._bring_up_to_date, id="panels")
            yield Deck([(title, cls(id=f"{title.lower()}-plot", classes="scene-view")) for title, cls in PLOTS],
                       prepare=self._prepare_plot, ahead=True, id="plots")
        yield Console(lambda: self.scene, self._backend_names, blink=self.blink, id="console")
        yield StatusLine(show_timing=self.show_timing, id="status")
        yield KeyHints([(binding.key, binding.action) for binding in self.BINDINGS], id="keys")

    def get_default_screen(self) -> Screen:
        """The first screen: a :class:`MainScreen` (no full repaint per focus change)."""
        return MainScreen(id="_default")

    def get_system_commands(self, screen) -> "Iterable[SystemCommand]":
        """The palette's commands: the app's own (not from the help screen), then Textual's."""
        if screen is self.screen_stack[0]:   # not from the help screen: there only Textual's own
            yield from app_commands(self)
        yield from super().get_system_commands(screen)

    @property
    def session(self) -> "Session | None":
        """The session (None for a moment at startup, until the worker has loaded the core)."""
        return self.runner.session

    @property
    def scene(self) -> "Scene | None":
        """The scene of the session the worker drives (None before the core has loaded)."""
        return self.runner.session.scene if self.runner.session is not None else None

    @property
    def repl(self) -> Console:
        """The console widget."""
        return self.query_one(Console)

    @property
    def status_line(self) -> StatusLine:
        """The status line widget."""
        return self.query_one(StatusLine)

    def _backend_names(self) -> list[str]:
        from stw_tui.sos.backend import available_backends

        return sorted(available_backends())

    def _load_settings(self) -> None:
        """Apply the remembered theme, and remember the next change of it."""
        if self.settings_path is None:
            return
        try:
            theme = json.loads(self.settings_path.read_text(encoding="utf-8")).get("theme")
        except (OSError, ValueError, AttributeError):
            theme = None
        if isinstance(theme, str) and theme in self.available_themes:
            self.theme = theme
        self.theme_changed_signal.subscribe(self, self._save_theme)

    def _save_theme(self, theme) -> None:
        try:
            self.settings_path.parent.mkdir(parents=True, exist_ok=True)
            self.settings_path.write_text(json.dumps({"theme": theme.name}) + "\n", encoding="utf-8")
        except OSError as exc:   # remembering is a convenience: say so, go on
            message = printable(f"cannot remember the theme in {self.settings_path}: {exc}")
            self.notify(message, severity="warning", markup=False)

    def on_resize(self, event: events.Resize) -> None:
        """Below 80x24 the layout does not fit: a screen says so until the terminal is larger."""
        self._guard_size(event.size)

    def _guard_size(self, size) -> None:
        shown = [screen for screen in self.screen_stack if isinstance(screen, TooSmallScreen)]
        if too_small(size):
            if not shown:
                self.push_screen(TooSmallScreen())
        elif shown and self.screen is shown[-1]:
            self.pop_screen()   # (one under another screen closes itself when it is on top again)

    def on_unmount(self) -> None:
        """The app is shutting down (Ctrl+Q, or the end of a test's run): its solver process ends
        with it rather than at the interpreter's exit; no live redraw is left due."""
        self._drop_live_report()
        self.runner.abandon()

    def on_mount(self) -> None:
        if self.quit_on_hangup and hasattr(signal, "SIGHUP"):
            asyncio.get_running_loop().add_signal_handler(signal.SIGHUP, self._hung_up)
        self._load_settings()
        self._guard_size(self.size)
        self.repl.input.focus()
        self.repl.write_note("stw — Spacetime Windows. Type a command (`help` lists them); "
                             "F1 help, F2 panels, F3 plots, F5 iterate, F4 stops, Esc back here, Ctrl+P palette, "
                             "Ctrl+Q quits.")
        journal = self.runner.session.journal.path if self.runner.session is not None else self.runner.journal
        if journal is not None:   # autosaved (stw_tui/session/autosave.py): say where, once
            self.repl.write_note(f"journal: {journal} (`journal` says more; `stw --resume` reopens it)")
        for note in self.notes:
            self.repl.write_note(note)
        if self.runner.session is not None:   # a session given (resumed): Up recalls its commands
            self.repl.input.history.extend(self.runner.session.journal.commands())
        self.status_line.show(state="loading")
        self.runner.submit(Job("", origin=Origin.STARTUP))   # loads the core and measures the scene, off the UI thread
        if self.session_path is not None:
            self._open(self.session_path)

    def _open(self, path: Path) -> None:
        try:
            text = path.read_text(encoding="utf-8")
        except (OSError, UnicodeDecodeError) as exc:
            from stw_tui.sym.errors import StwError

            self.repl.write_error(StwError(f"cannot read session {path}: {exc}"))
            return
        self.script = Script(path, text, stepping=self.stepping)
        self.runner.replay_folder = path.parent
        how = "stepping: F6 runs the next line, F7 the rest" if self.stepping else "replaying"
        self.repl.write_note(f"opened {path} ({how})")
        self.refresh_bindings()
        self._feed_script()

    # --- running commands --------------------------------------------------------------------
    def submit(self, line: str, origin: Origin = Origin.CONSOLE, number: int | None = None) -> None:
        """Run one command line through the session, after any running or queued ones. While a
        session file replays, a command that may change the scene waits for the file's end, and a
        read-only one runs before the file's next line (see :class:`Script`)."""
        job = Job(line, number=number, origin=origin)
        script = self.script
        if script is not None and script.running and origin != Origin.FILE:
            if changes_scene(line):
                script.held.append(job)
                self.repl.write_note(f"queued until the replay ends: {line}")
                return
            script.queries.append(job)
            if self.runner.solving:
                self.repl.write_note(f"answers when the running solve ends: {line}")
            self._feed_script()
            return
        if self.runner.submit(job) and origin != Origin.FILE:
            self.repl.write_note(f"queued until the running command ends: {line}")

    def _feed_script(self) -> None:
        """When nothing runs: the read-only commands typed during a replay (never inside a
        `linkage` block of the file, whose rows they would become), else the replay's next line."""
        script = self.script
        if script is None or self.runner.busy:
            return
        if script.queries and not (self.session is not None and self.session.in_block):
            for job in script.queries:
                self.runner.submit(job)
            script.queries.clear()
        elif script.running:
            self._send_next_line()

    def _send_next_line(self) -> None:
        comments, job = self.script.advance()
        for comment in comments:
            self.repl.write_note(comment)
        if job is None:
            self.script.running = False
            self.repl.write_note(f"end of {self.script.path.name}")
            typed = [*self.script.queries, *self.script.held]
            self.script.queries.clear()
            self.script.held.clear()
            if typed:
                self.repl.write_note(f"running the {len(typed)} command(s) typed during the replay")
            for job in typed:
                self.runner.submit(job)
            self.refresh_bindings()
            self._show_state()
            return
        # A replay measures its last line only (and a paused one where it stopped); a step, each
        job.measure = not self.script.running or self.script.upcoming() is None
        self.runner.submit(job)

    def _show_state(self) -> None:
        if self.runner.busy:
            state = "solving" if self.runner.solving else "running"
            if self.runner.stop_requested.is_set():
                state = "stopping"
        elif self.script is not None and not self.script.done:
            nxt = self.script.upcoming()
            state = f"step: line {nxt[0]} next" if nxt else "idle"
        else:
            state = "idle"
        self.status_line.show(state=state)

    def on_command_requested(self, event: CommandRequested) -> None:
        event.stop()
        if event.origin == Origin.CONSOLE and classify_line(event.line).words == ("help",):
            self.repl.write_command(event.line)
            self.repl.write_note("opened the help screen (F1); `help COMMAND` prints one command here")
            self.action_help()
            return
        self.submit(event.line, origin=event.origin)

    def on_command_started(self, event: CommandStarted) -> None:
        job = event.job
        if job.origin not in (Origin.STARTUP, Origin.MEASURE) and job.line.strip():
            self.repl.write_command(job.line, job.number, job.origin, job.continuation)
        if job.is_solve and classify_line(job.line).verb != "survey":   # a survey's starts go to its gallery
            self.query_one(ConvergencePlot).set_reports([])
        self._show_state()

    def on_iteration_reported(self, event: IterationReported) -> None:
        """Show the newest iterate at once, or when LIVE_INTERVAL has passed since the last."""
        self._latest_report = event.report
        self._live.request()

    def _show_latest_report(self) -> None:
        report, self._latest_report = self._latest_report, None
        if report is None:
            return
        try:
            status, convergence = self.status_line, self.query_one(ConvergencePlot)
        except NoMatches:   # the app is closing (Ctrl+Q, a test's end) with a live redraw still due
            return
        status.show(report=report)
        convergence.set_reports(self.runner.reports)
        if report.coefficients is not None and self.session is not None:
            self.show_iteration(report.coefficients)

    def _drop_live_report(self) -> None:
        """The solve has ended: its final state is shown, not an iterate still waiting."""
        self._live.cancel()
        self._latest_report = None

    LIVE_PLOTS = (DofPlot, ExpressionPlot, FigurePlot)

    def show_iteration(self, coefficients) -> None:
        """Redraw the curves, expression values and figure from the running solve's coefficients.

        The plots compute them in the background, over the scene of the last command with these
        control points (plot_data.live_scene), and build their text there too: the shown one and
        the one F3 shows next (hidden: at the size it will have), so an F3 during a solve draws
        the newest iterate in its first frame. (Left stale until shown, the next plot was drawn
        with an old iterate at the switch, then again 40-60 ms later: F3 settled at p95 140 ms in
        tmux at 80x24.) The others are brought up to date when shown, or when they come next.
        """
        if self._shown is None:
            return
        self._coefficients = coefficients
        plots = self.query_one("#plots", Deck)
        kept = self._kept_up_to_date(plots)
        for widget in plots.views.values():
            if isinstance(widget, self.LIVE_PLOTS):
                if widget in kept:
                    self._stale.discard(widget.id)
                    widget.set_scene(self._shown, self._info, coefficients=coefficients)
                else:
                    self._stale.add(widget.id)

    # --- surveys -----------------------------------------------------------------------------
    def on_survey_progressed(self, event: SurveyProgressed) -> None:
        """Fill the gallery in as the starts come back. It opens on the first table of each
        survey that reaches the UI (once: Esc closes it for the rest of that survey), whatever
        its count: a newer table replaces one not handled yet, and under load the first the UI
        saw already held two results (the gallery then never opened)."""
        if isinstance(self.screen, GalleryScreen):
            self.screen.show(event.table)
        elif len(self.screen_stack) == 1 and event.table.plan is not self._gallery_plan:
            self.push_screen(GalleryScreen(event.table))
        self._gallery_plan = event.table.plan   # (one object per survey: tables are shallow copies)
        self.status_line.show(state=f"survey {len(event.table.results)}/{event.table.plan.n}")

    def action_gallery(self) -> None:
        """Open the last survey's gallery."""
        survey = self.session.survey if self.session is not None else None
        if survey is None:
            self.repl.write_note("no survey yet: `survey N` runs one")
        elif not isinstance(self.screen, GalleryScreen):
            self.push_screen(GalleryScreen(survey))

    def on_optimum_chosen(self, event: OptimumChosen) -> None:
        """Adopt an optimum (the `adopt K` command), or play it in the figure player."""
        if event.action == "adopt":
            self.submit(f"adopt {event.rank}", origin="panel")
            return
        from stw_tui.session.survey import preview_scene

        survey = self.session.survey if self.session is not None else None
        table = survey if survey is not None else getattr(self.screen, "table", None)
        if table is None or event.rank > len(table.optima):
            return
        best = table.optima[event.rank - 1].best
        figure = self.query_one(FigurePlot)
        self._stale.discard(figure.id)   # showing its tab must not put the scene back over the preview
        self._plot_chosen = True
        self.query_one("#plots", Deck).active = "tab-figure"
        preview = preview_scene(self._shown, best)
        figure.set_scene(preview)
        figure.t = preview.t0
        if not figure.playing:
            figure.action_play()
        self.repl.write_note(f"playing optimum {event.rank} (objective {best.objective:.7g}); "
                             f"`adopt {event.rank}` makes it the scene")

    def on_command_finished(self, event: CommandFinished) -> None:
        job, outcome, error = event.job, event.outcome, event.error
        if error is None and isinstance(self.screen, GalleryScreen) and self.session.survey is not None \
                and classify_line(job.line).verb == "survey":
            self.screen.show(self.session.survey)
        if error is not None:
            self.repl.write_error(error)
            if job.origin == Origin.FILE and self.script is not None:
                self.script.running = False   # pause the replay; F6/F7 go on after the fix
                self.repl.write_note("replay paused: fix it at the console, then F6/F7 to go on" + self._held_note())
        elif outcome is not None:
            self.repl.write_result(outcome.message)
            if outcome.run is not None and outcome.run.reports:
                self.query_one(ConvergencePlot).set_reports(outcome.run.reports)
            if job.origin == Origin.FILE and _was_stopped(outcome) and self.script is not None:
                # The lines after a stopped solve assume it ran to the end: do not run them.
                self.script.running = False
                self.repl.write_note(f"replay halted: the solve at line {job.number} was stopped "
                                     "before it ended; F6 runs the next line, F7 the rest" + self._held_note())
        self._coefficients = None
        self._drop_live_report()
        self._show_measures(event)
        if event.scene is not None:
            self._shown = event.scene
        if self.session is None or self._shown is None:   # the core failed to load
            self.runner.finished()
            self._show_state()
            return
        self.repl.set_prompt(self.session.in_block)
        self._refresh_views(event.info)
        if event.info is None and not (self.script is not None and self.script.running):
            self.runner.submit(Job("", origin=Origin.MEASURE))   # a replay paused on an unmeasured line
        self.runner.finished()
        self._feed_script()
        self._show_state()

    def _show_measures(self, event: CommandFinished) -> None:
        """The status line's numbers after a command: the scene's, measured in the worker after
        every command (whatever it was: undo, reject, open, adopt, a solve). A replayed line
        with more to come is not measured: a solve's last iterate stands in for it, and after
        any other change the numbers shown are marked stale until the next measurement."""
        info, outcome = event.info, event.outcome
        if info is not None and (info.measures is not None or (event.scene is not None and not event.scene.dofs)):
            self.status_line.measured(info.measures, info.proposal.proposed if info.proposal is not None else None)
        elif event.error is None and outcome is not None and outcome.run is not None and outcome.run.reports:
            self.status_line.show(report=outcome.run.reports[-1])
        elif event.error is None and info is None and changes_scene(event.job.line):
            self.status_line.show(stale=True)   # the numbers shown no longer hold

    def on_task_finished(self, event: TaskFinished) -> None:
        if event.error is not None:
            self.repl.write_error(event.error)
        elif event.job.origin == Origin.COMPARE:
            self._show_compare(event.result)
        self.runner.finished()
        self._feed_script()
        self._show_state()

    @property
    def settled(self) -> bool:
        """Nothing running, queued, replaying or waiting to be redrawn (tests wait for this)."""
        replaying = self.script is not None and self.script.running
        if self.runner.busy or self.runner.queue or replaying or self._views.pending or self._live.pending:
            return False
        return not any(plot.redraw_pending for plot in self.query(ScenePlot))

    def _refresh_views(self, info=None) -> None:
        """Show the scene in the panels and plots, at most ~10 times a second (twice while a
        session replays; its last line, or the one it pauses at, at once)."""
        if info is not None:
            self._info = info
        script = self.script
        replaying = script is not None and script.running and script.upcoming() is not None
        interval = REPLAY_VIEW_INTERVAL if replaying else VIEW_INTERVAL
        if interval != self._views.throttle.interval:
            self._views.throttle.interval = interval
            if not replaying:
                self._views.cancel()   # a refresh waiting out the replay's interval: now instead
        self._views.request()

    def _open_on_figure(self, scene: "Scene | None") -> None:
        """Bring the figure player to the front the first time the scene has a linkage or a point
        object (a pair of x/y names), unless a plot was chosen before: the motion is what an
        animator opened the session to see (it took F3 three times and Space)."""
        if self._plot_chosen or scene is None or scene is self._figure_checked:
            return
        self._figure_checked = scene
        from stw_tui.session.figure import point_pairs

        try:
            drawable = bool(scene.linkages) or bool(point_pairs(scene))
        except Exception:   # a half-built scene: the curves stay in front
            return
        if drawable:
            self._plot_chosen = True
            self.query_one("#plots", Deck).active = "tab-figure"

    def _show_views(self) -> None:
        scene = self._shown
        self._open_on_figure(scene)
        for deck in self.query(Deck):
            kept = self._kept_up_to_date(deck)
            for widget in deck.views.values():
                # Other hidden views are brought up to date when shown (_bring_up_to_date).
                if widget in kept:
                    self._stale.discard(widget.id)
                    widget.set_scene(scene, self._info)
                else:
                    self._stale.add(widget.id)
        self.status_line.show(backend=scene.backend, window=scene.active_window)

    @staticmethod
    def _kept_up_to_date(deck: Deck) -> tuple[Widget, ...]:
        """The views of ``deck`` that every refresh reaches: the shown one and, of a deck whose
        views work in the background (the plots': data and text), the one its key shows next, so
        that key draws it once, as it is. (Keeping all three hidden live plots up to date
        during a solve doubled the TUI's CPU time on basketball at 80x24, and its event loop's
        stalls over 10 ms went from 1-2 to 19-26 in 20 s.)"""
        return (deck.current, deck.upcoming) if deck.ahead else (deck.current,)

    def _prepare_plot(self, widget: Widget) -> None:
        """A plot about to be shown, or to come next (Deck.prepare): brought up to date. Shown
        while a solve runs, it holds the running solve's last redraw (the next plot follows every
        one), and the next redraw is deferred to LIVE_INTERVAL from now: one sooner redrew it
        within a fraction of a second of the switch, a second draw (the Conv plot's count, at
        once in one F3 of two in tmux)."""
        self._bring_up_to_date(widget)
        if widget is self.query_one("#plots", Deck).current and self.runner.solving:
            self._live.defer()

    def _bring_up_to_date(self, widget: Widget) -> None:
        """A view about to be shown (Deck.prepare): show it the scene if it missed a refresh, while
        still hidden, so the switch draws it once, as it will stay."""
        if widget.id in self._stale and self._shown is not None:
            self._stale.discard(widget.id)
            if isinstance(widget, self.LIVE_PLOTS):
                widget.set_scene(self._shown, self._info, coefficients=self._coefficients)
            else:
                widget.set_scene(self._shown, self._info)

    def on_item_chosen(self, event: ItemChosen) -> None:
        if event.kind == "dof":
            plot, tab = self.query_one(DofPlot), "tab-curves"
            plot.dof = event.name
        else:
            plot, tab = self.query_one(ExpressionPlot), "tab-expr"
            plot.name_shown = event.name
        self._plot_chosen = True
        self.query_one("#plots", Deck).active = tab
        plot.request_data()

    # --- focus and keys ----------------------------------------------------------------------
    def on_descendant_focus(self, event: events.DescendantFocus) -> None:
        """Mark the tab bar of the tab group that holds the focus (see app.tcss)."""
        if len(self.screen_stack) == 1:
            focused = self.focused
            for deck in self.query(Deck):
                deck.mark(focused is not None and deck in focused.ancestors)

    async def on_event(self, event: events.Event) -> None:
        """A printable key that nothing binds, typed while a panel or plot has the focus, is
        typing meant for the console: focus the console *before* Textual hands the key to the
        focused widget, so this key and the ones right behind it land there, in order.

        (Moving the focus once the key had bubbled back up to the app lost keys typed fast: the
        next ones were already on their way to the panel, and reached the app after the focus.)
        """
        if isinstance(event, events.Key) and not event.is_forwarded and self._typed_for_console(event):
            self.screen.set_focus(self.repl.input)
        await super().on_event(event)

    def _typed_for_console(self, key: events.Key) -> bool:
        if not key.is_printable or key.character is None or len(self.screen_stack) > 1:
            return False
        return self.focused is not self.repl.input and key.key not in self.active_bindings

    def check_action(self, action: str, parameters: tuple) -> bool | None:
        """Enable stepping only while a session file has lines left, the gallery only after a
        survey, and the palette not while the terminal is too small."""
        if action == "command_palette" and isinstance(self.screen, TooSmallScreen):
            return False    # (the palette's key is the one that reaches past that modal screen)
        if action in ("step", "run_rest"):
            return self.script is not None and not self.script.done
        if action == "gallery":
            return self.session is not None and self.session.survey is not None
        return True

    def _cycle_tabs(self, deck_id: str) -> None:
        """Focus the deck's shown view; when it already has the focus, show the next one.
        Only on the main screen: pressed on the help screen, F2 and F3 moved its focus to a panel
        behind it, and Esc then no longer closed it (found by the key sweep). (Not disabled in
        check_action: the palette lists what that allows, and it is open when it asks.)"""
        if self.screen is not self.screen_stack[0]:
            return
        deck = self.query_one(f"#{deck_id}", Deck)
        if self.focused is not None and deck in self.focused.ancestors:
            deck.active = deck.next_tab()
        # set_focus now, not focus() (deferred): a second key press may arrive before a redraw.
        self.screen.set_focus(deck.current)

    def action_panels(self) -> None:
        self._cycle_tabs("panels")

    def action_plots(self) -> None:
        if self.screen is self.screen_stack[0]:
            self._plot_chosen = True
        self._cycle_tabs("plots")

    def action_help(self) -> None:
        """F1: the full-screen help (tutorial, keys, commands)."""
        if isinstance(self.screen, HelpScreen):
            return
        areas = [(f"{title} panel", cls) for title, cls in PANELS] + [(f"{title} plot", cls) for title, cls in PLOTS]
        self.push_screen(HelpScreen(help_sections(self, areas), blink=self.blink))

    def action_undo(self) -> None:
        """Ctrl+Z: the console's `undo` (journalled like any command)."""
        self.submit("undo", origin=Origin.KEY)

    def action_redo(self) -> None:
        self.submit("redo", origin=Origin.KEY)

    def action_accept(self) -> None:
        """F9: the console's `accept` of a solve's proposal under `set preview on`."""
        self.submit("accept", origin=Origin.KEY)

    def action_reject(self) -> None:
        self.submit("reject", origin=Origin.KEY)

    def action_iterate(self) -> None:
        self.submit(f"iterate {self.query_one(OptimizationPanel).iterations}", origin=Origin.KEY)

    def action_compare(self) -> None:
        """Solve copies of the scene with each installed backend (`iterate N` each, N from the Opt
        panel) in the worker, then show the table. Read-only: nothing is journalled."""
        n = self.query_one(OptimizationPanel).iterations
        backends = self._backend_names()

        def task(session: "Session") -> tuple[int, list[dict]]:
            from stw_tui.session.compare import compare_scene

            return n, compare_scene(session.scene, n, backends, label="session")

        waiting = self.runner.submit(Job("", origin=Origin.COMPARE, task=task))
        note = " (after the running command)" if waiting else ""
        self.repl.write_note(f"comparing {', '.join(backends)}: up to {n} iteration(s) each{note}…")
        self._show_state()

    def _show_compare(self, result: tuple[int, list[dict]]) -> None:
        n, rows = result
        self.repl.write_note(f"compared {len(rows)} backend(s): "
                             + ", ".join(f"{r['backend']} {'converged' if r['converged'] else 'not converged'}"
                                         f" in {r['iterations']}" for r in rows))
        self.push_screen(CompareScreen(rows, n, show_timing=self.show_timing))

    def action_step(self) -> None:
        if self.script is not None and not self.script.done:
            self.script.running = False
            if self.runner.busy:
                self.repl.write_note("busy: the next line runs when the current command ends")
            self._send_next_line()

    def action_run_rest(self) -> None:
        if self.script is not None and not self.script.done:
            self.script.running = True
            self._feed_script()

    def action_play(self) -> None:
        self._plot_chosen = True
        self.query_one("#plots", Deck).active = "tab-figure"
        self.query_one(FigurePlot).action_play()

    def action_stop(self) -> None:
        """F4: stop a solve at the next iteration boundary, and pause a replay."""
        stopped = self.runner.stop()
        if stopped:
            self.repl.write_note("stopping at the next iteration boundary…")
        if self.script is not None and self.script.running:
            self.script.running = False
            if not (stopped and self.runner.current.origin == Origin.FILE):   # else the solve's end says it
                self.repl.write_note("replay paused: F6 next line, F7 the rest" + self._held_note())
        elif not stopped:
            self.repl.write_note("nothing to stop")
        self._show_state()

    def _held_note(self) -> str:
        """What a paused replay's note adds about the commands waiting for its end."""
        held = self.script.held if self.script is not None else []
        return f"; {len(held)} command(s) typed during it run at its end" if held else ""

    def action_escape(self) -> None:
        """Esc: return to the console; at the console, drop an open linkage block. Never stops a solve."""
        if self.focused is not self.repl.input:
            self.repl.input.focus()
        elif self.session is not None and self.session.in_block and not self.runner.busy:
            self.session.cancel_block()
            self.repl.set_prompt(False)
            self.repl.write_note("linkage block dropped")

    async def action_quit(self) -> None:
        """Ctrl+Q: exit at once. A running solve's process is killed; another job is told to stop
        and left behind (a daemon thread)."""
        self.runner.abandon()
        self.exit()

    def _hung_up(self) -> None:
        """SIGHUP (the terminal or the SSH connection closed): quit as Ctrl+Q does, the journal and
        the solve's checkpoint kept, instead of the default abrupt end that left the solver process
        to fail on a broken pipe. A terminal that is gone may keep Textual from finishing: the
        process ends within HANGUP_EXIT_S regardless (the journal is on disk line by line)."""
        timer = threading.Timer(HANGUP_EXIT_S, os._exit, (EXIT_HANGUP,))
        timer.daemon = True
        timer.start()
        self.runner.abandon(grace=HANGUP_GRACE)
        self.exit(return_code=EXIT_HANGUP)


def _was_stopped(outcome) -> bool:
    """Whether a command's solve ended because the user stopped it."""
    from stw_tui.sos.backend import Status

    run = getattr(outcome, "run", None)
    return run is not None and run.status is Status.STOPPED
