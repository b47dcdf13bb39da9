"""Keyframes and Cartesian paths: joint values interpolated over time, points along lines, circles and waypoints.

Keyframes of pose vectors are interpolated (joint values linearly or smoothly,
orientations by quaternion slerp), as in the Finnish thesis and the Chinese
animation course notes; paths are timed with minimum-jerk profiles.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .. import spatial
from ..errors import InputError
from ..kinematics.tree import Tree, check_tree
from ..runtime.checks import check_array, check_count, check_flag, check_number, check_vector

Array = NDArray[np.float64]


def interpolate(tree: Tree, times: ArrayLike, keyframes: ArrayLike, t: ArrayLike, smooth: bool = False) -> Array:
    """Configurations ``(T, nq)`` at times ``t`` between keyframes ``(K, nq)`` at increasing ``times (K,)``.

    Hinge, slide and free-joint positions are interpolated linearly, or with a
    C² cubic spline when ``smooth``; ball and free-joint rotations by slerp
    between neighbouring keys. Keyframes are hit exactly; times outside are clamped.
    """
    times = check_array(times, "times")
    keys = check_tree(tree).check_q(keyframes, "keyframes")
    if keys.ndim != 2 or times.shape != (len(keys),) or len(times) < 2 or not np.all(np.diff(times) > 0):
        raise InputError("interpolate needs >= 2 keyframes (K, nq) with strictly increasing times (K,)")
    t = check_array(t, "t").ravel()
    if not np.isfinite(t).all():
        raise InputError("interpolate's times t must be finite")
    t = np.clip(t, times[0], times[-1])
    i = np.clip(np.searchsorted(times, t, side="right") - 1, 0, len(times) - 2)
    u = (t - times[i]) / (times[i + 1] - times[i])
    lay = tree.layout
    linear = np.concatenate([lay.scalar_q, lay.free_q[:, :3].ravel()]).astype(int)
    out = keys[i] + u[:, None] * (keys[i + 1] - keys[i])  # linear everywhere first
    if smooth and len(times) > 2:
        from scipy.interpolate import CubicSpline

        out[:, linear] = CubicSpline(times, keys[:, linear], bc_type="natural")(t)
    for quat in np.concatenate([lay.ball_q, lay.free_q[:, 3:]]):
        out[:, quat] = spatial.slerp(keys[i][:, quat], keys[i + 1][:, quat], u)
    for at, key in ((u == 0.0, i), (u == 1.0, i + 1)):  # at a key: exactly the key
        out[at] = keys[key[at]]
    return out


# ----------------------------------------------------------------------- paths
def line(start: ArrayLike, end: ArrayLike, n: int) -> Array:
    """``n`` points evenly spaced from ``start`` to ``end``, ``(n, 3)``."""
    return np.linspace(check_vector(start, "line start"), check_vector(end, "line end"), _count(n))


def circle(center: ArrayLike, radius: float, n: int, normal: ArrayLike = (0, 0, 1), turns: float = 1.0) -> Array:
    """``n`` points on a circle around ``center`` in the plane normal to ``normal``, ``(n, 3)``."""
    c, nrm = check_vector(center, "circle center"), check_vector(normal, "circle normal")
    radius, turns = check_number(radius, "circle radius"), check_number(turns, "circle turns")
    if radius <= 0 or np.linalg.norm(nrm) < 1e-12:
        raise InputError("circle needs a positive radius and a non-zero normal")
    nrm = nrm / np.linalg.norm(nrm)
    a = np.cross(nrm, [1.0, 0, 0] if abs(nrm[0]) < 0.9 else [0, 1.0, 0])
    a /= np.linalg.norm(a)
    b = np.cross(nrm, a)
    phi = np.linspace(0, 2 * np.pi * turns, _count(n))
    return c + radius * (np.cos(phi)[:, None] * a + np.sin(phi)[:, None] * b)


def min_jerk(u: ArrayLike) -> Array:
    """Minimum-jerk timing ``10u³ − 15u⁴ + 6u⁵`` of ``u`` in [0, 1]: no speed or acceleration at either end."""
    x = np.clip(check_array(u, "u"), 0.0, 1.0)
    return np.clip(x * x * x * (10.0 + x * (-15.0 + 6.0 * x)), 0.0, 1.0)  # rounding may pass 1 by an ulp


def waypoints(points: ArrayLike, n: int, times: ArrayLike | None = None, corner: float = 0.0,
              ease: bool = False) -> Array:
    """``n`` points ``(n, 3)`` through ``points (K, 3)``.

    By default piecewise linear at constant speed (or at ``times``, one per point).
    ``corner > 0`` rounds every inner corner with a parabolic arc that leaves the
    straight line ``corner`` (at most half a segment) before the waypoint and rejoins
    it as far after; ``ease`` times the whole path with :func:`min_jerk` (at rest at
    both ends, no jump in speed anywhere).
    """
    p = check_array(points, "waypoints")
    if p.ndim != 2 or p.shape[1] != 3 or len(p) < 2 or not np.isfinite(p).all():
        raise InputError(f"waypoints need at least two finite 3-D points, got shape {p.shape}")
    corner, ease = check_number(corner, "corner", 0.0), check_flag(ease, "ease")
    if times is not None and (corner > 0 or ease):
        raise InputError("waypoints: give times, or corner/ease (timed by the path's length), not both")
    if corner > 0:
        p = _rounded(p, corner)
    s = (np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(p, axis=0), axis=1))]) if times is None
        else check_array(times, "waypoint times"))
    if s.shape != (len(p),) or not np.all(np.diff(s) > 0) or not np.isfinite(s).all():
        raise InputError("waypoint times must increase strictly, one per point")
    u = np.linspace(0.0, 1.0, _count(n))
    q = s[0] + (min_jerk(u) if ease else u) * (s[-1] - s[0])
    return np.stack([np.interp(q, s, p[:, k]) for k in range(3)], -1)


def _rounded(p: Array, corner: float, per_arc: int = 24) -> Array:
    """A dense polyline through ``p (K, 3)`` with each inner corner replaced by a quadratic Bézier arc."""
    out = [p[0]]
    for i in range(1, len(p) - 1):
        a, b = p[i] - p[i - 1], p[i + 1] - p[i]
        la, lb = float(np.linalg.norm(a)), float(np.linalg.norm(b))
        r = min(corner, 0.5 * la, 0.5 * lb)
        if r <= 0 or la == 0 or lb == 0:
            out.append(p[i])
            continue
        start, end = p[i] - r * a / la, p[i] + r * b / lb
        t = np.linspace(0.0, 1.0, per_arc)[:, None]
        out.extend((1 - t) ** 2 * start + 2 * t * (1 - t) * p[i] + t ** 2 * end)
    out.append(p[-1])
    dense = np.array(out)
    keep = np.concatenate([[True], np.linalg.norm(np.diff(dense, axis=0), axis=1) > 1e-12])
    return dense[keep]


def _count(n: int) -> int:
    """A path's frame count: a whole number from 2 to 10 million (hours of frames at 1 kHz)."""
    count = check_count(n, "a path's frame count", 0, whole_floats=True, most=10_000_000)
    if count < 2:
        raise InputError(f"a path needs at least 2 frames, got {count}")
    return count


# ----------------------------------------------------------------- trajectories
