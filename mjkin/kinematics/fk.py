"""Forward kinematics: world frames of every body for a batch of configurations.

This is the textbook traversal of a hierarchical model (Algorithm 1 of the Polish lecture notes):
a body's world pose is its parent's world pose composed with the body's fixed
placement ``L`` (MJCF ``pos``/``quat``) and then each of its joints'
articulation ``A(q)`` in order, ``T_body = T_parent · L · A_1(q) · A_2(q) ...``.
Instead of a depth-first recursion with a matrix stack, the bodies are visited
in MuJoCo's order (every parent before its children), keeping each body's world
frame in an array; the composition order, and so the result, is the same. The
kernel is compiled with numba and loops over a leading batch of configurations.
The conventions are MuJoCo's ``mj_kinematics``: a hinge turns by
``q - qpos0`` about its axis through its anchor, a slide moves by ``q - qpos0``,
a ball turns by its normalised quaternion about its anchor, and a free joint
sets the body's world pose directly.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple, Protocol

import mujoco
import numpy as np
from numpy.typing import NDArray

from ..runtime.jit import njit, njit_inline
from .mat3 import axis_angle, quat_to_mat
from .qspace import BALL, FREE, HINGE, SLIDE, Joints

Array = NDArray[np.float64]
Index = NDArray[np.int64]


class Bodies(Joints, Protocol):
    """What the FK modules read of a tree (a :class:`mjkin.Tree` is one): its bodies, sites and derived arrays."""

    @property
    def model(self) -> mujoco.MjModel: ...  # noqa: D102
    @property
    def nbody(self) -> int: ...  # noqa: D102
    @property
    def njnt(self) -> int: ...  # noqa: D102
    @property
    def body_parent(self) -> Index: ...  # noqa: D102
    @property
    def body_pos(self) -> Array: ...  # noqa: D102
    @property
    def body_rot(self) -> Array: ...  # noqa: D102
    @property
    def jnt_body(self) -> Index: ...  # noqa: D102
    @property
    def jnt_pos(self) -> Array: ...  # noqa: D102
    @property
    def jnt_axis(self) -> Array: ...  # noqa: D102
    @property
    def site_body(self) -> Index: ...  # noqa: D102
    @property
    def site_pos(self) -> Array: ...  # noqa: D102
    @property
    def site_rot(self) -> Array: ...  # noqa: D102
    @property
    def plan(self) -> Plan: ...  # noqa: D102
    @property
    def body_dofs(self) -> tuple[Index, ...]: ...  # noqa: D102
    @property
    def kin(self) -> Kinematics: ...  # noqa: D102
    @property
    def fk_args(self) -> tuple: ...  # noqa: D102
    @property
    def n_inner(self) -> int: ...  # noqa: D102


@dataclass(frozen=True)
class Plan:
    """Per-tree constants for the FK and Jacobian kernels (plain arrays numba can take)."""

    parent: Index  # (nbody,) parent used for composition (world for free-joint bodies)
    fixed_rot: Array  # (nbody, 3, 3) fixed placement L (identity for free-joint bodies)
    fixed_pos: Array  # (nbody, 3)
    jnt_start: Index  # (nbody,) first joint of each body; its joints are contiguous
    jnt_count: Index  # (nbody,)
    jnt_inner: Index  # (njnt,) slot among the inner joints (not their body's last), else -1
    fixed_plain: NDArray[np.bool_]  # (nbody,) fixed placement has no rotation (skip a product)
    hinge_coord: Index  # (njnt,) 0/1/2 when a hinge turns about +x/+y/+z, else -1
    anchor_zero: NDArray[np.bool_]  # (njnt,) joint anchor at the body origin
    dof_jnt: Index  # (nv,) joint of each dof
    dof_axis: Array  # (nv, 3) axis in the joint's frame (world frame for free translations)
    dof_world: NDArray[np.bool_]  # (nv,) axis is fixed in the world (free-joint translation)
    dof_rot: NDArray[np.bool_]  # (nv,) rotational (else translational)
    dof_anchor: Array  # (nv, 3) anchor in the joint's frame

    @classmethod
    def of(cls, tree: Bodies) -> Plan:
        """Build the plan for ``tree``."""
        m = tree.model
        jt = tree.jnt_type
        start = np.array(m.body_jntadr, dtype=np.int64)
        count = np.array(m.body_jntnum, dtype=np.int64)
        is_free = np.zeros(len(count), dtype=bool)  # a free joint is its body's first (and only) joint
        is_free[count > 0] = jt[start[count > 0]] == FREE
        dof_jnt = np.array(m.dof_jntid, dtype=np.int64)
        dof_k = np.arange(tree.nv) - tree.jnt_dofadr[dof_jnt]  # index of the dof within its joint
        dof_t = jt[dof_jnt]
        one = ((dof_t == HINGE) | (dof_t == SLIDE))[:, None]
        last = start + count - 1
        inner = np.array([j != last[tree.jnt_body[j]] for j in range(tree.njnt)], dtype=bool)
        jnt_inner = np.where(inner, np.cumsum(inner) - 1, -1)
        return cls(parent=np.where(is_free, 0, tree.body_parent),
                   fixed_rot=np.where(is_free[:, None, None], np.eye(3), tree.body_rot),
                   fixed_pos=np.where(is_free[:, None], 0.0, tree.body_pos),
                   jnt_start=np.maximum(start, 0), jnt_count=count, jnt_inner=jnt_inner,
                   fixed_plain=np.all(tree.body_rot == np.eye(3), axis=(1, 2)) | is_free,
                   hinge_coord=np.array([int(np.argmax(a)) if jt[j] == HINGE and np.sum(a == 1.0) == 1
                                         and np.sum(a == 0.0) == 2 else -1
                                         for j, a in enumerate(tree.jnt_axis)], dtype=np.int64),
                   anchor_zero=np.all(tree.jnt_pos == 0.0, axis=1),
                   dof_jnt=dof_jnt, dof_axis=np.where(one, tree.jnt_axis[dof_jnt], np.eye(3)[dof_k % 3]),
                   dof_world=(dof_t == FREE) & (dof_k < 3),
                   dof_rot=(dof_t == HINGE) | (dof_t == BALL) | ((dof_t == FREE) & (dof_k >= 3)),
                   dof_anchor=np.where((dof_t == FREE)[:, None], 0.0, tree.jnt_pos[dof_jnt]))


@njit_inline
def fk_kernel(q: Array, parent: Index, fixed_rot: Array, fixed_pos: Array, jnt_start: Index, jnt_count: Index,
              jnt_inner: Index, fixed_plain: NDArray[np.bool_], hinge_coord: Index, anchor_zero: NDArray[np.bool_],
              jnt_type: Index, jnt_qadr: Index, jnt_axis: Array, jnt_pos: Array, qpos0: Array,
              rot: Array, pos: Array, inner_rot: Array, inner_pos: Array) -> None:
    """World frames of all bodies for ``q (B, nq)``.

    Writes ``rot (B, nbody, 3, 3)``, ``pos (B, nbody, 3)``, and the world frame
    right after each inner joint (one followed by another joint of the same
    body), ``inner_rot (B, n_inner, 3, 3)``, ``inner_pos (B, n_inner, 3)``; the
    frame after a body's last joint is the body frame itself. Common cases
    take short cuts: a placement without rotation, a hinge about a coordinate
    axis (only two columns change), a joint anchored at the body origin.
    Arrays are indexed element by element, never sliced (see :mod:`mjkin.runtime.jit`).
    """
    fk_kernel_in(q, parent, fixed_rot, fixed_pos, jnt_start, jnt_count, jnt_inner, fixed_plain, hinge_coord,
                 anchor_zero, jnt_type, jnt_qadr, jnt_axis, jnt_pos, qpos0, rot, pos, inner_rot, inner_pos,
                 np.empty((3, 3)), np.empty(3), np.empty((3, 3)))


@njit_inline
def fk_kernel_in(q: Array, parent: Index, fixed_rot: Array, fixed_pos: Array, jnt_start: Index, jnt_count: Index,
                 jnt_inner: Index, fixed_plain: NDArray[np.bool_], hinge_coord: Index, anchor_zero: NDArray[np.bool_],
                 jnt_type: Index, jnt_qadr: Index, jnt_axis: Array, jnt_pos: Array, qpos0: Array,
                 rot: Array, pos: Array, inner_rot: Array, inner_pos: Array, A: Array, t: Array, R: Array) -> None:
    """:func:`fk_kernel` with its scratch given (no allocation): ``A (3, 3)``, ``t (3,)``, ``R (3, 3)``.

    ``A`` and ``t`` hold a joint's articulation (rotation, translation), ``R`` a product.
    """
    for b in range(q.shape[0]):
        for i in range(3):
            pos[b, 0, i] = 0.0
            for k in range(3):
                rot[b, 0, i, k] = 1.0 if i == k else 0.0
        for body in range(1, parent.shape[0]):
            pb = parent[body]
            for i in range(3):  # body frame = parent frame · fixed placement
                for k in range(3):
                    rot[b, body, i, k] = rot[b, pb, i, k] if fixed_plain[body] else (
                        rot[b, pb, i, 0] * fixed_rot[body, 0, k] + rot[b, pb, i, 1] * fixed_rot[body, 1, k]
                        + rot[b, pb, i, 2] * fixed_rot[body, 2, k])
                pos[b, body, i] = pos[b, pb, i] + (rot[b, pb, i, 0] * fixed_pos[body, 0]
                                                   + rot[b, pb, i, 1] * fixed_pos[body, 1]
                                                   + rot[b, pb, i, 2] * fixed_pos[body, 2])
            for j in range(jnt_start[body], jnt_start[body] + jnt_count[body]):
                a = jnt_qadr[j]
                kind = jnt_type[j]
                c = hinge_coord[j]
                if c >= 0 and anchor_zero[j]:  # R <- R @ Rot(e_c, angle): columns c+1, c+2 turn
                    angle = q[b, a] - qpos0[a]
                    sn, cs = np.sin(angle), np.cos(angle)
                    c1, c2 = (c + 1) % 3, (c + 2) % 3
                    for i in range(3):
                        r1, r2 = rot[b, body, i, c1], rot[b, body, i, c2]
                        rot[b, body, i, c1] = cs * r1 + sn * r2
                        rot[b, body, i, c2] = cs * r2 - sn * r1
                else:
                    if kind == HINGE:
                        axis_angle(jnt_axis[j, 0], jnt_axis[j, 1], jnt_axis[j, 2], q[b, a] - qpos0[a], A)
                    elif kind == BALL:
                        quat_to_mat(q[b, a], q[b, a + 1], q[b, a + 2], q[b, a + 3], A)
                    elif kind == FREE:
                        quat_to_mat(q[b, a + 3], q[b, a + 4], q[b, a + 5], q[b, a + 6], A)
                    if kind == SLIDE or kind == FREE or not anchor_zero[j]:
                        for i in range(3):
                            if kind == SLIDE:
                                t[i] = jnt_axis[j, i] * (q[b, a] - qpos0[a])
                            elif kind == FREE:
                                t[i] = q[b, a + i]
                            else:  # hinge and ball turn about the anchor: t = anchor - A anchor
                                t[i] = jnt_pos[j, i] - (A[i, 0] * jnt_pos[j, 0] + A[i, 1] * jnt_pos[j, 1]
                                                        + A[i, 2] * jnt_pos[j, 2])
                        for i in range(3):
                            pos[b, body, i] += (rot[b, body, i, 0] * t[0] + rot[b, body, i, 1] * t[1]
                                                + rot[b, body, i, 2] * t[2])
                    if kind != SLIDE:
                        for i in range(3):
                            for k in range(3):
                                R[i, k] = (rot[b, body, i, 0] * A[0, k] + rot[b, body, i, 1] * A[1, k]
                                           + rot[b, body, i, 2] * A[2, k])
                        for i in range(3):
                            for k in range(3):
                                rot[b, body, i, k] = R[i, k]
                s = jnt_inner[j]
                if s >= 0:
                    for i in range(3):
                        inner_pos[b, s, i] = pos[b, body, i]
                        for k in range(3):
                            inner_rot[b, s, i, k] = rot[b, body, i, k]


def moved(local: Array, offset: Array) -> Array:
    """The frame ``local (4, 4)`` with its origin moved to the point ``offset (3,)`` given in it."""
    out = local.copy()
    out[:3, 3] = local[:3, 3] + local[:3, :3] @ offset
    return out


FK_ROWS = 64  # configurations fk_poses_kernel computes before copying them into 4x4s (64 x 10 bodies: ~60 KB)


@njit
def poses_kernel(R: Array, x: Array, T: Array) -> None:
    """4x4 poses ``T (N, 4, 4)`` from rotations ``R (N, 3, 3)`` and origins ``x (N, 3)``."""
    for n in range(R.shape[0]):
        for i in range(3):
            for k in range(3):
                T[n, i, k] = R[n, i, k]
            T[n, i, 3] = x[n, i]
            T[n, 3, i] = 0.0
        T[n, 3, 3] = 1.0


@njit
def fk_poses_kernel(q: Array, parent: Index, fixed_rot: Array, fixed_pos: Array, jnt_start: Index, jnt_count: Index,
                    jnt_inner: Index, fixed_plain: NDArray[np.bool_], hinge_coord: Index,
                    anchor_zero: NDArray[np.bool_], jnt_type: Index, jnt_qadr: Index, jnt_axis: Array, jnt_pos: Array,
                    qpos0: Array, T: Array, inner_rot: Array, inner_pos: Array) -> None:
    """World poses of all bodies ``T (B, nbody, 4, 4)`` for ``q (B, nq)``: :func:`fk_kernel`, then 4x4s.

    :data:`FK_ROWS` configurations at a time into small rotation and origin arrays, copied into
    ``T`` while they are still in cache: no ``(B, nbody, 3, 3)`` and ``(B, nbody, 3)`` arrays to
    allocate and read back. (Writing the kernel's frames into ``T``'s corners as strided views
    was slower than this copy.)
    """
    B, nbody = q.shape[0], T.shape[1]
    rot, pos = np.empty((FK_ROWS, nbody, 3, 3)), np.empty((FK_ROWS, nbody, 3))
    for lo in range(0, B, FK_ROWS):
        hi = min(B, lo + FK_ROWS)
        fk_kernel(q[lo:hi], parent, fixed_rot, fixed_pos, jnt_start, jnt_count, jnt_inner, fixed_plain, hinge_coord,
                  anchor_zero, jnt_type, jnt_qadr, jnt_axis, jnt_pos, qpos0, rot, pos, inner_rot[lo:hi],
                  inner_pos[lo:hi])
        for b in range(lo, hi):
            for n in range(nbody):
                for i in range(3):
                    for k in range(3):
                        T[b, n, i, k] = rot[b - lo, n, i, k]
                    T[b, n, i, 3] = pos[b - lo, n, i]
                    T[b, n, 3, i] = 0.0
                T[b, n, 3, 3] = 1.0


def to_poses(R: Array, x: Array) -> Array:
    """4x4 poses ``(..., 4, 4)`` from rotations ``(..., 3, 3)`` and origins ``(..., 3)``."""
    T = np.empty(R.shape[:-2] + (4, 4))
    poses_kernel(np.ascontiguousarray(R).reshape(-1, 3, 3), np.ascontiguousarray(x).reshape(-1, 3),
                 T.reshape(-1, 4, 4))
    return T


class Kinematics(NamedTuple):
    """The tree's arrays for the compiled code (``nbody`` bodies, ``njnt`` joints, ``nv`` dofs).

    The first fields are :class:`mjkin.kinematics.fk.Plan`'s (see there); the rest locate
    each dof (``dof_*``, ``(nv, ...)``) and each body's ancestor dofs
    (``body_dof_idx[body_dof_ptr[b]:body_dof_ptr[b + 1]]``), and give the joint
    limits ``jnt_lo``/``jnt_hi`` (``(njnt,)``, ±inf when unlimited), each body's
    mass ``body_mass (nbody,)`` (kg) and the centre of mass in its body frame
    ``body_ipos (nbody, 3)`` (MuJoCo's inertial frame position).
    """

    parent: Index
    fixed_rot: Array
    fixed_pos: Array
    jnt_start: Index
    jnt_count: Index
    jnt_inner: Index
    fixed_plain: NDArray[np.bool_]
    hinge_coord: Index
    anchor_zero: NDArray[np.bool_]
    jnt_type: Index
    jnt_qadr: Index
    jnt_axis: Array
    jnt_pos: Array
    qpos0: Array
    jnt_dofadr: Index
    body_dof_ptr: Index
    body_dof_idx: Index
    dof_body: Index
    dof_inner: Index
    dof_axis: Array
    dof_world: NDArray[np.bool_]
    dof_rot: NDArray[np.bool_]
    dof_anchor: Array
    jnt_lo: Array
    jnt_hi: Array
    dof_qadr: Index
    dof_jnt: Index
    jnt_body: Index
    body_mass: Array
    body_ipos: Array


def kinematic_arrays(tree: Bodies) -> Kinematics:
    """The :class:`Kinematics` of a tree under construction (a :class:`Tree` keeps it as ``tree.kin``)."""
    p = tree.plan
    dofs = tree.body_dofs
    ptr = np.concatenate([[0], np.cumsum([len(d) for d in dofs])]).astype(np.int64)
    idx = np.concatenate(dofs).astype(np.int64) if ptr[-1] else np.zeros(0, np.int64)
    lo, hi = tree.layout.jnt_lo, tree.layout.jnt_hi
    return Kinematics(
        p.parent, p.fixed_rot, p.fixed_pos, p.jnt_start, p.jnt_count, p.jnt_inner, p.fixed_plain,
        p.hinge_coord, p.anchor_zero, tree.jnt_type, tree.jnt_qadr, tree.jnt_axis, tree.jnt_pos, tree.qpos0,
        tree.jnt_dofadr, ptr, idx, tree.jnt_body[p.dof_jnt], p.jnt_inner[p.dof_jnt], p.dof_axis, p.dof_world,
        p.dof_rot, p.dof_anchor, lo, hi, np.array(tree.jnt_qadr[p.dof_jnt], dtype=np.int64), p.dof_jnt,
        tree.jnt_body, np.array(tree.model.body_mass, dtype=np.float64),
        np.array(tree.model.body_ipos, dtype=np.float64))


@njit
def fk_scratch(parent: Index, jnt_inner: Index) -> tuple[Array, Array, Array, Array]:
    """Empty :func:`fk_kernel` outputs for one configuration: body frames and inner-joint frames."""
    n_inner = 0
    for j in range(jnt_inner.shape[0]):
        n_inner += jnt_inner[j] >= 0
    nbody = parent.shape[0]
    return np.empty((1, nbody, 3, 3)), np.empty((1, nbody, 3)), np.empty((1, n_inner, 3, 3)), np.empty((1, n_inner, 3))


@njit_inline
def frame_world(rot: Array, pos: Array, b: int, body: int, local: Array, T: Array) -> None:
    """World pose ``T (4, 4)`` of a frame ``local (4, 4)`` fixed in ``body``, from FK output ``b``.

    Every path to a frame's pose (one configuration or a batch) goes through
    this one formula, so they agree to the last bit.
    """
    for i in range(3):
        for k in range(4):
            T[i, k] = rot[b, body, i, 0] * local[0, k] + rot[b, body, i, 1] * local[1, k] + (
                rot[b, body, i, 2] * local[2, k])
        T[i, 3] += pos[b, body, i]
        T[3, i] = 0.0
    T[3, 3] = 1.0


@njit
def frames_world(rot: Array, pos: Array, body: int, local: Array, out: Array) -> None:
    """:func:`frame_world` for every configuration: ``out (B, 4, 4)``."""
    for b in range(out.shape[0]):
        frame_world(rot, pos, b, body, local, out[b])
