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

import mujoco
import numpy as np
from numpy.typing import ArrayLike, NDArray

from .tree import Tree

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
        self._geom_names = [mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_GEOM, g) or f"#{g}" for g in range(m.ngeom)]
        self._body_names = [tree.names("body")[b] for b in body]  # body of each geom

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

    def counts(self, qs: NDArray[np.float64]) -> NDArray[np.int64]:
        """Counted contacts ``(B,)`` for already valid ``qs (B, nq)``: the tight loop an env steps with."""
        if self._masked:
            return np.array([len(self._collide(x)[1]) for x in qs], dtype=np.int64)
        m, d = self.model, self.data
        qpos, kinematics, collision = d.qpos, mujoco.mj_kinematics, mujoco.mj_collision
        out = np.empty(len(qs), dtype=np.int64)
        for b in range(len(qs)):
            qpos[:] = qs[b]
            kinematics(m, d)
            collision(m, d)
            out[b] = d.ncon
        return out

    def in_collision(self, q: ArrayLike, margin: float = 0.0) -> bool | NDArray[np.bool_]:
        """Whether any counted geom pair is closer than ``margin``: a bool for ``(nq,)``, ``(B,)`` for ``(B, nq)``."""
        n = self.count(q, margin)
        return bool(n) if isinstance(n, int) else n > 0
