"""Messages between the session worker, the widgets and the app (past tense: things that happened)."""

from __future__ import annotations

import enum
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Callable

from textual.message import Message

from stw_tui.sym.language import classify_line

if TYPE_CHECKING:
    from stw_tui.session.queries import SceneInfo
    from stw_tui.session.session import Session
    from stw_tui.sos.backend import StepReport
    from stw_tui.sos.scene import Scene


class Origin(enum.StrEnum):
    """Where a command line or task came from (the console shows it as a prompt, e.g. `key>`)."""

    CONSOLE = "console"   # typed
    PANEL = "panel"       # a panel's control
    KEY = "key"           # a key binding (F5, Ctrl+Z)
    FILE = "file"         # the opened session file
    STARTUP = "startup"   # the empty job that loads the core when the app starts
    MEASURE = "measure"   # an empty job that measures the scene for the views (after a replay paused)
    COMPARE = "compare"   # the backend comparison task


@dataclass
class Job:
    """One command line to run, and where it came from."""

    line: str
    number: int | None = None     # its line in the opened session file
    origin: Origin = Origin.CONSOLE
    continuation: bool = False    # a row inside an open `linkage` block (set by the worker)
    # A read-only task instead of a command line (e.g. comparing backends): called with the
    # session in the worker, not journalled; its result comes back in a TaskFinished message.
    task: "Callable[[Session], Any] | None" = None
    # Measure the scene for the views afterwards (queries.scene_info: the dense check, the
    # figure's bounds). A replayed line with more to come does not: the views redraw at most
    # ten times a second, and measuring after every line was 40% of a replay (arm_throw).
    measure: bool = True

    @property
    def is_solve(self) -> bool:
        """A solve that F4 stops: `iterate`, and `survey` and `adopt` (their starts are solves)."""
        return classify_line(self.line).verb in ("iterate", "survey", "adopt")


@dataclass
class CommandRequested(Message):
    """A widget asks for one command line to be run through the session (and shown in the console)."""

    line: str
    origin: Origin = Origin.PANEL


@dataclass
class IterationReported(Message):
    """The solver finished one iteration; later reports replace unhandled earlier ones."""

    report: "StepReport"

    def can_replace(self, message: Message) -> bool:
        # The worker keeps every report; the UI only needs the newest to redraw.
        """A newer report replaces one the UI has not handled yet."""
        return isinstance(message, IterationReported)


@dataclass
class CommandStarted(Message):
    """The worker began a command."""

    job: "Job"


@dataclass
class CommandFinished(Message):
    """The worker finished a command, successfully (outcome) or not (error); info describes the
    scene, and ``scene`` is a copy of it that the views may read while the worker goes on."""

    job: "Job"
    outcome: Any
    error: BaseException | None
    info: "SceneInfo | None"      # None: not measured (``job.measure``); the views keep the last
    scene: "Scene | None" = None


@dataclass
class TaskFinished(Message):
    """The worker finished a read-only task (a Job with ``task``): its result or its error."""

    job: "Job"
    result: Any
    error: BaseException | None


@dataclass
class ItemChosen(Message):
    """A panel chose the DOF or equation the plots follow."""

    kind: str     # "dof" or "equation"
    name: str


@dataclass
class SurveyProgressed(Message):
    """A survey's table so far (a copy the worker no longer changes); later ones replace earlier."""

    table: Any

    def can_replace(self, message: Message) -> bool:
        """A newer table replaces one the UI has not handled yet."""
        return isinstance(message, SurveyProgressed)


@dataclass
class PlotDataComputed(Message):
    """A plot's data came back from its background computation (posted to that plot); later
    ones replace unhandled earlier ones. ``sequence`` orders them (see background.LatestOnly)."""

    sequence: int
    data: Any
    error: BaseException | None

    def can_replace(self, message: Message) -> bool:
        """Newer plot data replaces data the UI has not handled yet."""
        return isinstance(message, PlotDataComputed)


@dataclass
class PlotBuilt(Message):
    """A plot's figure came back from its background build (posted to that plot): ``built`` is
    (render key, rich Text); later ones replace unhandled earlier ones."""

    sequence: int
    built: Any
    error: BaseException | None

    def can_replace(self, message: Message) -> bool:
        """A newer figure replaces one the UI has not handled yet."""
        return isinstance(message, PlotBuilt)
