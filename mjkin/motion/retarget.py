"""Retargeting motion capture (BVH) onto an MJCF figure, with the feet planted while they touch the floor.

The method, per clip (targets for every frame worked out at once, then one warm-started
solve per frame through one :class:`mjkin.Problem`):

1. The source is read (:mod:`mjkin.motion.bvh`), put in metres (``scale`` metres per BVH unit, by
   default the unit its height suggests), turned z-up and so that it first faces as the figure does (its
   left hip toward the figure's).
2. Roles (pelvis, hips, knees, ankles, toes, shoulders, elbows, wrists, head) are
   matched to source joints by name (Mixamo, LAFAN1/AMASS, CMU/MotionBuilder, the 19-joint
   ``Hips/Chest/LeftHip`` rig) and to figure bodies from the figure's tree and names
   (:mod:`mjkin.motion.roles`), or given by a mapping.
3. Targets keep the figure's proportions: the pelvis moves as the source's, in metres
   with a given ``scale``, else scaled by the ratio of leg lengths; each limb point is its parent's target plus
   the figure's segment length along the source segment's direction; pelvis, torso
   and feet turn as frames built from the source's points do (relative to its rest
   pose).
4. Foot contacts come from the source (toe or ankle near the floor and slow, with
   hysteresis). The ground is the plane z = 0 or a scene's world geoms (:mod:`~mjkin.motion.terrain`,
   ray casts down). A planted foot's target is frozen for the whole contact, resting on the ground
   under it by the lowest points of its geoms (tilted onto a slope), and eased back to the source's over
   :data:`EASE_S` seconds after it lifts, at any frame rate. Swinging feet are lifted so no point of their
   geoms is under the ground. The pelvis (and with it every limb) rises and falls with the ground under the
   planted feet.
5. Goals, in one priority level: both feet's toe and heel points weighted far above
   (:data:`FOOT_WEIGHT`) the pelvis, limb points, head, torso/pelvis orientations and the
   previous frame's pose; each frame is warm-started from the previous one. A hard
   :class:`~mjkin.goals.StepLimit` keeps each frame's change from the previous one within
   the joint speed limit, and hard :class:`~mjkin.goals.HalfSpace` goals keep the soles' corners above
   the ground planes under them, inside the solve, and a hard :class:`~mjkin.goals.Clearance` keeps the
   figure's own bodies :data:`SELF_CLEARANCE` apart (``clearance``).

:func:`report` measures the result: key-point errors, foot skate, floor penetration,
limits, speeds and self-penetration (MuJoCo contacts between non-adjacent bodies).

Never a silent failure: each frame's error is its worst key point (hands, feet and head, relative to the pelvis,
against their targets: :func:`frame_errors`), and a clip whose errors' 95th percentile over frames exceeds
``max_error`` (:data:`MAX_ERROR` by default) is ``failed`` (:func:`verdict`); its trajectory is still returned.
"""

from __future__ import annotations

import os
import time
from collections.abc import Sequence
from dataclasses import dataclass, replace
from typing import NamedTuple

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .. import goals as G
from .. import spatial
from ..errors import InputError
from ..ik import Problem
from ..ik.kernel import HARD_TOL
from ..ik.result import Result
from ..kinematics.geoms import contact_pairs
from ..kinematics.qspace import BALL, HINGE
from ..kinematics.tree import Tree, fingerprint
from ..runtime.checks import check_number, shown
from ..scene import Scene
from . import Trajectory, bvh, outside_limits, sole_points
from .clips import read_clip
from .roles import SIDES, figure_mapping, pelvis_lean, read_mapping, role_offsets, source_mapping
from .terrain import TEXT_SOURCE, Terrain, foot_points, lowest, sole_corners

Array = NDArray[np.float64]
KEYS = ("pelvis", "head", "left_wrist", "right_wrist", "left_ankle", "right_ankle")  # in Trajectory.targets
SCALE = (1e-6, 1e6)  # metres per BVH unit a clip may be given (micrometres to thousands of kilometres)
MAX_SPEED = 10.0  # rad/s (m/s) per dof when the caller gives none: MJCF has no joint speed limits
# The most frames of a clip retargeted at once: every frame's targets and goals are held (~20 kB a frame, 2 GB here;
# a 1e6-frame clip, 13 MB of BVH, ran out of memory). 14 minutes at 120 Hz; AMASS's longest clips are far shorter.
MAX_FRAMES = 100_000
# Each frame is one warm-started solve of MAX_ITERS iterations at most, all goals in one priority level (a second
# level costs a projection per iteration: 1.7-2x the time), the feet's toe and heel points weighted FOOT_WEIGHT
# against the body's goals (they slide a few micrometres per frame), REST_WEIGHT toward the previous frame's pose
# (less lets a shoulder or hip swing faster than the speed limit between frames). The body's goals conflict a
# little, so frames stop at MAX_ITERS, not at tol. At 6 the G1's crouch sat on an edge: on one CPU 2.0 cm off at
# the median, on another (or with the clip moved by 1e-6) its rise lagged on a straight right leg, 3.0 cm off; 7 to
# 15 iterations give 2.0 cm there, the moved clips too (8 costs 20-25 % of the frames/s of 6; 15 and two levels
# took 2.5-3x the time).
MAX_ITERS = 8
FOOT_WEIGHT = 1000.0
REST_WEIGHT = 0.02
# The body's goals against each other. The pelvis point leads (every key point follows it) and the pelvis's turn
# counts least: the lean it takes from the source (all of it on the G1) pulls the hips back of where a deep
# crouch needs them; at 1 and 0.3 the G1 crouched with one knee straight and its pelvis 10 cm high (key points
# 4.0 cm off at the median, 2.0 cm with these weights; the walks and the primate's crouch improve too).
BODY_WEIGHTS = {"pelvis": 3.0, "pelvis_turn": 0.05, "torso_turn": 0.3, "head": 0.5, "knee": 0.5, "shoulder": 0.5,
                "elbow": 0.5, "wrist": 1.0}
