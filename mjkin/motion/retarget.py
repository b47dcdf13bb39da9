"""Retargeting motion capture (BVH) onto an MJCF figure, with the feet planted while they touch the floor.

The method, per clip (targets for every frame worked out at once, then one warm-started
solve per frame through one :class:`mjkin.Problem`):

1. The source is read (:mod:`mjkin.bvh`), put in metres (``scale`` metres per BVH unit, by
   default the unit its height suggests), turned z-up and so that it first faces the figure's +x.
2. Roles (pelvis, hips, knees, ankles, toes, shoulders, elbows, wrists, head) are
   matched to source joints by name (Mixamo, CMU/MotionBuilder, the 19-joint
   ``Hips/Chest/LeftHip`` rig: :data:`SOURCE_NAMES`) and to figure bodies
   (:data:`FIGURES`, by model name), or given by a mapping.
3. Targets keep the figure's proportions: the pelvis moves as the source's, in metres
   with a given ``scale``, else scaled by the ratio of leg lengths; each limb point is its parent's target plus
   the figure's segment length along the source segment's direction; pelvis, torso
   and feet turn as frames built from the source's points do (relative to its rest
   pose).
4. Foot contacts come from the source (toe or ankle near the floor and slow, with
   hysteresis). A planted foot's target is frozen flat on the floor for the whole
   contact and eased back to the source's over :data:`EASE` frames after it lifts.
   Swinging feet are lifted so no sole point is below the floor.
5. Goals, in one priority level: both feet's toe and heel points weighted far above
   (:data:`FOOT_WEIGHT`) the pelvis, limb points, head, torso/pelvis orientations and the
   previous frame's pose; each frame is warm-started from the previous one. A hard
   :class:`~mjkin.goals.StepLimit` keeps each frame's change from the previous one within
   the joint speed limit, inside the solve (and, with ``clearance``, a hard
   :class:`~mjkin.goals.Clearance` keeps the figure's bodies apart).

:func:`report` measures the result: key-point errors, foot skate, floor penetration,
limits, speeds and self-penetration (MuJoCo contacts between non-adjacent bodies).
"""

from __future__ import annotations

import json
import os
import re
import time
from collections.abc import Sequence
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .. import goals as G
from .. import spatial
from ..errors import InputError, MjkinIOError
from ..ik import Problem
from ..ik.kernel import HARD_TOL
from ..kinematics.geoms import contact_pairs
from ..kinematics.tree import Tree, fingerprint
from ..runtime.checks import check_number, shown
from ..scene import Scene
from . import Trajectory, bvh, outside_limits, sole_points

Array = NDArray[np.float64]
SIDES = ("left", "right")
LIMB = ("hip", "knee", "ankle", "shoulder", "elbow", "wrist")
REQUIRED = ("pelvis", "head", *(f"{s}_{p}" for s in SIDES for p in LIMB))
ROLES = (*REQUIRED, "left_toe", "right_toe", "neck")

# Source joint names per role, by preference, compared lower-case without a namespace ('mixamorig:') or '_ -.';
# {s} is 'left'/'right', {c} 'l'/'r'. Mixamo's LeftShoulder is the collarbone, the 19-joint rig's the upper arm:
# LeftArm comes first, so each rig gets its own.
SOURCE_NAMES: dict[str, tuple[str, ...]] = {
    "pelvis": ("hips", "pelvis", "hip", "root"),
    "head": ("head",),
    "neck": ("neck", "neck1"),
    "hip": ("{s}upleg", "{s}hip", "{s}thigh", "{s}upperleg", "{c}thigh", "{c}hip", "{c}upleg"),
    "knee": ("{s}leg", "{s}knee", "{s}shin", "{s}lowerleg", "{c}shin", "{c}knee", "{c}leg"),
    "ankle": ("{s}foot", "{s}ankle", "{c}foot", "{c}ankle"),
    "toe": ("{s}toebase", "{s}toe", "{s}toes", "{c}toe", "{c}toes", "{s}footend", "{s}ankleend", "{c}footend"),
    "shoulder": ("{s}arm", "{s}upperarm", "{c}shldr", "{c}upperarm", "{c}humerus", "{s}shoulder", "{c}shoulder"),
    "elbow": ("{s}forearm", "{s}elbow", "{s}lowerarm", "{c}forearm", "{c}elbow", "{c}radius"),
    "wrist": ("{s}hand", "{s}wrist", "{c}hand", "{c}wrist"),
}

