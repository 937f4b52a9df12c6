"""A planar tree of uniform rods, rebuilt from DOF samples apart from stw's compiler and linkage
module: where every link is, the centre of mass, the external force and the rate of angular
momentum about the centre of mass (Newton-Euler for the whole body).

``rows``: (joint, parent joint or None for the base, theta, length, mass), parents first. A
link's angle is its joint's angle plus theta plus its parent's angle (planar revolute joints),
it runs ``length`` from where its parent's link ends (the base point X, Y for the first), its
mass at its midpoint with inertia m L^2 / 12. ``samples``: ``Session.sample``'s dict.
"""

from __future__ import annotations

import numpy as np

G = 9.81


def rebuild(samples: dict, rows) -> dict:
    """``t``; ``base`` (position, velocity, acceleration of the base point, 2 x n each); per
    joint its link's ``end`` (the same three) and ``angle`` (the same three); ``com`` (the same
    three); ``force`` (what the world exerts: M (C'' + g y)); ``spin`` (d/dt of the angular
    momentum about the moving centre of mass: sum m (c - C) x c'' + I th'')."""
    t = np.asarray(samples["X"]["t"])
    q = {n: [np.asarray(samples[n][k]) for k in ("value", "velocity", "acceleration")] for n in samples}
    base = [np.stack([q["X"][k], q["Y"][k]]) for k in range(3)]
    angle, end, bodies = {}, {}, []
    total = sum(r[4] for r in rows)
    for name, parent, theta, length, mass in rows:
        start = base if parent is None else end[parent]
        th = [q[name][k] + (angle[parent][k] if parent else 0.0) + (theta if k == 0 else 0.0) for k in range(3)]
        angle[name] = th
        u = np.stack([np.cos(th[0]), np.sin(th[0])])
        n = np.stack([-np.sin(th[0]), np.cos(th[0])])
        end[name] = [start[0] + length * u, start[1] + length * th[1] * n,
                     start[2] + length * (th[2] * n - th[1] ** 2 * u)]
        bodies.append((mass, mass * length ** 2 / 12, [(a + b) / 2 for a, b in zip(start, end[name])], th))
    com = [sum(m * c[k] for m, _, c, _ in bodies) / total for k in range(3)]
    force = total * (com[2] + np.array([[0.0], [G]]))
    spin = sum(m * ((c[0][0] - com[0][0]) * c[2][1] - (c[0][1] - com[0][1]) * c[2][0]) + inertia * th[2]
               for m, inertia, c, th in bodies)
    return {"t": t, "base": base, "end": end, "angle": angle, "com": com, "force": force, "spin": spin}
