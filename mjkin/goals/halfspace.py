"""HalfSpace: stay on one side of a wall."""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

from ..jit import njit_inline
from .base import Array
from .plane import Plane, distance_row, signed_distance

if TYPE_CHECKING:
    from ..kinematics.fk import Kinematics
    from .compiled import GoalArrays


@dataclass(frozen=True)
class HalfSpace(Plane):
    """Stay on the side of a wall that ``normal`` points to: ``g = min(0, n·(p - point))``."""


@njit_inline
def residual(kin: Kinematics, ga: GoalArrays, ws: tuple, rot: Array, pos: Array, irot: Array, ipos: Array, i: int,
             b: int, q: Array, g: Array, J: Array, r0: int, err: Array) -> None:
    """One row: the signed distance where it is negative (behind the wall), else zero."""
    s = signed_distance(ga, ws, i, b)
    if s < 0.0:
        distance_row(ga, ws, i, b, s, g, J, r0, err)
        return
    g[r0] = 0.0
    for j in range(J.shape[1]):
        J[r0, j] = 0.0
