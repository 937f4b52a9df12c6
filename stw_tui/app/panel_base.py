"""Base classes of the scene panels: a table that shows state and *emits command lines* to change it.

A panel never touches the scene. Every edit becomes one command line posted as
:class:`CommandRequested`; the app runs it through the session like a typed command, so it shows
in the console and lands in the journal.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Callable, Iterable

from rich.text import Text
from textual.widgets import DataTable

from stw_tui.app.dialogs import EditDialog
from stw_tui.app.messages import CommandRequested
from stw_tui.session.queries import SceneInfo

if TYPE_CHECKING:
    from stw_tui.sos.scene import Scene


def num(value: float | None) -> str:
    """A number as typed in a command (enough digits to round-trip what the user sees)."""
    return "" if value is None else f"{value:.10g}"


def show(value: float | None) -> str:
    """A number for a table cell."""
    return "—" if value is None else f"{value:.6g}"


def short(value: float | None) -> str:
    """A number for a narrow table cell (3 significant digits: `show NAME` has them all)."""
    return "—" if value is None else f"{value:.3g}"


MAX_WIDTH = 48   # longest cell shown in full
FLEX_MIN = 8     # narrowest the last column is cut to, to fit the panel's width
NAME_MIN = 12    # narrowest the first column (the names) is cut to, to keep the next ones in view
GAP = 1          # blank cells between columns (DataTable's own padding is two: one either side)


def _cell(value) -> "Text | object":
    """A cell as plain text, ending in an ellipsis where the column is narrower. DataTable reads
    a str cell as Rich markup: user text with [brackets] would be restyled or rejected, and
    parsing every cell again at each focus change (which clears the table's caches) was most of
    an F2's UI time on basketball at 80x24."""
    if isinstance(value, str):
        return Text(value, no_wrap=True, overflow="ellipsis", end="")
    if isinstance(value, Text):
        value.no_wrap, value.overflow = True, "ellipsis"
    return value


def column_widths(labels, rows, room: int | None, keep: int = 2) -> list[int]:
    """The width of each column: its longest cell or label (at most MAX_WIDTH). When ``room`` (the
    panel's width) is known and they do not all fit, the last column (a definition, a help text)
    gets what is left, down to FLEX_MIN; and a first column (the names) so long that the first
    ``keep`` columns (the Eqns panel's name, violation and scope) would not be in view is cut,
    down to NAME_MIN. The full text is in the dialog, `show` and `help`."""
    widths = [min(MAX_WIDTH, max([len(str(label))] + [len(str(cells[i])) for cells in rows]))
              for i, label in enumerate(labels)]
    if room and widths:
        left = room - sum(widths[:-1]) - GAP * (len(widths) - 1)
        widths[-1] = max(min(widths[-1], left), min(widths[-1], FLEX_MIN))
        if len(widths) > keep:
            others = sum(widths[1:keep]) + GAP * (keep - 1)
            widths[0] = max(min(widths[0], room - others), min(widths[0], NAME_MIN))
    return widths


class ScenePanel(DataTable):
    """A row-per-item table of one aspect of the scene. Subclasses define COLUMNS and rows()."""

    COLUMNS: tuple[str, ...] = ()
    KEEP_IN_VIEW = 2     # columns kept in view in a narrow panel (see column_widths)

    def __init__(self, **kwargs):
        # One blank between columns (GAP, in the widths) instead of DataTable's two: at 80x24 a
        # panel is 40 columns wide.
        super().__init__(cursor_type="row", zebra_stripes=True, cell_padding=0, **kwargs)
        self.scene: "Scene | None" = None
        self.info = SceneInfo()
        self._rows: list[tuple[str, tuple]] | None = None   # what the table shows

    def on_mount(self) -> None:
        self._widths: list[int] = []
        self._set_columns([len(label) for label in self.COLUMNS])

    def _set_columns(self, widths: list[int]) -> None:
        # Explicit widths: DataTable's own auto widths are measured on idle, and a table refilled
        # just as its tab is shown sometimes kept the header widths (flaky snapshots, cut names).
        self.clear(columns=True)
        self._rows = None
        last = len(self.COLUMNS) - 1
        for i, (label, width) in enumerate(zip(self.COLUMNS, widths)):
            self.add_column(label, width=width + (GAP if i < last else 0), key=label or "_")
        self._widths = widths

    def _room(self, rows: int) -> int | None:
        """The columns the table has for its cells when it shows ``rows`` rows, less a vertical
        scrollbar when they do not fit its height (None before it is laid out). A hidden panel
        (in a Deck) takes its deck's size: brought up to date just before it is shown, it is drawn
        once, with the columns it keeps (not refitted once laid out: a second draw)."""
        width, height = self.size
        if width <= 0 and self.parent is not None and not self.display:
            width, height = self.parent.size
        if width <= 0:
            return None
        if rows + self.show_header > height:
            width -= self.styles.scrollbar_size_vertical
        return width

    def on_resize(self) -> None:
        """Fit the columns to the new width (the last one is cut to fit, see column_widths); not
        in a hidden tab, nor when they are as they were (a tab shown at the size it had)."""
        if self.scene is None or not self.size.width:
            return
        rows = [cells for _, cells in self.table_rows(self.scene, self.info)]
        if column_widths(self.COLUMNS, rows, self._room(len(rows)), self.KEEP_IN_VIEW) != self._widths:
            self.set_scene(self.scene)

    def set_scene(self, scene: "Scene", info: SceneInfo | None = None) -> None:
        """Show ``scene``; the cursor stays on the same row."""
        self.scene = scene
        if info is not None:
            self.info = info
        row = self.cursor_row
        rows = list(self.table_rows(scene, self.info))
        widths = column_widths(self.COLUMNS, [cells for _, cells in rows], self._room(len(rows)),
                               self.KEEP_IN_VIEW)
        if widths == self._widths and rows == self._rows:
            return    # nothing changed: not cleared and drawn again
        self._rows = rows
        if widths != self._widths:
            self._set_columns(widths)
        else:
            self.clear()
        for key, cells in rows:
            self.add_row(*map(_cell, cells), key=key)
        if self.row_count:
            self.move_cursor(row=min(row, self.row_count - 1))

    def table_rows(self, scene: "Scene", info: SceneInfo) -> Iterable[tuple[str, tuple]]:
        """(row key, cells) of every row the panel shows for ``scene``."""
        raise NotImplementedError

    @property
    def selected(self) -> str | None:
        """The key of the row under the cursor."""
        if not self.row_count:
            return None
        return self.coordinate_to_cell_key(self.cursor_coordinate).row_key.value

    def emit(self, line: str) -> None:
        """Ask the app to run ``line`` as if typed in the console (journalled, undoable)."""
        self.post_message(CommandRequested(line))

    def ask(self, title: str, value: str, build: Callable[[str], str | None]) -> None:
        """Ask for a value; when given, run the command line ``build(value)``."""

        def done(answer: str | None) -> None:
            if answer is not None and answer.strip():
                line = build(answer.strip())
                if line:
                    self.emit(line)

        blink = getattr(self.app, "blink", True)
        self.app.push_screen(EditDialog(title, value, f"runs: {build('…')}", blink=blink), done)

    def on_data_table_row_selected(self, event: DataTable.RowSelected) -> None:
        event.stop()
        if self.selected is not None:
            self.activate(self.selected)

    def activate(self, key: str) -> None:
        """Enter on a row (edit its value, choose it for a plot…)."""


@dataclass
class SettingRow:
    """One editable row: what it shows and the command line an edit runs."""

    key: str
    label: str
    value: str
    build: Callable[[str], str] | None = None     # None: read-only
    help: str = ""


class SettingsPanel(ScenePanel):
    """A two-column table of settings; Enter edits the one under the cursor."""

    COLUMNS = ("setting", "value", "")

    def settings(self, scene: "Scene", info: SceneInfo) -> list[SettingRow]:
        """The panel's rows for ``scene``: what each shows and the command an edit runs."""
        raise NotImplementedError

    def table_rows(self, scene, info):
        """One row per setting: label, value and help."""
        self._settings_by_key = {row.key: row for row in self.settings(scene, info)}
        return [(row.key, (row.label, row.value, row.help)) for row in self._settings_by_key.values()]

    def activate(self, key: str) -> None:
        """Edit the setting under the cursor through a dialog, unless it is read-only."""
        row = self._settings_by_key[key]
        if row.build is None:
            self.app.notify(f"{row.label} is read-only here", severity="warning", markup=False)
            return
        value = row.value if row.value != "—" else ""
        self.ask(f"{row.label}{' — ' + row.help if row.help else ''}", value, row.build)