# Figure bodies per role for the figures mjkin knows by model name (body origins at the joint centres).
FIGURES: dict[str, dict[str, str]] = {
    "primate": {"pelvis": "lower_torso", "torso": "upper_torso", "head": "head",
                **{f"{s}_{p}": f"{s}_{b}" for s in SIDES for p, b in
                   (("hip", "thigh"), ("knee", "shin"), ("ankle", "foot"), ("shoulder", "upper_arm"),
                    ("elbow", "forearm"), ("wrist", "hand"))}},
    "g1": {"pelvis": "pelvis", "torso": "torso_link", "head": "torso_link",
           **{f"{s}_{p}": f"{s}_{b}" for s in SIDES for p, b in
              (("hip", "hip_roll_link"), ("knee", "knee_link"), ("ankle", "ankle_roll_link"),
               ("shoulder", "shoulder_roll_link"), ("elbow", "elbow_pitch_link"), ("wrist", "zero_link"))}},
}
FIGURE_OFFSETS = {"g1": {"head": (0.0, 0.0, 0.45)}}  # a role's point in its body, where it is not the origin
# how much of the source's lean (pelvis to mid-shoulders, from upright) the pelvis takes, by model name: half
# (the primate's waist turns 0.7 rad at most), all on the G1 (its torso only turns about the vertical)
FIGURE_LEAN = {"g1": 1.0}

KEYS = ("pelvis", "head", "left_wrist", "right_wrist", "left_ankle", "right_ankle")  # in Trajectory.targets
SCALE = (1e-6, 1e6)  # metres per BVH unit a clip may be given (micrometres to thousands of kilometres)
MAX_SPEED = 10.0  # rad/s (m/s) per dof when the caller gives none: MJCF has no joint speed limits
# Each frame is one warm-started solve of MAX_ITERS iterations at most, all goals in one priority level (a second
# level costs a projection per iteration: 1.7-2x the time), the feet's toe and heel points weighted FOOT_WEIGHT
# against the body's goals (they slide a few micrometres per frame), REST_WEIGHT toward the previous frame's pose
# (less lets a shoulder or hip swing faster than the speed limit between frames). The body's goals conflict a
# little, so frames stop at MAX_ITERS, not at tol; more iterations change no figure of the report by much
# (`mjkin bench retarget`: 15 iterations and two levels took 2.5-3x the time).
MAX_ITERS = 6
FOOT_WEIGHT = 1000.0
REST_WEIGHT = 0.02
EASE = 6  # frames over which a lifted foot's target returns from where it stood to the source's
CONTACT_ON = (0.03, 0.25)  # m above the floor, m/s: a foot point lower and slower touches down
CONTACT_OFF = (0.06, 0.5)  # ... higher or faster: it lifts (hysteresis)


def _norm(name: str) -> str:
    return re.sub(r"[\s_.\-]", "", name.rsplit(":", 1)[-1]).lower()


def source_mapping(clip: bvh.Clip, given: dict[str, str] | None = None) -> dict[str, int]:
    """Role -> joint index in ``clip``: ``given`` names first, the rest found by :data:`SOURCE_NAMES`.

    Raises:
        InputError: a required role has no joint (the message lists those and the clip's joint names).
    """
    found: dict[str, int] = {}
    by_norm: dict[str, int] = {}
    for i, n in enumerate(clip.names):
        by_norm.setdefault(_norm(n), i)
    for role, name in (given or {}).items():
        if role not in ROLES:
            raise InputError(f"unknown role {role!r} in the mapping; roles are: {', '.join(ROLES)}")
        found[role] = clip.index(name)
    for role in ROLES:
        if role in found:
            continue
        side, _, part = role.partition("_")
        pats = SOURCE_NAMES[part] if part else SOURCE_NAMES[role]
        for pat in pats:
            cand = pat.format(s=side, c=side[:1]) if part else pat
            if cand in by_norm and by_norm[cand] not in found.values():
                found[role] = by_norm[cand]
                break
    missing = [r for r in REQUIRED if r not in found]
    if missing:
        shown = ", ".join(clip.names[:40]) + (f", ... ({len(clip.names) - 40} more)" if len(clip.names) > 40 else "")
        raise InputError(f"cannot map {', '.join(missing)} of BVH {clip.source or 'clip'} by joint names; give a "
                         f"mapping file with those roles (its joints: {shown})")
    return found


def figure_mapping(tree: Tree, given: dict[str, str] | None = None) -> dict[str, str]:
    """Role -> body of ``tree`` (plus ``torso``): :data:`FIGURES` for known model names, overridden by ``given``.

    Raises:
        InputError: a required role (or ``torso``) has no body.
    """
    known = dict(FIGURES.get(tree.name, {}))
    known.update(given or {})
    missing = [r for r in (*REQUIRED, "torso") if r not in known]
    if missing:
        raise InputError(f"model {tree.name!r} has no retargeting roles for {', '.join(missing)}; give them in the "
                         f"mapping file's \"figure\" object (role -> body; known figures: {', '.join(FIGURES)})")
    for body in known.values():
        tree.id(body, "body")  # UnknownNameError lists the bodies
    return known


