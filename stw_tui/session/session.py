"""A session: the scene, its journal, and the interpreter that applies one command line at a time.

Every change goes through :meth:`Session.execute`: the line is appended to the journal, parsed
against the current names, and applied to a *copy* of the scene that replaces the scene only if
the whole command succeeds. A typo, a bad value or a diverging solve therefore leaves the scene
exactly as it was. Replaying the journal's successful lines rebuilds the same scene and numbers.
"""

from __future__ import annotations

import errno
import os
import stat
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

from stw_tui.session import interpreter
from stw_tui.session.history import NOT_STEPS, History, State
from stw_tui.session.outcome import Outcome, PrintResult
from stw_tui.session.preview import propose
from stw_tui.session.session_commands import SESSION_HANDLERS
from stw_tui.sos.backend import RunResult, StepReport, WarmStart
from stw_tui.sos.scene import Scene
from stw_tui.sym import limits
from stw_tui.sym.errors import SourceError, StwError
from stw_tui.sym.language import CommandLine, classify_line


@dataclass
class JournalEntry:
    """One command as typed or read, and what became of it."""

    text: str
    line: int | None = None
    ok: bool | None = None      # None while it is being applied
    error: str = ""


@dataclass
class Journal:
    """Append-only record of commands. Failed commands are kept but never replayed."""

    entries: list[JournalEntry] = field(default_factory=list)
    path: Path | None = None

    def append(self, text: str, line: int | None) -> JournalEntry:
        """Record a line before it is applied; :meth:`settle` then says what became of it."""
        entry = JournalEntry(text, line)
        self.entries.append(entry)
        return entry

    def settle(self, entry: JournalEntry, ok: bool, error: str = "") -> None:
        """Record what became of ``entry``: appended to the journal file, flushed and synced to
        disk before the caller acknowledges the command.

        Raises:
            StwError: the file could not be written (a full disk); the entry is then recorded
                as failed, so it is never replayed.
        """
        entry.ok, entry.error = ok, error
        if self.path is None:
            return
        try:
            data = (self._render(entry) + "\n").encode("utf-8")
            # never through a link, and only into a regular file (not a device or a fifo)
            fd = os.open(self.path, os.O_WRONLY | os.O_APPEND | os.O_CREAT | os.O_NOFOLLOW | os.O_NONBLOCK, 0o666)
            try:
                if not stat.S_ISREG(os.fstat(fd).st_mode):
                    raise OSError(errno.EINVAL, "not a regular file")
                self._write_whole(fd, data)
            finally:
                os.close(fd)
        except (OSError, ValueError) as exc:
            entry.ok, entry.error = False, f"the journal could not record it: {exc}"
            raise StwError(f"the journal {self.path} could not record the line ({exc}); "
                           "the scene is unchanged") from exc

    @staticmethod
    def _write_whole(fd: int, data: bytes) -> None:
        """Append ``data`` (whole lines) to the file and sync it; if any of it is refused (a full
        disk), cut the file back to its length before, so no fragment is left for the next line to
        be appended to (which a resume would then read as one line). Written with ``os.write``, not
        a buffered file, whose close would try the refused bytes again."""
        size = os.fstat(fd).st_size
        try:
            view = memoryview(data)
            while view:
                view = view[os.write(fd, view):]
            os.fsync(fd)
        except OSError:
            os.ftruncate(fd, size)
            raise

    @staticmethod
    def _render(entry: JournalEntry) -> str:
        if entry.ok:
            return entry.text
        first = entry.error.splitlines()[0] if entry.error else "failed"
        return "\n".join(f"# failed: {t}" for t in entry.text.splitlines()) + f"\n#   {first}"

    def replayable(self) -> list[str]:
        """The lines that succeeded, in order: running them again rebuilds the scene."""
        return [e.text for e in self.entries if e.ok]

    def commands(self) -> list[str]:
        """Every command line as typed or read, failed ones too, in order (a block's rows one by
        one; the journal's comments, such as an `export` kept as one, left out): a console's history."""
        return [line for entry in self.entries for line in entry.text.splitlines()
                if line.strip() and not line.lstrip().startswith("#")]

    def text(self) -> str:
        """The journal as session text: the lines that succeeded, and failed ones as comments."""
        return "\n".join(self._render(e) for e in self.entries if e.ok is not None) + "\n"


ReportCallback = Callable[[StepReport], "bool | None"]


