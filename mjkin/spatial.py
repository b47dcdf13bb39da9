"""Rotations and rigid transforms, vectorised over any leading batch shape.

Conventions: quaternions are ``(w, x, y, z)``; rotation matrices act on column
vectors (``v_world = R @ v_local``); poses are 4x4 homogeneous matrices; twists
are 6-vectors ``(v, w)``, linear part first, as in MuJoCo's Jacobians. Every
function takes arrays with a leading batch shape ``...`` and returns the same
leading shape.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .errors import InputError

Array = NDArray[np.float64]

_AXES = {"x": 0, "y": 1, "z": 2}


def _f(a: ArrayLike) -> Array:
    return np.asarray(a, dtype=np.float64)


def norm(v: Array) -> Array:
    """Euclidean norm over the last axis ``(...)``, scaled by the largest component first: no under- or overflow.

    Components near 1e-160 square to zero and near 1e160 to inf in :func:`numpy.linalg.norm`.
    """
    big = np.max(np.abs(v), axis=-1)
    safe = np.where(big > 0.0, big, 1.0)
    return big * np.linalg.norm(v / safe[..., None], axis=-1)


# ---------------------------------------------------------------- quaternions
def quat_normalize(q: ArrayLike) -> Array:
    """Unit quaternion ``(..., 4)``; a zero quaternion stays zero (callers validate)."""
    q = _f(q)
    n = np.linalg.norm(q, axis=-1, keepdims=True)
    return q / np.where(n > 0.0, n, 1.0)


def quat_conj(q: ArrayLike) -> Array:
    """Conjugate (the inverse of a unit quaternion), ``(..., 4)``."""
    return _f(q) * np.array([1.0, -1.0, -1.0, -1.0])


def quat_mul(a: ArrayLike, b: ArrayLike) -> Array:
    """Hamilton product ``a ⊗ b`` (rotate by ``b`` first, then ``a``), ``(..., 4)``."""
    a, b = _f(a), _f(b)
    aw, ax, ay, az = np.moveaxis(a, -1, 0)
    bw, bx, by, bz = np.moveaxis(b, -1, 0)
    return np.stack(
        [
            aw * bw - ax * bx - ay * by - az * bz,
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
        ],
        axis=-1,
    )


def quat_rotate(q: ArrayLike, v: ArrayLike) -> Array:
    """Rotate vectors ``v (..., 3)`` by unit quaternions ``q (..., 4)``."""
    q, v = _f(q), _f(v)
    w, u = q[..., :1], q[..., 1:]
    t = 2.0 * np.cross(u, v)
    return v + w * t + np.cross(u, t)


def quat_to_mat(q: ArrayLike) -> Array:
    """Rotation matrix ``(..., 3, 3)`` of unit quaternions ``(..., 4)``."""
    q = _f(q)
    w, x, y, z = np.moveaxis(q, -1, 0)
    xx, yy, zz = x * x, y * y, z * z
    xy, xz, yz, wx, wy, wz = x * y, x * z, y * z, w * x, w * y, w * z
    m = np.stack(
        [
            1 - 2 * (yy + zz), 2 * (xy - wz), 2 * (xz + wy),
            2 * (xy + wz), 1 - 2 * (xx + zz), 2 * (yz - wx),
            2 * (xz - wy), 2 * (yz + wx), 1 - 2 * (xx + yy),
        ],
        axis=-1,
    )
    return m.reshape(q.shape[:-1] + (3, 3))


def mat_to_quat(R: ArrayLike) -> Array:
    """Unit quaternion ``(..., 4)`` with ``w >= 0`` of rotation matrices ``(..., 3, 3)``.

    Shepperd's method: the largest of ``w, x, y, z`` is found from the diagonal
    and the others from the off-diagonal sums, so it is accurate near 180°.
    """
    R = _f(R)
    m00, m11, m22 = R[..., 0, 0], R[..., 1, 1], R[..., 2, 2]
    cand = np.stack(
        [
            np.stack([1 + m00 + m11 + m22, R[..., 2, 1] - R[..., 1, 2],
                      R[..., 0, 2] - R[..., 2, 0], R[..., 1, 0] - R[..., 0, 1]], -1),
            np.stack([R[..., 2, 1] - R[..., 1, 2], 1 + m00 - m11 - m22,
                      R[..., 0, 1] + R[..., 1, 0], R[..., 0, 2] + R[..., 2, 0]], -1),
            np.stack([R[..., 0, 2] - R[..., 2, 0], R[..., 0, 1] + R[..., 1, 0],
                      1 - m00 + m11 - m22, R[..., 1, 2] + R[..., 2, 1]], -1),
            np.stack([R[..., 1, 0] - R[..., 0, 1], R[..., 0, 2] + R[..., 2, 0],
                      R[..., 1, 2] + R[..., 2, 1], 1 - m00 - m11 + m22], -1),
        ],
        axis=-2,
    )
    diag = np.stack([m00 + m11 + m22, m00, m11, m22], -1)
    best = np.argmax(diag, axis=-1)[..., None, None]
    q = np.take_along_axis(cand, best, axis=-2)[..., 0, :]
    q = quat_normalize(q)
    return q * np.where(q[..., :1] < 0.0, -1.0, 1.0)


def quat_from_axis_angle(axis: ArrayLike, angle: ArrayLike) -> Array:
    """Quaternion of a rotation by ``angle (...)`` about the unit ``axis (..., 3)``."""
    half = 0.5 * _f(angle)[..., None]
    return np.concatenate([np.cos(half) + 0 * _f(axis)[..., :1], np.sin(half) * _f(axis)], -1)


def quat_to_axis_angle(q: ArrayLike) -> tuple[Array, Array]:
    """Unit axis ``(..., 3)`` and angle in ``[0, π]`` ``(...)``; axis ``x`` for no rotation."""
    r = quat_to_rotvec(q)
    angle = norm(r)
    safe = np.where(angle > 0.0, angle, 1.0)[..., None]
    axis = np.where(angle[..., None] > 0.0, r / safe, np.array([1.0, 0.0, 0.0]))
    return axis, angle


def rotvec_to_quat(r: ArrayLike) -> Array:
    """Exponential map: rotation vector ``(..., 3)`` (axis × angle) → unit quaternion."""
    r = _f(r)
    theta = np.linalg.norm(r, axis=-1, keepdims=True)
    # sin(θ/2)/θ written with np.sinc so that θ = 0 needs no special case
    return np.concatenate([np.cos(0.5 * theta), 0.5 * np.sinc(theta / (2 * np.pi)) * r], -1)


def quat_to_rotvec(q: ArrayLike) -> Array:
    """Logarithm map: unit quaternion → rotation vector with angle in ``[0, π]``."""
    q = _f(q)
    q = q * np.where(q[..., :1] < 0.0, -1.0, 1.0)
    w, v = q[..., 0], q[..., 1:]
    n = norm(v)
    # atan2(n, w) / n is exact to rounding for any n > 0, however small; n = 0 means v = 0 and no rotation
    scale = np.where(n > 0.0, 2.0 * np.arctan2(n, w) / np.where(n > 0.0, n, 1.0), 2.0)
    return scale[..., None] * v


def quat_distance(a: ArrayLike, b: ArrayLike) -> Array:
    """Rotation angle in ``[0, π]`` between unit quaternions (``q`` and ``-q`` are equal)."""
    rel = quat_mul(quat_conj(a), b)
    return 2.0 * np.arctan2(np.linalg.norm(rel[..., 1:], axis=-1), np.abs(rel[..., 0]))


def slerp(q0: ArrayLike, q1: ArrayLike, t: ArrayLike) -> Array:
    """Spherical linear interpolation along the shorter arc; ``t (...)`` in ``[0, 1]``."""
    q0, q1, t = _f(q0), _f(q1), _f(t)[..., None]
    q1 = q1 * np.where(np.sum(q0 * q1, -1, keepdims=True) < 0.0, -1.0, 1.0)
    rel = quat_to_rotvec(quat_mul(quat_conj(q0), q1))
    return quat_normalize(quat_mul(q0, rotvec_to_quat(t * rel)))


# ------------------------------------------------------------ rotation matrices
def skew(v: ArrayLike) -> Array:
    """Cross-product matrix ``[v]x`` ``(..., 3, 3)`` so that ``skew(a) @ b = a × b``."""
    v = _f(v)
    x, y, z = np.moveaxis(v, -1, 0)
    o = np.zeros_like(x)
    return np.stack([o, -z, y, z, o, -x, -y, x, o], -1).reshape(v.shape[:-1] + (3, 3))


def axis_angle_to_mat(axis: ArrayLike, angle: ArrayLike) -> Array:
    """Rodrigues' formula: rotation by ``angle (...)`` about the unit ``axis (..., 3)``."""
    K = skew(axis)
    a = _f(angle)[..., None, None]
    return np.eye(3) + np.sin(a) * K + (1.0 - np.cos(a)) * (K @ K)