def read_mapping(path: str | os.PathLike[str]) -> dict[str, dict[str, str]]:
    """A mapping file: ``{"source": {role: bvh joint}, "figure": {role: body}}``, either part optional.

    Raises:
        MjkinIOError: missing or not JSON.
        InputError: not of that shape.
    """
    try:
        doc = json.loads(Path(path).read_text())
    except FileNotFoundError:
        raise MjkinIOError(f"mapping file not found: {str(path)!r}") from None
    except (OSError, ValueError) as e:
        raise MjkinIOError(f"cannot read mapping {str(path)!r}: {e}") from None
    if not isinstance(doc, dict) or set(doc) - {"source", "figure"} or not all(
            isinstance(v, dict) and all(isinstance(a, str) and isinstance(b, str) for a, b in v.items())
            for v in doc.values()):
        raise InputError(f"mapping {str(path)!r} must be {{\"source\": {{role: joint}}, \"figure\": {{role: body}}}} "
                         f"with string names; roles: {', '.join(ROLES)}")
    return {k: dict(v) for k, v in doc.items()}


# ------------------------------------------------------------------ geometry
def _unit(v: Array) -> Array:
    return v / np.maximum(np.linalg.norm(v, axis=-1, keepdims=True), 1e-12)


def _frame(y: Array, up: Array) -> Array:
    """Rotations ``(..., 3, 3)`` with y along ``y`` and z as near ``up`` as orthogonality allows."""
    y = _unit(y)
    x = _unit(np.cross(y, up))
    return np.stack([x, y, np.cross(x, y)], axis=-1)


def _yaw(angle: float) -> Array:
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


Z_UP = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])  # BVH (x, y up, z) -> (y, z up, x)


def _facing(p: Array, roles: dict[str, int]) -> Array:
    """``p (F, J, 3)`` z-up turned about z so that frame 0 faces +x (its left hip on +y)."""
    left = p[0, roles["left_hip"]] - p[0, roles["right_hip"]]
    return p @ _yaw(-np.arctan2(-left[0], left[1])).T  # the left vector to +y, so forward (= left x up) to +x


@dataclass(frozen=True)
class Retarget:
    """What :func:`plan` works out: targets for every frame and the feet's contacts.

    ``points``: role -> ``(F, 3)`` target (world, m); ``rotations``: ``pelvis``, ``torso``,
    ``left_ankle``, ``right_ankle`` -> ``(F, 3, 3)``; ``contact (2, F)`` left/right planted,
    ``heel (2, F)`` its heel down too;
    ``feet (2, F, 4, 4)`` the foot bodies' target poses; ``source (F, J, 3)`` the source
    points in the figure's world (scaled as the root path), for drawing; ``metres_per_unit`` the
    clip's unit (given or from its height); ``root_ratio`` the figure's root path (m) per metre of the
    source's: 1 with a given scale, else the ratio of leg lengths (figure / source).
    """

    points: dict[str, Array]
    rotations: dict[str, Array]
    contact: NDArray[np.bool_]
    heel: NDArray[np.bool_]
    feet: Array
    source: Array
    metres_per_unit: float
    root_ratio: float
    bodies: dict[str, str]
    offsets: dict[str, Array]
    parents: NDArray[np.int64]


def _contacts(height: Array, speed: Array) -> NDArray[np.bool_]:
    """Contact ``(F,)`` of one foot from its points' heights and speeds ``(F, P)`` (m, m/s), with hysteresis."""
    on = np.any((height < CONTACT_ON[0]) & (speed < CONTACT_ON[1]), axis=1).tolist()
    off = np.all((height > CONTACT_OFF[0]) | (speed > CONTACT_OFF[1]), axis=1).tolist()
    out = np.zeros(len(height), dtype=np.bool_)
    state = False
    for k in range(len(height)):
        state = on[k] or (state and not off[k])
        out[k] = state
    return out


