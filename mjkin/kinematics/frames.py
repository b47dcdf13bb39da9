"""Body frames of a batch of configurations, and the poses and Jacobians read from them."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .. import spatial
from ..runtime.checks import check_vector
from ..runtime.parallel import parallel_chunks
from .fk import Bodies, fk_kernel, fk_poses_kernel, frames_world, moved, to_poses
from .jacobian import jacobian_kernel

Array = NDArray[np.float64]
POSES_CHUNK = 1024  # configurations a thread of poses() takes at least: less costs more to hand over than it saves


def rows(q: Array) -> Array:
    """``q (..., nq)`` as a C-ordered, writable ``(B, nq)``: a view where it is one, else a copy.

    Writable so that the kernels compile one version, not one per flag (a read-only ``q`` is rare). Plain
    attribute tests, not ``np.require`` and ``np.prod`` (~15 µs together: an env step's FK costs ~8 µs).
    """
    qf = q.reshape(math.prod(q.shape[:-1]), q.shape[-1])
    return qf if qf.flags.c_contiguous and qf.flags.writeable else np.array(qf, order="C")


def forward(tree: Bodies, q: Array) -> Frames:
    """World frames of all bodies for ``q (..., nq)`` (already validated)."""
    batch = q.shape[:-1]
    qf = rows(q)
    B = qf.shape[0]
    arrays = tree.fk_args
    nbody, n_inner = len(arrays[0]), tree.n_inner
    rot = np.empty((B, nbody, 3, 3))
    pos = np.empty((B, nbody, 3))
    inner_rot = np.empty((B, n_inner, 3, 3))
    inner_pos = np.empty((B, n_inner, 3))
    fk_kernel(qf, *arrays, rot, pos, inner_rot, inner_pos)  # type: ignore[call-arg]  # the 14 arrays of fk_arrays
    return Frames(tree, batch, rot, pos, inner_rot, inner_pos)


def poses(tree: Bodies, q: Array) -> Array:
    """World pose of every body ``(..., nbody, 4, 4)`` for ``q (..., nq)`` (already validated): :meth:`Tree.fk`'s batch.

    Written straight into the result (:func:`~mjkin.kinematics.fk.fk_poses_kernel`), in chunks over the
    solver threads (:func:`mjkin.runtime.parallel.parallel_chunks`; the kernel releases the GIL).
    """
    batch = q.shape[:-1]
    qf = rows(q)
    B, nbody, n_inner = qf.shape[0], len(tree.fk_args[0]), tree.n_inner
    T = np.empty((B, nbody, 4, 4))
    inner_rot, inner_pos = np.empty((B, n_inner, 3, 3)), np.empty((B, n_inner, 3))
    parallel_chunks(lambda lo, hi: fk_poses_kernel(qf[lo:hi], *tree.fk_args, T[lo:hi], inner_rot[lo:hi],
                                                   inner_pos[lo:hi]), B, POSES_CHUNK)
    return T.reshape(batch + (nbody, 4, 4))


@dataclass(frozen=True, eq=False)
class Frames:
    """Result of :func:`forward`, flattened over the batch (``B = prod(batch)``).

    ``rot (B, nbody, 3, 3)``, ``pos (B, nbody, 3)``: world rotation and origin
    of every body; ``inner_rot``, ``inner_pos``: world frame right after each
    inner joint (see :func:`fk_kernel`). A joint's anchor and axis are fixed in
    the frame right after it (MuJoCo's ``xanchor``/``xaxis``).
    """

    tree: Bodies
    batch: tuple[int, ...]
    rot: Array
    pos: Array
    inner_rot: Array
    inner_pos: Array

    def local_frame(self, kind: str, i: int) -> tuple[int, Array, Array]:
        """Body id, rotation ``(3, 3)`` and origin ``(3,)`` of a site/body frame in its body."""
        t = self.tree
        if kind == "site":
            return int(t.site_body[i]), t.site_rot[i], t.site_pos[i]
        return i, np.eye(3), np.zeros(3)

    def frame(self, kind: str, i: int, offset: Array | None = None) -> tuple[Array, Array]:
        """World rotation ``(B, 3, 3)`` and origin ``(B, 3)`` of a site or body (or a point ``offset`` on it)."""
        T = self.world(kind, i, offset)
        return T[:, :3, :3], T[:, :3, 3]

    def world(self, kind: str, i: int, offset: Array | None = None) -> Array:
        """World poses ``(B, 4, 4)`` of a site or body frame, moved to a local point ``offset (3,)`` if given."""
        b, r, o = self.local_frame(kind, i)
        local = spatial.make_transform(r, o)
        if offset is not None:
            local = moved(local, offset)
        T = np.empty((self.rot.shape[0], 4, 4))
        frames_world(self.rot, self.pos, b, local, T)
        return T

    def pose(self, kind: str, i: int) -> Array:
        """World pose ``(..., 4, 4)`` of a site or body."""
        return self.world(kind, i).reshape(self.batch + (4, 4))

    def poses(self) -> Array:
        """World pose of every body ``(..., nbody, 4, 4)``."""
        return to_poses(self.rot, self.pos).reshape(self.batch + (self.tree.nbody, 4, 4))

    def jacobian(self, kind: str, i: int, offset: ArrayLike | None = None) -> Array:
        """Jacobian ``(..., 6, nv)`` of a site/body origin (or a local ``offset``), world axes."""
        return frame_jacobian(self, kind, i, offset).reshape(self.batch + (6, self.tree.nv))


def point_jacobian(frames: Frames, body: int, point: Array) -> Array:
    """Jacobian ``(B, 6, nv)`` of world points ``point (B, 3)`` fixed to ``body``."""
    t, p = frames.tree, frames.tree.plan
    J = np.zeros((point.shape[0], 6, t.nv))
    jacobian_kernel(frames.rot, frames.pos, frames.inner_rot, frames.inner_pos, t.body_dofs[body],
                    t.jnt_body[p.dof_jnt], p.jnt_inner[p.dof_jnt], p.dof_axis, p.dof_world, p.dof_rot, p.dof_anchor,
                    np.ascontiguousarray(point), J)
    return J


def frame_jacobian(frames: Frames, kind: str, i: int, offset: ArrayLike | None = None) -> Array:
    """Jacobian ``(B, 6, nv)`` at a site/body origin, or at ``offset (3,)`` in its local frame."""
    body, _, _ = frames.local_frame(kind, i)
    _, x = frames.frame(kind, i, None if offset is None else check_vector(offset, "offset"))
    return point_jacobian(frames, body, x)
