"""The Pilot key sweep (issue 52 item 1): in a scene from each bundled session, every bound key is
pressed at the console, on every panel (F2 cycles), on every plot (F3 cycles), in every dialog or
screen a key opens, and in the survey gallery; no key may raise, and the journal stays intact.

The keys are read from the bindings active where the focus is (``Screen.active_bindings``), so a
binding added to the app, a panel, a plot, a dialog or the gallery is pressed without editing
this test (and the test checks that each key a class binds was pressed in its area). Left out:
Ctrl+Q (pressed once, last: it quits), and the text-editing keys of Textual's Input (cursor moves,
deletions, cut and paste, Enter in a dialog's field: they act on the field's text, and a dialog is
left with Esc); the console's own keys (history, Tab, PgUp/PgDn) are pressed. The app's keys
(F1-F10, Ctrl+Z/Y, Ctrl+P...) are pressed at the console, and on each screen that lets them
through (the help screen; a modal dialog, the palette and the gallery do not), not again on every
panel and plot: they do the same from any focus there, and F2, F3 and Esc are pressed on every
panel and plot anyway. F6 and F7 step an opened session
file: with none open they are disabled, and pressed anyway.

*The journal intact*: the journal file's lines before the sweep are, unchanged and in order, the
first lines of the file after it, and every entry the sweep added is a command line a key asked
for, which the worker ran (F5's `iterate 1`, the DOF panel's `refine`, Ctrl+Z's `undo`, the Win
panel's `use`, the gallery's `adopt`...). Such a line may have failed, and is then journalled as
a `# failed:` comment with its reason, never replayed, as any failed line is: F9 and F10 with no
proposal to accept or reject, or the gallery's `adopt` once the keys have changed the scene the
survey started from.

To keep it quick (about a minute for the nine sessions on two cores), each scene is the session's
lines without its solves and prints (the scene as set up, not solved), solves run one iteration
(the Opt panel's `iterate N` set to 1) in the app's own process, and a two-start serial survey
fills the gallery (converged optima on the particle jet, whose survey is cheap to solve; on the
others, one iteration a start: the gallery lists what did not converge).

There is no async test plugin here, so each session's scenario runs with ``asyncio.run``.
"""

from __future__ import annotations

import asyncio
from collections import defaultdict
from pathlib import Path

import pytest
import textual.app
import textual.pilot
from textual.binding import Binding
from textual.widgets import Input

import test_app_support as support
from stw_tui.app import StwApp, create_app
from stw_tui.app.app import PANELS, PLOTS
from stw_tui.app.console import CommandInput
from stw_tui.app.dialogs import CompareScreen, EditDialog
from stw_tui.app.gallery import GalleryScreen
from stw_tui.app.help_screen import HelpScreen
from stw_tui.app.messages import CommandStarted, Origin
from stw_tui.app.panel_base import ScenePanel
import catalogue
from stw_tui.app.panels import OptimizationPanel
from stw_tui.app.plots import FigurePlot, ScenePlot
from stw_tui.session.child_process import runs_in_solver_process
from stw_tui.session.session import Session
from stw_tui.sym.language import classify_line

# (the catalogue's HEAVY sessions compile for minutes before their first key: test_jumper.py)
SESSION_FILES = sorted(p for p in support.SESSIONS.glob("*.stw") if p.stem not in catalogue.HEAVY)
QUIT_KEYS = {"ctrl+q"}
# Keys Textual's Input binds for editing its text (the console's own bindings are not among them)
TEXT_KEYS = {(key.strip(), binding.action) for binding in Input.BINDINGS for key in binding.key.split(",")}
SIZE = (80, 24)


def scene_lines(path: Path) -> list[str]:
    """The session's lines that set its scene up: all but its solves and prints."""
    kept = []
    for line in path.read_text(encoding="utf-8").splitlines():
        kind = classify_line(line)
        if kind.is_blank or kind.verb == "print" or runs_in_solver_process(line):
            continue
        kept.append(line)
    return kept


