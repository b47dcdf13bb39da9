"""Aim: point an axis of a frame at a world point (look at)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, ClassVar

import numpy as np
from numpy.typing import ArrayLike

from ..errors import GoalError
from ..kinematics.mat3 import matvec3
from ..runtime.jit import njit_ir_inline
from .base import RADIANS, Array, FrameGoal, Units, point, unit
from .residuals import skew_times

if TYPE_CHECKING:
    from ..kinematics.fk import Kinematics
    from .residuals import GoalArrays


@dataclass(frozen=True)
class Aim(FrameGoal):
    """Point the frame's local ``axis`` at the world ``point``: ``g = R axis - unit(point - p)``."""

    axis: ArrayLike = (1.0, 0.0, 0.0)
    point: ArrayLike = (0.0, 0.0, 0.0)
    rows: ClassVar[int] = 3
    common: ClassVar[bool] = True  # cheap: in the shared IK loop
    units: ClassVar[Units] = RADIANS
    _batched: ClassVar[tuple[str, ...]] = ("point",)

    @classmethod
    def from_target(cls, frame: str, xyz: Array, quat: Array) -> Aim:
        """The frame's z axis (out of a flange) pointed at a placed target's point ``xyz (3,)`` (world, m)."""
        return cls(frame, axis=(0.0, 0.0, 1.0), point=xyz)

    def _validate(self) -> list[Array]:
        axis = unit(self.axis, "Aim axis")
        if axis.ndim != 1:
            raise GoalError("Aim axis is fixed in the frame: give one (3,) vector")
        return [point(self.point, "Aim point"), axis]


@njit_ir_inline
def residual(kin: Kinematics, ga: GoalArrays, ws: tuple, rot: Array, pos: Array, irot: Array, ipos: Array, i: int,
             b: int, q: Array, g: Array, J: Array, r0: int, err: Array) -> None:
    """Three rows: the frame axis minus the unit direction from the frame point to the target point."""
    J6, pt, R, v, f = ws[0], ws[1], ws[2], ws[5], ws[6]
    w = ga.sqrt_w[i]
    d = ga.data[b, i]
    matvec3(R, d[3:6], f)
    L = np.sqrt((d[0] - pt[0, 0]) ** 2 + (d[1] - pt[0, 1]) ** 2 + (d[2] - pt[0, 2]) ** 2)
    for a in range(3):
        v[a] = (d[a] - pt[0, a]) / L if L > 1e-12 else f[a]
    skew_times(f, J6[0, 3:], J, r0)
    if L > 1e-12:  # the direction to the point moves with p
        for a in range(3):
            for c in range(3):
                P = ((1.0 if a == c else 0.0) - v[a] * v[c]) / L
                for j in range(J.shape[1]):
                    J[r0 + a, j] += P * J6[0, c, j]
    n2 = 0.0
    for a in range(3):
        g[r0 + a] = w * (f[a] - v[a])
        n2 += (f[a] - v[a]) ** 2
        for j in range(J.shape[1]):
            J[r0 + a, j] *= w
    err[i, 1] = 2.0 * np.arcsin(min(0.5 * np.sqrt(n2), 1.0))
