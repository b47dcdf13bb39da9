"""Line: keep a frame's origin on a world line."""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, ClassVar

import numpy as np
from numpy.typing import ArrayLike

from ..runtime.jit import njit_ir_inline
from .base import METRES, Array, FrameGoal, Units, point, unit

if TYPE_CHECKING:
    from ..kinematics.fk import Kinematics
    from .residuals import GoalArrays


@dataclass(frozen=True)
class Line(FrameGoal):
    """Keep the frame origin on the line through ``point`` along ``direction``."""

    point: ArrayLike = (0.0, 0.0, 0.0)
    direction: ArrayLike = (0.0, 0.0, 1.0)
    rows: ClassVar[int] = 3
    common: ClassVar[bool] = True  # cheap: in the shared IK loop
    units: ClassVar[Units] = METRES
    _batched: ClassVar[tuple[str, ...]] = ("point", "direction")

    def _validate(self) -> list[Array]:
        return [point(self.point, "Line point"), unit(self.direction, "Line direction")]


@njit_ir_inline
def residual(kin: Kinematics, ga: GoalArrays, ws: tuple, rot: Array, pos: Array, irot: Array, ipos: Array, i: int,
             b: int, q: Array, g: Array, J: Array, r0: int, err: Array) -> None:
    """Three rows: the frame point's offset from the line, perpendicular to it."""
    J6, pt = ws[0], ws[1]
    w = ga.sqrt_w[i]
    d = ga.data[b, i]
    s = (pt[0, 0] - d[0]) * d[3] + (pt[0, 1] - d[1]) * d[4] + (pt[0, 2] - d[2]) * d[5]
    n2 = 0.0
    for a in range(3):
        e = pt[0, a] - d[a] - s * d[3 + a]
        g[r0 + a] = w * e
        n2 += e * e
        for j in range(J.shape[1]):
            J[r0 + a, j] = w * (J6[0, a, j] - d[3 + a] * (d[3] * J6[0, 0, j] + d[4] * J6[0, 1, j]
                                                         + d[5] * J6[0, 2, j]))
    err[i, 0] = np.sqrt(n2)
