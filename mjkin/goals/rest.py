"""Rest: stay near a rest ("comfort") pose, joint by joint."""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, ClassVar

import numpy as np
from numpy.typing import ArrayLike

from ..errors import GoalError, MjkinError
from ..kinematics.qspace import BALL, FREE, difference_kernel
from ..runtime.jit import njit_ir_inline
from .base import JOINT_UNITS, Array, Goal, Units, array, numbers
from .residuals import left_jacobian_inverse

if TYPE_CHECKING:
    from ..kinematics.fk import Kinematics
    from ..kinematics.tree import Tree
    from .residuals import GoalArrays


@dataclass(frozen=True)
class Rest(Goal):
    """Stay near a rest pose: ``g = sqrt(stiffness) · (q ⊖ q_rest)``, one row per dof.

    ``q_rest`` is ``(nq,)`` or ``(B, nq)``; ``stiffness`` a number or one per dof
    (``nv``): stiff joints move less. Never counted for success. Usually given a
    small weight or a low priority.
    """

    q_rest: ArrayLike = ()
    stiffness: ArrayLike = 1.0
    rows: ClassVar[int] = -1
    common: ClassVar[bool] = True  # cheap: in the shared IK loop
    units: ClassVar[Units] = JOINT_UNITS
    counted: ClassVar[bool] = False
    joint_target: ClassVar[bool] = True
    _batched: ClassVar[tuple[str, ...]] = ("q_rest",)

    def __post_init__(self) -> None:
        super().__post_init__()
        numbers(self.q_rest, "Rest q_rest")
        numbers(self.stiffness, "Rest stiffness")

    def key(self) -> tuple:  # noqa: D102
        return super().key() + (np.asarray(self.stiffness, dtype=float).tobytes(),)

    def batch(self) -> tuple[int, ...]:  # noqa: D102
        a = np.asarray(self.q_rest, dtype=np.float64)
        return a.shape[:-1] if a.ndim > 1 else ()

    def static(self, tree: Tree) -> tuple[int, Array, Array, int, Array | None]:
        """No frame; the square roots of the stiffness ``(nv,)`` as the goal's row."""
        k = (np.broadcast_to(np.asarray(self.stiffness, dtype=np.float64), (tree.nv,))
            if np.ndim(self.stiffness) == 0 else array(self.stiffness, (tree.nv,), "Rest stiffness"))
        if k.ndim != 1 or np.any(k < 0) or not np.isfinite(k).all():
            raise GoalError(f"Rest stiffness must be >= 0, one number or {tree.nv} (nv)")
        return -1, np.eye(3), np.zeros(3), 0, np.sqrt(k)

    def encode(self, tree: Tree, data: Array, rest: Array) -> None:
        """The rest pose, checked, into ``rest (B, nq)``."""
        try:
            rest[:] = tree.check_q(self.q_rest, "Rest q_rest")
        except MjkinError as e:
            raise GoalError(str(e)) from None


@njit_ir_inline
def residual(kin: Kinematics, ga: GoalArrays, ws: tuple, rot: Array, pos: Array, irot: Array, ipos: Array, i: int,
             b: int, q: Array, g: Array, J: Array, r0: int, err: Array) -> None:
    """One row per dof: the weighted, stiffness-scaled difference ``q ⊖ q_rest`` (never an error)."""
    Li, v, dv = ws[4], ws[5], ws[7]
    nv = J.shape[1]
    w = ga.sqrt_w[i]
    difference_kernel(q, ga.rest_q[i, b:b + 1], kin.jnt_type, kin.jnt_qadr, kin.jnt_dofadr, dv)
    J[r0:r0 + nv] = 0.0  # the rows at once (a Python loop per entry is slow interpreted, mjkin.runtime.tier)
    for j in range(nv):
        g[r0 + j] = w * ga.joint_row[i, j] * dv[0, j]
        J[r0 + j, j] = w * ga.joint_row[i, j]
    for jt in range(kin.jnt_type.shape[0]):  # rotations: d log(q_rest⁻¹ q) = J_r⁻¹(φ) ω (local ω)
        if kin.jnt_type[jt] == BALL or kin.jnt_type[jt] == FREE:
            d0 = kin.jnt_dofadr[jt] + (3 if kin.jnt_type[jt] == FREE else 0)
            for a in range(3):
                v[a] = -dv[0, d0 + a]
            theta = float(np.sqrt(v @ v))  # J_l⁻¹(-φ) = J_r⁻¹(φ)
            left_jacobian_inverse(v, theta, 1.0 / np.tan(0.5 * theta) if theta > 0.0 else np.inf, Li)
            for a in range(3):
                for c in range(3):
                    J[r0 + d0 + a, d0 + c] = Li[a, c] * (w * ga.joint_row[i, d0 + a])
