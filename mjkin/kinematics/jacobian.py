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
from numpy.typing import NDArray

from ..runtime.jit import njit, njit_inline
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
    for b in range(point.shape[0]):
        for d in dofs:  # element-wise indexing and scalars, no views or scratch arrays (see mjkin.runtime.jit)
            f00, f01, f02, f10, f11, f12, f20, f21, f22, x0, x1, x2 = _joint_frame(rot, pos, inner_rot, inner_pos, b,
                                                                                   dof_body[d], dof_inner[d])
            a0, a1, a2 = dof_axis[d, 0], dof_axis[d, 1], dof_axis[d, 2]
            if dof_world[d]:  # the world axis u
                u0, u1, u2 = a0, a1, a2
            else:
                u0, u1, u2 = f00 * a0 + f01 * a1 + f02 * a2, f10 * a0 + f11 * a1 + f12 * a2, f20 * a0 + f21 * a1 + (
                    f22 * a2)
            if dof_rot[d]:
                c0, c1, c2 = dof_anchor[d, 0], dof_anchor[d, 1], dof_anchor[d, 2]
                r0 = point[b, 0] - x0 - (f00 * c0 + f01 * c1 + f02 * c2)  # from the world anchor to the point
                r1 = point[b, 1] - x1 - (f10 * c0 + f11 * c1 + f12 * c2)
                r2 = point[b, 2] - x2 - (f20 * c0 + f21 * c1 + f22 * c2)
                J[b, 0, d] = u1 * r2 - u2 * r1
                J[b, 1, d] = u2 * r0 - u0 * r2
                J[b, 2, d] = u0 * r1 - u1 * r0
                J[b, 3, d], J[b, 4, d], J[b, 5, d] = u0, u1, u2
            else:
                J[b, 0, d], J[b, 1, d], J[b, 2, d] = u0, u1, u2
                J[b, 3, d], J[b, 4, d], J[b, 5, d] = 0.0, 0.0, 0.0


@njit_inline
def _joint_frame(rot: Array, pos: Array, inner_rot: Array, inner_pos: Array, b: int, body: int, s: int) -> tuple:
    """A dof's joint frame as 12 numbers, rotation row by row then origin: its body's, or inner joint ``s``'s."""
    R, X, k = (inner_rot, inner_pos, s) if s >= 0 else (rot, pos, body)
    return (R[b, k, 0, 0], R[b, k, 0, 1], R[b, k, 0, 2], R[b, k, 1, 0], R[b, k, 1, 1], R[b, k, 1, 2],
            R[b, k, 2, 0], R[b, k, 2, 1], R[b, k, 2, 2], X[b, k, 0], X[b, k, 1], X[b, k, 2])


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
