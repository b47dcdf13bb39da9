"""Motion: keyframes, Cartesian paths solved frame by frame, and trajectories as script files.

Seeds 002/004: keyframes of pose vectors are interpolated (joint values
linearly or smoothly, orientations by quaternion slerp); IK-driven animation
moves the goal a little each frame and re-solves from the previous pose; the
result is recorded as a script of joint values per frame and replayed without IK.
"""

from __future__ import annotations

import json
import os
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike, NDArray

from . import goals as G
from . import spatial
from .errors import InputError, MjkinIOError
from .files import write_text
from .ik.solve import solve
from .kinematics.qspace import BALL, HINGE, SLIDE
from .kinematics.tree import Tree, fingerprint
from .progress import track
from .retime import retime as retime  # mjkin.motion.retime (re-exported)

Array = NDArray[np.float64]
FORMAT = "mjkin-trajectory"


# ------------------------------------------------------------------- keyframes
def interpolate(tree: Tree, times: ArrayLike, keyframes: ArrayLike, t: ArrayLike, smooth: bool = False) -> Array:
    """Configurations ``(T, nq)`` at times ``t`` between keyframes ``(K, nq)`` at increasing ``times (K,)``.

    Hinge, slide and free-joint positions are interpolated linearly, or with a
    C² cubic spline when ``smooth``; ball and free-joint rotations by slerp
    between neighbouring keys. Keyframes are hit exactly; times outside are clamped.
    """
    times = np.asarray(times, dtype=np.float64)
    keys = tree.check_q(keyframes, "keyframes")
    if keys.ndim != 2 or len(keys) != len(times) or len(times) < 2 or np.any(np.diff(times) <= 0):
        raise InputError("interpolate needs >= 2 keyframes (K, nq) with strictly increasing times (K,)")
    t = np.clip(np.asarray(t, dtype=np.float64).ravel(), times[0], times[-1])
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
    return np.linspace(np.asarray(start, float), np.asarray(end, float), _count(n))


def circle(center: ArrayLike, radius: float, n: int, normal: ArrayLike = (0, 0, 1), turns: float = 1.0) -> Array:
    """``n`` points on a circle around ``center`` in the plane normal to ``normal``, ``(n, 3)``."""
    nrm = np.asarray(normal, float)
    if not np.isfinite(radius) or radius <= 0 or np.linalg.norm(nrm) < 1e-12:
        raise InputError("circle needs a positive radius and a non-zero normal")
    nrm = nrm / np.linalg.norm(nrm)
    a = np.cross(nrm, [1.0, 0, 0] if abs(nrm[0]) < 0.9 else [0, 1.0, 0])
    a /= np.linalg.norm(a)
    b = np.cross(nrm, a)
    phi = np.linspace(0, 2 * np.pi * turns, _count(n))
    return np.asarray(center, float) + radius * (np.cos(phi)[:, None] * a + np.sin(phi)[:, None] * b)


def min_jerk(u: ArrayLike) -> Array:
    """Minimum-jerk timing ``10u³ − 15u⁴ + 6u⁵`` of ``u`` in [0, 1]: no speed or acceleration at either end."""
    u = np.clip(np.asarray(u, dtype=np.float64), 0.0, 1.0)
    return np.clip(u * u * u * (10.0 + u * (-15.0 + 6.0 * u)), 0.0, 1.0)  # rounding may pass 1 by an ulp


def waypoints(points: ArrayLike, n: int, times: ArrayLike | None = None, corner: float = 0.0,
              ease: bool = False) -> Array:
    """``n`` points ``(n, 3)`` through ``points (K, 3)``.

    By default piecewise linear at constant speed (or at ``times``, one per point).
    ``corner > 0`` rounds every inner corner with a parabolic arc that leaves the
    straight line ``corner`` (at most half a segment) before the waypoint and rejoins
    it as far after; ``ease`` times the whole path with :func:`min_jerk` (at rest at
    both ends, no jump in speed anywhere).
    """
    p = np.asarray(points, float)
    if p.ndim != 2 or p.shape[1] != 3 or len(p) < 2 or not np.isfinite(p).all():
        raise InputError(f"waypoints need at least two finite 3-D points, got shape {p.shape}")
    if not (np.isfinite(corner) and corner >= 0):
        raise InputError(f"corner must be a radius >= 0, got {corner!r}")
    if times is not None and (corner > 0 or ease):
        raise InputError("waypoints: give times, or corner/ease (timed by the path's length), not both")
    if corner > 0:
        p = _rounded(p, corner)
    s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(p, axis=0), axis=1))]) if times is None \
        else np.asarray(times, float)
    if len(s) != len(p) or np.any(np.diff(s) <= 0):
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
    if int(n) < 2:
        raise InputError(f"a path needs at least 2 frames, got {n}")
    return int(n)


