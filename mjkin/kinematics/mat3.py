"""3x3 kernels the compiled FK, goals and CCD share, written element by element into arrays the caller owns.

Rotation matrices from a quaternion or an axis and angle, and a 3x3 matrix times a 3-vector.
"""

from __future__ import annotations

import numpy as np

from ..runtime.jit import njit


@njit
def quat_to_mat(w: float, x: float, y: float, z: float, out: np.ndarray) -> None:
    """Write the rotation matrix of the quaternion ``(w, x, y, z)``, normalised, into ``out (3, 3)``."""
    n2 = w * w + x * x + y * y + z * z
    if not n2 < 1e300:  # huge components (1e308): their squares overflow, so scale by the largest first
        m = max(abs(w), abs(x), abs(y), abs(z))
        w, x, y, z = w / m, x / m, y / m, z / m
        n2 = w * w + x * x + y * y + z * z
    n = np.sqrt(n2)
    w, x, y, z = w / n, x / n, y / n, z / n
    out[0, 0] = 1 - 2 * (y * y + z * z)
    out[0, 1] = 2 * (x * y - w * z)
    out[0, 2] = 2 * (x * z + w * y)
    out[1, 0] = 2 * (x * y + w * z)
    out[1, 1] = 1 - 2 * (x * x + z * z)
    out[1, 2] = 2 * (y * z - w * x)
    out[2, 0] = 2 * (x * z - w * y)
    out[2, 1] = 2 * (y * z + w * x)
    out[2, 2] = 1 - 2 * (x * x + y * y)


@njit
def axis_angle(x: float, y: float, z: float, angle: float, out: np.ndarray) -> None:
    """Write Rodrigues' rotation by ``angle`` about the unit axis ``(x, y, z)`` into ``out (3, 3)``."""
    s, c = np.sin(angle), np.cos(angle)
    t = 1.0 - c
    out[0, 0] = c + t * x * x
    out[0, 1] = t * x * y - s * z
    out[0, 2] = t * x * z + s * y
    out[1, 0] = t * x * y + s * z
    out[1, 1] = c + t * y * y
    out[1, 2] = t * y * z - s * x
    out[2, 0] = t * x * z - s * y
    out[2, 1] = t * y * z + s * x
    out[2, 2] = c + t * z * z


@njit
def matvec3(A: np.ndarray, v: np.ndarray, out: np.ndarray) -> None:
    """``out = A @ v`` for a 3x3 matrix and a 3-vector (``out`` must not alias ``v``)."""
    for i in range(3):
        out[i] = A[i, 0] * v[0] + A[i, 1] * v[1] + A[i, 2] * v[2]
