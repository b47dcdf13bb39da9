"""The MuJoCo bridge: a model and data pair driven by mjkin's q, for contacts and rendering.

mjkin's own FK answers every kinematic question; MuJoCo is asked only for
what it is best at — collision detection and drawing — after ``q`` is written
into ``qpos``.

A collision query costs what ``mj_kinematics`` + ``mj_collision`` cost plus a
few array reads: which geom pairs count is decided once, when the
:class:`Scene` is made. MuJoCo's own filters (``contype``/``conaffinity``,
``<exclude>``, welded bodies and, unless the model disables it, parent–child
pairs) already drop adjacent bodies, so the precomputed pair mask is consulted
only when the model can report pairs it would reject (explicit ``<pair>``
elements, or ``filterparent`` disabled).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import mujoco
import numpy as np
from numpy.typing import ArrayLike, NDArray

from .kinematics.distance import segments_closest
from .kinematics.geoms import contact_pairs
from .kinematics.tree import Tree
from .runtime.jit import njit, njit_inline

if TYPE_CHECKING:
    from .kinematics.frames import Frames

_NO_GEOMS = np.empty((0, 2), np.int32)
_NO_DISTANCES = np.empty(0)
_NO_GEOMS.setflags(write=False)
_NO_DISTANCES.setflags(write=False)


@dataclass(frozen=True)
class Contact:
    """One contact MuJoCo found: the two geoms (and their bodies) and the signed distance (m, < 0 = overlap)."""

    geom1: str
    geom2: str
    body1: str
    body2: str
    distance: float


class Scene:
    """``MjData`` for a tree, updated from mjkin configurations.

    Args:
        tree: the kinematic tree (its ``model`` is used as is).
        exclude_adjacent: ignore contacts between a body and its parent (and
            between bodies welded together), as a kinematic checker would;
            contacts with the world body always count.
    """

    def __init__(self, tree: Tree, exclude_adjacent: bool = True) -> None:
        self.tree = tree
        self.model = tree.model
        self.data = mujoco.MjData(self.model)
        self.exclude_adjacent = exclude_adjacent
        m = self.model
        body = np.asarray(m.geom_bodyid)
        weld = np.asarray(m.body_weldid)[body]  # (ngeom,) weld body of each geom
        parent_weld = np.asarray(m.body_weldid)[np.asarray(m.body_parentid)[weld]]
        both = (weld[:, None] != 0) & (weld[None, :] != 0)
        adjacent = (weld[:, None] == weld[None, :]) | (both & ((weld[:, None] == parent_weld[None, :])
                                                              | (parent_weld[:, None] == weld[None, :])))
        self._keep: NDArray[np.bool_] = ~adjacent if exclude_adjacent else np.ones_like(adjacent)
        filterparent = not m.opt.disableflags & mujoco.mjtDisableBit.mjDSBL_FILTERPARENT
        # MuJoCo drops every adjacent pair itself unless a <pair> or a disabled filter lets one through
        self._masked = exclude_adjacent and (m.npair > 0 or not filterparent)
        self._pairs_for_broadphase()
        self._geom_names = [mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_GEOM, g) or f"#{g}" for g in range(m.ngeom)]
        self._body_names = [tree.names("body")[b] for b in body]  # body of each geom

    def _pairs_for_broadphase(self) -> None:
        """The geom pairs MuJoCo could report (its own filters, and the pair mask), with their bounding radii.

        Used by :meth:`counts` to skip ``mj_collision`` for configurations where no
        such pair's bounding spheres (``geom_rbound`` + margin) meet. Planes have no
        bounding sphere: a pair with a plane fixed in the world is tested by the other
        geom's distance from the plane; a moving plane disables the shortcut.
        """
        m = self.model
        body = np.asarray(m.geom_bodyid)
        weld = np.asarray(m.body_weldid)[body]
        pairs = contact_pairs(self.tree)
        if self._masked:
            pairs = pairs[self._keep[pairs[:, 0], pairs[:, 1]]]
        kind = np.asarray(m.geom_type)
        plane = kind == mujoco.mjtGeom.mjGEOM_PLANE
        # every geom as a segment (half-length along its z axis) swept by a radius: capsules exactly,
        # spheres with no length, anything else as its bounding sphere; margins and a hair added
        capsule = kind == mujoco.mjtGeom.mjGEOM_CAPSULE
        exact = capsule | (kind == mujoco.mjtGeom.mjGEOM_SPHERE)
        self._half = np.where(capsule, np.asarray(m.geom_size)[:, 1], 0.0)
        reach = (np.where(exact, np.asarray(m.geom_size)[:, 0], np.asarray(m.geom_rbound))
            + np.asarray(m.geom_margin) + 1e-9 * max(float(m.stat.extent), 1.0))
        is_plane = plane[pairs]
        self._prefilter = not bool(np.any(is_plane & (weld[pairs] != 0)))
        mujoco.mj_kinematics(m, self.data)  # the world's planes are where qpos0 puts them
        sphere = pairs[~is_plane.any(1)]
        with_plane = pairs[is_plane.any(1)]
        with_plane = np.where(plane[with_plane[:, :1]], with_plane, with_plane[:, ::-1])  # (plane, other)
        self._spheres = (np.ascontiguousarray(sphere, dtype=np.int64), reach[sphere[:, 0]] + reach[sphere[:, 1]])
        normal = np.ascontiguousarray(self.data.geom_xmat.reshape(-1, 3, 3)[with_plane[:, 0], :, 2])
        self._planes = (np.ascontiguousarray(with_plane[:, 1], dtype=np.int64), normal,
                        np.einsum("ij,ij->i", normal, self.data.geom_xpos[with_plane[:, 0]]), reach[with_plane[:, 1]])
        self._geom_body, self._geom_pos = body.astype(np.int64), np.array(m.geom_pos, dtype=np.float64)
        quat = np.asarray(m.geom_quat)
        w, x, y, z = quat[:, 0], quat[:, 1], quat[:, 2], quat[:, 3]  # the geom's z axis in its body frame
        self._geom_axis = (np.stack([2 * (x * z + w * y), 2 * (y * z - w * x), 1 - 2 * (x * x + y * y)], 1)
            / np.sum(quat * quat, axis=1)[:, None])

    def set(self, q: ArrayLike) -> mujoco.MjData:
        """Write ``q (nq,)`` into ``qpos`` and update what drawing and collision need."""
        self.data.qpos[:] = self.tree.check_q(q)
        mujoco.mj_kinematics(self.model, self.data)
        mujoco.mj_comPos(self.model, self.data)
        mujoco.mj_camlight(self.model, self.data)
        return self.data

    def _collide(self, q: NDArray[np.float64]) -> tuple[NDArray[np.int32], NDArray[np.float64]]:
        """Geom pairs ``(n, 2)`` and distances ``(n,)`` of the counted contacts at one valid ``q (nq,)``."""
        m, d = self.model, self.data
        d.qpos[:] = q
        mujoco.mj_kinematics(m, d)
        mujoco.mj_collision(m, d)
        if d.ncon == 0:
            return _NO_GEOMS, _NO_DISTANCES
        geom, dist = d.contact.geom, d.contact.dist
        if self._masked:
            keep = self._keep[geom[:, 0], geom[:, 1]]
            return geom[keep], dist[keep]
        return geom, dist

    def contacts(self, q: ArrayLike) -> list[Contact]:
        """Contacts at ``q (nq,)`` (overlaps have negative distance), adjacent bodies excluded if asked."""
        geom, dist = self._collide(self.tree.check_q(q))
        names, bodies = self._geom_names, self._body_names
        return [Contact(names[g1], names[g2], bodies[g1], bodies[g2], x)
                for (g1, g2), x in zip(geom.tolist(), dist.tolist(), strict=True)]

    def count(self, q: ArrayLike, margin: float | None = None) -> NDArray[np.int64] | int:
        """Number of counted contacts at ``q (nq,)`` or ``(B, nq)`` (``(B,)``); ``margin``: only those closer."""
        qs = self.tree.check_q(q)
        flat = qs.reshape(-1, qs.shape[-1])
        if margin is None and not self._masked:
            out = self.counts(flat)
        else:
            out = np.array([np.count_nonzero(self._collide(x)[1] < (np.inf if margin is None else margin))
                            for x in flat], dtype=np.int64)
        return int(out[0]) if qs.ndim == 1 else out.reshape(qs.shape[:-1])

    def counts(self, qs: NDArray[np.float64], frames: Frames | None = None) -> NDArray[np.int64]:
        """Counted contacts ``(B,)`` for already valid ``qs (B, nq)``: the tight loop an env steps with.

        With ``frames``, mjkin's FK of ``qs`` (``tree.kinematics(qs)``), configurations
        where no pair MuJoCo could report has its bounding spheres within reach skip
        ``mj_collision`` (they have no contact); the counts are the same.
        """
        todo = range(len(qs)) if frames is None or not self._prefilter else np.flatnonzero(self._near(frames))
        out = np.zeros(len(qs), dtype=np.int64)
        if self._masked:
            for b in todo:
                out[b] = len(self._collide(qs[b])[1])
            return out
        m, d = self.model, self.data
        qpos, kinematics, collision = d.qpos, mujoco.mj_kinematics, mujoco.mj_collision
        for b in todo:
            qpos[:] = qs[b]
            kinematics(m, d)
            collision(m, d)
            out[b] = d.ncon
        return out

    def _near(self, frames: Frames) -> NDArray[np.bool_]:
        """``(B,)``: some pair MuJoCo could report is within reach (segment distances, or heights over planes)."""
        near = np.empty(frames.rot.shape[0], dtype=np.bool_)
        pairs, reach = self._spheres
        other, normal, offset, radius = self._planes
        near_kernel(frames.rot, frames.pos, self._geom_body, self._geom_pos, self._geom_axis, self._half, pairs,
                    reach, other, normal, offset, radius, near)
        return near

    def in_collision(self, q: ArrayLike, margin: float = 0.0) -> bool | NDArray[np.bool_]:
        """Whether any counted geom pair is closer than ``margin``: a bool for ``(nq,)``, ``(B,)`` for ``(B, nq)``."""
        n = self.count(q, margin)
        return bool(n) if isinstance(n, int) else n > 0


@njit_inline
def _segment_gap(C: NDArray[np.float64], H: NDArray[np.float64], i: int, j: int, S: NDArray[np.float64]) -> float:
    """Distance between segments ``C[i] ± H[i]`` and ``C[j] ± H[j]`` (centres and half-vectors, rows of ``(n, 3)``).

    The closest points from :func:`mjkin.kinematics.distance.segments_closest` (zero-length segments allowed).
    ``S (4, 3)``: scratch for the segments' starts and spans, written element by element (array
    expressions would allocate four arrays a pair, in the broad phase's inner loop).
    """
    for k in range(3):
        S[0, k], S[1, k] = C[i, k] - H[i, k], 2.0 * H[i, k]
        S[2, k], S[3, k] = C[j, k] - H[j, k], 2.0 * H[j, k]
    s, t = segments_closest(S[0], S[1], S[2], S[3])
    gap = 0.0
    for k in range(3):
        g = (S[0, k] + s * S[1, k]) - (S[2, k] + t * S[3, k])
        gap += g * g
    return float(np.sqrt(gap))


@njit
def near_kernel(rot: NDArray[np.float64], pos: NDArray[np.float64], geom_body: NDArray[np.int64],
                geom_pos: NDArray[np.float64], geom_axis: NDArray[np.float64], half: NDArray[np.float64],
                pairs: NDArray[np.int64], reach: NDArray[np.float64], other: NDArray[np.int64],
                normal: NDArray[np.float64], offset: NDArray[np.float64], radius: NDArray[np.float64],
                near: NDArray[np.bool_]) -> None:
    """For each of ``B`` body-frame sets ``rot (B, nbody, 3, 3)``, ``pos (B, nbody, 3)``: is a pair within reach."""
    ngeom = geom_body.shape[0]
    centre = np.empty((ngeom, 3))
    axis = np.empty((ngeom, 3))
    S = np.empty((4, 3))
    for b in range(rot.shape[0]):
        for g in range(ngeom):
            k = geom_body[g]
            for i in range(3):
                centre[g, i] = pos[b, k, i] + (rot[b, k, i, 0] * geom_pos[g, 0] + rot[b, k, i, 1] * geom_pos[g, 1]
                                               + rot[b, k, i, 2] * geom_pos[g, 2])
                axis[g, i] = half[g] * (rot[b, k, i, 0] * geom_axis[g, 0] + rot[b, k, i, 1] * geom_axis[g, 1]
                                        + rot[b, k, i, 2] * geom_axis[g, 2])
        hit = False
        for p in range(pairs.shape[0]):
            i, j = pairs[p, 0], pairs[p, 1]
            # the segments' points lie within half[i], half[j] of their centres: centres farther apart than
            # reach + both halves put the pair out of reach without the closest points
            lim, d2 = reach[p] + half[i] + half[j], 0.0
            for k in range(3):
                d2 += (centre[i, k] - centre[j, k]) ** 2
            if d2 <= lim * lim and _segment_gap(centre, axis, i, j, S) <= reach[p]:
                hit = True
                break
        for p in range(other.shape[0]):
            if hit:
                break
            g = other[p]
            height = -offset[p]
            along = 0.0
            for i in range(3):
                height += centre[g, i] * normal[p, i]
                along += axis[g, i] * normal[p, i]
            if height - abs(along) <= radius[p]:
                hit = True
        near[b] = hit