def _foot_targets(R: Array, p: Array, soles: Array, floor: float, rest: Array, contact: NDArray[np.bool_],
                  heel: NDArray[np.bool_], toe: Array) -> Array:
    """Foot body poses ``(F, 4, 4)`` from the source-driven ``R (F, 3, 3)``, ``p (F, 3)`` and the contacts ``(F,)``.

    Swinging: as driven, lifted so no sole point (``soles (P, 3)``, body frame) is below ``floor``.
    At touch-down the pose is frozen flat (``rest``'s tilt and height, the driven yaw); while
    ``heel`` is up in a contact the foot turns as driven about its frozen ``toe`` point.
    After lift-off the target eases from the last held pose to the driven one over :data:`EASE` frames.
    """
    F = len(p)
    T = np.broadcast_to(np.eye(4), (F, 4, 4)).copy()
    T[:, :3, :3], T[:, :3, 3] = R, p
    lowest = (np.einsum("fij,pj->fpi", R, soles) + p[:, None])[..., 2].min(axis=1)
    T[:, 2, 3] += np.maximum(0.0, floor - lowest)
    out = T.copy()
    held: Array | None = None
    last, since = 0, EASE
    pivot_f: list[int] = []  # contact frames with the heel up, their held pose's frame, eased frames, from, u
    pivot_from: list[int] = []
    ease_f: list[int] = []
    ease_from: list[int] = []
    ease_u: list[float] = []
    for f in range(F):
        if contact[f]:
            if held is None:
                held = T[f].copy()
                yaw = np.arctan2(T[f, 1, 0], T[f, 0, 0]) - np.arctan2(rest[1, 0], rest[0, 0])
                held[:3, :3] = _yaw(yaw) @ rest[:3, :3]
                held[2, 3] = rest[2, 3]
                start = f
            out[f] = held
            if not heel[f]:
                pivot_f.append(f)
                pivot_from.append(start)
            last, since = f, 0
        else:
            held = None
            if since < EASE:
                since += 1
                ease_f.append(f)
                ease_from.append(last)
                ease_u.append(since / EASE)
    if pivot_f:  # toe pivot: the driven turn about the frozen toe, unless it tips the heel under the floor
        R, H = T[pivot_f, :3, :3], out[pivot_from]
        p = H[:, :3, :3] @ toe + H[:, :3, 3] - R @ toe
        ok = (np.einsum("fij,pj->fpi", R, soles) + p[:, None])[..., 2].min(axis=1) >= floor - 1e-9
        out[np.array(pivot_f)[ok], :3, :3], out[np.array(pivot_f)[ok], :3, 3] = R[ok], p[ok]
    if ease_f:  # after a lift-off: from the last pose in contact to the driven one
        A, u = out[ease_from], np.array(ease_u)
        out[ease_f, :3, 3] = (1 - u)[:, None] * A[:, :3, 3] + u[:, None] * T[ease_f, :3, 3]
        out[ease_f, :3, :3] = spatial.quat_to_mat(spatial.slerp(
            spatial.mat_to_quat(A[:, :3, :3]), spatial.mat_to_quat(T[ease_f, :3, :3]), u))
    return out