# Metres kept between the figure's own geoms (a hard Clearance in every frame's solve) unless the caller says
# otherwise: limbs that come close in the source (hands at the hips, knees brushing, legs crossing at 120 Hz)
# stay apart, at 9-16 % of the primate's frames/s and 2-9 % of the G1's (`mjkin bench retarget`).
SELF_CLEARANCE = 0.002
MAX_ERROR = 0.10  # m: a clip whose frame errors' ERROR_PERCENTILE exceeds this is failed
ERROR_PERCENTILE = 95  # over frames: a few frames may miss (a hand through the body moved out), not a tenth of them
# m past the clearance within which a pair of the figure's geoms is measured in each evaluation (Clearance.reach):
# a humanoid's links stay near each other (the G1's meshes: 66 pairs within 10 cm, 14 within 2 cm, in a walk),
# and each pair measured costs a GJK on two hulls; a pair farther off joins when a step brings it near
SELF_REACH = 0.02
EASE_S = 0.2  # s over which a lifted foot's target returns from where it stood to the source's (6 frames at 30 Hz)
CONTACT_ON = (0.03, 0.25)  # m above the floor, m/s: a foot point lower and slower touches down
CONTACT_OFF = (0.06, 0.5)  # ... higher or faster: it lifts (hysteresis)
GROUND_SMOOTH = 0.1  # s: the ground height the pelvis follows is smoothed over this (a Gaussian's sigma)
TILT_MAX = 0.5  # rad: a planted foot lies on a slope up to this steep (beyond, it rests level on the highest point)
TILT_AGREE = 0.03  # rad: ... and only where the normals under its geoms agree this well (one plane, not an edge)


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


def _facing(p: Array, roles: dict[str, int], left_of: Array) -> Array:
    """``p (F, J, 3)`` z-up turned about z so that frame 0 faces as the figure does.

    The figure's left hip is ``left_of (3,)`` (world) from its right: +y for one facing +x.
    """
    left = p[0, roles["left_hip"]] - p[0, roles["right_hip"]]
    turn = np.arctan2(-left[0], left[1]) - np.arctan2(-left_of[0], left_of[1])
    return p @ _yaw(-turn).T  # the left vector to the figure's, so forward (= left x up) to its too


@dataclass(frozen=True)
class Retarget:
    """What :func:`plan` works out: targets for every frame and the feet's contacts.

    ``points``: role -> ``(F, 3)`` target (world, m); ``rotations``: ``pelvis``, ``torso``,
    ``left_ankle``, ``right_ankle`` -> ``(F, 3, 3)``; ``contact (2, F)`` left/right planted,
    ``heel (2, F)`` its heel down too;
    ``feet (2, F, 4, 4)`` the foot bodies' target poses; ``source (F, J, 3)`` the source
    points in the figure's world (scaled as the root path), for drawing; ``metres_per_unit`` the
    clip's unit (given or from its height); ``root_ratio`` the figure's root path (m) per metre of the
    source's: 1 with a given scale, else the ratio of leg lengths (figure / source); ``footing`` left/right
    :class:`Footing`, the ground planes under the soles' corners.
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
    footing: tuple[Footing, ...]


class Footing(NamedTuple):
    """Where a foot's sole corners must stay in every frame: on the positive side of the ground planes under them."""

    corners: Array  # (K, 3) ball centres in the foot body's frame (:func:`.terrain.sole_corners`)
    points: Array  # (F, K, 3) a point of each corner's plane, moved out by the ball's radius (world, m)
    normals: Array  # (F, K, 3) the planes' unit normals


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


def _turn(a: Array, b: Array) -> Array:
    """Rotations ``(S, 3, 3)`` turning unit vectors ``a (S, 3)`` onto unit ``b (S, 3)`` the shortest way (Rodrigues)."""
    v = np.cross(a, b)
    K = np.zeros((len(v), 3, 3))
    K[:, 0, 1], K[:, 0, 2], K[:, 1, 2] = -v[:, 2], v[:, 1], -v[:, 0]
    K -= np.swapaxes(K, 1, 2)
    return np.eye(3) + K + K @ K / (1.0 + np.einsum("si,si->s", a, b))[:, None, None]


def _about(axis: Array, angle: Array) -> Array:
    """Rotations ``(n, 3, 3)`` by ``angle (n,)`` (rad) about the fixed unit ``axis (3,)`` (Rodrigues)."""
    K = np.array([[0.0, -axis[2], axis[1]], [axis[2], 0.0, -axis[0]], [-axis[1], axis[0], 0.0]])
    return np.eye(3) + np.sin(angle)[:, None, None] * K + (1 - np.cos(angle))[:, None, None] * (K @ K)


def _foot_rolls(tree: Tree, shin: str, foot: str) -> bool:
    """Whether a foot can roll (turn about its forward axis) on its own: a ball joint, or a hinge within 60° of
    that axis, on a body from the foot up to (not including) the shin. A planar leg's foot (an ankle that only
    pitches) cannot: it rolls as the leg does.
    """  # noqa: D205
    T = tree.fk(tree.qpos0)
    f, stop = tree.id(foot, "body"), tree.id(shin, "body")
    ahead = _unit(T[f, :3, 0] * [1.0, 1.0, 0.0])
    chain = []
    while f not in (stop, 0):
        chain.append(f)
        f = int(tree.body_parent[f])
    for j in np.flatnonzero(np.isin(tree.jnt_body, chain)):
        if tree.jnt_type[j] == BALL or (tree.jnt_type[j] == HINGE and abs(
                (T[tree.jnt_body[j], :3, :3] @ tree.jnt_axis[j]) @ ahead) >= 0.5):
            return True
    return False


