"""The MuJoCo bridge: a model and data pair driven by mjkin's q, for contacts and rendering.

mjkin's own FK answers every kinematic question; MuJoCo is asked only for
what it is best at — collision detection and drawing — after ``q`` is written
into ``qpos``.
"""

from __future__ import annotations

from dataclasses import dataclass

import mujoco
from numpy.typing import ArrayLike

from .tree import Tree


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
        self._geom = tree.names("body")  # body names, for contact reports

    def set(self, q: ArrayLike) -> mujoco.MjData:
        """Write ``q (nq,)`` into ``qpos`` and update what drawing and collision need."""
        self.data.qpos[:] = self.tree.check_q(q)
        mujoco.mj_kinematics(self.model, self.data)
        mujoco.mj_comPos(self.model, self.data)
        mujoco.mj_camlight(self.model, self.data)
        return self.data

    def contacts(self, q: ArrayLike) -> list[Contact]:
        """Contacts at ``q`` (overlaps have negative distance), adjacent bodies excluded if asked."""
        self.set(q)
        mujoco.mj_collision(self.model, self.data)
        m, out = self.model, []
        for c in self.data.contact[: self.data.ncon]:
            b1, b2 = int(m.geom_bodyid[c.geom1]), int(m.geom_bodyid[c.geom2])
            if self.exclude_adjacent and self._adjacent(b1, b2):
                continue
            out.append(Contact(mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_GEOM, c.geom1) or f"#{c.geom1}",
                               mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_GEOM, c.geom2) or f"#{c.geom2}",
                               self._geom[b1], self._geom[b2], float(c.dist)))
        return out

    def in_collision(self, q: ArrayLike, margin: float = 0.0) -> bool:
        """Whether any (non-adjacent) pair of geoms is closer than ``margin`` at ``q``."""
        return any(c.distance < margin for c in self.contacts(q))

    def _adjacent(self, b1: int, b2: int) -> bool:
        m = self.model
        w1, w2 = int(m.body_weldid[b1]), int(m.body_weldid[b2])
        if w1 == 0 or w2 == 0:  # as MuJoCo's own filter: contacts with the world always count
            return w1 == w2
        parent1, parent2 = int(m.body_weldid[m.body_parentid[w1]]), int(m.body_weldid[m.body_parentid[w2]])
        return w1 == w2 or parent1 == w2 or parent2 == w1
