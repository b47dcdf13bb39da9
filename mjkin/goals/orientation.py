"""Orientation: turn a frame to a world rotation, all three axes or one."""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, ClassVar

import numpy as np
from numpy.typing import ArrayLike

from ..errors import GoalError
from ..runtime.jit import njit_ir_inline
from .base import RADIANS, Array, FrameGoal, Units, rotation
from .residuals import orientation_rows, skew_times

if TYPE_CHECKING:
    from ..kinematics.fk import Kinematics
    from ..kinematics.tree import Tree
    from .residuals import GoalArrays

AXES = {"x": 0, "y": 1, "z": 2}


@dataclass(frozen=True)
class Orientation(FrameGoal):
    """Turn the frame to ``quat`` (or a rotation matrix): ``g = log(R R_targetᵀ)``, world axes.

    ``axes`` names the frame axes that must match the target's: ``"xyz"`` (all,
    the default) is the full orientation; a single axis such as ``"z"`` leaves
    the rotation about it free (a direction goal: ``g = R e - R_target e``).
    """

    quat: ArrayLike = (1.0, 0.0, 0.0, 0.0)
    axes: str = "xyz"
    rows: ClassVar[int] = 3
    common: ClassVar[bool] = True  # cheap: in the shared IK loop
    units: ClassVar[Units] = RADIANS
    _batched: ClassVar[tuple[str, ...]] = ("quat",)
    _cores: ClassVar[tuple[int, ...]] = (2,)

    def __post_init__(self) -> None:
        super().__post_init__()
        axes = self.axes
        if not isinstance(axes, str) or not axes or set(axes) - set(AXES) or len(set(axes)) != len(axes):
            raise GoalError(f"Orientation axes must be one or more of 'x', 'y', 'z', got {self.axes!r}")

    def key(self) -> tuple:  # noqa: D102
        return super().key() + (self.axes,)

    def _validate(self) -> list[Array]:
        return [rotation(self.quat, "Orientation quat")]

    def static(self, tree: Tree) -> tuple[int, Array, Array, int, Array | None]:
        """The frame, and as ``aux`` the one constrained axis (0, 1, 2 for x, y, z) or -1 for all three."""
        body, lrot, lpos, _, _ = super().static(tree)
        return body, lrot, lpos, AXES[self.axes] if len(self.axes) == 1 else -1, None

    def encode(self, tree: Tree, data: Array, rest: Array) -> None:  # noqa: D102
        data[:, 3:12] = self.targets()[0].reshape(-1, 9)


@njit_ir_inline
def residual(kin: Kinematics, ga: GoalArrays, ws: tuple, rot: Array, pos: Array, irot: Array, ipos: Array, i: int,
             b: int, q: Array, g: Array, J: Array, r0: int, err: Array) -> None:
    """Three rows: the rotation vector to the target, or (one axis) the frame axis minus the target's."""
    ax = ga.aux[i]
    if ax < 0:
        orientation_rows(ga, ws, i, b, g, J, r0, err)
        return
    J6, R, f, v = ws[0], ws[2], ws[6], ws[5]
    w = ga.sqrt_w[i]
    for a in range(3):
        f[a] = R[a, ax]
        v[a] = ga.data[b, i, 3 + 3 * a + ax]
    skew_times(f, J6[0, 3:], J, r0)
    n2 = 0.0
    for a in range(3):
        g[r0 + a] = w * (f[a] - v[a])
        n2 += (f[a] - v[a]) ** 2
        for j in range(J.shape[1]):
            J[r0 + a, j] *= w
    err[i, 1] = 2.0 * np.arcsin(min(0.5 * np.sqrt(n2), 1.0))
