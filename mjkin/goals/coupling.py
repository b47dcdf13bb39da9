"""Coupling: a linear equality between hinge and slide joints (e.g. coupled fingers)."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, ClassVar

import numpy as np

from ..errors import GoalError
from ..kinematics.qspace import HINGE, SLIDE
from ..runtime.jit import njit_ir_inline
from .base import JOINT_UNITS, Array, Goal, Units, number

if TYPE_CHECKING:
    from ..kinematics.fk import Kinematics
    from ..kinematics.tree import Tree
    from .residuals import GoalArrays


@dataclass(frozen=True)
class Coupling(Goal):
    """``Σ coef_j q_j = value`` over hinge/slide joints.

    Its error is in joint units: judged against ``rot_tol`` when a hinge takes
    part (radians), against ``tol`` when only slides do (metres).
    """

    coefficients: Mapping[str, float] = field(default_factory=dict)
    value: float = 0.0
    rows: ClassVar[int] = 1
    common: ClassVar[bool] = True  # cheap: in the shared IK loop
    units: ClassVar[Units] = JOINT_UNITS

    def __post_init__(self) -> None:
        super().__post_init__()
        if not isinstance(self.coefficients, Mapping):
            raise GoalError("Coupling coefficients must be a mapping of joint name to number, got "
                            f"{type(self.coefficients).__name__}")
        for name, coef in self.coefficients.items():
            number(coef, f"Coupling coefficient of {name!r}")
        number(self.value, "Coupling value")

    def key(self) -> tuple:  # noqa: D102
        return super().key() + (tuple(self.coefficients.items()),)

    def static(self, tree: Tree) -> tuple[int, Array, Array, int, Array | None]:
        """No frame; the coefficients laid out over the dofs ``(nv,)`` as the goal's row."""
        if not self.coefficients:
            raise GoalError("Coupling needs at least one joint coefficient")
        c = np.zeros(tree.nv)
        for name, coef in self.coefficients.items():
            j = tree.id(name, "joint")
            if tree.jnt_type[j] not in (HINGE, SLIDE):
                raise GoalError(f"Coupling joint {name!r} must be a hinge or slide")
            c[tree.jnt_dofadr[j]] = coef
        return -1, np.eye(3), np.zeros(3), 0, c

    def column(self, tree: Tree) -> int:
        """1 (``rot_tol``) when a coupled joint is a hinge, else 0 (``tol``, slides in metres)."""
        hinges = [tree.jnt_type[tree.id(n, "joint")] == HINGE for n, c in self.coefficients.items() if c]
        return 1 if any(hinges) else 0

    def encode(self, tree: Tree, data: Array, rest: Array) -> None:  # noqa: D102
        data[:, 0] = self.value


@njit_ir_inline
def residual(kin: Kinematics, ga: GoalArrays, ws: tuple, rot: Array, pos: Array, irot: Array, ipos: Array, i: int,
             b: int, q: Array, g: Array, J: Array, r0: int, err: Array) -> None:
    """One row: ``w (Σ coef_j q_j - value)``; the error in the goal's column."""
    w = ga.sqrt_w[i]
    s = -ga.data[b, i, 0]
    for j in range(J.shape[1]):
        s += ga.joint_row[i, j] * q[0, kin.dof_qadr[j]]
        J[r0, j] = w * ga.joint_row[i, j]
    g[r0] = w * s
    err[i, ga.column[i]] = abs(s)
