"""The whole figure's centre of mass and its Jacobian, from the body frames.

The centre of mass is the mass-weighted mean of the bodies' own centres
(MuJoCo's ``xipos``: ``x_b = pos_b + rot_b · ipos_b``), ``c = Σ m_b x_b / M``,
over every body, so a model with several bodies under the world gets the
centre of all of them (MuJoCo's ``subtree_com[0]``). Its Jacobian is the same
mean of the bodies' point Jacobians at ``x_b`` (MuJoCo's
``mj_jacSubtreeCom(model, data, jacp, 0)``), each built by
:func:`mjkin.kinematics.jacobian.jacobian_kernel`.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from ..jit import njit, njit_inline
from .fk import Kinematics
from .jacobian import jacobian_kernel

Array = NDArray[np.float64]

MIN_MASS = 1e-15  # MuJoCo's mjMINVAL: a lighter figure has no centre of mass (c = 0, Jc = 0, as MuJoCo's world)


@njit_inline
def com_kernel(kin: Kinematics, rot: Array, pos: Array, irot: Array, ipos: Array, c: Array, Jc: Array) -> None:
    """Centre of mass ``c (3,)`` (world, m) and its Jacobian ``Jc (3, nv)`` for one configuration's FK.

    ``rot``, ``pos``, ``irot``, ``ipos`` are :func:`mjkin.kinematics.fk.fk_kernel`'s
    outputs for one configuration (leading axis 1). ``Jc @ v`` is the centre's
    velocity for the velocity ``v (nv,)``.
    """
    nv = Jc.shape[1]
    x = np.empty((1, 3))
    J6 = np.zeros((1, 6, nv))
    total = 0.0
    for i in range(3):
        c[i] = 0.0
        for d in range(nv):
            Jc[i, d] = 0.0
    for body in range(1, kin.body_mass.shape[0]):
        m = kin.body_mass[body]
        if m == 0.0:
            continue
        total += m
        for i in range(3):
            x[0, i] = pos[0, body, i] + (rot[0, body, i, 0] * kin.body_ipos[body, 0]
                                         + rot[0, body, i, 1] * kin.body_ipos[body, 1]
                                         + rot[0, body, i, 2] * kin.body_ipos[body, 2])
            c[i] += m * x[0, i]
        p0, p1 = kin.body_dof_ptr[body], kin.body_dof_ptr[body + 1]
        jacobian_kernel(rot, pos, irot, ipos, kin.body_dof_idx[p0:p1], kin.dof_body, kin.dof_inner, kin.dof_axis,
                        kin.dof_world, kin.dof_rot, kin.dof_anchor, x, J6)
        for k in range(p0, p1):
            d = kin.body_dof_idx[k]
            for i in range(3):
                Jc[i, d] += m * J6[0, i, d]
    if total < MIN_MASS:
        for i in range(3):
            c[i] = 0.0
            for d in range(nv):
                Jc[i, d] = 0.0
        return
    for i in range(3):
        c[i] /= total
        for d in range(nv):
            Jc[i, d] /= total


@njit
def com_many(kin: Kinematics, rot: Array, pos: Array, irot: Array, ipos: Array, C: Array, JC: Array) -> None:
    """:func:`com_kernel` for each of ``B`` FK outputs: ``C (B, 3)``, ``JC (B, 3, nv)``."""
    for b in range(C.shape[0]):
        com_kernel(kin, rot[b:b + 1], pos[b:b + 1], irot[b:b + 1], ipos[b:b + 1], C[b], JC[b])
