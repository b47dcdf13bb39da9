"""Geometric Jacobians built column by column from the joint frames.

For a point ``p`` on a body, each dof that moves the body contributes one
column (the Polish lecture notes, the Finnish thesis): a rotation about the unit axis ``u`` through the anchor
``a`` gives ``[u × (p - a); u]``, a translation along ``u`` gives ``[u; 0]``.
Ball and free joints contribute three rotational columns about the axes of
the frame after the joint (their angular velocity is local, as in MuJoCo), and
a free joint three translational columns along the world axes. The result
equals ``mj_jac`` stacked ``[jacp; jacr]``.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..errors import InputError
from ..jit import njit, njit_inline
from .fk import Kinematics, fk_kernel, fk_scratch, frame_world

Array = NDArray[np.float64]
Index = NDArray[np.int64]


@njit_inline
def jacobian_kernel(rot: Array, pos: Array, inner_rot: Array, inner_pos: Array, dofs: Index, dof_body: Index,
                    dof_inner: Index, dof_axis: Array, dof_world: NDArray[np.bool_], dof_rot: NDArray[np.bool_],
                    dof_anchor: Array, point: Array, J: Array) -> None:
    """Fill the columns ``dofs`` of ``J (B, 6, nv)`` for world points ``point (B, 3)``.

    ``rot``, ``pos``, ``inner_rot``, ``inner_pos`` come from the FK kernel: a
    dof's joint frame is its body's frame, or an inner joint's frame when
    ``dof_inner >= 0``. ``dofs`` are the dofs that move the point's body; other
    columns are left untouched.
    """
    F = np.empty((3, 3))  # the dof's joint frame: rotation F, origin x
    x = np.empty(3)
    u = np.empty(3)  # world axis
    r = np.empty(3)  # from the world anchor to the point
    for b in range(point.shape[0]):
        for d in dofs:  # element-wise indexing, no views (see mjkin.jit)
            s, body = dof_inner[d], dof_body[d]
            for i in range(3):
                x[i] = inner_pos[b, s, i] if s >= 0 else pos[b, body, i]
                for k in range(3):
                    F[i, k] = inner_rot[b, s, i, k] if s >= 0 else rot[b, body, i, k]
            for i in range(3):
                u[i] = dof_axis[d, i] if dof_world[d] else (
                    F[i, 0] * dof_axis[d, 0] + F[i, 1] * dof_axis[d, 1] + F[i, 2] * dof_axis[d, 2])
            if dof_rot[d]:
                for i in range(3):
                    r[i] = point[b, i] - x[i] - (F[i, 0] * dof_anchor[d, 0] + F[i, 1] * dof_anchor[d, 1]
                                                 + F[i, 2] * dof_anchor[d, 2])
                J[b, 0, d] = u[1] * r[2] - u[2] * r[1]
                J[b, 1, d] = u[2] * r[0] - u[0] * r[2]
                J[b, 2, d] = u[0] * r[1] - u[1] * r[0]
                for i in range(3):
                    J[b, 3 + i, d] = u[i]
            else:
                for i in range(3):
                    J[b, i, d] = u[i]
                    J[b, 3 + i, d] = 0.0


def check_offset(offset: ArrayLike) -> Array:
    """A point ``(3,)`` fixed in a frame, validated."""
    off = np.asarray(offset, dtype=np.float64)
    if off.shape != (3,) or not np.all(np.isfinite(off)):
        raise InputError(f"offset must be 3 finite numbers (a point in the frame), got shape {off.shape}")
    return off


@njit
def frame_jacobian_one(kin: Kinematics, q: Array, body: int, local: Array, J: Array) -> None:
    """Jacobian ``J (6, nv)`` at the origin of the frame ``local (4, 4)`` fixed in ``body``, one ``q (1, nq)``.

    The short path of :meth:`mjkin.Tree.jacobian` for a single configuration.
    """
    rot, pos, irot, ipos = fk_scratch(kin.parent, kin.jnt_inner)
    fk_kernel(q, kin.parent, kin.fixed_rot, kin.fixed_pos, kin.jnt_start, kin.jnt_count, kin.jnt_inner,
              kin.fixed_plain, kin.hinge_coord, kin.anchor_zero, kin.jnt_type, kin.jnt_qadr, kin.jnt_axis,
              kin.jnt_pos, kin.qpos0, rot, pos, irot, ipos)
    T = np.empty((4, 4))
    frame_world(rot, pos, 0, body, local, T)
    x = np.empty((1, 3))
    for i in range(3):
        x[0, i] = T[i, 3]
    J6 = np.zeros((1, 6, J.shape[1]))
    jacobian_kernel(rot, pos, irot, ipos, kin.body_dof_idx[kin.body_dof_ptr[body]:kin.body_dof_ptr[body + 1]],
                    kin.dof_body, kin.dof_inner, kin.dof_axis, kin.dof_world, kin.dof_rot, kin.dof_anchor, x, J6)
    J[:] = J6[0]