# ----------------------------------------------------------------- trajectories
LIMIT_TOL = 1e-9  # rad or m past a limit before a value counts as outside


def outside_limits(tree: Tree, q: ArrayLike) -> str | None:
    """One line naming the joints of ``q (nq,)`` or ``(T, nq)`` outside their limits (and where), or None.

    Hinges and slides outside their range, and limited ball joints turned past
    their cone; unlimited joints are never outside. For ``(T, nq)`` each joint is
    named once, with its first frame outside and how many frames are.
    """
    qs = tree.check_q(q)
    frames = qs.ndim == 2
    qs = np.atleast_2d(qs)
    lay, names = tree.layout, tree.names("joint")
    parts = []
    for j in range(tree.njnt):
        kind, a, lo, hi = int(tree.jnt_type[j]), int(tree.jnt_qadr[j]), lay.jnt_lo[j], lay.jnt_hi[j]
        if kind in (HINGE, SLIDE):
            value = qs[:, a]
            out = (value < lo - LIMIT_TOL) | (value > hi + LIMIT_TOL)
        elif kind == BALL and np.isfinite(hi):
            quat = qs[:, a:a + 4]
            value = 2 * np.arctan2(np.linalg.norm(quat[:, 1:], axis=-1), np.abs(quat[:, 0]))  # q and -q alike
            out = value > hi + LIMIT_TOL
        else:
            continue
        if not out.any():
            continue
        k, n = int(np.argmax(out)), int(out.sum())
        where = (f" at frame {k}" + (f" (and {n - 1} more frame{'s' * (n > 2)})" if n > 1 else "")) if frames else ""
        name = names[j] or str(j)
        parts.append(f"joint {name} turns {value[k]:.4g} rad, beyond its {hi:.4g} rad cone{where}" if kind == BALL
                     else f"joint {name} = {value[k]:.4g} is outside its range [{lo:.4g}, {hi:.4g}]{where}")
    return "; ".join(parts) or None


def _array(value: object, ndim: int, kind: type) -> NDArray | None:
    """``value`` (parsed JSON) as an ``ndim``-deep array of numbers (``kind`` float) or booleans; None if it is not.

    Only JSON numbers count as numbers and only ``true``/``false`` as booleans (numpy
    would read ``"no"`` as true and ``"1.5"`` as a number); the nesting is walked
    level by level, without recursion.
    """
    items: list[object] = [value]
    for _ in range(ndim):
        lists = [v for v in items if isinstance(v, list)]
        if len(lists) != len(items):
            return None
        items = [x for v in lists for x in v]
    leaf = (bool,) if kind is bool else (int, float)
    if not all(type(x) in leaf for x in items):
        return None
    try:
        a: NDArray = np.array(value, dtype=kind)
    except (ValueError, OverflowError):  # ragged lists; an integer beyond float range
        return None
    return a if a.ndim == ndim else None


