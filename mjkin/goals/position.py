"""Position: put a frame's origin (or a point on it) at a world point."""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, ClassVar

from numpy.typing import ArrayLike

from ..runtime.jit import njit_ir_inline
from .base import METRES, Array, FrameGoal, Units, array
from .residuals import position_rows

if TYPE_CHECKING:
    from ..kinematics.fk import Kinematics
    from ..kinematics.tree import Tree
    from .residuals import GoalArrays


@dataclass(frozen=True)
class Position(FrameGoal):
    """Put the frame origin (or ``offset``) at ``xyz (3,)`` or ``(B, 3)``: ``g = p - xyz``."""

    xyz: ArrayLike = (0.0, 0.0, 0.0)
    rows: ClassVar[int] = 3
    common: ClassVar[bool] = True  # cheap: in the shared IK loop
    units: ClassVar[Units] = METRES
    _batched: ClassVar[tuple[str, ...]] = ("xyz",)
    _cores: ClassVar[tuple[int, ...]] = (1,)

    @classmethod
    def from_target(cls, frame: str, xyz: Array, quat: Array) -> Position:
        """The frame's origin at a placed target's point ``xyz (3,)`` (world, m); its ``quat (4,)`` is not used."""
        return cls(frame, xyz=xyz)

    def _validate(self) -> list[Array]:
        return [array(self.xyz, (3,), "Position xyz")]

    def encode(self, tree: Tree, data: Array, rest: Array) -> None:  # noqa: D102
        data[:, 0:3] = self.targets()[0]


@njit_ir_inline
def residual(kin: Kinematics, ga: GoalArrays, ws: tuple, rot: Array, pos: Array, irot: Array, ipos: Array, i: int,
             b: int, q: Array, g: Array, J: Array, r0: int, err: Array) -> None:
    """``w (p - xyz)``, three rows."""
    position_rows(ga, ws, i, b, g, J, r0, err)
