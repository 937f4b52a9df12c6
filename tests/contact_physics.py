"""The ground's force and work on a planar creature, derived from its DOF samples alone.

Written apart from stw's compiler and linkage module: a chain of uniform rods (mass at each
rod's midpoint, inertia m L^2 / 12) hung from its first joint, the planted point, whose DOF are
the centre of mass (CX, CY) and the joint angles. From 1 ms samples of values, velocities and
accelerations (``stw run --json --samples N`` or ``Session.sample``) it rebuilds the planted
point and Newton-Euler for the whole body: the external force F = M (C'' + g y), and the external
moment about a point P, sum_i (r_i - P) x m_i (a_i + g y) + I_i alpha_i.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

G = 9.81


@dataclass(frozen=True)
class Body:
    """A chain of uniform rods: (length, mass) per link, from the planted joint outwards."""

    links: tuple[tuple[float, float], ...]

    @property
    def mass(self) -> float:
        return sum(m for _, m in self.links)

    @property
    def size(self) -> float:
        return sum(a for a, _ in self.links)

    @property
    def weight(self) -> float:
        return self.mass * G


def _angles(samples: dict, joints: list[str]):
    """Absolute link angles, their rates and accelerations: (n_links, n) each."""
    q = np.cumsum([samples[j]["value"] for j in joints], axis=0)
    w = np.cumsum([samples[j]["velocity"] for j in joints], axis=0)
    a = np.cumsum([samples[j]["acceleration"] for j in joints], axis=0)
    return q, w, a


def motion(body: Body, samples: dict, joints: list[str], com=("CX", "CY")) -> dict:
    """Times, root (the planted point) position/velocity, force and moments, from the samples."""
    t = np.asarray(samples[joints[0]]["t"])
    th, w, al = _angles(samples, joints)
    # rod midpoints and joint points relative to the root, with their derivatives
    mids, mid_v, mid_a, inertia = [], [], [], []
    p = np.zeros((2, t.size)); v = np.zeros((2, t.size)); acc = np.zeros((2, t.size))
    for k, (length, m) in enumerate(body.links):
        u = np.array([np.cos(th[k]), np.sin(th[k])])
        n = np.array([-np.sin(th[k]), np.cos(th[k])])
        du = n * w[k]
        ddu = n * al[k] - u * w[k] ** 2
        mids.append(p + 0.5 * length * u); mid_v.append(v + 0.5 * length * du)
        mid_a.append(acc + 0.5 * length * ddu); inertia.append(m * length ** 2 / 12.0)
        p = p + length * u; v = v + length * du; acc = acc + length * ddu
    masses = np.array([m for _, m in body.links])
    offset = sum(m * r for m, r in zip(masses, mids)) / body.mass          # C - root
    offset_v = sum(m * r for m, r in zip(masses, mid_v)) / body.mass
    offset_a = sum(m * r for m, r in zip(masses, mid_a)) / body.mass
    c = np.array([samples[com[0]]["value"], samples[com[1]]["value"]])
    cv = np.array([samples[com[0]]["velocity"], samples[com[1]]["velocity"]])
    ca = np.array([samples[com[0]]["acceleration"], samples[com[1]]["acceleration"]])
    root, root_v, root_a = c - offset, cv - offset_v, ca - offset_a
    force = body.mass * (ca + np.array([[0.0], [G]]))
    # accelerations of the rod midpoints in the world, and the moments about the root and the
    # centre of mass of m (a + g) plus I alpha: the external moment about each point
    gy = np.array([[0.0], [G]])
    about_root = sum(masses[k] * _cross(mids[k], root_a + mid_a[k] + gy) + inertia[k] * al[k]
                     for k in range(len(body.links)))
    about_com = sum(masses[k] * _cross(mids[k] - offset, root_a + mid_a[k] + gy) + inertia[k] * al[k]
                    for k in range(len(body.links)))
    return {"t": t, "root": root, "root_v": root_v, "force": force, "moment_root": about_root,
            "moment_com": about_com, "omega": w, "com": c, "com_v": cv}


def _cross(r, f):
    return r[0] * f[1] - r[1] * f[0]


def stance(m: dict, a: float, b: float, x0: float, height: float = 0.0) -> dict:
    """Figures of a stance [a, b] (both switch samples included): slide (distance from the
    planted place), penetration, the point's speed, the ground's work (integral of F . v over
    the point), the friction ratio max |Fx| / Fy, and the centre of pressure's range."""
    t = m["t"]
    on = (t >= a - 1e-9) & (t <= b + 1e-9)
    root, v, f = m["root"][:, on], m["root_v"][:, on], m["force"][:, on]
    slide = np.hypot(root[0] - x0, root[1] - height).max()
    power = (f * v).sum(axis=0)
    work = float(np.trapezoid(power, t[on])) if hasattr(np, "trapezoid") else float(np.trapz(power, t[on]))
    inside = on & (t > a + 1e-9) & (t < b - 1e-9)      # the stance's own forces: the switch samples read flight
    fy, fx, mom = m["force"][1, inside], m["force"][0, inside], m["moment_root"][inside]
    loaded = fy > 1e-9
    return {"slide": float(slide), "penetration": float(max(0.0, (height - root[1]).max())),
            "speed": float(np.hypot(v[0], v[1]).max()), "work": work,
            "positive_work": float(np.clip(power, 0, None).sum() * (t[1] - t[0])),
            "fy_min": float(fy.min()), "fy_max": float(fy.max()),
            "friction_excess": float((np.abs(fx) - fy).max()),
            "friction": float((np.abs(fx[loaded]) / fy[loaded]).max()) if loaded.any() else 0.0,
            "cop": (float((mom[loaded] / fy[loaded]).min()), float((mom[loaded] / fy[loaded]).max()))
            if loaded.any() else (0.0, 0.0),
            "moment": mom, "fy": fy, "t_inside": t[inside]}


def flight(m: dict, a: float, b: float) -> dict:
    """Largest net external force and moment (about the centre of mass) over [a, b], ends included."""
    t = m["t"]
    on = (t >= a - 1e-9) & (t <= b + 1e-9)
    f = m["force"][:, on]
    return {"force": float(np.hypot(f[0], f[1]).max()), "moment": float(np.abs(m["moment_com"][on]).max())}
