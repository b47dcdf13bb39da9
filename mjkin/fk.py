"""Forward kinematics: world frames of every body for a batch of configurations.

This is the textbook traversal of a hierarchical model (seed 000, Algorithm 1):
a body's world pose is its parent's world pose composed with the body's fixed
placement ``L`` (MJCF ``pos``/``quat``) and then each of its joints'
articulation ``A(q)`` in order, ``T_body = T_parent · L · A_1(q) · A_2(q) ...``.
Instead of a depth-first recursion with a matrix stack, the bodies are visited
level by level (all bodies at one depth at once) and every step is vectorised
over the batch of configurations; the composition order, and so the result, is
the same. The conventions are MuJoCo's ``mj_kinematics``: a hinge turns by
``q - qpos0`` about its axis through its anchor, a slide moves by ``q - qpos0``,
a ball turns by its normalised quaternion about its anchor, and a free joint
sets the body's world pose directly.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import ArrayLike, NDArray

from . import spatial
from .qspace import BALL, FREE, HINGE, SLIDE

if TYPE_CHECKING:
    from .tree import Tree

Array = NDArray[np.float64]
Index = NDArray[np.int64]


@dataclass(frozen=True)
class Plan:
    """Precomputed index arrays for :func:`forward` (one per tree)."""

    parent: Index  # (nbody,) parent used for composition (world for free-joint bodies)
    fixed_rot: Array  # (nbody, 3, 3) fixed placement L (identity for free-joint bodies)
    fixed_pos: Array  # (nbody, 3)
    levels: tuple[tuple[Index, Index], ...]  # (bodies, their parents), depth 1, 2, ...
    slots: tuple[tuple[Index, Index, Index, Index], ...]
    """Per joint slot k: (bodies with > k joints, their k-th joint, where those joints
    sit in ``inner`` and which of the bodies they belong to)."""
    inner: Index  # joints that are not their body's last (their frame is not the body frame)
    dof_jnt: Index  # (nv,) joint of each dof
    dof_axis: Array  # (nv, 3) axis in the joint's frame (world frame for free translations)
    dof_world: NDArray[np.bool_]  # (nv,) axis is fixed in the world (free-joint translation)
    dof_rot: NDArray[np.bool_]  # (nv,) rotational (else translational)
    dof_anchor: Array  # (nv, 3) anchor in the joint's frame
    hinge: Index
    slide: Index
    ball: Index
    free: Index

    @classmethod
    def of(cls, tree: Tree) -> Plan:
        """Build the plan for ``tree``."""
        nbody = tree.nbody
        jt, jb = tree.jnt_type, tree.jnt_body
        body_joints: list[list[int]] = [[] for _ in range(nbody)]
        for j in range(tree.njnt):
            body_joints[int(jb[j])].append(j)
        is_free = np.array([bool(js) and jt[js[0]] == FREE for js in body_joints])
        parent = np.where(is_free, 0, tree.body_parent)
        parent[0] = 0
        fixed_rot = np.where(is_free[:, None, None], np.eye(3), tree.body_rot)
        fixed_pos = np.where(is_free[:, None], 0.0, tree.body_pos)
        depth = np.zeros(nbody, dtype=np.int64)
        for b in range(1, nbody):  # MuJoCo orders parents before children
            depth[b] = depth[parent[b]] + 1
        levels = tuple((np.flatnonzero(depth == d), parent[depth == d]) for d in range(1, int(depth.max(initial=0)) + 1))
        inner = [j for js in body_joints for j in js[:-1]]
        slots = []
        for k in range(max((len(js) for js in body_joints), default=0)):
            bodies = [b for b in range(nbody) if len(body_joints[b]) > k]
            joints = [body_joints[b][k] for b in bodies]
            src = [n for n, j in enumerate(joints) if j in inner]
            slots.append(tuple(np.array(a, dtype=np.int64) for a in
                               (bodies, joints, [inner.index(joints[n]) for n in src], src)))
        dof_jnt = np.array(tree.model.dof_jntid, dtype=np.int64)
        dof_k = np.arange(tree.nv) - tree.jnt_dofadr[dof_jnt]  # index of the dof within its joint
        dof_t = jt[dof_jnt]
        eye = np.eye(3)
        one = ((dof_t == HINGE) | (dof_t == SLIDE))[:, None]
        dof_axis = np.where(one, tree.jnt_axis[dof_jnt], eye[dof_k % 3])
        return cls(parent=parent, fixed_rot=fixed_rot, fixed_pos=fixed_pos, levels=levels,
                   slots=tuple(slots), inner=np.array(inner, dtype=np.int64),
                   hinge=np.flatnonzero(jt == HINGE), slide=np.flatnonzero(jt == SLIDE),
                   ball=np.flatnonzero(jt == BALL), free=np.flatnonzero(jt == FREE),
                   dof_jnt=dof_jnt, dof_axis=dof_axis, dof_world=(dof_t == FREE) & (dof_k < 3),
                   dof_rot=(dof_t == HINGE) | (dof_t == BALL) | ((dof_t == FREE) & (dof_k >= 3)),
                   dof_anchor=np.where((dof_t == FREE)[:, None], 0.0, tree.jnt_pos[dof_jnt]))


def joint_transforms(tree: Tree, q: Array) -> tuple[Array, Array]:
    """Each joint's articulation ``A(q)`` as rotation ``(B, njnt, 3, 3)`` and translation ``(B, njnt, 3)``.

    ``A`` maps the frame after the joint into the frame before it; hinge and
    ball joints turn about their anchor ``a``: ``A = (R, a - R a)``.
    """
    p = tree.plan
    B = q.shape[0]
    rot = np.empty((B, tree.njnt, 3, 3))
    pos = np.empty((B, tree.njnt, 3))
    qa = tree.jnt_qadr
    if len(p.hinge):
        j = p.hinge
        rot[:, j] = spatial.axis_angle_to_mat(tree.jnt_axis[j], q[:, qa[j]] - tree.qpos0[qa[j]])
    if len(p.ball):
        j = p.ball
        rot[:, j] = spatial.quat_to_mat(spatial.quat_normalize(q[:, qa[j, None] + np.arange(4)]))
    for j in (p.hinge, p.ball):
        if len(j):
            anchor = tree.jnt_pos[j]
            pos[:, j] = anchor - (rot[:, j] @ anchor[:, :, None])[..., 0]
    if len(p.slide):
        j = p.slide
        rot[:, j] = np.eye(3)
        pos[:, j] = tree.jnt_axis[j] * (q[:, qa[j]] - tree.qpos0[qa[j]])[..., None]
    if len(p.free):
        j = p.free
        rot[:, j] = spatial.quat_to_mat(spatial.quat_normalize(q[:, qa[j, None] + np.arange(3, 7)]))
        pos[:, j] = q[:, qa[j, None] + np.arange(3)]
    return rot, pos


def forward(tree: Tree, q: Array) -> Frames:
    """World frames of all bodies for ``q (..., nq)`` (already validated)."""
    p = tree.plan
    batch = q.shape[:-1]
    q = q.reshape(-1, tree.nq)
    B = q.shape[0]
    jrot, jpos = joint_transforms(tree, q)

    # local transform of each body in its (composition) parent: L · A_1 · A_2 ...
    lrot = np.broadcast_to(p.fixed_rot, (B, tree.nbody, 3, 3)).copy()
    lpos = np.broadcast_to(p.fixed_pos, (B, tree.nbody, 3)).copy()
    inner_rot = np.empty((B, len(p.inner), 3, 3))
    inner_pos = np.empty((B, len(p.inner), 3))
    for bodies, joints, dst, src in p.slots:
        r = lrot[:, bodies]
        lpos[:, bodies] += (r @ jpos[:, joints, :, None])[..., 0]
        lrot[:, bodies] = r @ jrot[:, joints]
        if len(dst):  # the frame right after an inner joint, in the body's parent frame
            inner_rot[:, dst] = lrot[:, bodies[src]]
            inner_pos[:, dst] = lpos[:, bodies[src]]

    rot = np.empty((B, tree.nbody, 3, 3))
    pos = np.empty((B, tree.nbody, 3))
    rot[:, 0] = np.eye(3)
    pos[:, 0] = 0.0
    for bodies, parents in p.levels:
        pr = rot[:, parents]
        pos[:, bodies] = pos[:, parents] + (pr @ lpos[:, bodies, :, None])[..., 0]
        rot[:, bodies] = pr @ lrot[:, bodies]
    return Frames(tree, batch, rot, pos, inner_rot, inner_pos)


@dataclass(frozen=True, eq=False)
class Frames:
    """Result of :func:`forward`: body frames, flattened over the batch.

    ``rot (B, nbody, 3, 3)`` and ``pos (B, nbody, 3)`` are world rotation and
    origin of every body, ``B = prod(batch)``. Joint and dof frames are derived
    on demand for Jacobians.
    """

    tree: Tree
    batch: tuple[int, ...]
    rot: Array
    pos: Array
    inner_rot: Array  # (B, n_inner, 3, 3) local frame after each inner joint
    inner_pos: Array

    def _shape(self, a: Array, tail: tuple[int, ...]) -> Array:
        return a.reshape(self.batch + tail)

    def local_frame(self, kind: str, i: int) -> tuple[int, Array, Array]:
        """Body id, rotation ``(3, 3)`` and origin ``(3,)`` of a site/body frame in its body."""
        t = self.tree
        if kind == "site":
            return int(t.site_body[i]), t.site_rot[i], t.site_pos[i]
        return i, np.eye(3), np.zeros(3)

    def frame(self, kind: str, i: int) -> tuple[Array, Array]:
        """World rotation ``(B, 3, 3)`` and origin ``(B, 3)`` of a site or body (flat batch)."""
        b, r, o = self.local_frame(kind, i)
        R = self.rot[:, b]
        return R @ r, self.pos[:, b] + R @ o

    def pose(self, kind: str, i: int) -> Array:
        """World pose ``(..., 4, 4)`` of a site or body."""
        R, p = self.frame(kind, i)
        return self._shape(spatial.make_transform(R, p), (4, 4))

    @cached_property
    def joint_frames(self) -> tuple[Array, Array]:
        """World rotation ``(B, njnt, 3, 3)`` and origin of the frame right after each joint.

        A joint's anchor and axis are fixed in that frame (MuJoCo's ``xanchor``
        and ``xaxis`` for hinge and ball joints).
        """
        t, p = self.tree, self.tree.plan
        jb = t.jnt_body
        R = self.rot[:, jb].copy()
        P = self.pos[:, jb].copy()
        if len(p.inner):
            par = p.parent[jb[p.inner]]
            pr = self.rot[:, par]
            R[:, p.inner] = pr @ self.inner_rot
            P[:, p.inner] = self.pos[:, par] + (pr @ self.inner_pos[..., None])[..., 0]
        return R, P

    def jacobian(self, kind: str, i: int, offset: ArrayLike | None = None) -> Array:
        """Jacobian ``(..., 6, nv)`` of a site/body origin (or a local ``offset``), world axes."""
        from .jacobian import frame_jacobian

        return self._shape(frame_jacobian(self, kind, i, offset), (6, self.tree.nv))