def _ground_height(runs: Sequence[list[tuple[int, int]]], heights: Sequence[Array], F: int, dt: float) -> Array:
    """The height ``(F,)`` (m) of the ground under the feet: each foot's as it stands in its contacts
    (``runs``, ``heights`` one a contact), straight between them, both feet's mean, smoothed over
    :data:`GROUND_SMOOTH` (0 without contacts).
    """  # noqa: D205
    frames = np.arange(F)
    tracks = [np.interp(frames, np.ravel([(a, e - 1) for a, e in r]), np.repeat(h, 2)) for r, h in zip(runs, heights,
                                                                                                      strict=True) if r]
    base = np.mean(tracks, axis=0) if tracks else np.zeros(F)
    sigma = GROUND_SMOOTH / dt
    reach = int(np.ceil(3 * sigma))
    if reach < 1:
        return base
    kernel = np.exp(-0.5 * (np.arange(-reach, reach + 1) / sigma) ** 2)
    return np.convolve(np.pad(base, reach, mode="edge"), kernel / kernel.sum(), mode="valid")


class Foot(NamedTuple):
    """A foot body's geometry in its own frame (m): its geoms as balls and the points and axes of its sole."""

    points: Array  # (P, 3) ball centres (:func:`.terrain.foot_points`)
    radius: Array  # (P,)
    toe: Array  # (3,) the front of the sole (:func:`mjkin.motion.sole_points`), held through a contact
    middle: Array  # (3,) the middle of the sole, at its lowest
    ahead: Array  # (3,) unit: forward, level at rest
    across: Array  # (3,) unit: to the foot's left, level at rest
    rolls: bool  # it can roll (turn about ``ahead``) on its own (:func:`_foot_rolls`)


def _foot(tree: Tree, shin: str, body: str, rest: Array) -> Foot:
    """The :class:`Foot` of ``body`` (below ``shin``), posed ``rest (4, 4)`` at ``qpos0``."""
    pts, radius = foot_points(tree, body)
    level = _unit(rest[:3, 0] * [1.0, 1.0, 0.0])
    middle = np.array([*pts[:, :2].mean(axis=0), (pts[:, 2] - radius).min()])
    return Foot(pts, radius, sole_points(tree, body)[0], middle, rest[:3, :3].T @ level,
                rest[:3, :3].T @ np.cross([0.0, 0.0, 1.0], level), _foot_rolls(tree, shin, body))


def _plant(R: Array, p: Array, foot: Foot, ground: Terrain, rest: Array, contact: NDArray[np.bool_],
           side: str) -> tuple[Array, Array, Array]:
    """Held poses ``(F, 4, 4)`` of a foot in its contacts (``contact (F,)``; identity elsewhere), the tilts
    ``(F, 3, 3)`` onto the ground's slope, and the height ``(S,)`` of the ground under each of its S contacts.

    At touch-down the foot keeps the driven pose's (``R (F, 3, 3)``, ``p (F, 3)``) place across and its
    heading, with ``rest``'s tilt turned onto the ground's slope under it (when the normals under its balls
    agree within :data:`TILT_AGREE` and are at most :data:`TILT_MAX` steep; else it stays level, resting
    on the highest ground under it), raised or lowered until its lowest ball touches the ground, and held
    there through the contact.

    Raises:
        InputError: no ground under the foot at a touch-down.
    """  # noqa: D205
    F = len(p)
    starts = np.array([a for a, _ in _runs(contact)], dtype=np.int64)
    S = len(starts)
    level = _unit(rest[:3, 0] * [1.0, 1.0, 0.0])
    H = np.broadcast_to(np.eye(4), (S, 4, 4)).copy()
    heading = R[starts] @ foot.ahead + np.cross(R[starts] @ foot.across, [0.0, 0.0, 1.0])  # toes down: the across
    yaw = np.arctan2(heading[:, 1], heading[:, 0]) - np.arctan2(level[1], level[0])
    H[:, :3, :3] = _about(np.array([0.0, 0.0, 1.0]), yaw) @ rest[:3, :3]  # level, turned to the driven heading
    H[:, :3, 3] = p[starts]
    low = lowest(H, foot.points, foot.radius)  # (S, P, 3)
    h, n = ground.under(low.reshape(-1, 3))
    h, n = h.reshape(low.shape[:2]), n.reshape(low.shape)
    hit = np.isfinite(h)
    if not hit.any(axis=1).all():
        f = int(starts[np.argmin(hit.any(axis=1))])
        x, y = p[f, :2]
        raise InputError(f"no ground under the {side} foot at frame {f} (x={x:.2f}, y={y:.2f} m) in scene "
                         f"{ground.source!r}: extend the scene's geoms under the walk's path")
    mean = _unit(np.where(hit[..., None], n, 0.0).sum(axis=1))
    agree = (np.where(hit, np.einsum("spi,si->sp", n, mean), 1.0) >= np.cos(TILT_AGREE)).all(axis=1)
    slope = hit.all(axis=1) & agree & (mean[:, 2] >= np.cos(TILT_MAX))
    Q = np.tile(np.eye(3), (S, 1, 1))
    Q[slope] = _turn(np.tile([0.0, 0.0, 1.0], (int(slope.sum()), 1)), mean[slope])
    centre = low.mean(axis=1)
    H[:, :3, :3] = Q @ H[:, :3, :3]
    H[:, :3, 3] = centre + np.einsum("sij,sj->si", Q, H[:, :3, 3] - centre)
    moved = lowest(H, foot.points, foot.radius)
    grade = np.where(slope[:, None], -mean[:, :2] / mean[:, 2:], 0.0)  # the slope's dz/dx, dz/dy
    h = h + np.einsum("spi,si->sp", moved[..., :2] - low[..., :2], grade)  # the ground under the balls moved
    H[:, 2, 3] += np.where(hit, h - moved[..., 2], -np.inf).max(axis=1)
    held = np.broadcast_to(np.eye(4), (F, 4, 4)).copy()
    tilt = held[:, :3, :3].copy()
    r = _contact_number(contact)
    held[contact], tilt[contact] = H[r[contact]], Q[r[contact]]
    return held, tilt, (H[:, :3, :3] @ foot.middle + H[:, :3, 3])[:, 2]


