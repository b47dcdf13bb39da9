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
from .jit import matvec3, njit

if TYPE_CHECKING:
    from .fk import Frames

Array = NDArray[np.float64]
Index = NDArray[np.int64]


@njit
def jacobian_kernel(rot: Array, pos: Array, inner_rot: Array, inner_pos: Array, dofs: Index, dof_body: Index,
                    dof_inner: Index, dof_axis: Array, dof_world: NDArray[np.bool_], dof_rot: NDArray[np.bool_],
                    dof_anchor: Array, point: Array, J: Array) -> None:
    """Fill the columns ``dofs`` of ``J (B, 6, nv)`` for world points ``point (B, 3)``.

    ``rot``, ``pos``, ``inner_rot``, ``inner_pos`` come from the FK kernel: a
    dof's joint frame is its body's frame, or an inner joint's frame when
    ``dof_inner >= 0``. ``dofs`` are the dofs that move the point's body; other
    columns are left untouched.
    """
    u = np.empty(3)
    a = np.empty(3)
    for b in range(point.shape[0]):
        for d in dofs:
            if dof_inner[d] >= 0:
                R, x = inner_rot[b, dof_inner[d]], inner_pos[b, dof_inner[d]]
            else:
                R, x = rot[b, dof_body[d]], pos[b, dof_body[d]]
            if dof_world[d]:
                u[:] = dof_axis[d]
            else:
                matvec3(R, dof_axis[d], u)
            if dof_rot[d]:
                matvec3(R, dof_anchor[d], a)
                r0 = point[b, 0] - x[0] - a[0]
                r1 = point[b, 1] - x[1] - a[1]
                r2 = point[b, 2] - x[2] - a[2]
                J[b, 0, d] = u[1] * r2 - u[2] * r1
                J[b, 1, d] = u[2] * r0 - u[0] * r2
                J[b, 2, d] = u[0] * r1 - u[1] * r0
                J[b, 3:, d] = u
            else:
                J[b, :3, d] = u
                J[b, 3:, d] = 0.0


def point_jacobian(frames: Frames, body: int, point: Array) -> Array:
    """Jacobian ``(B, 6, nv)`` of world points ``point (B, 3)`` fixed to ``body``."""
    t, p = frames.tree, frames.tree.plan
    J = np.zeros((point.shape[0], 6, t.nv))
    jacobian_kernel(frames.rot, frames.pos, frames.inner_rot, frames.inner_pos, t.body_dofs[body],
                    t.jnt_body[p.dof_jnt], p.jnt_inner[p.dof_jnt], p.dof_axis, p.dof_world, p.dof_rot, p.dof_anchor,
                    np.ascontiguousarray(point), J)
    return J


def frame_jacobian(frames: Frames, kind: str, i: int, offset: ArrayLike | None = None) -> Array:
    """Jacobian ``(B, 6, nv)`` at a site/body origin, or at ``offset (3,)`` in its local frame."""
    body, _, _ = frames.local_frame(kind, i)
    R, x = frames.frame(kind, i)
    if offset is not None:
        off = np.asarray(offset, dtype=np.float64)
        if off.shape != (3,) or not np.all(np.isfinite(off)):
            raise InputError(f"offset must be 3 finite numbers (a point in the frame), got shape {off.shape}")
        x = x + R @ off
    return point_jacobian(frames, body, x)
