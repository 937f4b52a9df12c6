"""Text the user, a session file, the help or a plugin wrote is shown literally, never interpreted:
not as Textual markup in a dialog, label or table (issue 52: `n` on the Win panel crashed on
its title `New window: NAME [dofs=a,b|all] [[A, B]]`), and not as escape sequences by the
terminal, in the TUI or headless (issue 54: a session line's OSC 52 wrote the clipboard).

There is no async test plugin here, so each TUI test runs its scenario with ``asyncio.run``.
"""

from __future__ import annotations

import asyncio
import os
import subprocess
import sys
import textwrap

from textual.widgets import Label, Static

import test_app_support as support
from stw_tui.app import create_app
from stw_tui.app.panels import (ConstantsPanel, DofPanel, EquationsPanel, OptimizationPanel, TimePanel,
                                WindowsPanel)
from stw_tui.sym.errors import printable

ESC = "\x1b"
# What a hostile line may carry: OSC 52 (clipboard), OSC 2 (title), SGR (colours), a C1 CSI
# (U+009B), bidi overrides and isolates, DEL and a bell.
HOSTILE = (f"{ESC}]52;c;aGVsbG8={ESC}\\ {ESC}]2;TITLE{ESC}\\ {ESC}[41m \u009b31m \u202egnp.exe "
           f"\u202a\u202b\u202c\u202d \u2066\u2067\u2068\u2069 \x7f\x07")
RAW = [chr(c) for c in (*range(0x00, 0x09), *range(0x0b, 0x20), *range(0x7f, 0xa0),
                        *range(0x202a, 0x202f), *range(0x2066, 0x206a))]   # all but \t and \n

# Panel order (F2 cycles): every key bound on each panel and Enter on each row are pressed (and F1,
# the help screen, on the last: after it the focus is elsewhere and F2 starts the cycle again).
PANELS = (DofPanel, EquationsPanel, ConstantsPanel, WindowsPanel, TimePanel, OptimizationPanel)


def raw_in(text: str) -> list[str]:
    """The characters of ``text`` a terminal would act on instead of showing."""
    return sorted({c for c in text if c in RAW})


def run(scenario, app, size=(120, 40)):
    async def main():
        async with app.run_test(size=size) as pilot:
            await support.settle(pilot)
            await scenario(pilot)

    asyncio.run(main())
    assert app._exception is None, app._exception   # the app did not die on the way


def literal_texts(screen) -> list[tuple[str, str]]:
    """(what each label or static was given, what it shows) for every one holding a str."""
    pairs = []
    for widget in screen.query(Static):      # Label is a Static
        content = widget.content
        if isinstance(content, str) and content:
            pairs.append((content, widget.render().plain))
    return pairs


def test_every_dialog_a_panel_key_opens_shows_its_text_literally():
    """F2 to each panel; each of its keys (and Enter on each row) that opens a dialog opens it
    without an exception, with every label shown as given (`[dofs=a,b|all]` included)."""
    app = create_app(support.SESSIONS / "particle_jet.stw", show_timing=False, solver_process=False)
    opened: list[tuple[str, str, str]] = []

    async def scenario(pilot):
        for index, panel_class in enumerate(PANELS):
            await pilot.press("f2")
            panel = app.focused
            assert isinstance(panel, panel_class), (index, panel)
            keys = [b.key for b in panel_class.BINDINGS] + ["enter"] + (["f1"] if index == 5 else [])
            for key in keys:
                for row in range(panel.row_count if key == "enter" else 1):
                    panel.focus()
                    panel.move_cursor(row=row)
                    await pilot.press(key)
                    await support.settle(pilot, timeout=120)
                    await pilot.pause()
                    if len(app.screen_stack) == 1:      # no dialog: the key emitted a command
                        continue
                    for given, shown in literal_texts(app.screen):
                        assert shown == given, (panel_class.__name__, key, given, shown)
                        opened.append((panel_class.__name__, key, shown))
                    await pilot.press("escape")
                    await pilot.pause()
                    assert len(app.screen_stack) == 1

    run(scenario, app)
    titles = [shown for _panel, _key, shown in opened]
    assert "New window: NAME [dofs=a,b|all] [[A, B]]" in titles          # the crash of issue 52
    assert any(title.startswith("runs: set ") for title in titles)        # Enter on a setting
    assert any(key == "f1" for _panel, key, _shown in opened)
    assert {panel for panel, _key, _shown in opened} >= {"DofPanel", "EquationsPanel", "ConstantsPanel",
                                                         "WindowsPanel", "TimePanel", "OptimizationPanel"}
    assert any(key == "c" for panel, key, _ in opened if panel == "OptimizationPanel")   # compare table


def test_a_dialog_shows_markup_and_control_characters_literally():
    from stw_tui.app.dialogs import EditDialog

    app = create_app(show_timing=False, blink=False)
    title = "New [b]x[/b] [dofs=a,b|all] [[A, B]] [$v] [/close] trailing\\" + ESC + "]2;T" + ESC + "\\"

    async def scenario(pilot):
        app.push_screen(EditDialog(title, "[@click=x]", hint="[red]hint[/red] \u202e"))
        await pilot.pause()
        shown = dict((w.id, w.render().plain) for w in app.screen.query(Label))
        assert shown["dialog-title"] == printable(title)
        assert shown["dialog-hint"] == "[red]hint[/red] \\u202e"
        assert not raw_in(shown["dialog-title"] + shown["dialog-hint"])
        await pilot.press("escape")

    run(scenario, app)


