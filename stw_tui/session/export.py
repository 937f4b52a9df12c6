"""Exporting a scene's motion: CSV (one row per frame), JSON (the same, plus the curves and the
session text) and BVH (a linkage's skeleton and joint angles, :mod:`.bvh`), from the console
(`export csv|json|bvh FILE [fps=N] [what=NAME,…]`) or headless
(`stw export SESSION --format csv|json|bvh -o FILE`).

Columns: ``t``; every DOF ``X`` with ``X'`` and ``X''``; and every linkage's joint, tip and centre
of mass positions (``arm.ELBOW.x``, ``arm.tip.y``, ``arm.com.z``), evaluated from the derived
kinematics on the scene's curves; and the subexpressions asked for (``what=tau_ELBOW,f``). Numbers are written with 17 significant digits, so reading a
file back gives the very floats stw computed.

Export writes a file and changes nothing in the scene. Its journal line is kept as a comment, so a
replayed journal never writes files.
"""

from __future__ import annotations

import csv
import io
import json
from pathlib import Path


import numpy as np

from stw_tui.session.atomic_file import replace_text
from stw_tui.session.outcome import Outcome
from stw_tui.session.protocol import SessionLike
from stw_tui.sos.scene import Scene
from stw_tui.sym.errors import StwError
from stw_tui.sym.symbols import named_symbol


DEFAULT_FPS = 30
FORMAT_NAME = "stw-motion"
FORMAT_VERSION = 1
MAX_FRAMES = 1_000_000


def frame_times(scene: Scene, fps: int) -> np.ndarray:
    """t0, t0 + 1/fps, … up to t1 (and t1 itself when the span is a whole number of frames)."""
    count = int(np.floor((scene.t1 - scene.t0) * fps + 1e-9)) + 1
    if count > MAX_FRAMES:
        raise StwError(f"{count} frames at fps={fps} is too many (at most {MAX_FRAMES}); lower fps")
    return np.minimum(scene.t0 + np.arange(count) / fps, scene.t1)


def position_names(scene: Scene) -> list[str]:
    """Every linkage's joint, tip and centre of mass coordinates, in chain order."""
    names = []
    for spec in scene.linkages.values():
        for point in [j.name for j in spec.joints] + ["tip", "com"]:
            names += [n for n in (f"{spec.name}.{point}.{axis}" for axis in "xyz") if n in scene.derived]
    return names


def check_what(scene: Scene, what) -> tuple[str, ...]:
    """The names asked for with ``what=``: subexpressions or linkage quantities, perhaps primed.

    Raises:
        StwError: a name that is not one.
    """
    for name in what:
        base = name.rstrip("'")
        if base not in scene.lets and base not in scene.derived:
            known = ", ".join([*scene.lets, *[n for n in scene.derived if n.startswith("tau_")]][:8])
            raise StwError(f"what={name}: not a subexpression or linkage quantity"
                           + (f" (for example {known})" if known else ""))
    return tuple(dict.fromkeys(what))


def motion_table(scene: Scene, times: np.ndarray, what=()) -> dict[str, np.ndarray]:
    """Column name -> values at ``times``: t, each DOF and its two derivatives, each position, and
    each subexpression in ``what``."""
    columns = {"t": np.asarray(times, float)}
    for name in scene.dofs:
        for order, suffix in enumerate(("", "'", "''")):
            columns[name + suffix] = scene.dof_values(name, times, order)
    for name in [*position_names(scene), *(n for n in check_what(scene, what) if n not in columns)]:
        columns[name] = np.broadcast_to(scene.evaluate(named_symbol(name), times), times.shape)
    return columns


def csv_text(scene: Scene, fps: int, what=()) -> str:
    """The motion as CSV: a header of column names, then one row per frame."""
    columns = motion_table(scene, frame_times(scene, fps), what)
    out = io.StringIO()
    writer = csv.writer(out, lineterminator="\n")
    writer.writerow(columns)
    for row in zip(*columns.values()):
        writer.writerow([repr(float(v)) for v in row])
    return out.getvalue()


def json_document(scene: Scene, fps: int, session_text: str, what=()) -> dict:
    """The motion as JSON: the columns, each DOF's curve, the constants and the session text."""
    columns = motion_table(scene, frame_times(scene, fps), what)
    return {
        "format": FORMAT_NAME, "version": FORMAT_VERSION, "fps": fps,
        "span": [scene.t0, scene.t1], "frames": int(columns["t"].size),
        "columns": {name: [float(v) for v in values] for name, values in columns.items()},
        "dofs": {name: {"degree": dof.curve.degree, "knots": dof.curve.knots.tolist(),
                        "control_points": dof.curve.coef.tolist(), "lo": dof.lo, "hi": dof.hi}
                 for name, dof in scene.dofs.items()},
        "constants": dict(scene.constants),
        "session": session_text,
    }