@dataclass
class Trajectory:
    """Configurations over time: ``q (T, nq)`` at ``times (T,)`` (seconds), with what made them.

    ``model`` is the model's name; ``source`` where it was loaded from (an absolute
    MJCF/URDF path or a bundled model's name, '' when unknown), so a replay finds it.
    """

    times: Array
    q: Array
    fingerprint: str
    model: str = ""
    site: str | None = None
    targets: Array | None = None  # (T, n, 3) goal points per frame, for overlays
    success: NDArray[np.bool_] | None = None
    meta: dict = field(default_factory=dict)
    source: str = ""

    def jumps(self, tree: Tree) -> Array:
        """Largest joint change between consecutive frames ``(T-1,)`` (rad or m; unlimited hinges the short way)."""
        return np.abs(tree.difference(self.q[1:], self.q[:-1], periodic=True)).max(axis=-1)

    def discontinuities(self, tree: Tree, threshold: float = 0.5) -> NDArray[np.int64]:
        """Frames whose step from the previous one exceeds ``threshold`` (a flip to another IK branch)."""
        return np.flatnonzero(self.jumps(tree) > threshold) + 1

    def save(self, path: str | os.PathLike[str]) -> Path:
        """Write the script as JSON (atomically)."""
        doc = {"format": FORMAT, "version": 1, "model": self.model, "source": self.source,
               "fingerprint": self.fingerprint, "site": self.site, "times": self.times.tolist(),
               "qpos": self.q.tolist(), "targets": None if self.targets is None else self.targets.tolist(),
               "success": None if self.success is None else self.success.tolist(), "meta": self.meta}
        return write_text(path, json.dumps(doc))

    def check(self, tree: Tree, path: str | os.PathLike[str] = "") -> None:
        """Raise :class:`InputError` unless this script was recorded on ``tree`` (same fingerprint, ``nq``).

        ``path`` names the script in the message.
        """
        name = f"trajectory {str(path)!r}" if str(path) else "the trajectory"
        if self.fingerprint != fingerprint(tree):
            raise InputError(f"{name} was recorded on model {self.model!r} (fingerprint {self.fingerprint}), "
                             f"not on {tree.name!r} ({fingerprint(tree)})")
        tree.check_q(self.q, "trajectory qpos")

    @classmethod
    def load(cls, path: str | os.PathLike[str], tree: Tree | None = None) -> Trajectory:
        """Read a script; with ``tree``, refuse one recorded on another model (fingerprint mismatch).

        Times must not decrease and, over two frames or more, must not all be equal.
        Joint values are read as recorded: :func:`outside_limits` says which are
        outside the joint limits, ``tree.clip`` clips them. A ``.jsonl`` file is read as
        the journal of a recording ``mjkin play`` took (:mod:`mjkin.apps.play.journal`).

        Raises:
            MjkinIOError: the file is missing, unreadable, not JSON, or nested too deeply.
            InputError: a key is missing, or a value has the wrong type, shape or order (the message names it).
        """
        name = repr(str(path))
        try:
            doc = _journal_script(path) if Path(path).suffix == ".jsonl" else json.loads(Path(path).read_text())
        except FileNotFoundError:
            raise MjkinIOError(f"trajectory file not found: {name}") from None
        except RecursionError:
            raise MjkinIOError(f"cannot read trajectory {name}: its JSON is nested too deeply") from None
        except (OSError, ValueError) as e:
            raise MjkinIOError(f"cannot read trajectory {name}: {e}") from None
        if not isinstance(doc, dict) or doc.get("format") != FORMAT:
            raise MjkinIOError(f"{name} is not an mjkin trajectory (no \"format\": \"{FORMAT}\")")

        def numbers(key: str, ndim: int, what: str, kind: type = float) -> NDArray:
            if key not in doc:
                raise InputError(f"trajectory {name} has no {key!r} ({what}); keys needed: times, qpos, fingerprint")
            a = _array(doc[key], ndim, kind)
            if a is None or (kind is float and not np.isfinite(a).all()):
                raise InputError(f"trajectory {name}: {key!r} must be {what}"
                                 + (" (finite numbers)" if kind is float else ""))
            return a

        times = numbers("times", 1, "a list of T times in seconds")
        q = numbers("qpos", 2, "a list of T configurations, each a list of nq numbers")
        fp = doc.get("fingerprint")
        if not isinstance(fp, str):
            raise InputError(f"trajectory {name}: 'fingerprint' must be a string (from the model it was recorded on)")
        if len(times) != len(q) or len(q) == 0:
            raise InputError(f"trajectory {name}: 'times' ({len(times)}) and 'qpos' ({len(q)}) must have the same "
                             "number of frames, at least one")
        targets = None if doc.get("targets") is None else numbers("targets", 3, "per frame a list of x,y,z points")
        success = None if doc.get("success") is None else numbers("success", 1, "one true/false per frame", bool)
        if targets is not None and (len(targets) != len(q) or targets.shape[-1] != 3):
            raise InputError(f"trajectory {name}: 'targets' must hold x,y,z points for each of the {len(q)} frames")
        if success is not None and len(success) != len(q):
            raise InputError(f"trajectory {name}: 'success' must hold one true/false for each of the {len(q)} frames")
        model, site, meta = doc.get("model", ""), doc.get("site"), doc.get("meta") or {}
        source = doc.get("source") or ""
        if not all(isinstance(v, str) for v in (model, source)) or not (site is None or isinstance(site, str)) \
                or not isinstance(meta, dict):
            raise InputError(f"trajectory {name}: 'model', 'source' and 'site' must be strings (or site null), "
                             "'meta' an object")
        traj = cls(times=times, q=q, fingerprint=fp, model=model, site=site, targets=targets, success=success,
                   meta=dict(meta), source=source)
        if tree is not None:
            traj.check(tree, path)
        step = np.diff(times)
        if (step < 0).any():
            k = int(np.argmax(step < 0)) + 1
            raise InputError(f"trajectory {name}: 'times' must not decrease, but frame {k} is at {times[k]:g} s "
                             f"after {times[k - 1]:g} s")
        if len(times) > 1 and times[-1] == times[0]:
            raise InputError(f"trajectory {name}: 'times' are all {times[0]:g} s; they must increase over the "
                             f"{len(times)} frames")
        return traj