def rotvec_to_mat(r: ArrayLike) -> Array:
    """Exponential map on SO(3): rotation vector ``(..., 3)`` → matrix ``(..., 3, 3)``."""
    return quat_to_mat(rotvec_to_quat(r))


def mat_to_rotvec(R: ArrayLike) -> Array:
    """Logarithm map on SO(3), accurate up to and at 180° (goes through the quaternion)."""
    return quat_to_rotvec(mat_to_quat(R))


def orthonormalize(R: ArrayLike) -> Array:
    """Nearest rotation matrix (polar factor by SVD) to a drifted ``(..., 3, 3)`` matrix."""
    U, _, Vt = np.linalg.svd(_f(R))
    d = np.sign(np.linalg.det(U @ Vt))
    U = U.copy()
    U[..., :, 2] *= d[..., None]
    return U @ Vt


def _parse_seq(seq: str) -> tuple[tuple[int, int, int], bool]:
    """Axis indices of an Euler sequence in extrinsic order, and whether it was intrinsic."""
    if (not isinstance(seq, str) or len(seq) != 3 or not (seq.islower() or seq.isupper())
            or any(c not in _AXES for c in seq.lower())):
        raise InputError(f"Euler sequence {seq!r}: expected three of x/y/z, lower case = extrinsic, upper = intrinsic")
    i, j, k = (_AXES[c] for c in seq.lower())
    if i == j or j == k:
        raise InputError(f"Euler sequence {seq!r}: consecutive axes must differ, e.g. 'xyz' or 'zxz'")
    intrinsic = seq.isupper()
    return ((k, j, i) if intrinsic else (i, j, k)), intrinsic


