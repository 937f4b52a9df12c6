"""What a checkpoint holds: the part of a scene a solve changes (control points, added
instances, windows) and the solver's warm start, as JSON numbers, names and flags (never code).
Numbers are written with ``repr`` precision, so they read back bit for bit. Shared by the
checkpoints of finished solves (stw_tui/session/autosave.py) and of running ones
(stw_tui/session/midsolve.py).
"""

from __future__ import annotations

from dataclasses import fields

import numpy as np

from stw_tui.session.history import State
from stw_tui.session.protocol import SessionLike
from stw_tui.sos.scene import Window
from stw_tui.sos.spline import DofCurve
from stw_tui.sym.errors import StwError

VERSION = 1


def _plain(value):
    """JSON-ready form of numpy arrays and numbers, tuples as lists."""
    if isinstance(value, np.ndarray):
        return {"array": value.tolist(), "dtype": str(value.dtype)}
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, (list, tuple)):
        return [_plain(v) for v in value]
    return value


def _restored(value):
    """Inverse of :func:`_plain` (lists back to tuples, for the warm start's signature)."""
    if isinstance(value, dict) and set(value) == {"array", "dtype"}:
        return np.array(value["array"], dtype=value["dtype"])
    if isinstance(value, list):
        return tuple(_restored(v) for v in value)
    return value


def _warm_record(warm) -> dict | None:
    if warm is None:
        return None
    state = {f.name: _plain(getattr(warm.state, f.name)) for f in fields(warm.state)}
    return {"signature": _plain(warm.signature), "state": state}


def _warm_from(record):
    if record is None:
        return None
    from stw_tui.sos.backend import SolverState, WarmStart

    state = {name: _restored(value) for name, value in record["state"].items()}
    return WarmStart(_restored(record["signature"]), SolverState(**state))


def scene_record(scene, warm, offset: int) -> dict:
    """What a solve changes in ``scene`` (with the warm start ``warm``), and a journal offset."""
    return {
        "version": VERSION, "offset": offset,
        "coef": {name: dof.curve.coef.tolist() for name, dof in scene.dofs.items()},
        # the knots too: adaptive refinement inserts them during a solve
        "knots": {name: dof.curve.knots.tolist() for name, dof in scene.dofs.items()},
        "extra_instances": {k: list(v) for k, v in scene.extra_instances.items()},
        "windows": {k: [list(w.dofs) if w.dofs else None, list(w.interval) if w.interval else None]
                    for k, w in scene.windows.items()},
        "active_window": scene.active_window,
        "warm": _warm_record(warm),
    }


def restored_scene(session: SessionLike, record: dict):
    """A copy of the session's scene with a checkpoint's state in it; the session is not changed.

    Raises:
        StwError: the checkpoint does not fit the scene (other DOF or control point counts).
    """
    scene = session.scene.copy()
    coef = record["coef"]
    knots = record.get("knots")   # (absent from checkpoints written before refinement inserted knots)
    if list(coef) != list(scene.dofs) or (knots is not None and list(knots) != list(coef)):
        raise StwError("the checkpoint does not fit the replayed scene")
    for name, dof in scene.dofs.items():
        try:
            if knots is not None:
                dof.curve = DofCurve(np.array(knots[name], dtype=float), np.array(coef[name], dtype=float))
            elif len(coef[name]) == dof.curve.n_coef:
                dof.curve = dof.curve.with_coef(np.array(coef[name], dtype=float))
            else:
                raise ValueError
        except (ValueError, TypeError):
            raise StwError("the checkpoint does not fit the replayed scene") from None
    scene.extra_instances = {k: tuple(float(t) for t in v) for k, v in record["extra_instances"].items()}
    scene.windows = {k: Window(k, tuple(d) if d else None, tuple(i) if i else None)
                     for k, (d, i) in record["windows"].items()}
    scene.active_window = record["active_window"]
    return scene


def install(session: SessionLike, scene, record: dict, text: str) -> None:
    """Make ``scene`` (from :func:`restored_scene`) and the record's warm start the session's, as
    the solve ``text`` would have: a history step that `undo` takes back."""
    before = State.of(session)
    session.scene, session.warm = scene, _warm_from(record["warm"])
    session.history.settled(text, before)