def write_text(path: str | Path, text: str, overwrite: bool = False, folder: Path | None = None) -> Path:
    """Write a whole file at once (:func:`~stw_tui.session.atomic_file.replace_text`: never half a
    file), only a new one unless ``overwrite``, and never through a link.

    Args:
        folder: where a replayed session file may write (its own folder): a path outside it is
            refused. None: anywhere (a command the user typed).
    Raises:
        StwError: the file exists (without ``overwrite``), is not a regular file, lies outside
            ``folder``, or cannot be written.
    """
    target = Path(path).expanduser()
    if folder is not None and not _inside(target, folder):
        raise StwError(f"a session file may write only inside its own folder {folder}, not {path}; "
                       "type the command at the console to write there")
    try:
        if target.is_dir():
            raise IsADirectoryError(f"{target} is a folder")
        replace_text(target, text, overwrite=overwrite)
    except FileExistsError as exc:
        why = exc.strerror if target.is_symlink() or not target.is_file() else \
            "it exists (add `overwrite` to replace it)"
        raise StwError(f"cannot write {path}: {why}") from exc
    except FileNotFoundError as exc:
        raise StwError(f"cannot write {path}: there is no folder {target.parent}") from exc
    except OSError as exc:   # strerror alone: the temporary file's name would only puzzle
        raise StwError(f"cannot write {path}: {exc.strerror or exc}") from exc
    return target


def _inside(target: Path, folder: Path) -> bool:
    """Whether ``target``'s folder, links resolved, is ``folder`` or below it."""
    try:
        return target.parent.resolve().is_relative_to(folder.resolve())
    except (OSError, RuntimeError):   # a loop of links
        return False


def _folder(session: SessionLike, cmd) -> Path | None:
    """Where the command may write: anywhere when typed, else the replayed file's folder."""
    if cmd.line is None:
        return None
    return getattr(session, "replay_folder", None) or Path.cwd()


def export_text(session: SessionLike, fmt: str, fps: int, what=()) -> str:
    """The text of an export in format ``fmt`` (csv, json or bvh) at ``fps`` frames per second."""
    scene = session.scene
    if not 1 <= fps <= 10_000:
        raise StwError(f"fps must be from 1 to 10000, not {fps}")
    if not scene.dofs:
        raise StwError("there is no motion to export: declare a DOF first")
    if fmt == "csv":
        return csv_text(scene, fps, what)
    if fmt == "json":
        return json.dumps(json_document(scene, fps, session.journal.text(), what), indent=1) + "\n"
    if fmt == "bvh":
        from stw_tui.session.bvh import bvh_text

        return bvh_text(scene, frame_times(scene, fps), fps, what)
    raise StwError(f"unknown export format '{fmt}' (csv, json or bvh)")


def export(session: SessionLike, scene: Scene, cmd) -> Outcome:
    """`export FORMAT FILE [fps=N] [what=NAME,…] [overwrite]`: not a step, and journalled as a comment."""

    text = export_text(session, cmd.format, cmd.fps, cmd.what)
    target = write_text(cmd.path, text, cmd.overwrite, _folder(session, cmd))
    frames = text.count("\n") - 1 if cmd.format == "csv" else len(frame_times(session.scene, cmd.fps))
    return Outcome(message=f"exported {frames} frames at {cmd.fps} fps to {target}",
                   journal_text=f"# {cmd.text or 'export'}")


def save(session: SessionLike, scene: Scene, cmd) -> Outcome:
    """`save FILE [--journal] [overwrite]`: the session so far, replayable: the clean session (the
    lines that rebuild the scene, history.History.lines) or, with `--journal`, the whole journal.
    Not a step, and journalled as a comment."""

    if cmd.journal:
        text = session.journal.text()
    else:
        text = "".join(line + "\n" for line in session.history.lines)
    target = write_text(cmd.path, text, cmd.overwrite, _folder(session, cmd))
    lines = _command_lines(text)
    message = f"saved {lines} command line(s) to {target}"
    kept = _command_lines(session.journal.text())
    if not cmd.journal and kept > lines:
        message += f" (the lines that make the scene; `--journal` saves all {kept} of the journal)"
    return Outcome(message=message, journal_text=f"# {cmd.text or 'save'}")


def _command_lines(text: str) -> int:
    return sum(1 for line in text.splitlines() if line.strip() and not line.lstrip().startswith("#"))