def euler_to_quat(angles: ArrayLike, seq: str = "xyz") -> Array:
    """Unit quaternion ``(..., 4)`` of Euler angles ``(..., 3)`` in radians.

    ``seq`` follows SciPy: upper case (``"XYZ"``) is intrinsic, rotating about
    the moving axes (``R = Rx(a) Ry(b) Rz(c)``); lower case (``"xyz"``) is
    extrinsic, about the fixed axes (``R = Rz(c) Ry(b) Rx(a)``).
    """
    (i, j, k), intrinsic = _parse_seq(seq)
    a = _f(angles)
    if intrinsic:  # intrinsic "XYZ" is extrinsic "zyx" with the angles reversed
        a = a[..., ::-1]
    eye = np.eye(3)
    q = [quat_from_axis_angle(eye[ax], a[..., n]) for n, ax in enumerate((i, j, k))]
    return quat_mul(q[2], quat_mul(q[1], q[0]))


def euler_to_mat(angles: ArrayLike, seq: str = "xyz") -> Array:
    """Rotation matrix ``(..., 3, 3)`` of Euler angles ``(..., 3)``; ``seq`` as in :func:`euler_to_quat`."""
    return quat_to_mat(euler_to_quat(angles, seq))


_LOCK = 1e-14  # half-angle pair norm (relative) below which gimbal lock is declared: costs < 1e-13 rad


def quat_to_euler(q: ArrayLike, seq: str = "xyz") -> Array:
    """Euler angles ``(..., 3)`` of unit quaternions ``(..., 4)``, inverse of :func:`euler_to_quat`.

    Angles follow SciPy's ranges: the middle one in ``[-π/2, π/2]`` (Tait–Bryan,
    e.g. ``"xyz"``) or ``[0, π]`` (proper Euler, e.g. ``"zxz"``), the others in
    ``[-π, π]``. At gimbal lock only the sum or difference of the outer angles
    is defined and, as in SciPy, the third angle is set to zero.

    The angles are read directly from the quaternion (the half-angle sums and
    differences are each ``atan2`` of a pair of components; Bernardes & Viollet,
    PLoS ONE 2022), so the result reproduces the rotation to rounding error
    right up to gimbal lock, where angles taken from matrix entries lose
    accuracy.
    """
    (i, j, k), intrinsic = _parse_seq(seq)
    q = _f(q)
    w = q[..., 0]
    v = [q[..., 1 + n] for n in range(3)]
    proper = i == k
    m = 3 - i - j if proper else k  # the axis that is neither i nor j
    s = 1.0 if (i, j, m) in ((0, 1, 2), (1, 2, 0), (2, 0, 1)) else -1.0
    if proper:  # q = (cB cos(G+A), cB sin(G+A) e_i + sB cos(G-A) e_j + s sB sin(G-A) e_m), halves A, B, G
        a, b, c, d = w, v[i], v[j], s * v[m]
    else:  # the same form after a quarter turn about e_j: B -> B + π/4
        a, b, c, d = w - v[j], v[i] + s * v[k], v[j] + w, s * v[k] - v[i]
    n_ab, n_cd = np.hypot(a, b), np.hypot(c, d)
    mid = 2.0 * np.arctan2(n_cd, n_ab)
    hs, hd = np.arctan2(b, a), np.arctan2(d, c)  # (G + A) and (G - A), up to the sign s for Tait-Bryan
    # At gimbal lock one of hs, hd is undefined: choose it so that the third angle the caller sees is zero
    # (extrinsic: the last angle G, i.e. hd = -hs; intrinsic: the extrinsic first angle A, i.e. hd = hs).
    flip = 1.0 if intrinsic else -1.0
    hd = np.where(n_cd < _LOCK * n_ab, flip * hs, hd)
    hs = np.where(n_ab < _LOCK * n_cd, flip * hd, hs)
    first = hs - hd
    third = (hs + hd) * (1.0 if proper else s)
    if not proper:
        mid = mid - 0.5 * np.pi
    out = np.stack([_wrap(first), mid, _wrap(third)], -1)
    return out[..., ::-1] if intrinsic else out