class Session:
    """The headless core that both the TUI and the CLI drive."""

    def __init__(self, journal_path: str | Path | None = None):
        self.scene = Scene()
        self.journal = Journal(path=Path(journal_path) if journal_path else None)
        self.prints: list[PrintResult] = []
        self.runs: list[RunResult] = []
        self.warm: WarmStart | None = None
        self._block: list[tuple[int | None, str]] | None = None   # lines of an open `linkage` block
        self.history = History()    # undo, redo and named snapshots (history.py)
        self.survey = None          # the last survey's table, for `adopt` (survey_session.py)
        self.checkpoints = None     # autosave.Checkpoints: solves are checkpointed beside the journal
        self.proposal: State | None = None   # a solve's result under `set preview on` (preview.py)
        self.trusted_schedulers: set[str] = set()   # clusters named on the command line (survey_session.py)
        self.replay_folder: Path | None = None   # the replayed file's folder: its lines write only there (export.py)
        # child_process.SolverProcess: where `stw run` has a plugin backend solve (_solve_in_process);
        # never pickled (the copy sent there solves itself)
        self.solver_process = None

    def __getstate__(self) -> dict:
        return {**self.__dict__, "solver_process": None}

    def __setstate__(self, state: dict) -> None:
        self.__dict__.update({"solver_process": None, **state})

    # --- commands ----------------------------------------------------------------------------
    @property
    def in_block(self) -> bool:
        """True while a multi-line block (`linkage … end`) is being typed."""
        return self._block is not None

    def execute(self, text: str, *, line: int | None = None,
                on_report: ReportCallback | None = None) -> Outcome:
        """Apply one command line.

        Args:
            text: the command, as typed (comments and blank lines are accepted and ignored).
            line: its line number in a session file, for error messages.
            on_report: called after each solver iteration; returning False stops the solve.
        Raises:
            SourceError: bad input, with line and column; the scene is unchanged.
            SolveError: a solve diverged or its backend raised; the scene is unchanged.
        """
        self._check_length(text, line)
        self._check_text(text, line)
        kind = classify_line(text)
        if self._block is not None:
            return self._continue_block(text, kind, line)
        if kind.is_blank:
            return Outcome()
        if kind.verb == "linkage":
            self._block = [(line, text)]
            return Outcome(message="linkage block: enter joint rows, then `end`")
        if kind.verb == "open":
            return self._open(text, line, on_report)
        if self.solver_process is not None and self._plugin_solves(kind):
            return self._solve_in_process(text.rstrip(), line, on_report)
        return self._apply(text.rstrip(), line, on_report)

    def _plugin_solves(self, kind: CommandLine) -> bool:
        """Whether ``kind`` is a solve by a backend whose calls may hang (a plugin of its own, not
        the shared SQP: ``Backend.bounded_calls``). A backend that does not load says so when it runs."""
        from stw_tui.session.child_process import SOLVE_VERBS
        from stw_tui.sos.backend import load_backend

        if kind.verb not in SOLVE_VERBS:
            return False
        try:
            return not load_backend(self.scene.backend).bounded_calls
        except StwError:
            return False

    def _solve_in_process(self, text: str, line: int | None, on_report) -> Outcome:
        """A solve in :attr:`solver_process` (stw_tui/session/child_process.py) on a copy of this
        session, which then takes the copy's state, changed exactly as the solve here would have
        changed it (its journal line and checkpoints written there). Ctrl+C, or the process's
        death, leaves everything as it was, with the line journalled as failed."""
        from stw_tui.session.child_process import NotPortable

        solver = self.solver_process
        try:
            session, outcome, error = solver.execute(self, text, line, on_report or (lambda report: True),
                                                     lambda: False)
        except NotPortable:   # a session that does not pickle still solves, here
            return self._apply(text, line, on_report)
        except StwError as exc:
            entry = self.journal.append(text, line)
            self._settle_failed(entry, str(exc))
            if self.checkpoints is not None:   # the ended process's running checkpoint, if it wrote one
                self.checkpoints.midsolve.ended(force=True)
            raise type(exc)(f"line {line}: {exc}" if line is not None else str(exc)) from exc
        self.__dict__.update(session.__dict__, solver_process=solver)
        if error is not None:
            raise error
        return outcome

    def _open(self, text: str, line: int | None, on_report) -> Outcome:
        """`open FILE`: run the file's lines as if typed, each journalled (and undoable) on its
        own; the `open` line itself is not journalled, so a replay never reads the file again.
        Stops at the first failing line, keeping the lines before it."""
        from stw_tui.sym.language import COMMAND_NAMES
        from stw_tui.sym.language.session_commands import parse_file_command

        path = Path(parse_file_command(text, line).path).expanduser()
        try:
            content = path.read_text(encoding="utf-8")
        except (OSError, UnicodeDecodeError) as exc:
            raise StwError(f"cannot open {path}: {exc}") from exc
        if self._block is not None:
            raise StwError("finish the open `linkage` block first")
        first = next((s for s in content.splitlines() if not classify_line(s).is_blank), "")
        if first and classify_line(first).verb not in COMMAND_NAMES:
            # its lines are not quoted back: the file may be anything (a key, a password)
            raise StwError(f"{path} is not an stw session: its first line is not an stw command")
        count = 0
        folder, self.replay_folder = self.replay_folder, path.parent
        try:
            for number, source in enumerate(content.splitlines(), start=1):
                self.execute(source, line=number, on_report=on_report)
                count += not classify_line(source).is_blank
            if self._block is not None:
                self._block = None
                raise SourceError("`linkage` block is not closed", line=None, expected="a line `end`")
        except StwError as exc:
            raise StwError(f"{path}: {exc} ({count} line(s) before it were applied)") from exc
        finally:
            self.replay_folder = folder
        return Outcome(message=f"opened {path}: {count} line(s) applied")

    def _check_length(self, text: str, line: int | None) -> None:
        """Refuse an over-long line before anything reads it (a 1 MB line must fail at once). A
        comment line is exempt: the journal's `# failed:` lines quote a refused line and its error,
        and a resume must read them back."""
        if text.lstrip().startswith("#"):
            return
        with limits.active(self.scene.limits):
            longest = limits.value("line_length")
            if len(text) > longest:
                raise SourceError(limits.over("line_length", f"{len(text)} characters", "a line of"), line=line,
                                  column=longest + 1, expected=f"at most {longest} characters")

    @staticmethod
    def _check_text(text: str, line: int | None) -> None:
        """Refuse text that is not valid Unicode (a lone surrogate from a badly decoded file), even
        in a comment: the journal could not record it, and a line must not apply and then fail."""
        try:
            text.encode("utf-8")
        except UnicodeEncodeError as exc:
            raise SourceError(f"character {text[exc.start]!r} is not valid text (a lone surrogate)",
                              line=line, column=exc.start + 1, expected="UTF-8 text") from None

    def _continue_block(self, text: str, kind: CommandLine, line: int | None) -> Outcome:
        if kind.words == ("end",):
            block, self._block = self._block, None
            joined = "\n".join(t.rstrip() for _, t in block) + "\n" + text.rstrip()
            return self._apply(joined, block[0][0], None, block=block)
        if not kind.is_blank:
            self._block.append((line, text))
        return Outcome()

    def cancel_block(self) -> None:
        """Drop an open `linkage` block (Esc at the console)."""
        self._block = None

    def _apply(self, text: str, line: int | None, on_report, block=None) -> Outcome:
        try:
            return self._apply_journalled(text, line, on_report, block)
        finally:   # the line is journalled (or the journal failed): a running checkpoint is stale
            if self.checkpoints is not None:
                self.checkpoints.midsolve.ended()

    def _apply_journalled(self, text: str, line: int | None, on_report, block=None) -> Outcome:
        entry = self.journal.append(text, line)
        before = State.of(self)
        kept = self.history.saved(), self.proposal, self.survey   # what handlers change in place
        scene = self.scene.copy()
        try:
            with limits.active(self.scene.limits):
                if block is not None:
                    self._check_joints(block)
                    outcome = interpreter.apply_linkage(self, scene, block)
                else:
                    outcome = interpreter.apply_line(self, scene, text, line, on_report, SESSION_HANDLERS)
        except SourceError as exc:
            self._unwind(before, kept)   # the warm start too (a solve may have run), the history
            error = exc if exc.line is not None or line is None else exc.at_line(line)
            self._settle_failed(entry, str(error))
            raise error from None
        except StwError as exc:
            self._unwind(before, kept)   # the warm start too (a solve may have run), the history
            self._settle_failed(entry, str(exc))
            raise type(exc)(f"line {line}: {exc}" if line is not None else str(exc)) from exc
        except Exception as exc:  # a bug must not lose the scene or the session: report it
            self._unwind(before, kept)   # the warm start too (a solve may have run), the history
            message = f"internal error ({type(exc).__name__}: {exc}); the scene is unchanged"
            self._settle_failed(entry, message)
            raise StwError(f"line {line}: {message}" if line is not None else message) from exc
        broken = [name for name, dof in scene.dofs.items() if not np.all(np.isfinite(dof.curve.coef))]
        if broken:   # shake amplitude=1e308, a key at 1e308: a curve must stay a curve
            message = (f"the command would make the curve of {', '.join(broken)} non-finite; "
                       "the scene is unchanged")
            self._unwind(before, kept)
            self._settle_failed(entry, message)
            raise StwError(f"line {line}: {message}" if line is not None else message)
        if outcome.journal_text is not None:
            entry.text = outcome.journal_text
        try:
            self.journal.settle(entry, True)   # on disk first: only then is the command applied
        except StwError as exc:   # not on disk, so not applied: `undo` pops no step, `snapshot` keeps none
            self._unwind(before, kept)
            raise StwError(f"line {line}: {exc}" if line is not None else str(exc)) from exc.__cause__
        if outcome.run is not None and scene.settings.get("preview"):
            
            self.runs.append(outcome.run)
            return propose(self, scene, before, outcome, text)
        self.scene = scene
        self.history.settled(text, before, outcome.journal_text, outcome.lines)
        if self.proposal is not None and classify_line(text).verb not in NOT_STEPS:
            self.proposal = None    # proposed from a scene that is no longer the scene
        self.prints.extend(outcome.prints)
        if outcome.run is not None:
            self.runs.append(outcome.run)
            if self.checkpoints is not None and outcome.journal_text is None:   # not a stopped solve
                self.checkpoints.record(self)
        return outcome

    def _unwind(self, before: State, kept: tuple) -> None:
        """Undo what a command that is not applied changed outside its scene copy: the warm start,
        and the history, proposal and survey that session commands change in place."""
        self.warm = before.warm
        self.history.put_back(kept[0])
        self.proposal, self.survey = kept[1], kept[2]

    def _settle_failed(self, entry: JournalEntry, message: str) -> None:
        """Record a failed line; a journal that cannot record it must not hide the line's error."""
        try:
            self.journal.settle(entry, False, message)
        except StwError:
            pass   # the line failed anyway: its own error is what the user needs to see

    @staticmethod
    def _check_joints(block: list[tuple[int | None, str]]) -> None:
        """Refuse a linkage with more joint rows than the limit, before deriving its equations
        of motion (their size grows about fourfold with every joint)."""
        most = limits.value("joints")
        if len(block) - 1 > most:
            number, text = block[most + 1]
            raise SourceError(limits.over("joints", f"{len(block) - 1} joints", "a linkage of"), line=number,
                              column=1, source=text, expected=f"at most {most} joint rows")

    def run_text(self, text: str, on_report: ReportCallback | None = None,
                 on_line: Callable[[int, str, Outcome], None] | None = None) -> None:
        """Execute a whole session text, stopping at the first error (which is raised)."""
        for number, line in enumerate(text.splitlines(), start=1):
            outcome = self.execute(line, line=number, on_report=on_report)
            if on_line is not None:
                on_line(number, line, outcome)
        if self._block is not None:
            start = self._block[0][0]
            self._block = None
            raise SourceError("`linkage` block is not closed", line=start, expected="a line `end`")

    def run_file(self, path: str | Path, **kwargs) -> None:
        """Execute a session file, stopping at the first error (which is raised)."""
        try:
            text = Path(path).read_text(encoding="utf-8")
        except (OSError, UnicodeDecodeError) as exc:
            raise StwError(f"cannot read session {path}: {exc}") from exc
        self.replay_folder = Path(path).expanduser().parent
        self.run_text(text, **kwargs)

    # --- queries -----------------------------------------------------------------------------
    def sample(self, n: int = 21) -> dict[str, dict[str, list[float]]]:
        """Values, velocities and accelerations of every DOF at n uniform times over the span (a
        held object's: the holding point's while it is held)."""
        times = np.linspace(self.scene.t0, self.scene.t1, n)
        return {name: {"t": times.tolist(),
                       "value": self.scene.dof_values(name, times, 0).tolist(),
                       "velocity": self.scene.dof_values(name, times, 1).tolist(),
                       "acceleration": self.scene.dof_values(name, times, 2).tolist()}
                for name in self.scene.dofs}