def plan(clip: bvh.Clip, tree: Tree, mapping: dict[str, dict[str, str]] | None = None,
         scale: float | None = None) -> Retarget:
    """Targets for every frame of ``clip`` on ``tree`` (see the module's steps 1–4); ``scale`` in metres per unit.

    With ``scale`` the root moves the source's distance in metres (``scale`` times its BVH units);
    without it the root path is fitted to the figure (the source's times the ratio of leg lengths).
    """
    mapping = mapping or {}
    roles = source_mapping(clip, mapping.get("source"))
    bodies = figure_mapping(tree, mapping.get("figure"))
    unit = bvh.unit_scale(clip)[0] if scale is None else check_number(scale, "scale (metres per BVH unit)", 0,
                                                                       strict=True)
    if not SCALE[0] <= unit <= SCALE[1]:  # 1e-300 divided by zero further on
        raise InputError(f"scale must be from {SCALE[0]:g} to {SCALE[1]:g} metres per BVH unit, got {scale!r}")
    p = _facing(clip.positions() @ Z_UP.T * unit, roles)
    rest = _facing(clip.positions(rest=True) @ Z_UP.T * unit, roles)[0]
    F = clip.frames
    feet_idx = [[j for j in (roles.get(f"{s}_ankle"), roles.get(f"{s}_toe")) if j is not None] for s in SIDES]
    floor = float(np.percentile(p[:, sum(feet_idx, []), 2].min(axis=1), 2))  # feet's lowest points
    rest_floor = float(rest[:, 2].min())

    # the figure at qpos0: role points, segment lengths, orientations
    q0 = tree.qpos0
    offsets = {r: np.asarray(FIGURE_OFFSETS.get(tree.name, {}).get(r, (0.0, 0.0, 0.0)), float) for r in bodies}
    fig_T = {r: tree.pose(q0, b, "body") for r, b in bodies.items()}
    fig = {r: fig_T[r][:3, :3] @ offsets[r] + fig_T[r][:3, 3] for r in bodies}
    fig_floor = min(float((fig_T[f"{s}_ankle"][:3, :3] @ pt + fig_T[f"{s}_ankle"][:3, 3])[2])
                    for s in SIDES for pt in sole_points(tree, bodies[f"{s}_ankle"]))

    def seg(a: str, b: str, pts: Array) -> Array:
        return np.linalg.norm(pts[..., roles[b], :] - pts[..., roles[a], :], axis=-1)

    src_leg = float(np.mean([seg(f"{s}_hip", f"{s}_knee", rest) + seg(f"{s}_knee", f"{s}_ankle", rest)
                             for s in SIDES]))
    fig_leg = float(np.mean([np.linalg.norm(fig[f"{s}_knee"] - fig[f"{s}_hip"])
                             + np.linalg.norm(fig[f"{s}_ankle"] - fig[f"{s}_knee"]) for s in SIDES]))
    k = fig_leg / src_leg if scale is None else 1.0

    def frames_of(pts: Array) -> dict[str, Array]:
        """Constructed rotations of pelvis, torso and feet from source points ``(..., J, 3)``."""
        up = np.array([0.0, 0.0, 1.0])
        P = lambda r: pts[..., roles[r], :]  # noqa: E731
        mid_sh = 0.5 * (P("left_shoulder") + P("right_shoulder"))
        lean = FIGURE_LEAN.get(tree.name, 0.5)
        pelvis = _frame(P("left_hip") - P("right_hip"), lean * _unit(mid_sh - P("pelvis")) + (1 - lean) * up)
        torso = _frame(P("left_shoulder") - P("right_shoulder"), mid_sh - P("pelvis"))
        out = {"pelvis": pelvis, "torso": torso}
        for s in SIDES:
            ahead = P(f"{s}_toe") - P(f"{s}_ankle") if f"{s}_toe" in roles else pelvis[..., :, 0]
            x = _unit(ahead)
            y = _unit(np.cross(P(f"{s}_knee") - P(f"{s}_ankle"), x))  # across the shin: defined however the toe points
            out[f"{s}_ankle"] = np.stack([x, y, np.cross(x, y)], axis=-1)
        return out

    R_src, R_rest = frames_of(p), frames_of(rest)
    rot = {r: R_src[r] @ np.swapaxes(R_rest[r], -1, -2) @ fig_T[r][:3, :3] for r in R_src}

    # points: pelvis scaled from the source, the rest chained with the figure's own lengths
    pts: dict[str, Array] = {}
    pelvis_src = p[:, roles["pelvis"]]
    pts["pelvis"] = np.empty((F, 3))
    pts["pelvis"][:, :2] = fig["pelvis"][:2] + k * (pelvis_src[:, :2] - pelvis_src[0, :2])
    pts["pelvis"][:, 2] = fig["pelvis"][2] + k * ((pelvis_src[:, 2] - floor) - (rest[roles["pelvis"], 2] - rest_floor))
    R_pel0, R_tor0 = fig_T["pelvis"][:3, :3], fig_T["torso"][:3, :3]
    torso_at = pts["pelvis"] + np.einsum("fij,j->fi", rot["pelvis"], R_pel0.T @ (fig_T["torso"][:3, 3] - fig["pelvis"]))
    for r, base, R, R0 in (("head", torso_at, rot["torso"], R_tor0),):
        pts[r] = base + np.einsum("fij,j->fi", R, R0.T @ (fig[r] - fig_T["torso"][:3, 3]))
    for s in SIDES:
        pts[f"{s}_hip"] = pts["pelvis"] + np.einsum("fij,j->fi", rot["pelvis"], R_pel0.T @ (fig[f"{s}_hip"]
                                                                                         - fig["pelvis"]))
        pts[f"{s}_shoulder"] = torso_at + np.einsum("fij,j->fi", rot["torso"],
                                                    R_tor0.T @ (fig[f"{s}_shoulder"] - fig_T["torso"][:3, 3]))
        for a, b in (("hip", "knee"), ("knee", "ankle"), ("shoulder", "elbow"), ("elbow", "wrist")):
            length = np.linalg.norm(fig[f"{s}_{b}"] - fig[f"{s}_{a}"])
            pts[f"{s}_{b}"] = pts[f"{s}_{a}"] + length * _unit(p[:, roles[f"{s}_{b}"]] - p[:, roles[f"{s}_{a}"]])

    # feet: contacts from the source; a planted foot is frozen flat on the floor, then pivots on its frozen toe
    # once its heel lifts; swinging feet follow the source above the floor, eased in after a lift-off
    contact = np.zeros((2, F), dtype=np.bool_)
    heel = np.zeros((2, F), dtype=np.bool_)
    feet = np.empty((2, F, 4, 4))
    for i, s in enumerate(SIDES):
        idx = feet_idx[i]
        h = p[:, idx, 2] - floor - (rest[idx, 2] - rest_floor)
        v = np.zeros((F, len(idx)))
        v[1:] = np.linalg.norm(np.diff(p[:, idx, :2], axis=0), axis=-1) / clip.frame_time
        v[0] = v[1] if F > 1 else 0.0
        contact[i] = _contacts(h, v)
        heel[i] = contact[i] & _contacts(h[:, :1], v[:, :1])
        body = fig_T[f"{s}_ankle"]
        toe_local, _ = sole_points(tree, bodies[f"{s}_ankle"])
        feet[i] = _foot_targets(rot[f"{s}_ankle"], pts[f"{s}_ankle"] - rot[f"{s}_ankle"] @ offsets[f"{s}_ankle"],
                                np.array(sole_points(tree, bodies[f"{s}_ankle"])), fig_floor, body, contact[i],
                                heel[i], toe_local)
    src = fig["pelvis"] + k * (p - np.array([*pelvis_src[0, :2], floor + rest[roles["pelvis"], 2] - rest_floor]))
    src[..., 2] += fig_floor
    return Retarget(points=pts, rotations=rot, contact=contact, heel=heel, feet=feet, source=src, metres_per_unit=unit,
                    root_ratio=k, bodies=bodies, offsets=offsets, parents=clip.parents)


