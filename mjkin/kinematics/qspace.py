"""Configuration space of a tree: validating, sampling, clipping, integrating q.

``q`` is MuJoCo's ``qpos`` (length ``nq``): hinge and slide values, ball joints
as unit quaternions, free joints as position + quaternion. Velocities have
MuJoCo's ``nv`` layout, with ball and free angular velocities in the body's
local frame (as ``mj_integratePos``). All functions take a leading batch shape.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Protocol

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .. import spatial
from ..errors import InputError
from ..runtime.jit import njit, njit_inline

Array = NDArray[np.float64]
Index = NDArray[np.int64]

# MuJoCo's joint type codes (mjtJoint) and their sizes in q and in velocity
FREE, BALL, SLIDE, HINGE = 0, 1, 2, 3
JOINT_NAMES = {FREE: "free", BALL: "ball", SLIDE: "slide", HINGE: "hinge"}
NQ = {FREE: 7, BALL: 4, SLIDE: 1, HINGE: 1}
NV = {FREE: 6, BALL: 3, SLIDE: 1, HINGE: 1}

UNLIMITED_SLIDE = 1.0  # random_q samples unlimited slides within ±1 m of qpos0
UNLIMITED_FREE = 1.0  # and free-joint positions within ±1 m of qpos0 per axis


class Joints(Protocol):
    """What the configuration-space functions read of a tree (a :class:`mjkin.Tree` is one)."""

    @property
    def nq(self) -> int: ...  # noqa: D102
    @property
    def nv(self) -> int: ...  # noqa: D102
    @property
    def qpos0(self) -> Array: ...  # noqa: D102
    @property
    def jnt_type(self) -> Index: ...  # noqa: D102
    @property
    def jnt_qadr(self) -> Index: ...  # noqa: D102
    @property
    def jnt_dofadr(self) -> Index: ...  # noqa: D102
    @property
    def jnt_limited(self) -> NDArray[np.bool_]: ...  # noqa: D102
    @property
    def jnt_range(self) -> Array: ...  # noqa: D102
    @property
    def layout(self) -> Layout: ...  # noqa: D102


@dataclass(frozen=True)
class Layout:
    """Index arrays grouping the joints by kind, for vectorised q arithmetic."""

    scalar_q: Index  # (ns,) qpos index of each hinge/slide joint
    scalar_hinge: NDArray[np.bool_]
    scalar_lo: Array  # (ns,) lower limit, -inf when unlimited
    scalar_hi: Array
    ball_q: Index  # (nb, 4)
    ball_v: Index  # (nb, 3) the ball joints' velocity (dof) indices
    ball_max: Array  # (nb,) largest rotation angle, inf when unlimited
    free_q: Index  # (nf, 7)
    quats: Index  # (nb + nf, 4) every quaternion in q
    jnt_lo: Array  # (njnt,) per joint: hinge/slide lower limit, -inf when unlimited
    jnt_hi: Array  # (njnt,) upper limit, or a ball joint's largest angle; inf when unlimited
    unlimited_hinge_q: Index  # (nu,) qpos index of each hinge without limits (its angle is periodic)
    unlimited_hinge_v: Index  # (nu,) and its velocity (dof) index

    @classmethod
    def of(cls, tree: Joints) -> Layout:
        """Group the joints of ``tree``."""
        t = tree.jnt_type
        s = np.flatnonzero((t == HINGE) | (t == SLIDE))
        b = np.flatnonzero(t == BALL)
        f = np.flatnonzero(t == FREE)
        unlimited = np.flatnonzero((t == HINGE) & ~tree.jnt_limited)
        lo = np.where(tree.jnt_limited, tree.jnt_range[:, 0], -np.inf)
        hi = np.where(tree.jnt_limited, tree.jnt_range[:, 1], np.inf)
        ball_q = tree.jnt_qadr[b, None] + np.arange(4)
        ball_v = tree.jnt_dofadr[b, None] + np.arange(3)
        free_q = tree.jnt_qadr[f, None] + np.arange(7)
        return cls(scalar_q=tree.jnt_qadr[s], scalar_hinge=t[s] == HINGE, scalar_lo=lo[s], scalar_hi=hi[s],
                   ball_q=ball_q, ball_v=ball_v, ball_max=hi[b], free_q=free_q,
                   quats=np.concatenate([ball_q, free_q[:, 3:]]),
                   jnt_lo=lo, jnt_hi=hi, unlimited_hinge_q=tree.jnt_qadr[unlimited],
                   unlimited_hinge_v=tree.jnt_dofadr[unlimited])


def check(tree: Joints, q: ArrayLike, name: str = "q") -> Array:
    """``q`` as a float64 array ``(..., nq)``; :class:`InputError` for a bad shape or value."""
    try:
        a = q if type(q) is np.ndarray and q.dtype == np.float64 else np.asarray(q, dtype=np.float64)
    except (TypeError, ValueError):
        raise InputError(f"{name} must be an array of numbers of shape (..., {tree.nq})") from None
    if a.ndim == 0 or a.shape[-1] != tree.nq:
        raise InputError(f"{name} has shape {a.shape}; this model needs (..., {tree.nq}) (nq = {tree.nq})")
    if not all_finite(a.reshape(-1)):
        raise InputError(f"{name} contains NaN or inf")
    quats = tree.layout.quats
    if quats.size and _zero_quaternion(np.ascontiguousarray(a).reshape(-1, a.shape[-1]), quats):
        raise InputError(f"{name} has a zero quaternion for a ball or free joint; use (1, 0, 0, 0) for no rotation")
    return a


@njit
def all_finite(a: Array) -> bool:
    """No NaN or inf in ``a (n,)`` (one compiled pass, no temporary)."""
    for x in a:
        if not np.isfinite(x):
            return False
    return True


@njit
def _zero_quaternion(q: Array, quats: Index) -> bool:
    """Whether any quaternion ``q[b, quats[i]]`` of ``q (B, nq)`` is (nearly) zero."""
    for b in range(q.shape[0]):
        for i in range(quats.shape[0]):
            n = 0.0
            for k in range(4):
                n += q[b, quats[i, k]] ** 2
            if n < 1e-18:
                return True
    return False


def _rng(rng: np.random.Generator | int | None) -> np.random.Generator:
    if isinstance(rng, np.random.Generator):
        return rng
    try:
        return np.random.default_rng(rng)
    except (TypeError, ValueError):
        raise InputError("rng must be a numpy Generator, "
                         f"a seed (a whole number >= 0) or None, got {rng!r:.40}") from None


def random_quat(rng: np.random.Generator, shape: tuple[int, ...]) -> Array:
    """Uniformly distributed unit quaternions ``shape + (4,)`` with ``w >= 0``."""
    q = spatial.quat_normalize(rng.normal(size=shape + (4,)))
    return q * np.where(q[..., :1] < 0, -1.0, 1.0)


def random(tree: Joints, rng: np.random.Generator | int | None = None, n: int | tuple[int, ...] | None = None,
           spread: bool = False) -> Array:
    """Configurations inside the joint limits: ``(n, nq)`` (``n + (nq,)`` for a shape), or ``(nq,)`` when ``n`` is None.

    Limited hinges and slides are uniform in their range; unlimited hinges
    uniform in ``qpos0 ± π``; unlimited slides and free positions within
    ``±1 m`` of ``qpos0``; ball and free rotations uniform (within the cone of a
    limited ball joint). ``spread`` draws the hinges and slides from a scrambled
    Sobol sequence instead: as uniform, but with no clusters or gaps, so a few
    IK restarts cover the joint space better.
    """
    g, lay = _rng(rng), tree.layout
    batch = () if n is None else _batch_shape(n)
    shape = (int(np.prod(batch)),)
    q = np.broadcast_to(tree.qpos0, shape + (tree.nq,)).copy()
    lo, hi = lay.scalar_lo, lay.scalar_hi
    half = np.where(lay.scalar_hinge, np.pi, UNLIMITED_SLIDE)
    base = tree.qpos0[lay.scalar_q]
    lo = np.where(np.isfinite(lo), lo, base - half)
    hi = np.where(np.isfinite(hi), hi, base + half)
    if spread and len(lo) and shape[0]:
        from scipy.stats import qmc

        u = qmc.Sobol(d=len(lo), scramble=True, seed=g).random_base2(int(np.ceil(np.log2(shape[0]))))
        q[:, lay.scalar_q] = lo + u[:shape[0]] * (hi - lo)
    else:
        q[:, lay.scalar_q] = g.uniform(lo, hi, shape + lo.shape)
    nb = len(lay.ball_q)
    if nb:
        quat = random_quat(g, shape + (nb,))
        axis, _ = spatial.quat_to_axis_angle(quat)
        angle = g.uniform(0.0, np.minimum(lay.ball_max, np.pi), shape + (nb,))
        q[:, lay.ball_q] = np.where(np.isfinite(lay.ball_max)[:, None], spatial.quat_from_axis_angle(axis, angle), quat)
    nf = len(lay.free_q)
    if nf:
        q[:, lay.free_q[:, :3]] += g.uniform(-UNLIMITED_FREE, UNLIMITED_FREE, shape + (nf, 3))
        q[:, lay.free_q[:, 3:]] = random_quat(g, shape + (nf,))
    return q[0] if n is None else q.reshape(batch + (tree.nq,))


def _batch_shape(n: object) -> tuple[int, ...]:
    """``n`` (a count or a shape) as a shape tuple; :class:`InputError` unless whole numbers >= 0."""
    dims = n if isinstance(n, tuple) else (n,)
    if not all(isinstance(d, (int, np.integer)) and not isinstance(d, bool) and d >= 0 for d in dims):
        raise InputError(f"n must be a count >= 0 or a shape tuple of them, got {n!r}")
    if math.prod(int(d) for d in dims) >= 2**40:  # 8 TB of configurations: NumPy could not even index them
        raise InputError(f"n = {n!r} asks for more configurations than any memory holds")
    return tuple(int(d) for d in dims)


@njit
def quat_angle_clip(q: Array, a: int, max_angle: float) -> None:
    """Normalise the quaternion at ``q[a:a+4]`` and pull it back onto a cone of ``max_angle``.

    Huge components (1e308), whose squares overflow, are scaled by the largest first.
    """
    w, x, y, z = q[a], q[a + 1], q[a + 2], q[a + 3]
    n2 = w * w + x * x + y * y + z * z
    if not n2 < 1e300:
        m = max(abs(w), abs(x), abs(y), abs(z))
        w, x, y, z = w / m, x / m, y / m, z / m
        n2 = w * w + x * x + y * y + z * z
    n = np.sqrt(n2)
    w, x, y, z = w / n, x / n, y / n, z / n
    if w < 0.0:
        w, x, y, z = -w, -x, -y, -z
    s = np.sqrt(x * x + y * y + z * z)
    if 2.0 * np.arctan2(s, w) > max_angle:
        h = 0.5 * max_angle
        w, x, y, z = np.cos(h), np.sin(h) * x / s, np.sin(h) * y / s, np.sin(h) * z / s
    q[a], q[a + 1], q[a + 2], q[a + 3] = w, x, y, z


@njit_inline
def clip_kernel(q: Array, jnt_type: Index, jnt_qadr: Index, lo: Array, hi: Array) -> None:
    """Project ``q (B, nq)`` into the joint limits, in place.

    Hinges and slides are clamped to ``[lo, hi]`` (per joint), ball joints pulled
    into their cone (``hi`` is the max angle), every quaternion normalised.
    """
    for b in range(q.shape[0]):
        for j in range(jnt_type.shape[0]):
            a = jnt_qadr[j]
            if jnt_type[j] == HINGE or jnt_type[j] == SLIDE:
                q[b, a] = min(max(q[b, a], lo[j]), hi[j])
            elif jnt_type[j] == BALL:
                quat_angle_clip(q[b], a, hi[j])
            else:
                quat_angle_clip(q[b], a + 3, np.inf)


@njit
def quat_turn(q: Array, a: int, wx: float, wy: float, wz: float) -> None:
    """``q[a:a+4] <- q ⊗ exp(w)``, normalised (local-frame angular velocity, as mj_integratePos)."""
    th = np.sqrt(wx * wx + wy * wy + wz * wz)
    c = np.cos(0.5 * th)
    s = 0.5 if th < 1e-12 else np.sin(0.5 * th) / th
    bw, bx, by, bz = c, s * wx, s * wy, s * wz
    aw, ax, ay, az = q[a], q[a + 1], q[a + 2], q[a + 3]
    w = aw * bw - ax * bx - ay * by - az * bz
    x = aw * bx + ax * bw + ay * bz - az * by
    y = aw * by - ax * bz + ay * bw + az * bx
    z = aw * bz + ax * by - ay * bx + az * bw
    n = np.sqrt(w * w + x * x + y * y + z * z)
    q[a], q[a + 1], q[a + 2], q[a + 3] = w / n, x / n, y / n, z / n


@njit_inline
def integrate_kernel(q: Array, v: Array, jnt_type: Index, jnt_qadr: Index, jnt_dofadr: Index) -> None:
    """In place ``q <- q ⊕ v`` for ``q (B, nq)``, ``v (B, nv)``."""
    for b in range(q.shape[0]):
        for j in range(jnt_type.shape[0]):
            a, d = jnt_qadr[j], jnt_dofadr[j]
            if jnt_type[j] == HINGE or jnt_type[j] == SLIDE:
                q[b, a] += v[b, d]
            elif jnt_type[j] == BALL:
                quat_turn(q[b], a, v[b, d], v[b, d + 1], v[b, d + 2])
            else:
                for i in range(3):
                    q[b, a + i] += v[b, d + i]
                quat_turn(q[b], a + 3, v[b, d + 3], v[b, d + 4], v[b, d + 5])


@njit
def _log_rel(p: Array, a: int, r: Array, c: int, out: Array, d: int) -> None:
    """``out[d:d+3] = log(p[a:a+4]^-1 ⊗ r[c:c+4])`` for unit quaternions, angle in [0, π]."""
    pw, px, py, pz = p[a], -p[a + 1], -p[a + 2], -p[a + 3]
    rw, rx, ry, rz = r[c], r[c + 1], r[c + 2], r[c + 3]
    w = pw * rw - px * rx - py * ry - pz * rz
    x = pw * rx + px * rw + py * rz - pz * ry
    y = pw * ry - px * rz + py * rw + pz * rx
    z = pw * rz + px * ry - py * rx + pz * rw
    if w < 0.0:
        w, x, y, z = -w, -x, -y, -z
    s = np.sqrt(x * x + y * y + z * z)
    k = 2.0 / w if s < 1e-12 else 2.0 * np.arctan2(s, w) / s
    out[d], out[d + 1], out[d + 2] = k * x, k * y, k * z


@njit_inline
def difference_kernel(q1: Array, q0: Array, jnt_type: Index, jnt_qadr: Index, jnt_dofadr: Index, v: Array) -> None:
    """``v = q1 ⊖ q0`` (the velocity taking ``q0`` to ``q1`` in unit time), rows of ``(B, ·)``."""
    for b in range(v.shape[0]):
        for j in range(jnt_type.shape[0]):
            a, d = jnt_qadr[j], jnt_dofadr[j]
            if jnt_type[j] == HINGE or jnt_type[j] == SLIDE:
                v[b, d] = q1[b, a] - q0[b, a]
            elif jnt_type[j] == BALL:
                _log_rel(q0[b], a, q1[b], a, v[b], d)
            else:
                for i in range(3):
                    v[b, d + i] = q1[b, a + i] - q0[b, a + i]
                _log_rel(q0[b], a + 3, q1[b], a + 3, v[b], d + 3)


def _rows(a: Array, n: int, shape: tuple[int, ...]) -> Array:
    """``a`` broadcast to ``shape + (n,)`` as C-contiguous rows ``(prod(shape), n)``, read-only.

    A view, or a copy where the broadcast repeats rows: read-only too, so the kernels reading it compile one version.
    """
    rows = int(np.prod(shape, dtype=np.int64))  # not -1: a model without joints has n = 0
    out = np.ascontiguousarray(np.broadcast_to(a, shape + (n,)).reshape(rows, n), dtype=np.float64)
    out.setflags(write=False)
    return out


def wrap(tree: Joints, q: Array, index: Index | None = None) -> None:
    """Turn unlimited hinges of ``q (..., nq)`` into ``(-π, π]`` about ``qpos0``, in place (the same pose).

    MuJoCo turns a hinge by ``q - qpos0``, so that difference is what is wrapped; ``index``
    (default: every unlimited hinge, :attr:`Layout.unlimited_hinge_q`) says which entries.
    Values already inside are left bit for bit; huge ones (1e308) keep the angle FK sees.
    """
    a = tree.layout.unlimited_hinge_q if index is None else index
    if not len(a):
        return
    d = q[..., a] - tree.qpos0[a]
    outside = (d > np.pi) | (d <= -np.pi)
    if outside.any():
        # the angle FK turns by, as sin/cos reduce it (by the true π: d mod the float 2π is off for huge d)
        w = np.arctan2(np.sin(d), np.cos(d))
        q[..., a] = np.where(outside, tree.qpos0[a] + np.where(w == -np.pi, np.pi, w), q[..., a])


def clip(tree: Joints, q: Array) -> Array:
    """Project into the joint limits; ball joints past their cone are pulled back onto it."""
    out = _rows(q, tree.nq, q.shape[:-1]).copy()
    clip_kernel(out, tree.jnt_type, tree.jnt_qadr, tree.layout.jnt_lo, tree.layout.jnt_hi)
    return out.reshape(q.shape)


def integrate(tree: Joints, q: Array, v: Array) -> Array:
    """``q ⊕ v``: add hinge/slide velocities, rotate quaternions by ``exp(w)`` in the local frame."""
    if v.ndim == 0 or v.shape[-1] != tree.nv:
        raise InputError(f"velocity has shape {v.shape}; this model needs (..., {tree.nv})")
    shape = np.broadcast_shapes(q.shape[:-1], v.shape[:-1])
    out = _rows(q, tree.nq, shape).copy()
    integrate_kernel(out, _rows(v, tree.nv, shape), tree.jnt_type, tree.jnt_qadr, tree.jnt_dofadr)
    return out.reshape(shape + (tree.nq,))


def difference(tree: Joints, q1: Array, q0: Array, periodic: bool = False) -> Array:
    """``q1 ⊖ q0``: the velocity ``(..., nv)`` with ``integrate(q0, v) == q1``.

    ``periodic``: unlimited hinges take the short way round, in ``(-π, π]`` (their values are angles
    that :func:`wrap` and :func:`mjkin.solve` bring into one turn); otherwise plain differences, as
    MuJoCo's ``mj_differentiatePos``.
    """
    shape = np.broadcast_shapes(q1.shape[:-1], q0.shape[:-1])
    v = np.empty((int(np.prod(shape, dtype=np.int64)), tree.nv))
    a1, a0 = _rows(q1, tree.nq, shape), _rows(q0, tree.nq, shape)
    difference_kernel(a1, a0, tree.jnt_type, tree.jnt_qadr, tree.jnt_dofadr, v)
    d = tree.layout.unlimited_hinge_v
    if periodic and len(d):
        w = np.arctan2(np.sin(v[:, d]), np.cos(v[:, d]))
        v[:, d] = np.where(w == -np.pi, np.pi, w)
    return v.reshape(shape + (tree.nv,))
