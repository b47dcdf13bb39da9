"""Pose: position and orientation of a frame at once."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING, ClassVar

import numpy as np
from numpy.typing import ArrayLike

from .. import spatial
from ..runtime.jit import njit_ir_inline
from .base import METRES_AND_RADIANS, Array, FrameGoal, Units, array, rotation_matrix
from .residuals import orientation_rows, position_rows

if TYPE_CHECKING:
    from ..kinematics.fk import Kinematics
    from ..kinematics.tree import Tree
    from .residuals import GoalArrays


@dataclass(frozen=True)
class Pose(FrameGoal):
    """Position and orientation at once, from a 4x4 pose ``T`` (or ``(B, 4, 4)``): rows ``[position; orientation]``."""

    T: ArrayLike = field(default_factory=lambda: np.eye(4))
    rows: ClassVar[int] = 6
    common: ClassVar[bool] = True  # cheap: in the shared IK loop
    units: ClassVar[Units] = METRES_AND_RADIANS
    _batched: ClassVar[tuple[str, ...]] = ("T",)
    _cores: ClassVar[tuple[int, ...]] = (2, 1)

    @classmethod
    def from_target(cls, frame: str, xyz: Array, quat: Array) -> Pose:
        """The frame at a placed target: point ``xyz (3,)`` (world, m), orientation ``quat (4,)`` (w, x, y, z)."""
        return cls(frame, T=spatial.make_transform(spatial.quat_to_mat(quat), xyz))

    def _validate(self) -> list[Array]:
        T = array(self.T, (4, 4), "Pose T")
        return [rotation_matrix(T[..., :3, :3], "Pose T rotation"), T[..., :3, 3]]

    def encode(self, tree: Tree, data: Array, rest: Array) -> None:  # noqa: D102
        R, p = self.targets()
        data[:, 0:3] = p
        data[:, 3:12] = R.reshape(-1, 9)


@njit_ir_inline
def residual(kin: Kinematics, ga: GoalArrays, ws: tuple, rot: Array, pos: Array, irot: Array, ipos: Array, i: int,
             b: int, q: Array, g: Array, J: Array, r0: int, err: Array) -> None:
    """Six rows: position, then the rotation vector to the target."""
    position_rows(ga, ws, i, b, g, J, r0, err)
    orientation_rows(ga, ws, i, b, g, J, r0 + 3, err)