def _contact_number(contact: NDArray[np.bool_]) -> NDArray[np.int64]:
    """Which contact (0, 1, ...) each frame of ``contact (F,)`` is in or last was (-1 before the first)."""
    return np.cumsum(np.diff(np.concatenate([[0], contact.astype(np.int8)])) == 1) - 1


def _lean(held: Array, hip: Array, foot: Foot) -> Array:
    """How far ``(F,)`` (rad, + left side up) a planted foot that cannot roll on its own leans across.

    Its leg is planar (an ankle that only pitches): the leg's plane holds the hip ``(F, 3)``, the ankle
    and the foot's forward axis, so the foot's left axis is across it (``held (F, 4, 4)``'s forward axis
    crossed with the way up the leg); 0 for a foot that rolls.
    """
    if foot.rolls:
        return np.zeros(len(held))
    left = _unit(np.cross(hip - held[:, :3, 3], held[:, :3, :3] @ foot.ahead))
    up = held[:, :3, :3] @ np.cross(foot.ahead, foot.across)
    return np.arcsin(np.clip(np.einsum("fi,fi->f", left, up), -1.0, 1.0))


def _foot_targets(R: Array, p: Array, foot: Foot, ground: Terrain, contact: NDArray[np.bool_], held: Array,
                  tilt: Array, lean: Array, heel: NDArray[np.bool_], ease_frames: int) -> Array:
    """Foot body poses ``(F, 4, 4)`` from the source-driven ``R (F, 3, 3)``, ``p (F, 3)`` and the contacts ``(F,)``.

    In a contact the foot is as ``held`` (``(F, 4, 4)``, :func:`_plant`), leaning across by ``lean (F,)``
    (:func:`_lean`) about the middle of its sole and onto its lower edge. While ``heel`` is up it pitches
    heel up as the driven pose does (relative to the slope it stands on, ``tilt (F, 3, 3)``) about its
    frozen toe. After lift-off the target eases from the last held pose to the driven one over
    ``ease_frames`` frames (:data:`EASE_S` at the clip's rate). Every pose is raised as far as a ball is under
    the ground straight below it.
    """
    F = len(p)
    T = np.broadcast_to(np.eye(4), (F, 4, 4)).copy()
    T[:, :3, :3], T[:, :3, 3] = R, p
    out = T.copy()
    at = np.flatnonzero(contact)
    H = held[at]
    H[:, :3, :3] = H[:, :3, :3] @ _about(foot.ahead, lean[at])
    H[:, :3, 3] = held[at, :3, :3] @ foot.middle + held[at, :3, 3] - H[:, :3, :3] @ foot.middle
    pitch = np.arcsin(np.clip(-np.einsum("nji,nj->ni", tilt[at], R[at] @ foot.ahead)[:, 2], -1.0, 1.0))
    up = ~heel[at] & (pitch > 0)  # toe pivot: the heel as far up as the driven foot's, about the frozen toe
    P = H[up].copy()
    P[:, :3, :3] = H[up, :3, :3] @ _about(foot.across, pitch[up])
    P[:, :3, 3] = H[up, :3, :3] @ foot.toe + H[up, :3, 3] - P[:, :3, :3] @ foot.toe
    H[up] = P
    out[at] = H
    last = np.maximum.accumulate(np.where(contact, np.arange(F), -1))  # the last frame in contact
    ease = np.flatnonzero(~contact & (last >= 0) & (np.arange(F) - last < ease_frames))
    if len(ease):  # after a lift-off: from the last pose in contact to the driven one
        A, u = out[last[ease]], (ease - last[ease]) / ease_frames
        out[ease, :3, 3] = (1 - u)[:, None] * A[:, :3, 3] + u[:, None] * T[ease, :3, 3]
        out[ease, :3, :3] = spatial.quat_to_mat(spatial.slerp(
            spatial.mat_to_quat(A[:, :3, :3]), spatial.mat_to_quat(T[ease, :3, :3]), u))
    out[:, 2, 3] += ground.lift(lowest(out, foot.points, foot.radius))
    return out