def retarget(source: str | os.PathLike[str] | bvh.Clip, tree: Tree,
             mapping: dict | str | os.PathLike[str] | None = None, *, scale: float | None = None,
             max_speed: ArrayLike = MAX_SPEED, tol: float = 1e-4, clearance: float | None = None,
             extra_goals: Sequence[G.Goal] = (), model_source: str = "") -> Trajectory:
    """Retarget a BVH clip onto ``tree``: a :class:`Trajectory` of ``q (F, nq)`` at the clip's frame times.

    Args:
        source: a BVH path or a parsed :class:`mjkin.motion.bvh.Clip`.
        tree: the figure; it needs a free root joint.
        mapping: ``{"source": {role: joint}, "figure": {role: body}}`` (or a JSON file of it);
            by default roles are found by name (:data:`SOURCE_NAMES`, :data:`FIGURES`).
        scale: metres per BVH unit: the root then moves the source's distance in metres (its
            path in BVH units times ``scale``). Default: the unit suggested by the skeleton's
            height, and the root path fitted to the figure (times the ratio of leg lengths).
        max_speed: joint speed limit, rad/s (m/s), one number or ``(nv,)``: a hard
            :class:`~mjkin.goals.StepLimit` of ``max_speed`` times the frame time in every frame's
            solve (a joint's limit is the least of its dofs').
        tol: IK position tolerance (m).
        clearance: when given (metres), a hard :class:`~mjkin.goals.Clearance` of that margin between
            the figure's own geoms (MuJoCo's contact pairs without the world's) in every frame's solve.
        extra_goals: goals added to every frame's as they are (targets that do not change from
            frame to frame, such as a clearance between the figure's bodies); their priority
            decides whether they outrank the feet (0) or join the body's goals (1).
        model_source: where ``tree`` was loaded from, recorded so ``mjkin replay`` finds it.

    Returns:
        The trajectory; ``meta["retarget"]`` holds the contacts ``(2, F)``, ``metres_per_unit`` and
        ``root_ratio`` (see :class:`Retarget`), the frames per second (planning and solving, the first
        frame left out: it may compile the solver); ``targets (F, 6, 3)`` are the key-point targets
        (:data:`KEYS`; the feet's as held).

    Raises:
        BvhError, InputError: unreadable clip, roles that cannot be mapped, bad options.
    """
    clip = source if isinstance(source, bvh.Clip) else bvh.read(source)
    if mapping is not None and not isinstance(mapping, dict):
        mapping = read_mapping(mapping)
    try:
        speed = np.broadcast_to(np.asarray(max_speed, float), (tree.nv,))
    except (TypeError, ValueError):
        raise InputError(f"max_speed must be one number or {tree.nv} (one a dof), rad/s, got "
                         f"{shown(max_speed)}") from None
    if not (np.isfinite(speed).all() and (speed > 0).all()):
        raise InputError(f"max_speed must be positive rad/s, got {max_speed!r}")
    if tree.nq < 7 or tree.layout.free_q.size == 0:
        raise InputError(f"model {tree.name!r} has no free root joint to carry the figure")
    t0 = time.perf_counter()
    plan_ = plan(clip, tree, mapping, scale)
    extra = tuple(extra_goals)
    if clearance is not None:
        extra += (G.Clearance(check_number(clearance, "clearance (m)"), pairs=self_pairs(tree)),)
    q, t_first = solve_frames(tree, plan_, tol, extra, step_limit(tree, speed * clip.frame_time))
    elapsed = time.perf_counter() - t0 - t_first
    feet = {f"{s}_ankle": plan_.feet[i, :, :3, :3] @ plan_.offsets[f"{s}_ankle"] + plan_.feet[i, :, :3, 3]
            for i, s in enumerate(SIDES)}  # the feet's own targets: frozen while planted
    targets = np.stack([feet[r] if r in feet else plan_.points[r] for r in KEYS], axis=1)
    meta = {"retarget": {"clip": str(clip.source), "metres_per_unit": plan_.metres_per_unit,
                         "root_ratio": plan_.root_ratio,
                         "contact": plan_.contact.tolist(), "heel": plan_.heel.tolist(),
                         "frames_per_second": max(clip.frames - 1, 1) / elapsed,
                         "max_speed": speed.tolist(), "bodies": plan_.bodies}}
    times = np.arange(clip.frames, dtype=np.float64) * clip.frame_time
    return Trajectory(times=times, q=q, fingerprint=fingerprint(tree), model=tree.name, targets=targets, meta=meta,
                      source=model_source)


