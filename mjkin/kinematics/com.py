"""The whole figure's centre of mass and its Jacobian, from the body frames.

The centre of mass is the mass-weighted mean of the bodies' own centres
(MuJoCo's ``xipos``: ``x_b = pos_b + rot_b · ipos_b``), ``c = Σ m_b x_b / M``,
over every body, so a model with several bodies under the world gets the
centre of all of them (MuJoCo's ``subtree_com[0]``). Its Jacobian is the same
mean of the bodies' point Jacobians at ``x_b`` (MuJoCo's
``mj_jacSubtreeCom(model, data, jacp, 0)``), summed per dof (see :func:`com_kernel`).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from ..runtime.jit import njit, njit_inline
from .fk import Kinematics
from .jacobian import jacobian_kernel

Array = NDArray[np.float64]

MIN_MASS = 1e-15  # MuJoCo's mjMINVAL: a lighter figure has no centre of mass (c = 0, Jc = 0, as MuJoCo's world)


@njit_inline
def com_kernel(kin: Kinematics, rot: Array, pos: Array, irot: Array, ipos: Array, c: Array, Jc: Array) -> None:
    """Centre of mass ``c (3,)`` (world, m) and its Jacobian ``Jc (3, nv)`` for one configuration's FK.

    ``rot``, ``pos``, ``irot``, ``ipos`` are :func:`mjkin.kinematics.fk.fk_kernel`'s
    outputs for one configuration (leading axis 1). ``Jc @ v`` is the centre's
    velocity for the velocity ``v (nv,)``. Each dof moves the bodies below it
    rigidly, so its column is ``(ω_d × S_d + v_d M_d) / M`` with ``[v_d; ω_d]`` the
    dof's Jacobian column at the world origin, ``M_d`` the mass it moves and
    ``S_d`` that mass's first moment: one pass over the bodies' dof lists and one
    Jacobian, not one Jacobian per body.
    """
    nv = Jc.shape[1]
    moment = np.zeros((nv, 4))  # S_d, M_d
    x = np.empty(3)
    total = 0.0
    for i in range(3):
        c[i] = 0.0
    for body in range(1, kin.body_mass.shape[0]):
        m = kin.body_mass[body]
        if m == 0.0:
            continue
        total += m
        for i in range(3):
            x[i] = pos[0, body, i] + (rot[0, body, i, 0] * kin.body_ipos[body, 0]
                                      + rot[0, body, i, 1] * kin.body_ipos[body, 1]
                                      + rot[0, body, i, 2] * kin.body_ipos[body, 2])
            c[i] += m * x[i]
        for k in range(kin.body_dof_ptr[body], kin.body_dof_ptr[body + 1]):
            d = kin.body_dof_idx[k]
            for i in range(3):
                moment[d, i] += m * x[i]
            moment[d, 3] += m
    if total < MIN_MASS:
        for i in range(3):
            c[i] = 0.0
            for d in range(nv):
                Jc[i, d] = 0.0
        return
    J0 = np.zeros((1, 6, nv))
    jacobian_kernel(rot, pos, irot, ipos, np.arange(nv), kin.dof_body, kin.dof_inner, kin.dof_axis, kin.dof_world,
                    kin.dof_rot, kin.dof_anchor, np.zeros((1, 3)), J0)
    for i in range(3):
        c[i] /= total
    for d in range(nv):
        w0, w1, w2 = J0[0, 3, d], J0[0, 4, d], J0[0, 5, d]
        S0, S1, S2, Md = moment[d, 0], moment[d, 1], moment[d, 2], moment[d, 3]
        Jc[0, d] = (w1 * S2 - w2 * S1 + J0[0, 0, d] * Md) / total
        Jc[1, d] = (w2 * S0 - w0 * S2 + J0[0, 1, d] * Md) / total
        Jc[2, d] = (w0 * S1 - w1 * S0 + J0[0, 2, d] * Md) / total


@njit
def com_many(kin: Kinematics, rot: Array, pos: Array, irot: Array, ipos: Array, C: Array, JC: Array) -> None:
    """:func:`com_kernel` for each of ``B`` FK outputs: ``C (B, 3)``, ``JC (B, 3, nv)``."""
    for b in range(C.shape[0]):
        com_kernel(kin, rot[b:b + 1], pos[b:b + 1], irot[b:b + 1], ipos[b:b + 1], C[b], JC[b])