def plan(clip: bvh.Clip, tree: Tree, mapping: dict[str, dict[str, str]] | None = None,
         scale: float | None = None, terrain: Terrain | None = None) -> Retarget:
    """Targets for every frame of ``clip`` on ``tree`` (see the module's steps 1–4); ``scale`` in metres per unit.

    With ``scale`` the root moves the source's distance in metres (``scale`` times its BVH units);
    without it the root path is fitted to the figure (the source's times the ratio of leg lengths).
    The feet stand on ``terrain`` (default: the plane z = 0).
    """
    mapping = mapping or {}
    roles = source_mapping(clip, mapping.get("source"))
    bodies = figure_mapping(tree, mapping.get("figure"))
    unit = bvh.unit_scale(clip)[0] if scale is None else check_number(scale, "scale (metres per BVH unit)", 0,
                                                                       strict=True)
    if not SCALE[0] <= unit <= SCALE[1]:  # 1e-300 divided by zero further on
        raise InputError(f"scale must be from {SCALE[0]:g} to {SCALE[1]:g} metres per BVH unit, got {scale!r}")
    # the figure at qpos0: role points, segment lengths, orientations
    q0 = tree.qpos0
    offsets = role_offsets(tree, bodies)
    fig_T = {r: tree.pose(q0, b, "body") for r, b in bodies.items()}
    fig = {r: fig_T[r][:3, :3] @ offsets[r] + fig_T[r][:3, 3] for r in bodies}
    left_of = fig["left_hip"] - fig["right_hip"]
    p = _facing(clip.positions() @ Z_UP.T * unit, roles, left_of)
    rest = _facing(clip.positions(rest=True) @ Z_UP.T * unit, roles, left_of)[0]
    F = clip.frames
    feet_idx = [[j for j in (roles.get(f"{s}_ankle"), roles.get(f"{s}_toe")) if j is not None] for s in SIDES]
    floor = float(np.percentile(p[:, sum(feet_idx, []), 2].min(axis=1), 2))  # feet's lowest points
    rest_floor = float(rest[:, 2].min())

    feet_geom = [_foot(tree, bodies[f"{s}_knee"], bodies[f"{s}_ankle"], fig_T[f"{s}_ankle"]) for s in SIDES]
    fig_floor = min(float(lowest(fig_T[f"{s}_ankle"], f.points, f.radius)[:, 2].min())
                    for f, s in zip(feet_geom, SIDES, strict=True))

    def seg(a: str, b: str, pts: Array) -> Array:
        return np.linalg.norm(pts[..., roles[b], :] - pts[..., roles[a], :], axis=-1)

    src_leg = float(np.mean([seg(f"{s}_hip", f"{s}_knee", rest) + seg(f"{s}_knee", f"{s}_ankle", rest)
                             for s in SIDES]))
    fig_leg = float(np.mean([np.linalg.norm(fig[f"{s}_knee"] - fig[f"{s}_hip"])
                             + np.linalg.norm(fig[f"{s}_ankle"] - fig[f"{s}_knee"]) for s in SIDES]))
    k = fig_leg / src_leg if scale is None else 1.0

    lean = pelvis_lean(tree, bodies)

    def frames_of(pts: Array) -> dict[str, Array]:
        """Constructed rotations of pelvis, torso and feet from source points ``(..., J, 3)``."""
        up = np.array([0.0, 0.0, 1.0])
        P = lambda r: pts[..., roles[r], :]  # noqa: E731
        mid_sh = 0.5 * (P("left_shoulder") + P("right_shoulder"))
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
    pts["pelvis"][:, 2] = fig["pelvis"][2] - fig_floor + k * ((pelvis_src[:, 2] - floor)
                                                              - (rest[roles["pelvis"], 2] - rest_floor))
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

    # feet: contacts from the source; a planted foot rests on the ground under it, then pivots on its frozen toe
    # once its heel lifts; swinging feet follow the source above the ground, eased in after a lift-off; the body
    # rises and falls with the ground under the feet
    ground = terrain or Terrain.flat()
    contact = np.zeros((2, F), dtype=np.bool_)
    heel = np.zeros((2, F), dtype=np.bool_)
    driven, held, tilt, stand = [], [], [], []
    for i, s in enumerate(SIDES):
        idx = feet_idx[i]
        h = p[:, idx, 2] - floor - (rest[idx, 2] - rest_floor)
        v = np.zeros((F, len(idx)))
        v[1:] = np.linalg.norm(np.diff(p[:, idx, :2], axis=0), axis=-1) / clip.frame_time
        v[0] = v[1] if F > 1 else 0.0
        contact[i] = _contacts(h, v)
        heel[i] = contact[i] & _contacts(h[:, :1], v[:, :1])
        driven.append((rot[f"{s}_ankle"], pts[f"{s}_ankle"] - rot[f"{s}_ankle"] @ offsets[f"{s}_ankle"]))
        H, Q, z = _plant(*driven[i], feet_geom[i], ground, fig_T[f"{s}_ankle"], contact[i], s)
        held.append(H)
        tilt.append(Q)
        stand.append(z)
    base = _ground_height([_runs(c) for c in contact], stand, F, clip.frame_time)
    for r in pts:
        pts[r][:, 2] += base
    feet = np.empty((2, F, 4, 4))
    footing = []
    ease = max(1, round(EASE_S / clip.frame_time))
    for i, s in enumerate(SIDES):
        R, at = driven[i]
        foot = feet_geom[i]
        feet[i] = _foot_targets(R, at + base[:, None] * [0.0, 0.0, 1.0], foot, ground, contact[i], held[i], tilt[i],
                                _lean(held[i], pts[f"{s}_hip"], foot), heel[i], ease)
        corners, radius = sole_corners(foot.points, foot.radius)
        centres = np.einsum("fij,kj->fki", feet[i, :, :3, :3], corners) + feet[i, :, None, :3, 3]
        at_plane, normal = ground.planes(centres.reshape(-1, 3), np.tile(radius, F))
        footing.append(Footing(corners, at_plane.reshape(centres.shape), normal.reshape(centres.shape)))
    src = fig["pelvis"] + k * (p - np.array([*pelvis_src[0, :2], floor + rest[roles["pelvis"], 2] - rest_floor]))
    src[..., 2] += base[:, None]
    return Retarget(points=pts, rotations=rot, contact=contact, heel=heel, feet=feet, source=src, metres_per_unit=unit,
                    root_ratio=k, bodies=bodies, offsets=offsets, parents=clip.parents, footing=tuple(footing))