@dataclass(frozen=True)
class FrameGoals:
    """Every frame's goals, laid out once for the clip: frame ``f``'s goals are :meth:`at` ``(f, q_prev)``.

    ``frames[f]`` are frame ``f``'s goals but the rest pose, every frame's of the same kinds,
    frames, weights and priorities, their targets checked once for the clip
    (:meth:`mjkin.goals.Goal.unbatch`); ``extra`` goals are the same object in every frame.
    ``rest`` pulls toward the previous frame's pose; it comes last.
    """

    frames: tuple[tuple[G.Goal, ...], ...]
    rest: G.Rest

    def at(self, f: int, q_prev: Array) -> list[G.Goal]:
        """Frame ``f``'s goals, resting toward ``q_prev (nq,)``."""
        return [*self.frames[f], replace(self.rest, q_rest=q_prev)]


def frame_goals(tree: Tree, plan_: Retarget, extra: Sequence[G.Goal] = ()) -> FrameGoals:
    """Every frame's goals (see :class:`FrameGoals`), made from targets laid out as arrays over the clip.

    At priority 1, weighted: the feet's toe and heel points (:data:`FOOT_WEIGHT`), the pelvis,
    the torso's and pelvis's turn, the limb points and head, the previous frame's pose
    (:data:`REST_WEIGHT`); ``extra`` as given.
    """
    b = plan_.bodies
    F = len(plan_.points["pelvis"])
    per_goal: list[list[G.Goal]] = []  # each goal's F frames
    for i, s in enumerate(SIDES):
        T = plan_.feet[i]
        for point in sole_points(tree, b[f"{s}_ankle"]):
            per_goal.append(G.Position(b[f"{s}_ankle"], T[:, :3, :3] @ point + T[:, :3, 3], kind="body",
                                       offset=tuple(point), priority=1, weight=FOOT_WEIGHT).unbatch())
    per_goal.append(G.Position(b["pelvis"], plan_.points["pelvis"], kind="body", priority=1).unbatch())
    for r in ("pelvis", "torso"):
        per_goal.append(G.Orientation(b[r], plan_.rotations[r], kind="body", priority=1, weight=0.3).unbatch())
    for r in ("head", *(f"{s}_{p}" for s in SIDES for p in ("knee", "shoulder", "elbow", "wrist"))):
        off = plan_.offsets[r]
        per_goal.append(G.Position(b[r], plan_.points[r], kind="body", priority=1,
                                   offset=tuple(off) if np.any(off) else None,
                                   weight=1.0 if "wrist" in r else 0.5).unbatch())
    per_goal.extend([g] * F for g in extra)
    rest = G.Rest(q_rest=tree.qpos0, weight=REST_WEIGHT, priority=1)
    return FrameGoals(tuple(zip(*per_goal, strict=True)), rest)


def step_limit(tree: Tree, max_step: Array) -> G.StepLimit:
    """A :class:`~mjkin.goals.StepLimit` from per-dof steps ``max_step (nv,)``: each joint takes its dofs' least.

    Aimed ``HARD_TOL`` inside, the tolerance to which the solver keeps a hard constraint, so no step exceeds it.
    """
    per_joint = np.minimum.reduceat(max_step, tree.jnt_dofadr) if tree.njnt else np.zeros(0)
    return G.StepLimit(q_prev=tree.qpos0, max_step=np.maximum(per_joint - HARD_TOL, 0.0))


def self_pairs(tree: Tree) -> list[tuple[int, int]]:
    """The geom pairs ``[(geom1, geom2), ...]`` (ids) MuJoCo would collide between the figure's own bodies."""
    pairs = contact_pairs(tree)
    body = tree.model.geom_bodyid
    return [(int(a), int(b)) for a, b in pairs if body[a] != 0 and body[b] != 0]


def solve_frames(tree: Tree, plan_: Retarget, tol: float, extra: Sequence[G.Goal] = (),
                 limit: G.StepLimit | None = None) -> tuple[Array, float]:
    """Joint values ``(F, nq)``, frame by frame through one :class:`~mjkin.Problem`.

    Each frame is warm-started from (and rests toward) the previous frame's pose; ``extra``
    goals join every frame's; ``limit``, with ``q_prev`` the previous frame's pose, every frame's
    after the first. Also returns the seconds the first frame took (it may include compiling the solver).
    """
    F = len(plan_.points["pelvis"])
    q = tree.qpos0.copy()
    free = tree.layout.free_q[0]
    q[free[:3]] += plan_.points["pelvis"][0] - tree.pose(q, plan_.bodies["pelvis"], "body")[:3, 3]
    out = np.empty((F, tree.nq))
    layout = frame_goals(tree, plan_, extra)
    t = time.perf_counter()
    first = Problem(tree, layout.at(0, q), tol=tol, restarts=0, max_iters=MAX_ITERS)  # no previous frame to limit
    q = out[0] = first.solve(q).q
    t_first = time.perf_counter() - t
    problem = Problem(tree, layout.at(0, q) + ([] if limit is None else [limit]), tol=tol, restarts=0,
                      max_iters=MAX_ITERS)
    for f in range(1, F):
        goals = layout.at(f, q)
        if limit is not None:
            goals.append(replace(limit, q_prev=q))
        q = out[f] = problem.solve(q, goals).q
    return out, t_first


