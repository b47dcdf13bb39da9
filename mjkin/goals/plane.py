"""Plane: keep a frame's origin on a world plane."""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, ClassVar

from numpy.typing import ArrayLike

from ..runtime.jit import njit_inline, njit_ir_inline
from .base import METRES, Array, FrameGoal, Units, point, unit

if TYPE_CHECKING:
    from ..kinematics.fk import Kinematics
    from .residuals import GoalArrays


@dataclass(frozen=True)
class Plane(FrameGoal):
    """Keep the frame origin on the plane through ``point`` with ``normal``: ``g = n·(p - point)``."""

    point: ArrayLike = (0.0, 0.0, 0.0)
    normal: ArrayLike = (0.0, 0.0, 1.0)
    rows: ClassVar[int] = 1
    common: ClassVar[bool] = True  # cheap: in the shared IK loop
    units: ClassVar[Units] = METRES
    _batched: ClassVar[tuple[str, ...]] = ("point", "normal")

    def _validate(self) -> list[Array]:
        return [point(self.point, f"{type(self).__name__} point"),
                unit(self.normal, f"{type(self).__name__} normal")]


@njit_inline
def signed_distance(ga: GoalArrays, ws: tuple, i: int, b: int) -> float:
    """``n·(p - point)`` of goal ``i``'s frame point."""
    pt, d = ws[1], ga.data[b, i]
    return (pt[0, 0] - d[0]) * d[3] + (pt[0, 1] - d[1]) * d[4] + (pt[0, 2] - d[2]) * d[5]


@njit_inline
def distance_row(ga: GoalArrays, ws: tuple, i: int, b: int, s: float, g: Array, J: Array, r0: int,
                 err: Array) -> None:
    """Row ``r0``: ``w s`` with the normal's projection of the point Jacobian; the error ``|s|``."""
    J6, d = ws[0], ga.data[b, i]
    w = ga.sqrt_w[i]
    g[r0] = w * s
    for j in range(J.shape[1]):
        J[r0, j] = w * (d[3] * J6[0, 0, j] + d[4] * J6[0, 1, j] + d[5] * J6[0, 2, j])
    err[i, 0] = abs(s)


@njit_ir_inline
def residual(kin: Kinematics, ga: GoalArrays, ws: tuple, rot: Array, pos: Array, irot: Array, ipos: Array, i: int,
             b: int, q: Array, g: Array, J: Array, r0: int, err: Array) -> None:
    """One row: the signed distance from the plane."""
    distance_row(ga, ws, i, b, signed_distance(ga, ws, i, b), g, J, r0, err)
