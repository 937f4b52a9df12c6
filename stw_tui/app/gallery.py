"""The survey gallery: the distinct local optima of a survey, filled in as its starts come back.

One row per optimum (rank, objective, dense violation, how many starts reached it, a strip of
stick figures at a few times, descriptors), a progress bar while the survey runs, and what did not converge under it. Enter plays the
optimum under the cursor in the figure player, `a` adopts it (the `adopt K` command), Esc closes;
F4 (the app's key) cancels the starts still outstanding. The screen only shows: choosing an
optimum posts :class:`OptimumChosen` and the app acts on it.
"""

from __future__ import annotations

from dataclasses import dataclass

from textual.app import ComposeResult
from textual.binding import Binding
from textual.containers import Vertical
from textual.message import Message
from textual.screen import ModalScreen
from textual.widgets import DataTable, Label, ProgressBar

from stw_tui.app.thumbnails import curves, has_geometry, strip
from stw_tui.sym.errors import printable

GALLERY_COLUMNS = ("rank", "objective", "dense viol", "count", "frames", "descriptors")
THUMBNAIL = (5, 2)      # characters per frame (width, height) of the thumbnail strip


@dataclass
class OptimumChosen(Message):
    """The user chose optimum ``rank`` (from 1) of the survey shown: to ``play`` or ``adopt``."""

    rank: int
    action: str


def thumbnail(result) -> str:
    """Stick figures of a start's motion at a few times; its DOF curves where it has no figure."""
    if has_geometry(result.frames):
        return strip(result.frames, *THUMBNAIL)
    frames = len(result.frames) or 4
    width = frames * THUMBNAIL[0] + frames - 1          # as wide as the strip would be
    return curves(result.motion if result.motion is not None else [], width, THUMBNAIL[1])


class GalleryScreen(ModalScreen[None]):
    """The optima of a survey (a :class:`~stw_tui.session.survey.SurveyTable`), updated with :meth:`show`."""

    BINDINGS = [Binding("escape", "close", "Close"), Binding("a", "adopt", "Adopt"),
                Binding("enter", "play", "Play", show=False)]

    def __init__(self, table=None):
        super().__init__()
        self.table = table

    def compose(self) -> ComposeResult:
        with Vertical(id="gallery"):
            yield Label("Survey", id="gallery-title", markup=False)
            yield ProgressBar(id="gallery-progress", show_eta=False)
            yield DataTable(id="gallery-table", cursor_type="row", zebra_stripes=True)
            yield Label("", id="gallery-notes", markup=False)   # a start's error text: literal
            yield Label("Enter plays · a adopts · F4 cancels the starts left · Esc closes", id="gallery-hint")

    def on_mount(self) -> None:
        table = self.query_one(DataTable)
        table.add_columns(*GALLERY_COLUMNS)
        table.focus()
        if self.table is not None:
            self.show(self.table)

    def show(self, survey) -> None:
        """Show ``survey`` (the table so far, or the finished one); the cursor stays on its row."""
        from stw_tui.session.survey import describe_text

        self.table = survey
        optima = survey.optima
        bar = self.query_one(ProgressBar)
        bar.update(total=survey.plan.n, progress=len(survey.results))
        self.query_one("#gallery-title", Label).update(printable(survey.summary()))
        grid = self.query_one(DataTable)
        row = grid.cursor_row
        grid.clear()
        for rank, optimum in enumerate(optima, start=1):
            best = optimum.best
            grid.add_row(str(rank), f"{best.objective:.7g}", f"{best.dense_violation:.1e}", str(optimum.count),
                         thumbnail(best), describe_text(best.descriptors),
                         key=str(rank), height=THUMBNAIL[1])
        if grid.row_count:
            grid.move_cursor(row=min(row, grid.row_count - 1))
        others = [f"start {r.index}: {r.status}" + (f" ({r.error[:60]})" if r.error else "")
                  for r in (survey.unconverged + survey.failed)[:3]]
        notes = "\n".join(others + survey.notes[-2:])
        self.query_one("#gallery-notes", Label).update(printable(notes, newlines=True))

    @property
    def selected(self) -> int | None:
        """The rank (from 1) of the optimum under the cursor; None while the table is empty."""
        grid = self.query_one(DataTable)
        if not grid.row_count:
            return None
        return int(grid.coordinate_to_cell_key(grid.cursor_coordinate).row_key.value)

    def on_data_table_row_selected(self, event: DataTable.RowSelected) -> None:
        event.stop()
        self.action_play()

    def _choose(self, action: str) -> None:
        rank = self.selected
        if rank is None:
            self.app.notify("no optimum yet", severity="warning")
            return
        self.app.post_message(OptimumChosen(rank, action))
        self.dismiss(None)

    def action_play(self) -> None:
        self._choose("play")

    def action_adopt(self) -> None:
        self._choose("adopt")

    def action_close(self) -> None:
        self.dismiss(None)