# ------------------------------------------------------------------- report
def _runs(mask: NDArray[np.bool_]) -> list[tuple[int, int]]:
    """``(start, end)`` of each run of True in ``mask (F,)``, end exclusive."""
    edges = np.diff(np.concatenate([[0], mask.astype(np.int8), [0]]))
    return list(zip(np.flatnonzero(edges == 1).tolist(), np.flatnonzero(edges == -1).tolist(), strict=True))


def _point(tree: Tree, q: Array, body: str, role: str) -> Array:
    """World point ``(F, 3)`` of a role on its body (the body origin, or :data:`FIGURE_OFFSETS`)."""
    T = tree.pose(q, body, "body")
    return T[..., :3, :3] @ np.asarray(FIGURE_OFFSETS.get(tree.name, {}).get(role, (0.0, 0.0, 0.0))) + T[..., :3, 3]


def report(tree: Tree, traj: Trajectory) -> dict:
    """Measured figures of a retargeted clip (lengths in m, speeds per second); see the keys.

    ``metres_per_unit`` (the clip's unit used) and ``root_ratio`` (figure root path per source metre)
    come from ``traj.meta`` (:class:`Retarget`);
    ``keypoint_error_median``/``_max``: hands, feet and head relative to the pelvis against
    their targets; ``skate_per_frame_mean`` (mean horizontal slide of a planted foot per
    frame), ``skate_per_contact_max`` (its largest drift over one contact); ``floor_min``
    (lowest sole point, < 0 below the floor); ``limits`` (None or what is outside);
    ``speed_max``/``speed_limit_ratio``; ``self_contact_frames``, ``self_contact_deepest``.
    """
    info = traj.meta["retarget"]
    bodies = info["bodies"]
    q, F = traj.q, len(traj.q)
    contact = np.array(info["contact"], dtype=np.bool_)
    out: dict = {"frames": F, "frames_per_second": info["frames_per_second"],
                 "metres_per_unit": info["metres_per_unit"], "root_ratio": info["root_ratio"]}
    if traj.targets is not None:
        got = np.stack([_point(tree, q, bodies[r], r) for r in KEYS], 1)
        err = np.linalg.norm((got[:, 1:] - got[:, :1]) - (traj.targets[:, 1:] - traj.targets[:, :1]), axis=-1)
        out["keypoint_error_median"], out["keypoint_error_max"] = float(np.median(err)), float(err.max())
    heel = np.array(info["heel"], dtype=np.bool_)
    slide, drift, lowest = [], [], np.inf
    for i, s in enumerate(SIDES):
        T = tree.pose(q, bodies[f"{s}_ankle"], "body")
        soles = np.array(sole_points(tree, bodies[f"{s}_ankle"]))  # toe, heel
        pts = np.einsum("fij,pj->fpi", T[:, :3, :3], soles) + T[:, None, :3, 3]  # (F, 2, 3)
        lowest = min(lowest, float(pts[..., 2].min()))
        for k, held in ((0, contact[i]), (1, heel[i])):  # the toe is held through a contact, the heel while down
            xy = pts[:, k, :2]
            slide.extend(np.linalg.norm(np.diff(xy, axis=0), axis=-1)[held[1:] & held[:-1]].tolist())
            for a, e in _runs(held):
                drift.append(float(np.linalg.norm(xy[a:e] - xy[a], axis=-1).max()))
    out["contact_frames"] = int(contact.sum())
    out["skate_per_frame_mean"] = float(np.mean(slide)) if slide else 0.0
    out["skate_per_contact_max"] = max(drift) if drift else 0.0
    out["floor_min"] = lowest
    out["limits"] = outside_limits(tree, q)
    dt = np.diff(traj.times)
    speed = np.abs(tree.difference(q[1:], q[:-1])) / dt[:, None] if F > 1 else np.zeros((0, tree.nv))
    limit = np.asarray(info["max_speed"])
    out["speed_max"] = float(speed.max()) if speed.size else 0.0
    out["speed_limit_ratio"] = float((speed / limit).max()) if speed.size else 0.0
    scene = Scene(tree)
    deep, frames = 0.0, 0
    for f in range(F):
        mine = [c.distance for c in scene.contacts(q[f]) if "world" not in (c.body1, c.body2)]
        if mine and min(mine) < 0:
            frames += 1
            deep = min(deep, min(mine))
    out["self_contact_frames"], out["self_contact_deepest"] = frames, deep
    return out
