"""One measure of a retargeted motion against its source clip, whichever tool made it (issue 55).

:func:`score` takes any joint trajectory ``q (F, nq)`` on a figure (mjkin's, or a peer's such as GMR's) and the
clip it came from, and measures it the same way for every tool:

* **key points** — hands (the wrists' role points), feet (ankles) and head, each relative to the pelvis, against
  the source's joints relative to its hips, the source put in the figure's world and scaled to the figure as
  :func:`mjkin.motion.retarget.plan` does (metres from the skeleton's height, times the ratio of the figure's leg
  length to the source's). Relative to the pelvis, so a tool that places or scales the root path its own way (GMR
  assumes a 1.75 m human and does not ground the root) is judged on its pose, not on where its root went; the
  figure's world is turned about the vertical by the one yaw that fits the clip best (least squares over all
  frames), so a tool that keeps the clip's own heading (mjkin turns it to face +x) is not charged for it.
  Distances in m: mean and 95th percentile over every frame and key point.
* **self-contact** — MuJoCo's ``mj_collision`` on the figure's collision geoms (through :class:`mjkin.Scene`:
  the pairs MuJoCo itself excludes stay excluded — ``contype``/``conaffinity``, parent–child, welded bodies),
  the world's geoms left out: frames with a contact deeper than :data:`SELF_DEPTH`, and the deepest.
* **ground** — the lowest points of each foot's collision geoms (:func:`.terrain.foot_points`) against the
  ground under them: the deepest penetration, and the share of frames with both feet more than :data:`FLOAT`
  above it. The ground is the plane z = 0 unless ``terrain`` says otherwise; nothing is moved to meet it.
* **slide** — a planted sole's horizontal speed while the source's foot is planted (the contacts
  :func:`~mjkin.motion.retarget.plan` finds in the source, the same frames for every tool): the toe through a
  contact, the heel while it is down too, as :func:`mjkin.motion.retarget.report` counts skate.
* **smoothness** — the mean absolute joint acceleration of the hinges and slides (second differences).

The ground, slide and self-contact measures are those :func:`mjkin.motion.retarget.report` takes of mjkin's own
output (which also measures it against its own targets), kept per frame here; on mjkin's output the two agree
(``tests/motion/test_quality.py``).
"""

from __future__ import annotations

import os
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..errors import InputError
from ..kinematics.qspace import HINGE, SLIDE
from ..kinematics.tree import Tree
from ..runtime.checks import check_number
from ..scene import Scene
from . import bvh, outside_limits, sole_points
from .clips import read_clip
from .retarget import plan
from .roles import SIDES, source_mapping
from .terrain import Terrain, foot_points, lowest

Array = NDArray[np.float64]
KEYPOINTS = ("head", "left_wrist", "right_wrist", "left_ankle", "right_ankle")  # relative to the pelvis
SELF_DEPTH = 1e-3  # m: a self-contact deeper than this counts
FLOAT = 0.03  # m: both feet higher than this above the ground is a frame in the air


def _yaw(a: Array, b: Array) -> float:
    """The turn about z (rad) that brings vectors ``a (..., 3)`` closest to ``b (..., 3)`` (least squares)."""
    a, b = a.reshape(-1, 3), b.reshape(-1, 3)
    return float(np.arctan2(np.sum(a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]), np.sum(a[:, 0] * b[:, 0]
                                                                                  + a[:, 1] * b[:, 1])))


def _turned(v: Array, angle: float) -> Array:
    c, s = np.cos(angle), np.sin(angle)
    return v @ np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]).T


def _runs(mask: NDArray[np.bool_]) -> NDArray[np.bool_]:
    """Frame pairs ``(F - 1,)`` whose both frames are in ``mask (F,)``."""
    return mask[1:] & mask[:-1]


def keypoint_errors(tree: Tree, q: Array, source: Array, roles: dict[str, int], bodies: dict[str, str],
                    offsets: dict[str, Array]) -> Array:
    """Distances ``(F, 5)`` (m) of :data:`KEYPOINTS` from the source's, each relative to its pelvis.

    ``source (F, J, 3)`` are the source's joints in the figure's world, scaled to it (``plan().source``);
    ``roles`` the source's joint per role, ``bodies`` and ``offsets`` the figure's body and point per role. The
    figure's pelvis-relative points are turned about z by the yaw that fits them best to the source's.
    """
    def point(r: str) -> Array:
        T = tree.pose(q, bodies[r], "body")
        return T[..., :3, :3] @ offsets[r] + T[..., :3, 3]

    pelvis = point("pelvis")
    got = np.stack([point(r) - pelvis for r in KEYPOINTS], axis=1)  # (F, 5, 3)
    want = np.stack([source[:, roles[r]] - source[:, roles["pelvis"]] for r in KEYPOINTS], axis=1)
    return np.linalg.norm(_turned(got, _yaw(got, want)) - want, axis=-1)


