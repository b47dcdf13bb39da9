"""Clearance: geoms keep a distance from each other and from the world (a hard constraint)."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, ClassVar

import mujoco
import numpy as np

from ..errors import GoalError, UnknownNameError
from ..kinematics.distance import distance_gradient, pair_distance_normal
from ..kinematics.geoms import (
    BOX,
    CAPSULE,
    PLANE,
    SPHERE,
    Geoms,
    contact_pairs,
    native_pairs,
    near_pairs,
)
from ..runtime.checks import check_count
from ..runtime.jit import njit, njit_ir_inline
from ..runtime.numba_ext import on_stack, unshared
from .base import METRES, Array, Goal, Units, number
from .residuals import owned

if TYPE_CHECKING:
    from ..kinematics.fk import Kinematics
    from ..kinematics.tree import Tree
    from .residuals import GoalArrays

Index = np.ndarray
KEPT = 11  # numbers kept of each of the closest pairs: distance, pair, two witness points, normal


@dataclass(frozen=True)
class Clearance(Goal):
    """Every geom pair keeps a signed distance ``>= margin`` (m): ``s = d - margin >= 0``, hard.

    ``pairs``: the geom pairs ``[(geom1, geom2), ...]`` (names or ids); None: every pair
    MuJoCo's collision tests would make (:func:`mjkin.kinematics.geoms.contact_pairs`:
    contype/conaffinity, parent–child and welded bodies, ``<exclude>``, ``<pair>``).
    Distances and gradients come from mjkin's FK and its own sphere/capsule/box/plane/cylinder
    primitives (:func:`mjkin.kinematics.geoms.pair_distance`). Each evaluation takes the
    pairs whose bounding spheres and boxes come within ``margin + reach`` (a broad phase,
    :func:`~mjkin.kinematics.geoms.near_pairs`; ``reach`` default :data:`REACH`), computes
    their distances and gives a row to the ``closest`` nearest (a fixed number of rows;
    spare rows read ``reach``, inert). Meshes are measured on their convex hulls, as MuJoCo
    collides them. In a pair mjkin does not compute (a height field, an SDF) the geom it cannot
    take is measured as its bounding sphere (:func:`bounded_geoms`): that pair's clearance kept
    is a lower bound of the true one. A pair farther than ``reach`` gives no row until a step
    brings it near; the step is then judged with it (a smaller reach measures fewer pairs per
    evaluation: faster where many geoms stay near each other, as a humanoid's).
    """

    margin: float = 0.0
    pairs: Sequence[tuple[int | str, int | str]] | None = None
    closest: int = field(default=8, kw_only=True)
    reach: float | None = field(default=None, kw_only=True)
    rows: ClassVar[int] = -1
    units: ClassVar[Units] = METRES
    hard: ClassVar[bool] = True
    REACH: ClassVar[float] = 0.1  # m past the margin that a pair must come within to be measured

    def __post_init__(self) -> None:
        super().__post_init__()
        number(self.margin, "Clearance margin (m)")
        check_count(self.closest, "Clearance closest", 1)
        if self.reach is not None and not number(self.reach, "Clearance reach (m)") > 0:
            raise GoalError(f"Clearance reach must be positive metres, got {self.reach!r}")
        if self.pairs is not None and not _pairs_given(self.pairs):
            raise GoalError("Clearance pairs must be None or (geom1, geom2) pairs of geom names or ids")

    def key(self) -> tuple:
        """The structure key, made once (a solve per frame asks for it, and the G1's 579 pairs took 0.3 ms)."""
        cached = self.__dict__.get("_key")
        if cached is None:
            pairs = None if self.pairs is None else tuple(tuple(p) for p in self.pairs)
            cached = super().key() + (pairs, int(self.closest))
            object.__setattr__(self, "_key", cached)
        return cached

    def geom_pairs(self, tree: Tree) -> Index:
        """The geom pairs ``(P, 2)`` this goal keeps apart, checked against ``tree``.

        Raises:
            GoalError: a malformed pair.
            UnknownNameError: a geom name the model does not have.
        """
        cached = self.__dict__.get("_pairs")
        if cached is not None and cached[0] is tree:
            return cached[1]
        if self.pairs is None:
            pairs = contact_pairs(tree)
        else:
            pairs = np.array([[_geom(tree, a), _geom(tree, b)] for a, b in self.pairs], dtype=np.int64).reshape(-1, 2)
        pairs = np.ascontiguousarray(pairs, dtype=np.int64)
        object.__setattr__(self, "_pairs", (tree, pairs))
        return pairs

    def nrows(self, tree: Tree) -> int:
        """``closest`` rows, or one per pair when there are fewer."""
        return min(int(self.closest), len(self.geom_pairs(tree)))

    def encode(self, tree: Tree, data: Array, rest: Array) -> None:
        """The margin and the broad phase's reach into ``data``."""
        data[:, 0] = float(self.margin)
        data[:, 1] = float(self.margin) + (self.REACH if self.reach is None else float(self.reach))


def _pairs_given(pairs: object) -> bool:
    """Whether ``pairs`` is a sequence of two-item pairs of geom names or ids."""
    try:
        given = [tuple(p) for p in pairs]  # type: ignore[attr-defined]
    except TypeError:
        return False
    named = (str, int, np.integer)
    return not isinstance(pairs, (str, bytes)) and all(
        len(p) == 2 and all(isinstance(x, named) and not isinstance(x, bool) for x in p) for p in given)


def bounded_geoms(geoms: Geoms, pairs: Index) -> Geoms:
    """``geoms`` with every geom that makes a pair of ``pairs (P, 2)`` mjkin cannot measure turned into its
    bounding sphere (about its origin, radius ``rbound``), for those pairs only (see :func:`clearance_rows`).
    """  # noqa: D205
    bad = pairs[~native_pairs(geoms, pairs)] if len(pairs) else pairs
    if not len(bad):
        return geoms
    kind, size = geoms.type.copy(), geoms.size.copy()
    for g in np.unique(bad):
        if kind[g] not in (PLANE, SPHERE, CAPSULE, BOX):
            kind[g], size[g] = SPHERE, (geoms.rbound[g], 0.0, 0.0)
    return geoms._replace(type=kind, size=size)


def _geom(tree: Tree, g: int | str) -> int:
    m = tree.model
    if isinstance(g, (int, np.integer)) and not isinstance(g, bool):
        if not 0 <= g < m.ngeom:
            raise GoalError(f"Clearance geom id {g} is not in 0..{m.ngeom - 1}")
        return int(g)
    if not isinstance(g, str):
        raise GoalError(f"Clearance geoms are names or ids, got {g!r}")
    i = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, g)
    if i < 0:
        raise UnknownNameError("geom", g, [m.geom(k).name for k in range(m.ngeom) if m.geom(k).name])
    return int(i)


@njit
def clearance_rows(kin: Kinematics, geoms: Geoms, bounded: Geoms, pairs: Index, i: int, rot: Array, pos: Array,
                   irot: Array, ipos: Array, margin: float, reach: float, g: Array, J: Array, r0: int, k: int) -> int:
    """Rows ``r0:r0+k``: ``d - margin`` and ``∂d/∂v`` of the ``k`` closest of goal ``i``'s pairs near the margin.

    ``pairs (P, 4)``: ``[geom1, geom2, goal, bounded]``, each goal's contiguous; a pair marked
    ``bounded`` is measured on ``bounded`` (:func:`bounded_geoms`). Spare rows read
    ``reach - margin`` with a zero gradient, and so does a pair found farther than ``reach`` (its measure
    stops there). The broad phase's pairs are measured nearest lower bound first, each only as far as the
    ``k``-th closest so far (a GJK stops past it), and none whose lower bound is past it: the rows are those
    of measuring every pair. The ``k`` closest keep their witness points and normal for their gradients.
    Returns the number of pairs measured.
    """
    lo, hi = owned(pairs[:, 2], i)
    near = np.empty(hi - lo, dtype=np.int64)
    low = np.empty(hi - lo)
    n = near_pairs(geoms, rot, pos, pairs[lo:hi, :2], reach, near, low)
    for c in range(n):  # a bounded pair's measure is under its geoms' own (a sphere for a geom): no bound known
        if pairs[lo + near[c], 3]:
            low[c] = -np.inf
    for c in range(1, n):  # nearest lower bound first (insertion sort: a few dozen pairs)
        x, y, j = low[c], near[c], c
        while j > 0 and low[j - 1] > x:
            low[j], near[j] = low[j - 1], near[j - 1]
            j -= 1
        low[j], near[j] = x, y
    S = on_stack(KEPT * k + 9)  # the k closest, sorted, each [d, pair, p1, p2, normal]; then the pair at hand
    best = unshared(S, 0, (k, KEPT))
    for j in range(k):
        best[j, 0], best[j, 1] = np.inf, -1.0
    here = unshared(S, KEPT * k, (9,))
    measured = 0
    for c in range(n):
        if low[c] >= best[k - 1, 0]:  # this pair and the rest are no nearer than the k kept
            break
        p = lo + near[c]
        measured += 1
        d = pair_distance_normal(bounded if pairs[p, 3] else geoms, rot, pos, pairs[p, 0], pairs[p, 1],
                                 unshared(here, 0, (3,)), unshared(here, 3, (3,)), unshared(here, 6, (3,)),
                                 min(reach, best[k - 1, 0]))
        if d <= reach and d < best[k - 1, 0]:
            j = k - 1
            while j > 0 and best[j - 1, 0] > d:
                for x in range(KEPT):
                    best[j, x] = best[j - 1, x]
                j -= 1
            best[j, 0], best[j, 1] = d, p
            for x in range(9):
                best[j, 2 + x] = here[x]
    for j in range(k):
        r = r0 + j
        if best[j, 1] < 0:
            g[r] = reach - margin
            for c in range(J.shape[1]):
                J[r, c] = 0.0
        else:
            p, o = int(best[j, 1]), KEPT * j
            distance_gradient(kin, rot, pos, irot, ipos, geoms.body[pairs[p, 0]], geoms.body[pairs[p, 1]],
                              unshared(S, o + 2, (1, 3)), unshared(S, o + 5, (1, 3)), unshared(S, o + 8, (3,)), J[r])
            g[r] = best[j, 0] - margin
    return measured


@njit_ir_inline
def residual(kin: Kinematics, ga: GoalArrays, ws: tuple, rot: Array, pos: Array, irot: Array, ipos: Array, i: int,
             b: int, q: Array, g: Array, J: Array, r0: int, err: Array) -> None:
    """The ``closest`` nearest pairs' ``d - margin`` (m), unweighted, and their gradients."""
    clearance_rows(kin, ga.geoms, ga.bounded, ga.pairs, i, rot, pos, irot, ipos, ga.data[b, i, 0], ga.data[b, i, 1],
                   g, J, r0, ga.row[i + 1] - ga.row[i])
