"""A walk: feet placed by IK heel to toe, the planted foot the IK root, switching every step."""

from __future__ import annotations

from dataclasses import dataclass, fields

import numpy as np

from .. import goals as G
from .. import spatial
from ..errors import InputError
from ..ik import Problem
from ..kinematics.tree import Tree, check_tree, fingerprint
from ..runtime.checks import check_count, check_number
from .keyframes import Array, min_jerk
from .trajectory import Trajectory

TOE_OFF, HEEL_STRIKE = 0.15, 0.85  # parts of a step spent rolling onto the toe, and down from the heel


@dataclass(frozen=True)
class Gait:
    """The numbers of a walk (:func:`walk_cycle`): lengths in metres, angles in radians.

    The swinging foot goes ``stride`` forward in ``frames_per_step`` frames, heel to toe
    (:func:`swing_foot`): it rolls onto its toe (heel up ``toe_off``), travels in an arc
    ``step_height`` high and lands on its heel (toe up ``heel_strike``); its knee bends
    ``knee_bend · sin(π s)``. The pelvis is ``crouch`` lower than standing, bobs ``bob``, sways
    ``sway`` toward the planted foot with its free side dropping ``hip_drop``; the upper body
    leans ``lean`` and the arms swing ``arm_swing`` against the legs.

    Raises:
        InputError: ``stride`` not positive, ``frames_per_step`` not a whole number >= 2, or a number not finite.
    """

    stride: float = 0.3
    step_height: float = 0.06
    frames_per_step: int = 24
    knee_bend: float = 0.7
    crouch: float = 0.04
    sway: float = 0.03
    lean: float = 0.08
    hip_drop: float = 0.06
    bob: float = 0.015
    arm_swing: float = 0.35
    toe_off: float = 0.35
    heel_strike: float = 0.25

    def __post_init__(self) -> None:
        for f in fields(self):
            value, what = getattr(self, f.name), f"Gait {f.name}"
            checked = (check_count(value, what, 2) if f.name == "frames_per_step"
                       else check_number(value, what, 0.0 if f.name == "stride" else None, strict=True))
            object.__setattr__(self, f.name, checked)


@dataclass(frozen=True)
class Rig:
    """The names a walk moves (:func:`walk_cycle`), the bundled primate's by default (``models/primate.xml``).

    ``feet`` (left, right) and ``pelvis`` are bodies; ``knees``, ``waist``, ``shoulders`` and
    ``elbows`` joints (``waist`` a ball joint that leans the upper body, ``shoulders`` ball joints
    that swing the arms); ``None``: that part is not moved.
    """

    feet: tuple[str, str] = ("left_foot", "right_foot")
    pelvis: str = "lower_torso"
    knees: tuple[str, str] = ("left_knee", "right_knee")
    waist: str | None = "waist"
    shoulders: tuple[str, str] | None = ("left_shoulder", "right_shoulder")
    elbows: tuple[str, str] | None = ("left_elbow", "right_elbow")


WALK, PRIMATE = Gait(), Rig()  # the defaults of walk_cycle


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


def swing_foot(start: Array, end: Array, s: float, toe: Array, heel: Array, gait: Gait = WALK) -> Array:
    """The swinging foot's pose at step phase ``s`` in [0, 1], from flat pose ``start`` to flat pose ``end``.

    Heel to toe: until :data:`TOE_OFF` it rolls onto its toe (the toe stays where it
    is, the heel rises to ``gait.toe_off`` rad), then it travels in an arc ``gait.step_height``
    high while turning toe-up, lands on its heel (``gait.heel_strike`` rad) at :data:`HEEL_STRIKE`
    and rolls down flat about the heel. ``toe`` and ``heel`` are in the foot's frame.
    """
    height, toe_off, heel_strike = gait.step_height, gait.toe_off, gait.heel_strike
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


