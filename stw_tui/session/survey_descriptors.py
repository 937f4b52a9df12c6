"""Descriptors that help an animator choose among a survey's optima: each joint's range, which
revolute joints make a full turn, which way each DOF first moves, and for a throw (a `hold … at
LINKAGE.POINT on [A, B]`) the release style, from where the hand is at release."""

from __future__ import annotations

import numpy as np

SAMPLES = 401
FIRST_MOVE = 0.05        # a DOF's first excursion: where it first leaves its start by this ...
FIRST_MOVE_SCALE = 0.1   # ... times its whole range (or by this much, whichever is larger)
LEVEL_BAND = 0.25        # release within this fraction of the arm's reach of the shoulder: sidearm


def describe(scene) -> dict:
    """Plain data (JSON-ready): ``ranges`` {DOF: (min, max)} of the linkage joints (every DOF when
    there is no linkage), ``multi_turn`` [revolute joints turning more than 2π], ``first_move``
    {DOF: +1 or -1, the sign of its first excursion} and ``release`` (a throw's style, or absent)."""
    times = np.linspace(scene.t0, scene.t1, SAMPLES)
    joints = _joints(scene)
    names = [n for n in joints if n in scene.dofs] or list(scene.dofs)
    values = {n: scene.dofs[n].curve.evaluate(times) for n in scene.dofs}
    out = {"ranges": {n: (float(values[n].min()), float(values[n].max())) for n in names},
           "multi_turn": [n for n in names if joints.get(n) == "revolute" and np.ptp(values[n]) > 2 * np.pi],
           "first_move": {n: first_move(v) for n, v in values.items()}}
    release = release_style(scene)
    if release:
        out["release"] = release
    return out


def _joints(scene) -> dict[str, str]:
    return {j.name: j.kind for spec in scene.linkages.values() for j in spec.joints}


def first_move(values: np.ndarray) -> int:
    """+1 or -1: the sign of the first excursion from the start value (0: it never moves)."""
    away = values - values[0]
    threshold = max(FIRST_MOVE, FIRST_MOVE_SCALE * float(np.ptp(values)))
    moved = np.flatnonzero(np.abs(away) > threshold)
    return int(np.sign(away[moved[0]])) if moved.size else 0


def release_style(scene) -> str | None:
    """'overhand', 'sidearm' or 'underhand' for the first `hold P at LINK.POINT on [A, B]` of a
    linkage: where the point is at B relative to the linkage's first joint, in units of the
    arm's reach; None for a scene without a throw."""
    from stw_tui.session.interpreter import SceneScope
    from stw_tui.sym import language as lang
    from stw_tui.sym.symbols import named_symbol

    for text, _ in scene.verbs.values():
        command = lang.parse_command(text, SceneScope(scene))
        if not isinstance(command, lang.HoldCmd):
            continue
        link = command.at.split(".")[0]
        spec = scene.linkages.get(link)
        if spec is None or not spec.joints:
            continue
        release = scene.numeric(command.interval[1], "release time")
        first = spec.joints[0].name
        height = scene.evaluate(named_symbol(f"{command.at}.y") - named_symbol(f"{link}.{first}.y"),
                                np.array([release]))[0]
        reach = sum(abs(j.a) for j in spec.joints) or 1.0
        if height > LEVEL_BAND * reach:
            return "overhand"
        return "underhand" if height < -LEVEL_BAND * reach else "sidearm"
    return None