def _journal_script(path: str | os.PathLike[str]) -> dict:
    """The script a ``mjkin play`` recording's journal holds (:func:`mjkin.apps.play.journal.script`)."""
    from .apps.play import journal

    return journal.script(path)


def follow(tree: Tree, site: str, targets: ArrayLike, q0: ArrayLike | None = None, fps: float = 30.0,
           extra: Sequence[G.Goal] = (), tol: float = 1e-4, smooth: float = 0.3,
           **solve_options: object) -> Trajectory:
    """IK-driven animation: put ``site`` on ``targets (T, 3)`` frame by frame, warm-starting from the last pose.

    ``extra`` goals (e.g. an orientation, a rest pose at low priority) hold on every
    frame. Warm starts, minimum-norm steps and, with ``smooth > 0``, a rest goal
    of that weight at the previous frame's pose (priority 1: only in the freedom
    the path leaves) keep consecutive poses close, so redundant joints do not
    swing when another low-priority goal (a comfort pose) pulls them. A frame
    that fails from the warm start is retried with random restarts; failures are
    recorded in ``success``.
    """
    pts = np.asarray(targets, float)
    if pts.ndim != 2 or pts.shape[1] != 3 or len(pts) == 0:
        raise InputError(f"targets must be (T, 3) points, got shape {pts.shape}")
    if not smooth >= 0:
        raise InputError(f"smooth must be a weight >= 0, got {smooth!r}")
    q = tree.qpos0.copy() if q0 is None else tree.check_q(q0, "q0").copy()
    out, ok = np.empty((len(pts), tree.nq)), np.empty(len(pts), bool)
    for k in track(range(len(pts)), "solve path", total=len(pts)):
        goals = [G.Position(site, pts[k]), *extra, *([G.Rest(q_rest=q, weight=smooth, priority=1)] if smooth else [])]
        res = solve(tree, goals, q0=q, tol=tol, restarts=0, **solve_options)  # type: ignore[arg-type]
        if not res.success:
            retry = solve(tree, goals, q0=q, tol=tol, **solve_options)  # type: ignore[arg-type]
            res = retry if retry.success or retry.error[0] < res.error[0] else res
        q = res.q
        out[k], ok[k] = q, bool(res.success)
    return Trajectory(times=np.arange(len(pts)) / fps, q=out, fingerprint=fingerprint(tree), model=tree.name,
                      site=site, targets=pts[:, None, :], success=ok)


TOE_OFF, HEEL_STRIKE = 0.15, 0.85  # parts of a step spent rolling onto the toe, and down from the heel


def sole_points(tree: Tree, foot: str) -> tuple[Array, Array]:
    """Toe and heel ``(3,)`` of a foot body, in its frame: the front and back of its geoms' boxes, at the sole."""
    m = tree.model
    body = tree.id(foot, "body")
    corners = []
    for g in np.flatnonzero(m.geom_bodyid == body):
        signs = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], dtype=np.float64)
        local = m.geom_aabb[g, :3] + signs * m.geom_aabb[g, 3:]
        corners.append(local @ spatial.quat_to_mat(spatial.quat_normalize(m.geom_quat[g])).T + m.geom_pos[g])
    if not corners:
        raise InputError(f"foot {foot!r} has no geom to stand on")
    c = np.concatenate(corners)
    y, z = 0.5 * (c[:, 1].min() + c[:, 1].max()), c[:, 2].min()
    return np.array([c[:, 0].max(), y, z]), np.array([c[:, 0].min(), y, z])


