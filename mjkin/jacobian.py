"""Geometric Jacobians built column by column from the joint frames.

For a point ``p`` on a body, each dof that moves the body contributes one
column (seed 000/002): a rotation about the unit axis ``u`` through the anchor
``a`` gives ``[u × (p - a); u]``, a translation along ``u`` gives ``[u; 0]``.
Ball and free joints contribute three rotational columns about the axes of
the frame after the joint (their angular velocity is local, as in MuJoCo), and
a free joint three translational columns along the world axes. The result
equals ``mj_jac`` stacked ``[jacp; jacr]``.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .errors import InputError

if TYPE_CHECKING:
    from .fk import Frames

Array = NDArray[np.float64]


def dof_frames(frames: Frames) -> tuple[Array, Array]:
    """World axis ``(B, nv, 3)`` and anchor ``(B, nv, 3)`` of every dof."""
    cached = frames.__dict__.get("_dofs")
    if cached is None:
        p = frames.tree.plan
        R, P = frames.joint_frames
        R, P = R[:, p.dof_jnt], P[:, p.dof_jnt]
        axis = np.where(p.dof_world[:, None], p.dof_axis, (R @ p.dof_axis[:, :, None])[..., 0])
        anchor = P + (R @ p.dof_anchor[:, :, None])[..., 0]
        cached = (axis, anchor)
        object.__setattr__(frames, "_dofs", cached)
    return cached


def point_jacobian(frames: Frames, body: int, point: Array) -> Array:
    """Jacobian ``(B, 6, nv)`` of world points ``point (B, 3)`` fixed to ``body``."""
    t = frames.tree
    dofs = t.body_dofs[body]
    J = np.zeros((point.shape[0], 6, t.nv))
    if len(dofs):
        axis, anchor = dof_frames(frames)
        u, a = axis[:, dofs], anchor[:, dofs]
        rot = t.plan.dof_rot[dofs][:, None]
        J[:, :3, dofs] = np.swapaxes(np.where(rot, np.cross(u, point[:, None] - a), u), 1, 2)
        J[:, 3:, dofs] = np.swapaxes(np.where(rot, u, 0.0), 1, 2)
    return J


def frame_jacobian(frames: Frames, kind: str, i: int, offset: ArrayLike | None = None) -> Array:
    """Jacobian ``(B, 6, nv)`` at a site/body origin, or at ``offset (3,)`` in its local frame."""
    body, _, _ = frames.local_frame(kind, i)
    R, p = frames.frame(kind, i)
    if offset is not None:
        off = np.asarray(offset, dtype=np.float64)
        if off.shape != (3,) or not np.all(np.isfinite(off)):
            raise InputError(f"offset must be 3 finite numbers (a point in the frame), got shape {off.shape}")
        p = p + R @ off
    return point_jacobian(frames, body, p)