def retarget(source: str | os.PathLike[str] | bvh.Clip, tree: Tree,
             mapping: dict | str | os.PathLike[str] | None = None, *, scale: float | None = None,
             max_speed: ArrayLike = MAX_SPEED, tol: float = 1e-4, clearance: float | None = SELF_CLEARANCE,
             extra_goals: Sequence[G.Goal] = (), model_source: str = "",
             body_model: str | os.PathLike[str] | None = None,
             scene: str | os.PathLike[str] | Terrain | None = None, max_error: float = MAX_ERROR) -> Trajectory:
    """Retarget a clip (BVH or AMASS/SMPL ``.npz``) onto ``tree``: a :class:`Trajectory`, ``q (F, nq)`` per frame.

    Args:
        source: a BVH path, an AMASS/SMPL-H/SMPL-X ``.npz`` path (with ``body_model``) or a parsed
            :class:`mjkin.motion.bvh.Clip`.
        tree: the figure; it needs a free root joint.
        mapping: ``{"source": {role: joint}, "figure": {role: body}}`` (or a JSON file of it);
            by default roles are found (:mod:`mjkin.motion.roles`).
        scale: metres per BVH unit: the root then moves the source's distance in metres (its
            path in BVH units times ``scale``). Default: the unit suggested by the skeleton's
            height, and the root path fitted to the figure (times the ratio of leg lengths).
        max_speed: joint speed limit, rad/s (m/s), one number or ``(nv,)``: a hard
            :class:`~mjkin.goals.StepLimit` of ``max_speed`` times the frame time in every frame's
            solve (a joint's limit is the least of its dofs').
        tol: IK position tolerance (m).
        clearance: a hard :class:`~mjkin.goals.Clearance` of that margin (m, default
            :data:`SELF_CLEARANCE`) between the figure's own geoms (:func:`self_pairs`) in every
            frame's solve; None: none (about 15 % more frames/s, limbs may pass through each other).
        extra_goals: goals added to every frame's as they are (targets that do not change from
            frame to frame, such as a clearance between the figure's bodies); their priority
            decides whether they outrank the feet (0) or join the body's goals (1).
        model_source: where ``tree`` was loaded from, recorded so ``mjkin replay`` finds it.
        body_model: the SMPL-H/SMPL-X body-model ``.npz`` of an ``.npz`` source (:mod:`mjkin.motion.smpl`).
        scene: the ground, an MJCF file whose world geoms the feet stand on (floors, ramps, steps; a
            Menagerie ``scene.xml``) or a :class:`~mjkin.motion.terrain.Terrain`; default: the plane z = 0.
        max_error: the bound (m, > 0) on the frames' errors' :data:`ERROR_PERCENTILE` th percentile
            (:func:`frame_errors`) past which the clip is ``failed``; it judges, the solve is the same.

    Returns:
        The trajectory; ``meta["retarget"]`` holds the contacts ``(2, F)``, ``metres_per_unit`` and
        ``root_ratio`` (see :class:`Retarget`), the ``clearance`` held (m, or None), the frames per
        second (planning and solving, the first frame left out: it may compile the solver), ``errors``
        (each frame's, m, a list of F: :func:`frame_errors`), ``max_error`` and ``status``: ``ok``, or
        ``failed`` when the errors' percentile exceeds ``max_error``; ``targets (F, 6, 3)`` are the
        key-point targets (:data:`KEYS`; the feet's as held).

    Raises:
        MjkinIOError, InputError: unreadable clip, body model or scene, roles that cannot be mapped, bad options,
            a clip of over :data:`MAX_FRAMES` frames.
        ModelError: a scene MuJoCo cannot compile.
    """
    clip = source if isinstance(source, bvh.Clip) else read_clip(source, body_model)
    if clip.frames > MAX_FRAMES:
        raise InputError(f"clip {clip.source!r} has {clip.frames:,} frames; mjkin retargets at most {MAX_FRAMES:,} "
                         "frames of a clip (each frame's targets are held in memory): cut it into shorter clips")
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
    max_error = check_max_error(max_error)
    ground = scene if isinstance(scene, Terrain) else None if scene is None else Terrain.load(scene)
    extra, margin = tuple(extra_goals), None
    if clearance is not None:  # the figure's own (a model's, not the clip's: not timed, as a compile is not)
        margin = check_number(clearance, "clearance (m)")
        pairs = self_pairs(tree, margin)
        extra += (G.Clearance(margin, pairs=pairs, reach=SELF_REACH),) if pairs else ()
    t0 = time.perf_counter()
    plan_ = plan(clip, tree, mapping, scale, ground)
    q, t_first, unmet = solve_frames(tree, plan_, tol, extra, step_limit(tree, speed * clip.frame_time))
    elapsed = time.perf_counter() - t0 - t_first
    feet = {f"{s}_ankle": plan_.feet[i, :, :3, :3] @ plan_.offsets[f"{s}_ankle"] + plan_.feet[i, :, :3, 3]
            for i, s in enumerate(SIDES)}  # the feet's own targets: frozen while planted
    targets = np.stack([feet[r] if r in feet else plan_.points[r] for r in KEYS], axis=1)
    meta = {"retarget": {"clip": str(clip.source), "metres_per_unit": plan_.metres_per_unit,
                         "root_ratio": plan_.root_ratio,
                         "contact": plan_.contact.tolist(), "heel": plan_.heel.tolist(),
                         "frames_per_second": max(clip.frames - 1, 1) / elapsed,
                         "max_speed": speed.tolist(), "bodies": plan_.bodies, "clearance": margin,
                         "constraint_unmet": unmet, "scene": None if ground is None else ground.source}}
    times = np.arange(clip.frames, dtype=np.float64) * clip.frame_time
    traj = Trajectory(times=times, q=q, fingerprint=fingerprint(tree), model=tree.name, targets=targets, meta=meta,
                      source=model_source)
    errors = frame_errors(tree, traj)
    meta["retarget"].update(errors=errors.tolist(), max_error=max_error,
                            status=verdict(float(np.percentile(errors, ERROR_PERCENTILE)), max_error))
    return traj


def check_max_error(value: object) -> float:
    """``value`` as a bound for :func:`verdict`: metres, finite, > 0.

    Raises:
        InputError: anything else.
    """
    return check_number(value, "max_error (m)", 0.0, strict=True)