def foot_gaps(tree: Tree, q: Array, bodies: dict[str, str], ground: Terrain) -> Array:
    """Each foot's lowest collision-geom point above the ground under it, ``(2, F)`` (m, left and right; < 0: in it)."""
    out = np.empty((2, len(q)))
    for i, s in enumerate(SIDES):
        low = lowest(tree.pose(q, bodies[f"{s}_ankle"], "body"), *foot_points(tree, bodies[f"{s}_ankle"]))
        out[i] = (low[..., 2] - ground.under(low.reshape(-1, 3))[0].reshape(low.shape[:2])).min(axis=1)
    return out


def sole_speeds(tree: Tree, q: Array, bodies: dict[str, str], contact: NDArray[np.bool_], heel: NDArray[np.bool_],
                frame_time: float) -> Array:
    """Horizontal speeds (m/s) of the planted soles, one per planted frame pair: toes in ``contact (2, F)``,
    heels in ``heel (2, F)`` (both feet's, concatenated).
    """  # noqa: D205
    out = []
    for i, s in enumerate(SIDES):
        T = tree.pose(q, bodies[f"{s}_ankle"], "body")
        for k, held in enumerate((contact[i], heel[i])):
            xy = (T[:, :3, :3] @ sole_points(tree, bodies[f"{s}_ankle"])[k] + T[:, :3, 3])[:, :2]
            out.append(np.linalg.norm(np.diff(xy, axis=0), axis=-1)[_runs(held)] / frame_time)
    return np.concatenate(out)


def self_contact_depths(tree: Tree, q: Array) -> Array:
    """The deepest contact between the figure's own geoms in each frame, ``(F,)`` (m, < 0: overlap; 0: none).

    MuJoCo's contacts (:meth:`mjkin.Scene.contacts`: its own pair filters, parent–child pairs excluded); those
    with a world geom (a floor) are left out.
    """
    scene = Scene(tree)
    out = np.zeros(len(q))
    for f in range(len(q)):
        mine = [c.distance for c in scene.contacts(q[f]) if "world" not in (c.body1, c.body2)]
        out[f] = min(0.0, *mine) if mine else 0.0
    return out


def joint_accelerations(tree: Tree, q: Array, frame_time: float) -> Array:
    """Accelerations ``(F - 2, n)`` (rad/s², m/s²) of the hinge and slide dofs (no free or ball joint) by second
    differences.
    """  # noqa: D205
    dofs = [int(tree.jnt_dofadr[j]) for j in range(tree.njnt) if tree.jnt_type[j] in (HINGE, SLIDE)]
    if len(q) < 3:
        return np.zeros((0, len(dofs)))
    v = tree.difference(q[1:], q[:-1])[:, dofs] / frame_time
    return np.diff(v, axis=0) / frame_time


def score(tree: Tree, q: ArrayLike, source: str | os.PathLike[str] | bvh.Clip, frame_time: float | None = None,
          terrain: Terrain | None = None) -> dict[str, Any]:
    """The module's measures of ``q (F, nq)`` on ``tree``, retargeted from ``source`` (a BVH path or clip).

    ``frame_time`` (s) defaults to the clip's. Keys: ``frames``; ``keypoint_mean``, ``keypoint_p95`` (m);
    ``self_contact_frames`` (deeper than :data:`SELF_DEPTH`), ``self_contact_deepest`` (m, <= 0);
    ``foot_penetration`` (m, >= 0), ``float_share`` (0..1: both feet above :data:`FLOAT`);
    ``slide_speed_mean`` (m/s), ``contact_frames`` (the source's, both feet); ``joint_accel_mean`` (rad/s²);
    ``limits`` (None or what is outside, :func:`mjkin.motion.outside_limits`).

    Raises:
        InputError: ``q`` of the wrong shape, or a clip with another number of frames.
    """
    clip = source if isinstance(source, bvh.Clip) else read_clip(source)
    qs = tree.check_q(np.asarray(q, dtype=np.float64), "q")
    if qs.ndim != 2 or len(qs) != clip.frames:
        raise InputError(f"q must be ({clip.frames}, {tree.nq}): one pose a frame of the clip; got {qs.shape}")
    dt = clip.frame_time if frame_time is None else check_number(frame_time, "frame_time (s)", 0, strict=True)
    ground = terrain or Terrain.flat()
    p = plan(clip, tree, terrain=ground)
    err = keypoint_errors(tree, qs, p.source, source_mapping(clip), p.bodies, p.offsets)
    gaps = foot_gaps(tree, qs, p.bodies, ground)
    slide = sole_speeds(tree, qs, p.bodies, p.contact, p.heel, dt)
    depth = self_contact_depths(tree, qs)
    acc = joint_accelerations(tree, qs, dt)
    return {"frames": len(qs),
            "keypoint_mean": float(err.mean()), "keypoint_p95": float(np.percentile(err, 95)),
            "self_contact_frames": int(np.count_nonzero(depth < -SELF_DEPTH)),
            "self_contact_deepest": float(depth.min()),
            "foot_penetration": max(0.0, -float(gaps.min())),
            "float_share": float(np.mean((gaps > FLOAT).all(axis=0))),
            "slide_speed_mean": float(slide.mean()) if slide.size else 0.0,
            "contact_frames": int(p.contact.sum()),
            "joint_accel_mean": float(np.abs(acc).mean()) if acc.size else 0.0,
            "limits": outside_limits(tree, qs)}