def walk_cycle(tree: Tree, steps: int = 4, gait: Gait = WALK, rig: Rig = PRIMATE, fps: float = 30.0,
               tol: float = 1e-4) -> Trajectory:
    """A walk of ``steps`` steps: feet placed by IK, the planted foot switching every step (IK-driven animation).

    In each step one foot is planted — it is the IK root (``root=``), held where it
    stands while the free pelvis joint and the legs move — and the other swings
    forward by ``gait.stride`` heel to toe (:func:`swing_foot`: rolls onto its toe, an arc
    ``gait.step_height`` high, lands on its heel). The pelvis moves forward at a steady
    pace between the feet, ``gait.crouch`` lower than standing, bobbing ``gait.bob`` (highest
    over the planted foot) and swaying toward the planted foot: aimed ``gait.sway`` m
    sideways (as far as legs without ankle roll allow), its free side dropping
    ``gait.hip_drop`` rad, the upper body (joint ``rig.waist``) leaning ``gait.lean`` rad; the
    arms swing ``gait.arm_swing`` rad opposite to the legs, elbows a little bent; the swinging
    knee follows ``θ(s) = knee_bend · sin(π s)``. Arms, knees and the rest of the
    body are low-priority rest goals. Frames (``gait.frames_per_step`` a step, ``fps`` a second)
    are solved warm-started to ``tol`` (m, rad); ``success`` marks frames whose feet are on target.

    Raises:
        InputError: ``steps`` is not a whole number >= 1.
        UnknownNameError: a name of ``rig`` is not in the model.
    """
    check_tree(tree)
    steps = check_count(steps, "walk_cycle steps", 1, most=10_000)
    fps = check_number(fps, "walk_cycle fps", 0.0, strict=True)
    feet, pelvis, per = rig.feet, rig.pelvis, gait.frames_per_step
    q = tree.qpos0.copy()
    foot_T = {f: tree.pose(q, f, "body") for f in feet}
    soles = {f: sole_points(tree, f) for f in feet}
    T_pelvis = tree.pose(q, pelvis, "body")
    knee_q = [tree.jnt_qadr[tree.id(k, "joint")] for k in rig.knees]
    arm_q = None if rig.shoulders is None else [tree.jnt_qadr[tree.id(j, "joint")] for j in rig.shoulders]
    elbow_q = None if rig.elbows is None else [tree.jnt_qadr[tree.id(j, "joint")] for j in rig.elbows]
    waist_q = None if rig.waist is None else int(tree.jnt_qadr[tree.id(rig.waist, "joint")])
    out, ok = [], []
    problems: dict[str, Problem] = {}  # one per planted foot: the goals' structure is the same every frame
    arm_end = 0.0
    for k in range(steps):
        side = k % 2
        planted, swing = feet[side], feet[1 - side]
        start = foot_T[swing].copy()
        end = start.copy()
        end[0, 3] = (foot_T[planted] if k else start)[0, 3] + 0.5 * gait.stride
        arm_start, arm_end = -arm_end, gait.arm_swing * (0.5 if k == 0 else 1.0)  # same-side arm: front to back
        toward = np.sign(foot_T[planted][1, 3] - T_pelvis[1, 3])
        for f in range(1, per + 1):
            s = f / per
            T = swing_foot(start, end, s, *soles[swing], gait)
            P = T_pelvis.copy()
            P[0, 3] = 0.5 * (start[0, 3] + s * (end[0, 3] - start[0, 3]) + foot_T[planted][0, 3])
            P[1, 3] += toward * gait.sway * np.sin(np.pi * s)
            P[2, 3] -= gait.crouch + gait.bob * 0.5 * (1 + np.cos(2 * np.pi * s))
            roll = toward * gait.hip_drop * np.sin(np.pi * s)  # about x: the free side (off the planted foot) drops
            P[:3, :3] = spatial.quat_to_mat(spatial.quat_from_axis_angle([1.0, 0.0, 0.0], roll)) @ T_pelvis[:3, :3]
            rest = tree.qpos0.copy()
            if waist_q is not None:  # the upper body leans over the planted foot, against the hip drop
                rest[waist_q:waist_q + 4] = spatial.quat_from_axis_angle([1.0, 0.0, 0.0],
                                                                        -toward * (gait.lean + gait.hip_drop)
                                                                        * np.sin(np.pi * s))
            rest[knee_q[1 - side]] = gait.knee_bend * np.sin(np.pi * s)
            if arm_q is not None:
                a = arm_start + (arm_end - arm_start) * 0.5 * (1 - np.cos(np.pi * s))
                for j, angle in ((1 - side, a), (side, -a)):  # positive about y swings an arm back
                    rest[arm_q[j]:arm_q[j] + 4] = spatial.quat_from_axis_angle([0.0, 1.0, 0.0], angle)
                    if elbow_q is not None:
                        rest[elbow_q[j]] = 0.25 + 0.3 * max(0.0, -angle)
            goals = [G.Pose(swing, kind="body", T=T), G.Position(pelvis, P[:3, 3], kind="body", priority=1),
                     G.Orientation(pelvis, P[:3, :3], kind="body", priority=1), G.Rest(q_rest=rest, priority=2)]
            if planted not in problems:
                problems[planted] = Problem(tree, goals, root=planted, tol=tol, restarts=0)
            res = problems[planted].solve(q, goals)
            q = res.q
            out.append(q)
            ok.append(bool(res.goal_errors[0, 0] <= tol and res.goal_errors[1, 0] <= tol))  # feet on target
        foot_T[swing] = end
    return Trajectory(times=np.arange(len(out)) / fps, q=np.array(out), fingerprint=fingerprint(tree),
                      model=tree.name, frame=None, success=np.array(ok),
                      meta={"walk": {"steps": steps, "stride": gait.stride, "frames_per_step": per,
                                     "feet": list(feet), "toe_off": TOE_OFF, "heel_strike": HEEL_STRIKE}})