def _pitched(T: Array, pivot: Array, angle: float) -> Array:
    """Pose ``T (4, 4)`` turned by ``angle`` about the world y axis through the world point ``pivot``."""
    c, s = np.cos(angle), np.sin(angle)
    R = np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])
    out = T.copy()
    out[:3, :3] = R @ T[:3, :3]
    out[:3, 3] = pivot + R @ (T[:3, 3] - pivot)
    return out


def swing_foot(start: Array, end: Array, s: float, toe: Array, heel: Array, height: float, toe_off: float,
               heel_strike: float) -> Array:
    """The swinging foot's pose at step phase ``s`` in [0, 1], from flat pose ``start`` to flat pose ``end``.

    Heel to toe: until :data:`TOE_OFF` it rolls onto its toe (the toe stays where it
    is, the heel rises to ``toe_off`` rad), then it travels in an arc ``height`` high
    while turning toe-up, lands on its heel (``heel_strike`` rad) at :data:`HEEL_STRIKE`
    and rolls down flat about the heel. ``toe`` and ``heel`` are in the foot's frame.
    """
    toe_w = start[:3, :3] @ toe + start[:3, 3]
    heel_w = end[:3, :3] @ heel + end[:3, 3]
    if s <= TOE_OFF:
        return _pitched(start, toe_w, toe_off * float(min_jerk(s / TOE_OFF)))
    if s >= HEEL_STRIKE:
        return _pitched(end, heel_w, -heel_strike * (1.0 - float(min_jerk((s - HEEL_STRIKE) / (1 - HEEL_STRIKE)))))
    a, b = _pitched(start, toe_w, toe_off), _pitched(end, heel_w, -heel_strike)
    u = float(min_jerk((s - TOE_OFF) / (HEEL_STRIKE - TOE_OFF)))
    T = _pitched(start, start[:3, 3], toe_off + (-heel_strike - toe_off) * u)  # the turn, about its own origin
    T[:3, 3] = (1 - u) * a[:3, 3] + u * b[:3, 3]
    T[2, 3] += height * np.sin(np.pi * (s - TOE_OFF) / (HEEL_STRIKE - TOE_OFF))
    return T


