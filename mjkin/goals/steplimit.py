"""StepLimit: no joint moves more than a given step from a previous configuration (a hard constraint)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, ClassVar

import numpy as np
from numpy.typing import ArrayLike

from ..errors import GoalError, MjkinError
from ..kinematics.qspace import BALL, FREE, HINGE, SLIDE, difference_kernel
from ..runtime.jit import njit_inline, njit_ir_inline
from .base import JOINT_UNITS, Array, Goal, Units, numbers

if TYPE_CHECKING:
    from ..kinematics.fk import Kinematics
    from ..kinematics.tree import Tree
    from .residuals import GoalArrays


@dataclass(frozen=True)
class StepLimit(Goal):
    """Per joint ``|q ⊖ q_prev| <= max_step``: hard, for trajectories whose joints may only move so far per frame.

    ``q_prev`` is ``(nq,)`` or one per target ``(B, nq)``; ``max_step`` one number or
    one per joint ``(njnt,)`` (radians for hinges, metres for slides). A ball joint is
    limited by the angle of its rotation from ``q_prev``; a free joint by that angle
    and by the distance its origin moves, both against its one ``max_step``. An
    unlimited hinge's step is taken modulo 2π. One row per joint (two for a free joint):
    ``s = max_step - |step|``.
    """

    q_prev: ArrayLike = ()
    max_step: ArrayLike = np.inf
    rows: ClassVar[int] = -1
    common: ClassVar[bool] = True  # cheap: in the shared IK loop
    units: ClassVar[Units] = JOINT_UNITS
    hard: ClassVar[bool] = True
    joint_target: ClassVar[bool] = True
    _batched: ClassVar[tuple[str, ...]] = ("q_prev",)

    def __post_init__(self) -> None:
        super().__post_init__()
        numbers(self.q_prev, "StepLimit q_prev")
        numbers(self.max_step, "StepLimit max_step")

    def key(self) -> tuple:  # noqa: D102
        return super().key() + (np.asarray(self.max_step, dtype=float).tobytes(),)

    def nrows(self, tree: Tree) -> int:
        """One row per joint, two for a free joint."""
        return tree.njnt + int(np.count_nonzero(tree.jnt_type == FREE))

    def batch(self) -> tuple[int, ...]:  # noqa: D102
        a = np.asarray(self.q_prev, dtype=np.float64)
        return a.shape[:-1] if a.ndim > 1 else ()

    def static(self, tree: Tree) -> tuple[int, Array, Array, int, Array | None]:
        """No frame; each joint's ``max_step`` at its first dof (a free joint's also at its fourth), ``(nv,)``."""
        try:
            step = np.broadcast_to(np.asarray(self.max_step, dtype=np.float64), (tree.njnt,))
        except (TypeError, ValueError):
            raise GoalError(f"StepLimit max_step must be one number or one per joint ({tree.njnt}, njnt), got "
                            f"shape {np.shape(self.max_step)}") from None
        if np.any(np.isnan(step)) or np.any(step < 0):
            raise GoalError("StepLimit max_step must be >= 0 (inf: no limit)")
        row = np.zeros(tree.nv)
        for j in range(tree.njnt):
            d = int(tree.jnt_dofadr[j])
            row[d] = step[j]
            if tree.jnt_type[j] == FREE:
                row[d + 3] = step[j]
        return -1, np.eye(3), np.zeros(3), 0, row

    def encode(self, tree: Tree, data: Array, rest: Array) -> None:
        """The previous configuration, checked, into ``rest (B, nq)``."""
        try:
            rest[:] = tree.check_q(self.q_prev, "StepLimit q_prev")
        except MjkinError as e:
            raise GoalError(str(e)) from None


@njit_inline
def _norm_row(dv: Array, d: int, n: int, limit: float, g: Array, J: Array, r: int) -> None:
    """Row ``r``: ``limit - |dv[d:d+n]|`` and its gradient ``-dv/|dv|`` on those dofs (0 at no step)."""
    a = 0.0
    for k in range(n):
        a += dv[0, d + k] * dv[0, d + k]
    a = np.sqrt(a)
    g[r] = limit - a
    for k in range(n):
        J[r, d + k] = -dv[0, d + k] / a if a > 0.0 else 0.0


@njit_ir_inline
def residual(kin: Kinematics, ga: GoalArrays, ws: tuple, rot: Array, pos: Array, irot: Array, ipos: Array, i: int,
             b: int, q: Array, g: Array, J: Array, r0: int, err: Array) -> None:
    """One row per joint (two for a free joint): ``max_step - |q ⊖ q_prev|``, its gradient on the joint's dofs.

    A ball's (and a free joint's) rotation step is ``φ = log(R_prevᵀ R)`` in the joint's frame,
    where its velocity lives: ``d|φ|/dω = φᵀ/|φ|``.
    """
    dv = ws[7]
    difference_kernel(q, ga.rest_q[i, b:b + 1], kin.jnt_type, kin.jnt_qadr, kin.jnt_dofadr, dv)
    step = ga.joint_row[i]
    r = r0
    for j in range(kin.jnt_type.shape[0]):
        for c in range(J.shape[1]):
            J[r, c] = 0.0
        d, t = kin.jnt_dofadr[j], kin.jnt_type[j]
        if t == HINGE or t == SLIDE:
            x = dv[0, d]
            if t == HINGE and kin.jnt_lo[j] == -np.inf:  # an unlimited hinge: the shorter way round
                x -= 2.0 * np.pi * np.round(x / (2.0 * np.pi))
                dv[0, d] = x
            _norm_row(dv, d, 1, step[d], g, J, r)
        elif t == BALL:
            _norm_row(dv, d, 3, step[d], g, J, r)
        else:
            _norm_row(dv, d, 3, step[d], g, J, r)
            r += 1
            for c in range(J.shape[1]):
                J[r, c] = 0.0
            _norm_row(dv, d + 3, 3, step[d + 3], g, J, r)
        r += 1
