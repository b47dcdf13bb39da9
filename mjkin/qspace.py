"""Configuration space of a tree: validating, sampling, clipping, integrating q.

``q`` is MuJoCo's ``qpos`` (length ``nq``): hinge and slide values, ball joints
as unit quaternions, free joints as position + quaternion. Velocities have
MuJoCo's ``nv`` layout, with ball and free angular velocities in the body's
local frame (as ``mj_integratePos``). All functions take a leading batch shape.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import ArrayLike, NDArray

from . import spatial
from .errors import InputError

if TYPE_CHECKING:
    from .tree import Tree

Array = NDArray[np.float64]
Index = NDArray[np.int64]

# MuJoCo's joint type codes (mjtJoint) and their sizes in q and in velocity
FREE, BALL, SLIDE, HINGE = 0, 1, 2, 3
JOINT_NAMES = {FREE: "free", BALL: "ball", SLIDE: "slide", HINGE: "hinge"}
NQ = {FREE: 7, BALL: 4, SLIDE: 1, HINGE: 1}
NV = {FREE: 6, BALL: 3, SLIDE: 1, HINGE: 1}

UNLIMITED_SLIDE = 1.0  # random_q samples unlimited slides within ±1 m of qpos0
UNLIMITED_FREE = 1.0  # and free-joint positions within ±1 m of qpos0 per axis


@dataclass(frozen=True)
class Layout:
    """Index arrays grouping the joints by kind, for vectorised q arithmetic."""

    scalar_q: Index  # (ns,) qpos index of each hinge/slide joint
    scalar_v: Index  # (ns,) its dof index
    scalar_hinge: NDArray[np.bool_]
    scalar_lo: Array  # (ns,) lower limit, -inf when unlimited
    scalar_hi: Array
    ball_q: Index  # (nb, 4)
    ball_v: Index  # (nb, 3)
    ball_max: Array  # (nb,) largest rotation angle, inf when unlimited
    free_q: Index  # (nf, 7)
    free_v: Index  # (nf, 6)
    quats: Index  # (nb + nf, 4) every quaternion in q

    @classmethod
    def of(cls, tree: Tree) -> Layout:
        """Group the joints of ``tree``."""
        t = tree.jnt_type
        s = np.flatnonzero((t == HINGE) | (t == SLIDE))
        b = np.flatnonzero(t == BALL)
        f = np.flatnonzero(t == FREE)
        lim = tree.jnt_limited
        return cls(
            scalar_q=tree.jnt_qadr[s], scalar_v=tree.jnt_dofadr[s], scalar_hinge=t[s] == HINGE,
            scalar_lo=np.where(lim[s], tree.jnt_range[s, 0], -np.inf),
            scalar_hi=np.where(lim[s], tree.jnt_range[s, 1], np.inf),
            ball_q=tree.jnt_qadr[b, None] + np.arange(4), ball_v=tree.jnt_dofadr[b, None] + np.arange(3),
            ball_max=np.where(lim[b], tree.jnt_range[b, 1], np.inf),
            free_q=tree.jnt_qadr[f, None] + np.arange(7), free_v=tree.jnt_dofadr[f, None] + np.arange(6),
            quats=np.concatenate([tree.jnt_qadr[b, None] + np.arange(4), tree.jnt_qadr[f, None] + np.arange(3, 7)]),
        )


def check(tree: Tree, q: ArrayLike, name: str = "q") -> Array:
    """``q`` as a float64 array ``(..., nq)``; :class:`InputError` for a bad shape or value."""
    try:
        a = np.asarray(q, dtype=np.float64)
    except (TypeError, ValueError):
        raise InputError(f"{name} must be an array of numbers of shape (..., {tree.nq})") from None
    if a.ndim == 0 or a.shape[-1] != tree.nq:
        raise InputError(f"{name} has shape {a.shape}; this model needs (..., {tree.nq}) (nq = {tree.nq})")
    if not np.isfinite(a).all():
        raise InputError(f"{name} contains NaN or inf")
    quats = tree.layout.quats
    if quats.size and (np.square(a[..., quats]).sum(-1) < 1e-18).any():
        raise InputError(f"{name} has a zero quaternion for a ball or free joint; use (1, 0, 0, 0) for no rotation")
    return a


def _rng(rng: np.random.Generator | int | None) -> np.random.Generator:
    return rng if isinstance(rng, np.random.Generator) else np.random.default_rng(rng)


def random_quat(rng: np.random.Generator, shape: tuple[int, ...]) -> Array:
    """Uniformly distributed unit quaternions ``shape + (4,)`` with ``w >= 0``."""
    q = spatial.quat_normalize(rng.normal(size=shape + (4,)))
    return q * np.where(q[..., :1] < 0, -1.0, 1.0)


def random(tree: Tree, rng: np.random.Generator | int | None = None, n: int | None = None) -> Array:
    """Configurations inside the joint limits: ``(n, nq)``, or ``(nq,)`` when ``n`` is None.

    Limited hinges and slides are uniform in their range; unlimited hinges
    uniform in ``qpos0 ± π``; unlimited slides and free positions within
    ``±1 m`` of ``qpos0``; ball and free rotations uniform (within the cone of a
    limited ball joint).
    """
    g, lay = _rng(rng), tree.layout
    shape = (1 if n is None else int(n),)
    q = np.broadcast_to(tree.qpos0, shape + (tree.nq,)).copy()
    lo, hi = lay.scalar_lo, lay.scalar_hi
    half = np.where(lay.scalar_hinge, np.pi, UNLIMITED_SLIDE)
    base = tree.qpos0[lay.scalar_q]
    lo = np.where(np.isfinite(lo), lo, base - half)
    hi = np.where(np.isfinite(hi), hi, base + half)
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
    return q[0] if n is None else q


def clip(tree: Tree, q: Array) -> Array:
    """Project into the joint limits; ball joints past their cone are pulled back onto it."""
    lay = tree.layout
    q = q.copy()
    q[..., lay.scalar_q] = np.clip(q[..., lay.scalar_q], lay.scalar_lo, lay.scalar_hi)
    if len(lay.ball_q):
        r = spatial.quat_to_rotvec(spatial.quat_normalize(q[..., lay.ball_q]))
        angle = np.linalg.norm(r, axis=-1, keepdims=True)
        over = angle > lay.ball_max[:, None]
        r = np.where(over, r * lay.ball_max[:, None] / np.where(over, angle, 1.0), r)
        q[..., lay.ball_q] = spatial.rotvec_to_quat(r)
    if len(lay.free_q):
        q[..., lay.free_q[:, 3:]] = spatial.quat_normalize(q[..., lay.free_q[:, 3:]])
    return q


def integrate(tree: Tree, q: Array, v: Array) -> Array:
    """``q ⊕ v``: add hinge/slide velocities, rotate quaternions by ``exp(w)`` in the local frame."""
    lay = tree.layout
    if v.shape[-1] != tree.nv:
        raise InputError(f"velocity has shape {v.shape}; this model needs (..., {tree.nv})")
    shape = np.broadcast_shapes(q.shape[:-1], v.shape[:-1])
    out = np.broadcast_to(q, shape + (tree.nq,)).copy()
    out[..., lay.scalar_q] += v[..., lay.scalar_v]
    if len(lay.ball_q):
        out[..., lay.ball_q] = _turn(out[..., lay.ball_q], v[..., lay.ball_v])
    if len(lay.free_q):
        out[..., lay.free_q[:, :3]] += v[..., lay.free_v[:, :3]]
        out[..., lay.free_q[:, 3:]] = _turn(out[..., lay.free_q[:, 3:]], v[..., lay.free_v[:, 3:]])
    return out


def _turn(quat: Array, w: Array) -> Array:
    return spatial.quat_normalize(spatial.quat_mul(spatial.quat_normalize(quat), spatial.rotvec_to_quat(w)))


def difference(tree: Tree, q1: Array, q0: Array) -> Array:
    """``q1 ⊖ q0``: the velocity ``(..., nv)`` with ``integrate(q0, v) == q1``."""
    lay = tree.layout
    shape = np.broadcast_shapes(q1.shape[:-1], q0.shape[:-1])
    v = np.zeros(shape + (tree.nv,))
    v[..., lay.scalar_v] = q1[..., lay.scalar_q] - q0[..., lay.scalar_q]
    for qi, vi in ((lay.ball_q, lay.ball_v), (lay.free_q[:, 3:], lay.free_v[:, 3:])):
        if len(qi):
            rel = spatial.quat_mul(spatial.quat_conj(spatial.quat_normalize(q0[..., qi])),
                                   spatial.quat_normalize(q1[..., qi]))
            v[..., vi] = spatial.quat_to_rotvec(rel)
    if len(lay.free_q):
        v[..., lay.free_v[:, :3]] = q1[..., lay.free_q[:, :3]] - q0[..., lay.free_q[:, :3]]
    return v