def walk_cycle(tree: Tree, steps: int = 4, stride: float = 0.3, step_height: float = 0.06, frames_per_step: int = 24,
               fps: float = 30.0, feet: tuple[str, str] = ("left_foot", "right_foot"), pelvis: str = "lower_torso",
               knees: tuple[str, str] = ("left_knee", "right_knee"), knee_bend: float = 0.7,
               crouch: float = 0.04, sway: float = 0.03, lean: float = 0.08, hip_drop: float = 0.06,
               bob: float = 0.015, arm_swing: float = 0.35, waist: str | None = "waist",
               shoulders: tuple[str, str] | None = ("left_shoulder", "right_shoulder"),
               elbows: tuple[str, str] | None = ("left_elbow", "right_elbow"), toe_off: float = 0.35,
               heel_strike: float = 0.25, tol: float = 1e-4) -> Trajectory:
    """A walk (seeds 002/004): feet placed by IK, the planted foot switching every step.

    In each step one foot is planted — it is the IK root (``root=``), held where it
    stands while the free pelvis joint and the legs move — and the other swings
    forward by ``stride`` heel to toe (:func:`swing_foot`: rolls onto its toe, an arc
    ``step_height`` high, lands on its heel). The pelvis moves forward at a steady
    pace between the feet, ``crouch`` lower than standing, bobbing ``bob`` (highest
    over the planted foot) and swaying toward the planted foot: aimed ``sway`` m
    sideways (as far as legs without ankle roll allow), its free side dropping
    ``hip_drop`` rad, the upper body (joint ``waist``) leaning ``lean`` rad; the arms
    swing ``arm_swing`` rad opposite to the legs, elbows a little bent; the swinging
    knee follows ``θ(s) = knee_bend · sin(π s)``. Arms, knees and the rest of the
    body are low-priority rest goals. Frames are solved warm-started; ``success``
    marks frames whose feet are on target. ``shoulders``/``elbows`` None: no arm swing.
    """
    if steps < 1 or frames_per_step < 2:
        raise InputError("walk_cycle needs steps >= 1 and frames_per_step >= 2")
    if not (np.isfinite(stride) and stride > 0):
        raise InputError(f"stride must be a positive length, got {stride!r}")
    q = tree.qpos0.copy()
    foot_T = {f: tree.pose(q, f, "body") for f in feet}
    soles = {f: sole_points(tree, f) for f in feet}
    T_pelvis = tree.pose(q, pelvis, "body")
    knee_q = [tree.jnt_qadr[tree.id(k, "joint")] for k in knees]
    arm_q = None if shoulders is None else [tree.jnt_qadr[tree.id(j, "joint")] for j in shoulders]
    elbow_q = None if elbows is None else [tree.jnt_qadr[tree.id(j, "joint")] for j in elbows]
    waist_q = None if waist is None else int(tree.jnt_qadr[tree.id(waist, "joint")])
    out, ok = [], []
    arm_end = 0.0
    for k in range(steps):
        side = k % 2
        planted, swing = feet[side], feet[1 - side]
        start = foot_T[swing].copy()
        end = start.copy()
        end[0, 3] = foot_T[planted][0, 3] + 0.5 * stride if k else start[0, 3] + 0.5 * stride
        arm_start, arm_end = -arm_end, arm_swing * (0.5 if k == 0 else 1.0)  # same-side arm: front to back
        toward = np.sign(foot_T[planted][1, 3] - T_pelvis[1, 3])
        for f in range(1, frames_per_step + 1):
            s = f / frames_per_step
            T = swing_foot(start, end, s, *soles[swing], step_height, toe_off, heel_strike)
            P = T_pelvis.copy()
            P[0, 3] = 0.5 * (start[0, 3] + s * (end[0, 3] - start[0, 3]) + foot_T[planted][0, 3])
            P[1, 3] += toward * sway * np.sin(np.pi * s)
            P[2, 3] -= crouch + bob * 0.5 * (1 + np.cos(2 * np.pi * s))
            roll = toward * hip_drop * np.sin(np.pi * s)  # about x: the free side (away from the planted foot) drops
            P[:3, :3] = spatial.quat_to_mat(spatial.quat_from_axis_angle([1.0, 0.0, 0.0], roll)) @ T_pelvis[:3, :3]
            rest = tree.qpos0.copy()
            if waist_q is not None:  # the upper body leans over the planted foot, against the hip drop
                rest[waist_q:waist_q + 4] = spatial.quat_from_axis_angle([1.0, 0.0, 0.0],
                                                                        -toward * (lean + hip_drop) * np.sin(np.pi * s))
            rest[knee_q[1 - side]] = knee_bend * np.sin(np.pi * s)
            if arm_q is not None:
                a = arm_start + (arm_end - arm_start) * 0.5 * (1 - np.cos(np.pi * s))
                for j, angle in ((1 - side, a), (side, -a)):  # positive about y swings an arm back
                    rest[arm_q[j]:arm_q[j] + 4] = spatial.quat_from_axis_angle([0.0, 1.0, 0.0], angle)
                    if elbow_q is not None:
                        rest[elbow_q[j]] = 0.25 + 0.3 * max(0.0, -angle)
            goals = [G.Pose(swing, kind="body", T=T), G.Position(pelvis, P[:3, 3], kind="body", priority=1),
                     G.Orientation(pelvis, P[:3, :3], kind="body", priority=1), G.Rest(q_rest=rest, priority=2)]
            res = solve(tree, goals, q0=q, root=planted, tol=tol, restarts=0)
            q = res.q
            out.append(q)
            ok.append(bool(res.goal_errors[0, 0] <= tol and res.goal_errors[1, 0] <= tol))  # feet on target
        foot_T[swing] = end
    return Trajectory(times=np.arange(len(out)) / fps, q=np.array(out), fingerprint=fingerprint(tree),
                      model=tree.name, site=None, success=np.array(ok),
                      meta={"walk": {"steps": steps, "stride": stride, "frames_per_step": frames_per_step,
                                     "feet": list(feet), "toe_off": TOE_OFF, "heel_strike": HEEL_STRIKE}})
