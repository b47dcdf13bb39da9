"""HalfSpace: stay on one side of a wall (a hard constraint)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, ClassVar

from ..runtime.jit import njit_ir_inline
from .base import Array
from .plane import Plane, signed_distance
from .residuals import HARD_TOL

if TYPE_CHECKING:
    from ..kinematics.fk import Kinematics
    from .residuals import GoalArrays


@dataclass(frozen=True)
class HalfSpace(Plane):
    """Keep the frame origin on the side of a wall that ``normal`` points to: ``d = n·(p - point) >= 0``.

    Hard, and exact: the solver keeps a hard row ``s >= -HARD_TOL`` (1e-6 m), so the row is
    ``s = d - HARD_TOL`` and an answer never ends past the wall (its reported error reads up to
    ``HARD_TOL`` on the wall itself). The weight only switches it on (> 0) or off.
    """

    hard: ClassVar[bool] = True
    common: ClassVar[bool] = True  # cheap: in the shared IK loop


@njit_ir_inline
def residual(kin: Kinematics, ga: GoalArrays, ws: tuple, rot: Array, pos: Array, irot: Array, ipos: Array, i: int,
             b: int, q: Array, g: Array, J: Array, r0: int, err: Array) -> None:
    """One row: the signed distance from the wall less ``HARD_TOL`` (unweighted), and the normal's part of the point
    Jacobian.
    """  # noqa: D205
    J6, d = ws[0], ga.data[b, i]
    g[r0] = signed_distance(ga, ws, i, b) - HARD_TOL
    for j in range(J.shape[1]):
        J[r0, j] = d[3] * J6[0, 0, j] + d[4] * J6[0, 1, j] + d[5] * J6[0, 2, j]