def mat_to_euler(R: ArrayLike, seq: str = "xyz") -> Array:
    """Euler angles ``(..., 3)`` of rotation matrices ``(..., 3, 3)``, inverse of :func:`euler_to_mat`.

    Goes through :func:`mat_to_quat`; ranges and gimbal lock as in :func:`quat_to_euler`.
    """
    return quat_to_euler(mat_to_quat(R), seq)


def _wrap(x: Array) -> Array:
    """Angles in ``[-2π, 2π]`` brought into ``[-π, π]``."""
    return np.where(x > np.pi, x - 2.0 * np.pi, np.where(x < -np.pi, x + 2.0 * np.pi, x))


# ------------------------------------------------------------- rigid transforms
def make_transform(R: ArrayLike, p: ArrayLike) -> Array:
    """4x4 pose ``(..., 4, 4)`` from a rotation ``(..., 3, 3)`` and a position ``(..., 3)``."""
    R, p = _f(R), _f(p)
    shape = np.broadcast_shapes(R.shape[:-2], p.shape[:-1])
    T = np.zeros(shape + (4, 4))
    T[..., :3, :3] = R
    T[..., :3, 3] = p
    T[..., 3, 3] = 1.0
    return T


def transform_inverse(T: ArrayLike) -> Array:
    """Inverse of rigid 4x4 poses, using ``R^T`` rather than a general inverse."""
    T = _f(T)
    Rt = np.swapaxes(T[..., :3, :3], -1, -2)
    return make_transform(Rt, -(Rt @ T[..., :3, 3:])[..., 0])


def transform_apply(T: ArrayLike, v: ArrayLike) -> Array:
    """Map points ``(..., 3)`` through poses ``(..., 4, 4)``."""
    T, v = _f(T), _f(v)
    return (T[..., :3, :3] @ v[..., None])[..., 0] + T[..., :3, 3]


def _V_coeffs(theta: Array) -> tuple[Array, Array]:
    """``(1 - cos θ)/θ²`` and ``(θ - sin θ)/θ³`` with Taylor series near zero."""
    small = theta < 1e-4
    t = np.where(small, 1.0, theta)
    t2 = theta * theta
    b = np.where(small, 0.5 - t2 / 24.0, (1.0 - np.cos(t)) / (t * t))
    c = np.where(small, 1.0 / 6.0 - t2 / 120.0, (t - np.sin(t)) / (t * t * t))
    return b, c


def se3_exp(xi: ArrayLike) -> Array:
    """Pose ``(..., 4, 4)`` reached by following the twist ``xi = (v, w) (..., 6)`` for unit time."""
    xi = _f(xi)
    v, w = xi[..., :3], xi[..., 3:]
    theta = np.linalg.norm(w, axis=-1)
    K = skew(w)
    b, c = _V_coeffs(theta)
    V = np.eye(3) + b[..., None, None] * K + c[..., None, None] * (K @ K)
    return make_transform(rotvec_to_mat(w), (V @ v[..., None])[..., 0])


def se3_log(T: ArrayLike) -> Array:
    """Twist ``(v, w) (..., 6)`` with ``se3_exp(se3_log(T)) == T`` (rotation angle ≤ π)."""
    T = _f(T)
    w = mat_to_rotvec(T[..., :3, :3])
    theta = np.linalg.norm(w, axis=-1)
    K = skew(w)
    b, c = _V_coeffs(theta)
    V = np.eye(3) + b[..., None, None] * K + c[..., None, None] * (K @ K)
    v = np.linalg.solve(V, T[..., :3, 3:])[..., 0]
    return np.concatenate([v, w], -1)
