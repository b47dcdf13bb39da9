"""Two 6-axis arms with known solution counts, built from DH tables, and their closed-form IK.

* :data:`UR` — a UR5e-type arm (standard DH): joints 2, 3 and 4 parallel, up to 8 solutions
  (shoulder left/right × wrist up/down × elbow up/down), after Hawkins, *Analytic inverse
  kinematics for the Universal Robots UR-5/UR-10 arms* (2013);
* :data:`SPHERICAL` — an elbow arm with a spherical wrist (axes 4, 5, 6 meet in one point),
  up to 8 solutions (shoulder front/back × elbow up/down × wrist flip), after Spong, Hutchinson
  and Vidyasagar, *Robot modeling and control*, §5.

Every closed-form answer is the table's own: :func:`mjkin.kinematics.build.dh_fk` of it gives the
target back (the tests check that, and that the eight are distinct), so the arms built with
:func:`mjkin.kinematics.build.dh_chain` (site ``ee``) can be checked against them.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from ...kinematics.build import dh_chain, dh_fk

Array = NDArray[np.float64]
PI = np.pi

# UR5e: d1, a2, a3, d4, d5, d6 (metres)
UR = np.array([[0.0, PI / 2, 0.1625, 0.0], [-0.425, 0.0, 0.0, 0.0], [-0.3922, 0.0, 0.0, 0.0],
               [0.0, PI / 2, 0.1333, 0.0], [0.0, -PI / 2, 0.0997, 0.0], [0.0, 0.0, 0.0996, 0.0]])
# elbow arm with a spherical wrist: shoulder height 0.4, upper arm 0.45, forearm 0.4, flange 0.1
SPHERICAL = np.array([[0.0, PI / 2, 0.4, 0.0], [0.45, 0.0, 0.0, 0.0], [0.0, PI / 2, 0.0, PI / 2],
                      [0.0, -PI / 2, 0.4, 0.0], [0.0, PI / 2, 0.0, 0.0], [0.0, 0.0, 0.1, 0.0]])
ARMS = {"ur": UR, "spherical": SPHERICAL}


def mjcf(name: str) -> str:
    """MJCF of arm ``name`` (``"ur"`` or ``"spherical"``): unlimited hinges ``j1..j6``, site ``ee``."""
    return dh_chain(ARMS[name], name=f"{name}_arm")


def _row(table: Array, i: int, theta: float) -> Array:
    """Transform ``(4, 4)`` of DH row ``i`` at joint value ``theta``."""
    return dh_fk(table[i:i + 1], np.array([theta]))


def _wrap(a: Array) -> Array:
    return np.arctan2(np.sin(a), np.cos(a))


def ur_ik(T: Array, table: Array = UR) -> Array:
    """Every solution ``(k, 6)`` (k ≤ 8) of the UR-type arm for the flange pose ``T (4, 4)``, in ``(-π, π]``."""
    a2, a3, d4, d6 = table[1, 0], table[2, 0], table[3, 2], table[5, 2]
    out = []
    p05 = T @ np.array([0.0, 0.0, -d6, 1.0])
    r = np.hypot(p05[0], p05[1])
    if r < abs(d4):
        return np.zeros((0, 6))
    psi, phi = np.arctan2(p05[1], p05[0]), np.arccos(d4 / r)
    Tinv = np.linalg.inv(T)
    for s1 in (1.0, -1.0):
        t1 = psi + s1 * phi + PI / 2
        c5 = (T[0, 3] * np.sin(t1) - T[1, 3] * np.cos(t1) - d4) / d6
        if abs(c5) > 1.0:
            continue
        for s5 in (1.0, -1.0):
            t5 = s5 * np.arccos(c5)
            sin5 = np.sin(t5)
            if abs(sin5) < 1e-9:
                continue  # wrist singular: a family, not isolated solutions
            t6 = np.arctan2((-Tinv[1, 0] * np.sin(t1) + Tinv[1, 1] * np.cos(t1)) / sin5,
                            (Tinv[0, 0] * np.sin(t1) - Tinv[0, 1] * np.cos(t1)) / sin5)
            T14 = np.linalg.inv(_row(table, 0, t1)) @ T @ np.linalg.inv(_row(table, 4, t5) @ _row(table, 5, t6))
            p13 = T14 @ np.array([0.0, -d4, 0.0, 1.0])
            n = np.linalg.norm(p13[:3])
            c3 = (n ** 2 - a2 ** 2 - a3 ** 2) / (2 * a2 * a3)
            if abs(c3) > 1.0:
                continue
            for s3 in (1.0, -1.0):
                t3 = s3 * np.arccos(c3)
                t2 = -np.arctan2(p13[1], -p13[0]) + np.arcsin(a3 * np.sin(t3) / n)
                T34 = np.linalg.inv(_row(table, 1, t2) @ _row(table, 2, t3)) @ T14
                t4 = np.arctan2(T34[1, 0], T34[0, 0])
                out.append([t1, t2, t3, t4, t5, t6])
    return _wrap(np.array(out).reshape(-1, 6))


def spherical_ik(T: Array, table: Array = SPHERICAL) -> Array:
    """Every solution ``(k, 6)`` (k ≤ 8) of the spherical-wrist arm for the flange pose ``T (4, 4)``, in ``(-π, π]``."""
    d1, a2, d4, d6 = table[0, 2], table[1, 0], table[3, 2], table[5, 2]
    c = T[:3, 3] - d6 * T[:3, 2]  # the wrist centre
    out = []
    for t1 in (np.arctan2(c[1], c[0]), np.arctan2(c[1], c[0]) + PI):
        u, v = c[0] * np.cos(t1) + c[1] * np.sin(t1), c[2] - d1
        c3 = (u * u + v * v - a2 * a2 - d4 * d4) / (2 * a2 * d4)
        if abs(c3) > 1.0:
            continue
        for s3 in (1.0, -1.0):
            t3 = s3 * np.arccos(c3)
            t2 = np.arctan2(v, u) - np.arctan2(d4 * np.sin(t3), a2 + d4 * np.cos(t3))
            R36 = dh_fk(table[:3], np.array([t1, t2, t3]))[:3, :3].T @ T[:3, :3]
            s5 = np.hypot(R36[0, 2], R36[1, 2])
            if s5 < 1e-9:
                continue  # wrist singular
            for sign in (1.0, -1.0):
                t5 = np.arctan2(sign * s5, R36[2, 2])
                t4 = np.arctan2(sign * R36[1, 2], sign * R36[0, 2])
                t6 = np.arctan2(sign * R36[2, 1], -sign * R36[2, 0])
                out.append([t1, t2, t3, t4, t5, t6])
    return _wrap(np.array(out).reshape(-1, 6))


CLOSED_FORMS = {"ur": ur_ik, "spherical": spherical_ik}