def verdict(percentile: float, max_error: float) -> str:
    """A clip's status from its frame errors' :data:`ERROR_PERCENTILE` th percentile (m): ``ok`` or ``failed``."""
    return "ok" if percentile <= max_error else "failed"


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

    At priority 1, hard: the soles' corners above the ground (:class:`Footing`); weighted: the feet's toe and
    heel points (:data:`FOOT_WEIGHT`), the pelvis,
    the torso's and pelvis's turn, the limb points and head (:data:`BODY_WEIGHTS`), the previous
    frame's pose (:data:`REST_WEIGHT`); ``extra`` as given.
    """
    b = plan_.bodies
    F = len(plan_.points["pelvis"])
    per_goal: list[list[G.Goal]] = []  # each goal's F frames
    for i, s in enumerate(SIDES):
        T = plan_.feet[i]
        for point in sole_points(tree, b[f"{s}_ankle"]):
            per_goal.append(G.Position(b[f"{s}_ankle"], T[:, :3, :3] @ point + T[:, :3, 3], kind="body",
                                       offset=tuple(point), priority=1, weight=FOOT_WEIGHT).unbatch())
        ground = plan_.footing[i]
        for k, corner in enumerate(ground.corners):  # hard: each sole corner above the ground plane under it
            per_goal.append(G.HalfSpace(b[f"{s}_ankle"], kind="body", offset=tuple(corner), point=ground.points[:, k],
                                        normal=ground.normals[:, k], priority=1).unbatch())
    per_goal.append(G.Position(b["pelvis"], plan_.points["pelvis"], kind="body", priority=1,
                               weight=BODY_WEIGHTS["pelvis"]).unbatch())
    for r in ("pelvis", "torso"):
        per_goal.append(G.Orientation(b[r], plan_.rotations[r], kind="body", priority=1,
                                      weight=BODY_WEIGHTS[f"{r}_turn"]).unbatch())
    for r in ("head", *(f"{s}_{p}" for s in SIDES for p in ("knee", "shoulder", "elbow", "wrist"))):
        off = plan_.offsets[r]
        per_goal.append(G.Position(b[r], plan_.points[r], kind="body", priority=1,
                                   offset=tuple(off) if np.any(off) else None,
                                   weight=BODY_WEIGHTS[r.rpartition("_")[2]]).unbatch())
    per_goal.extend([g] * F for g in extra)
    rest = G.Rest(q_rest=tree.qpos0, weight=REST_WEIGHT, priority=1)
    return FrameGoals(tuple(zip(*per_goal, strict=True)), rest)


def step_limit(tree: Tree, max_step: Array) -> G.StepLimit:
    """A :class:`~mjkin.goals.StepLimit` from per-dof steps ``max_step (nv,)``: each joint takes its dofs' least.

    Aimed ``HARD_TOL`` inside, the tolerance to which the solver keeps a hard constraint, so no step exceeds it.
    """
    per_joint = np.minimum.reduceat(max_step, tree.jnt_dofadr) if tree.njnt else np.zeros(0)
    return G.StepLimit(q_prev=tree.qpos0, max_step=np.maximum(per_joint - HARD_TOL, 0.0))


def self_pairs(tree: Tree, margin: float | None = None) -> list[tuple[int, int]]:
    """The geom pairs ``[(geom1, geom2), ...]`` (ids) MuJoCo would collide between the figure's own bodies.

    With a ``margin`` (m), only those at least that far apart in the rest pose (``qpos0``): a pair nearer there
    touches by design (a shell around a joint, parts built against each other) and a clearance of ``margin`` on
    it could not be met at the start, which would hold the figure still.
    """
    pairs = contact_pairs(tree)
    body = tree.model.geom_bodyid
    pairs = pairs[(body[pairs[:, 0]] != 0) & (body[pairs[:, 1]] != 0)]
    if margin is not None and len(pairs):
        pairs = pairs[tree.distances(tree.qpos0, pairs) >= margin]
    return [(int(a), int(b)) for a, b in pairs]


def solve_frames(tree: Tree, plan_: Retarget, tol: float, extra: Sequence[G.Goal] = (),
                 limit: G.StepLimit | None = None) -> tuple[Array, float, list[int]]:
    """Joint values ``(F, nq)``, frame by frame through one :class:`~mjkin.Problem`.

    Each frame is warm-started from (and rests toward) the previous frame's pose; ``extra``
    goals join every frame's; ``limit``, with ``q_prev`` the previous frame's pose, every frame's
    after the first. Also returns the seconds the first frame took (it may include compiling the solver)
    and the frames whose hard constraints could not all be met (each keeps the pose the solver found nearest
    to meeting them: it ranks a pose that meets them above any that does not, then by how far it misses).
    """
    F = len(plan_.points["pelvis"])
    q = tree.qpos0.copy()
    free = tree.layout.free_q[0]
    q[free[:3]] += plan_.points["pelvis"][0] - tree.pose(q, plan_.bodies["pelvis"], "body")[:3, 3]
    out = np.empty((F, tree.nq))
    layout = frame_goals(tree, plan_, extra)
    unmet: list[int] = []
    t = time.perf_counter()
    first = Problem(tree, layout.at(0, q), tol=tol, restarts=0, max_iters=MAX_ITERS)  # no previous frame to limit
    res = first.solve(q)
    q = out[0] = res.q
    if _misses(res):
        unmet.append(0)
    t_first = time.perf_counter() - t
    problem = Problem(tree, layout.at(0, q) + ([] if limit is None else [limit]), tol=tol, restarts=0,
                      max_iters=MAX_ITERS)
    for f in range(1, F):
        goals = layout.at(f, q)
        if limit is not None:
            goals.append(replace(limit, q_prev=q))
        res = problem.solve(q, goals)
        q = out[f] = res.q
        if _misses(res):
            unmet.append(f)
    return out, t_first, unmet


def _misses(res: Result) -> bool:
    """Whether a frame's answer leaves a hard constraint unmet (by more than the solver's ``HARD_TOL``)."""
    return any(g.hard and res.goal_errors[i, 0] > HARD_TOL for i, g in enumerate(res.goals))


# ------------------------------------------------------------------- report
def _runs(mask: NDArray[np.bool_]) -> list[tuple[int, int]]:
    """``(start, end)`` of each run of True in ``mask (F,)``, end exclusive."""
    edges = np.diff(np.concatenate([[0], mask.astype(np.int8), [0]]))
    return list(zip(np.flatnonzero(edges == 1).tolist(), np.flatnonzero(edges == -1).tolist(), strict=True))


def _ground(scene: str | os.PathLike[str] | Terrain | None) -> Terrain:
    """The ground a report measures against: a :class:`Terrain`, a scene file's, or the plane z = 0 (None, "").

    Raises:
        InputError: the clip's scene was XML text, which the trajectory does not keep.
    """
    if isinstance(scene, Terrain):
        return scene
    if scene == TEXT_SOURCE:
        raise InputError("the clip was retargeted onto a scene given as XML text: pass it to report(..., terrain=...)")
    return Terrain.load(scene) if scene else Terrain.flat()


def _point(tree: Tree, q: Array, body: str, offset: Array) -> Array:
    """World point ``(F, 3)`` at ``offset (3,)`` in a body: a role's point (:func:`.roles.role_offsets`)."""
    T = tree.pose(q, body, "body")
    return T[..., :3, :3] @ offset + T[..., :3, 3]