def test_a_session_file_named_with_brackets_is_offered_by_the_palette(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "a[dofs=a,b|all][b].stw").write_text("dof x\n")
    app = create_app(show_timing=False, blink=False)

    async def scenario(pilot):
        from textual.command import CommandPalette

        await pilot.press("ctrl+p")
        await support.until(pilot, lambda: isinstance(app.screen, CommandPalette), "the palette open")
        await pilot.press(*"open a")
        await pilot.pause(0.5)
        await support.until(pilot, lambda: app.screen.query_one("CommandList").option_count > 0,
                            "a match listed")
        options = app.screen.query_one("CommandList")
        prompts = [str(options.get_option_at_index(i).prompt) for i in range(options.option_count)]
        assert any("a[dofs=a,b|all][b].stw" in p for p in prompts), prompts
        await pilot.press("escape")

    run(scenario, app)


def test_the_console_echoes_hostile_text_escaped(tmp_path):
    """A replayed line, a typed one, what a command prints and an error: shown with every control
    character escaped; the log holds no character a terminal would act on."""
    session = tmp_path / "hostile.stw"
    session.write_text(f"const c = 3 # {ESC}]2;REPLAYED{ESC}\\ \u009b1m\n", encoding="utf-8")
    app = create_app(session, show_timing=False, blink=False)

    async def scenario(pilot):
        await support.submit(pilot, f"const a = 1 # {HOSTILE}")
        await support.submit(pilot, f"const b{ESC}[41m = 2")          # an error with a caret
        await support.settle(pilot)
        app.repl.write_result(f"plugin says{ESC}]52;c;x{ESC}\\\nsecond \u202eline")
        app.repl.write_note(f"note {ESC}[2J")
        await pilot.pause()
        text = support.log_text(app)
        assert not raw_in(text)
        text = " ".join(text.split())     # as if the log were wide enough not to wrap
        assert "# \\x1b]52;c;aGVsbG8=\\x1b\\ \\x1b]2;TITLE\\x1b\\ \\x1b[41m \\x9b31m \\u202egnp.exe" in text
        assert "\\u2066\\u2067\\u2068\\u2069 \\x7f\\x07" in text
        assert "const b\\x1b[41m = 2" in text and "plugin says\\x1b]52;c;x\\x1b\\" in text
        assert "second \\u202eline" in text and "note \\x1b[2J" in text
        assert "1| const c = 3 # \\x1b]2;REPLAYED\\x1b\\ \\x9b1m" in text
        assert app.session.scene.constants["a"] == 1.0    # the comment did not change the command

    run(scenario, app)


def _stw(*args, env=None, cwd=None) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "stw_tui.cli.main", *args], capture_output=True,
                          text=True, encoding="utf-8", env=env, cwd=cwd, timeout=300)


def test_stw_run_prints_hostile_lines_and_paths_escaped(tmp_path):
    folder = tmp_path / "dir\u202eevil\u009b"
    folder.mkdir()
    session = folder / "s\u2066.stw"
    session.write_text(f"const a = 1 # {HOSTILE}\nprint a\nsave out\u202e\u2067.stw\n"
                       f"dof x\nconstraint c{ESC}]2;T{ESC}\\: x = 1 @ 0\n", encoding="utf-8")
    out = _stw("run", str(session), cwd=folder)   # a session file writes only inside its folder
    assert out.returncode == 2, out
    printed = out.stdout + out.stderr
    assert "saved 1 command line(s) to out\\u202e\\u2067.stw" in out.stdout
    assert "dir\\u202eevil\\x9b/s\\u2066.stw: line 5" in out.stderr
    assert "constraint c\\x1b]2;T\\x1b\\: x = 1 @ 0" in out.stderr
    assert not raw_in(printed), raw_in(printed)


HOSTILE_PLUGIN = textwrap.dedent('''
    """A backend whose messages carry escape sequences."""
    from stw_tui.sos.backend import Backend

    MESSAGE = "bad \\x1b]52;c;aGVsbG8=\\x1b\\\\ \\x9b31m \\u202eevil"

    class Hostile(Backend):
        """Raises at its first step \\x1b]2;TITLE\\x1b\\\\."""
        name = "hostile"

        def init(self, problem, state, settings):
            return state

        def step(self, problem, state, iteration):
            raise RuntimeError(MESSAGE)

        def state(self, inner):
            return inner
''')


def test_a_plugins_text_is_printed_escaped(tmp_path):
    (tmp_path / "stw_hostile.py").write_text(HOSTILE_PLUGIN)
    (tmp_path / "stw_gone.py").write_text("raise ImportError('missing \\x1b]2;TITLE\\x1b\\\\ \\u202e')\n")
    info = tmp_path / "stw_hostile-0.1.dist-info"
    info.mkdir()
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: stw-hostile\nVersion: 0.1\n")
    (info / "entry_points.txt").write_text("[stw_tui.backends]\nhostile = stw_hostile:Hostile\n"
                                           "gone = stw_gone:Nothing\n")
    env = dict(os.environ, PYTHONPATH=str(tmp_path) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    session = tmp_path / "s.stw"
    session.write_text("dof x\nobjective o: x - 1\nbackend hostile\niterate 2\n")
    solved = _stw("run", str(session), env=env)
    listed = _stw("backends", env=env)
    assert "bad \\x1b]52;c;aGVsbG8=\\x1b\\ \\x9b31m \\u202eevil" in solved.stderr, solved
    assert "missing \\x1b]2;TITLE\\x1b\\ \\u202e" in listed.stdout, listed
    assert "Raises at its first step \\x1b]2;TITLE\\x1b\\." in listed.stdout, listed
    for printed in (solved.stdout, solved.stderr, listed.stdout, listed.stderr):
        assert not raw_in(printed), raw_in(printed)