def set_up(path: Path, journal: Path) -> Session:
    """A journalled session holding the scene of ``path`` and a two-start survey of it."""
    session = Session(journal_path=journal)
    session.run_text("\n".join(scene_lines(path)) + "\n")
    solve = "" if path.name == "particle_jet.stw" else " iterate=1"
    session.run_text(f"set scheduler serial\nsurvey 2 seed=1 window=all{solve}\n")
    return session


def own_keys(app, within) -> list[str]:
    """The keys bound where the focus is, by ``within`` or below it (a node: the app's own keys
    are not pressed again on every panel), less quitting and Textual's text-editing keys."""
    keys = []
    for key, active in app.screen.active_bindings.items():
        node = active.node
        if key in QUIT_KEYS or (isinstance(node, Input) and (key, active.binding.action) in TEXT_KEYS):
            continue
        if within is None or node is within or within in node.ancestors:
            keys.append(key)
    return keys


class Sweep:
    """Presses keys in one app and keeps what it pressed where."""

    def __init__(self, app, pilot):
        self.app, self.pilot = app, pilot
        self.pressed: dict[str, set[str]] = defaultdict(set)   # keys pressed in each area (class name)
        self.played = False                                     # a key started the figure player

    async def quiet(self) -> None:
        """Wait until the worker has nothing running or queued (plots may still draw)."""
        runner = self.app.runner
        if runner.busy or runner.queue:
            await support.until(self.pilot, lambda: not runner.busy and not runner.queue, "the worker idle",
                                timeout=120)
            await self.pilot.pause()

    async def press(self, area: str, key: str) -> None:
        self.pressed[area].add(key)
        await self.pilot.press(key)
        await self.pilot.pause()     # what the key's handlers deferred (a focus, a screen pushed)
        await self.quiet()
        assert self.app._exception is None, (area, key, self.app._exception)
        figure = self.app.query_one(FigurePlot)
        if figure.playing:    # F8, Space, the gallery's Enter: played; stopped, or it redraws all along
            self.played = True
            figure.action_play()

    async def keys_at(self, area: str, focus, keys: list[str]) -> None:
        """Press each of ``keys`` with the focus on ``focus``; sweep each screen one opens."""
        main = self.app.screen_stack[0]
        for key in keys:
            async def open_it(key=key):
                self.app.screen.set_focus(focus)
                await self.press(area, key)

            await open_it()
            if self.app.screen is not main:
                await self.screen_keys(open_it, opened=True)

    async def screen_keys(self, open_it, opened: bool = False) -> None:
        """Press each key of the screen ``open_it`` opens (open already when ``opened``), opening
        it again after a key that closes it. The app's keys are pressed too where the screen lets
        them through (the help screen is not modal). The screen's own keys go last (Esc, the gallery's
        Enter and `a`, the comparison's `c`: the ones that close it), Esc the very last. A kind of
        screen already swept (the panels open a dozen edit dialogs) is only closed, with Esc."""
        main = self.app.screen_stack[0]
        remaining: list[str] | None = None
        while True:
            if not opened:
                await open_it()
            opened = False
            screen = self.app.screen
            if screen is main:
                return
            area = type(screen).__name__
            if remaining is None:
                own = declared_keys(type(screen))
                remaining = sorted(own_keys(self.app, None), key=lambda k: (k == "escape", k in own))
                if area in self.pressed:
                    remaining = ["escape"]
            while remaining:
                await self.press(area, remaining.pop(0))
                if self.app.screen is not screen:
                    break
            else:
                await self.escape_to(main)
                return
            await self.escape_to(main)
            if not remaining:
                return

    async def escape_to(self, main) -> None:
        """Esc until ``main`` shows again (a key may have opened a screen over a screen)."""
        for _ in range(5):
            if self.app.screen is main:
                return
            await self.press(type(self.app.screen).__name__, "escape")
        assert self.app.screen is main, self.app.screen_stack


def declared_keys(cls) -> set[str]:
    """The keys a class binds itself (its BINDINGS; a binding may name several keys)."""
    return {key.strip() for b in cls.__dict__.get("BINDINGS", []) if isinstance(b, Binding)
            for key in b.key.split(",")}