def keypoint_errors(tree: Tree, traj: Trajectory) -> Array:
    """How far each key point misses its target, ``(F, 5)`` (m): head, hands and feet (:data:`KEYS` after the
    pelvis), each relative to the pelvis, against ``traj.targets`` (relative to the pelvis's target).
    """  # noqa: D205
    if traj.targets is None:
        raise InputError("the trajectory has no key-point targets: it was not made by mjkin.retarget")
    bodies = traj.meta["retarget"]["bodies"]
    offsets = role_offsets(tree, bodies)
    got = np.stack([_point(tree, traj.q, bodies[r], offsets[r]) for r in KEYS], 1)
    return np.linalg.norm((got[:, 1:] - got[:, :1]) - (traj.targets[:, 1:] - traj.targets[:, :1]), axis=-1)


def frame_errors(tree: Tree, traj: Trajectory) -> Array:
    """Each frame's error ``(F,)`` (m): its worst key point (:func:`keypoint_errors`)."""
    return keypoint_errors(tree, traj).max(axis=1)


def report(tree: Tree, traj: Trajectory, terrain: str | os.PathLike[str] | Terrain | None = None) -> dict:
    """Measured figures of a retargeted clip (lengths in m, speeds per second); see the keys.

    ``metres_per_unit`` (the clip's unit used) and ``root_ratio`` (figure root path per source metre)
    come from ``traj.meta`` (:class:`Retarget`);
    ``keypoint_error_median``/``_max``: hands, feet and head relative to the pelvis against
    their targets (:func:`keypoint_errors`, every point of every frame); ``frame_error_median``/``_p95``/``_max``
    and ``worst_frame`` (its index): each frame's worst of them (:func:`frame_errors`);
    ``skate_per_frame_mean`` (mean horizontal slide of a planted foot per frame), ``skate_per_contact_max`` (its
    largest drift over one contact); ``floor_min`` (the
    feet's geoms' lowest point above the ground under it, < 0 into it), ``terrain_penetration`` (how
    deep a foot geom goes into the ground at most, 0 when none) and ``planted_float_max`` (how high a
    planted foot's lowest point is above the ground at most): the ground is ``terrain`` (by default the
    one the clip was retargeted onto, ``meta["retarget"]["scene"]``, else the plane z = 0), its height
    by rays cast down from the lowest points of the feet's geoms (:func:`.terrain.foot_points`, every
    :data:`.terrain.SPACING` on boxes and meshes); ``limits`` (None or what is outside);
    ``speed_max``/``speed_limit_ratio``; ``self_contact_frames``, ``self_contact_deepest``;
    ``constraint_unmet_frames``: frames whose hard constraints (clearance, ground, speed) the solver could not
    all meet (``meta["retarget"]["constraint_unmet"]`` lists them).
    """
    info = traj.meta["retarget"]
    bodies = info["bodies"]
    q, F = traj.q, len(traj.q)
    ground = _ground(info.get("scene") if terrain is None else terrain)
    contact = np.array(info["contact"], dtype=np.bool_)
    out: dict = {"frames": F, "frames_per_second": info["frames_per_second"],
                 "metres_per_unit": info["metres_per_unit"], "root_ratio": info["root_ratio"]}
    if traj.targets is not None:
        err = keypoint_errors(tree, traj)
        out["keypoint_error_median"], out["keypoint_error_max"] = float(np.median(err)), float(err.max())
        worst = err.max(axis=1)
        out["frame_error_median"] = float(np.median(worst))
        out["frame_error_p95"] = float(np.percentile(worst, ERROR_PERCENTILE))
        out["frame_error_max"], out["worst_frame"] = float(worst.max()), int(np.argmax(worst))
    heel = np.array(info["heel"], dtype=np.bool_)
    slide, drift, gap = [], [], np.empty((2, F))
    for i, s in enumerate(SIDES):
        T = tree.pose(q, bodies[f"{s}_ankle"], "body")
        soles = np.array(sole_points(tree, bodies[f"{s}_ankle"]))  # toe, heel
        pts = np.einsum("fij,pj->fpi", T[:, :3, :3], soles) + T[:, None, :3, 3]  # (F, 2, 3)
        low = lowest(T, *foot_points(tree, bodies[f"{s}_ankle"]))  # (F, P, 3)
        gap[i] = (low[..., 2] - ground.under(low.reshape(-1, 3))[0].reshape(low.shape[:2])).min(axis=1)
        for k, held in ((0, contact[i]), (1, heel[i])):  # the toe is held through a contact, the heel while down
            xy = pts[:, k, :2]
            slide.extend(np.linalg.norm(np.diff(xy, axis=0), axis=-1)[held[1:] & held[:-1]].tolist())
            for a, e in _runs(held):
                drift.append(float(np.linalg.norm(xy[a:e] - xy[a], axis=-1).max()))
    out["contact_frames"] = int(contact.sum())
    out["skate_per_frame_mean"] = float(np.mean(slide)) if slide else 0.0
    out["skate_per_contact_max"] = max(drift) if drift else 0.0
    out["floor_min"] = float(gap.min())
    out["terrain_penetration"] = max(0.0, -out["floor_min"])
    out["planted_float_max"] = float(gap[contact].max()) if contact.any() else 0.0
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
    out["constraint_unmet_frames"] = len(info.get("constraint_unmet", ()))
    return out
