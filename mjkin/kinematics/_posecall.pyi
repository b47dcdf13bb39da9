"""Types of the C module built from ``_posecall.c`` (optional: ``setup.py`` builds it where a C compiler is)."""

import numpy as np
from numpy.typing import NDArray

def bind(pose_address: object, poses_address: object, /) -> None:
    """Bind the kernels: the addresses (ints) of ``chain._pose_cfunc`` and ``chain._poses_cfunc``.

    TypeError for anything but two ints, ValueError for 0.
    """

def pose(chain: NDArray[np.float64], q: object, /) -> NDArray[np.float64] | None:
    """The chain's frame pose ``(4, 4)`` for ``q``, or None (``chain.pose_numba``'s contract)."""

def poses(chain: NDArray[np.float64], q: object, /) -> NDArray[np.float64] | None:
    """Each body's pose ``(n, 4, 4)`` for ``q``, or None (``chain.poses_numba``'s contract)."""