def added_entries(before: list[str], after: list[str]) -> tuple[list[str], list[str]]:
    """(command lines, failed lines) the journal gained: ``after`` less its first lines (a failed
    line is a `# failed: LINE` comment, then one with the reason)."""
    ok, failed = [], []
    for line in after[len(before):]:
        if line.startswith("# failed: "):
            failed.append(line[len("# failed: "):])
        elif not line.startswith("#"):
            ok.append(line)
    return ok, failed


async def _yield(*_args, **_kwargs) -> None:
    await asyncio.sleep(0)


async def _open_gallery(sweep: Sweep) -> None:
    """The palette's "Survey gallery" (no key opens it)."""
    sweep.app.action_gallery()
    await sweep.quiet()


@pytest.mark.parametrize("path", SESSION_FILES, ids=lambda p: p.stem)
def test_every_bound_key_everywhere_leaves_the_app_up_and_the_journal_intact(path, tmp_path, monkeypatch):
    # Pilot waits after each key until the process's CPU has been idle for 20 ms (up to 1 s),
    # which the plots' background drawing postpones: 90 ms a key here. Each key is handled whole
    # without it (Pilot still waits for every message the key queued, and the sweep for the
    # worker); the plots draw between keys and at the end.
    monkeypatch.setattr(textual.app, "wait_for_idle", _yield)
    monkeypatch.setattr(textual.pilot, "wait_for_idle", _yield)
    journal = tmp_path / "journal.stw"
    app = create_app(session=set_up(path, journal), show_timing=False, blink=False, solver_process=False)
    started: list[str] = []

    def hook(message) -> None:
        if isinstance(message, CommandStarted) and message.job.origin not in (Origin.STARTUP, Origin.MEASURE):
            started.append(message.job.line)

    async def scenario(pilot):
        await support.settle(pilot, timeout=120)
        before = journal.read_text(encoding="utf-8").splitlines()
        app.query_one(OptimizationPanel).iterations = 1    # F5 and the Opt panel's `i`: one iteration
        sweep = Sweep(app, pilot)
        console = app.repl.input
        keys = own_keys(app, None)
        keys += sorted(declared_keys(StwApp) - QUIT_KEYS - set(keys))   # disabled now (F6, F7: no file to step)
        await sweep.keys_at("console", console, keys)
        for group, kind, count in (("f2", ScenePanel, len(PANELS)), ("f3", ScenePlot, len(PLOTS))):
            seen, widget = [], console
            for _ in range(count):
                app.screen.set_focus(widget)      # F2 (F3) from the console: the active one; then the next
                await sweep.press(group, group)
                widget = app.focused
                assert isinstance(widget, kind), (group, widget)
                seen.append(type(widget).__name__)
                await sweep.keys_at(type(widget).__name__, widget, own_keys(app, widget))
            assert len(set(seen)) == count, seen     # each panel (plot) once
        await sweep.screen_keys(lambda: _open_gallery(sweep))
        figure = app.query_one(FigurePlot)
        if figure.playing:
            figure.action_play()
        await support.settle(pilot, timeout=120)
        assert app._exception is None, app._exception
        await pilot.press("ctrl+q")
        return before, sweep

    async def main():
        async with app.run_test(size=SIZE, message_hook=hook) as pilot:
            return await scenario(pilot)

    before, sweep = asyncio.run(main())
    assert app._exception is None, app._exception
    assert app.return_code == 0
    # Every key each area binds itself was pressed there (the reading of the bindings works)
    areas = {"console": [StwApp, CommandInput], **{cls.__name__: [cls] for _, cls in PANELS + PLOTS},
             **{cls.__name__: [cls] for cls in (EditDialog, HelpScreen, CompareScreen, GalleryScreen)}}
    for area, classes in areas.items():
        wanted = set().union(*map(declared_keys, classes)) - QUIT_KEYS
        assert wanted <= sweep.pressed[area], (area, wanted - sweep.pressed[area])
    assert "CommandPalette" in sweep.pressed and sweep.played
    after = journal.read_text(encoding="utf-8").splitlines()
    assert after[:len(before)] == before                      # nothing before the keys rewritten or lost
    ok, failed = added_entries(before, after)
    assert all(line in started for line in ok + failed), (ok, failed, started)
    assert {"iterate 1", "undo", "redo"} <= set(ok)

