"""Geoms for clearance: their arrays for the compiled code, the pairs MuJoCo would collide, and a broad phase.

:func:`contact_pairs` lists the geom pairs MuJoCo's collision tests (its
``mj_collision`` filters: ``contype``/``conaffinity``, bodies welded together,
parent–child bodies unless ``filterparent`` is disabled, ``<exclude>``, plus
the explicit ``<pair>`` elements); :func:`near_pairs` keeps those whose
bounding spheres come within a distance, for one configuration. Their signed
distances and gradients are :mod:`mjkin.kinematics.distance`'s.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, NamedTuple

import mujoco
import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..runtime.jit import njit, njit_inline
from ..runtime.numba_ext import borrowed, on_stack, unshared

if TYPE_CHECKING:
    from .fk import Bodies

Array = NDArray[np.float64]
Index = NDArray[np.int64]

PLANE, HFIELD, SPHERE, CAPSULE, ELLIPSOID, CYLINDER, BOX, MESH, SDF = (
    int(mujoco.mjtGeom.mjGEOM_PLANE), int(mujoco.mjtGeom.mjGEOM_HFIELD), int(mujoco.mjtGeom.mjGEOM_SPHERE),
    int(mujoco.mjtGeom.mjGEOM_CAPSULE), int(mujoco.mjtGeom.mjGEOM_ELLIPSOID), int(mujoco.mjtGeom.mjGEOM_CYLINDER),
    int(mujoco.mjtGeom.mjGEOM_BOX), int(mujoco.mjtGeom.mjGEOM_MESH), int(mujoco.mjtGeom.mjGEOM_SDF))


class Geoms(NamedTuple):
    """A model's geoms as the compiled code reads them (``ngeom`` geoms, MuJoCo's ids and conventions)."""

    type: Index  # (ngeom,) mjtGeom
    body: Index  # (ngeom,) body the geom is fixed to
    size: Array  # (ngeom, 3) MuJoCo's geom_size
    pos: Array  # (ngeom, 3) geom origin in its body frame
    rot: Array  # (ngeom, 3, 3) geom axes in its body frame
    rbound: Array  # (ngeom,) bounding-sphere radius about the origin (0 for planes: unbounded)
    margin: Array  # (ngeom,) MuJoCo's geom_margin
    box: Array  # (ngeom, 6) MuJoCo's geom_aabb: the centre and half-sizes of a box about the geom, its own axes
    # a mesh geom's convex hull, which is what MuJoCo collides (:func:`hulls`): vertices hull_adr[g] .. + hull_num[g]
    hull_adr: Index  # (ngeom,) first vertex of geom g's hull in hull_vert (0 and hull_num 0 for other geoms)
    hull_num: Index  # (ngeom,)
    hull_vert: Array  # (H, 3) hull vertices, each in its geom's frame
    hull_nbr_adr: Index  # (H + 1,) vertex v's neighbours on its hull: hull_nbr[hull_nbr_adr[v]:hull_nbr_adr[v + 1]]
    hull_nbr: Index  # (E,) vertex ids into hull_vert; a hull without them is searched vertex by vertex
    hull_dir: Index  # (ngeom, DIRS) geom g's hull vertex (an id into hull_vert) farthest along each of
    # :func:`direction_cell`'s cells' centres, in its own frame: a climb to the farthest along v starts there


def geom_arrays(model: mujoco.MjModel) -> Geoms:
    """The :class:`Geoms` of a compiled model (a :class:`mjkin.Tree` keeps them as ``tree.geoms``)."""
    n = model.ngeom
    rot = np.empty((n, 9))
    for g in range(n):
        q = np.asarray(model.geom_quat[g], dtype=np.float64)
        mujoco.mju_quat2Mat(rot[g], q / np.linalg.norm(q))
    return Geoms(np.array(model.geom_type, dtype=np.int64), np.array(model.geom_bodyid, dtype=np.int64),
                 np.array(model.geom_size, dtype=np.float64).reshape(n, 3),
                 np.array(model.geom_pos, dtype=np.float64).reshape(n, 3), rot.reshape(n, 3, 3),
                 np.array(model.geom_rbound, dtype=np.float64), np.array(model.geom_margin, dtype=np.float64),
                 np.array(model.geom_aabb, dtype=np.float64).reshape(n, 6), *hulls(model))


def _mesh_hull(model: mujoco.MjModel, mesh: int) -> tuple[Array, Index, Index]:
    """A mesh's convex hull: its vertices ``(h, 3)`` (the mesh's frame, which is its geoms') and each one's
    neighbours as ``adr (h + 1,)`` into ``nbr`` (local ids).

    MuJoCo's own hull when it made one (``mesh_graph``, made for every mesh a geom collides with, honouring
    ``maxhullvert``; laid out as ``numvert, numface, vert_edgeadr[numvert], vert_globalid[numvert],
    edge_localid[numvert + 3 numface] (each vertex's neighbours, -1 after the last), face_globalid[3 numface]``),
    else every vertex with no neighbours (searched one by one; MuJoCo makes no hull for a mesh no geom of which
    collides, and such a geom is measured only when a caller names it).
    """  # noqa: D205
    adr, num = int(model.mesh_vertadr[mesh]), int(model.mesh_vertnum[mesh])
    vert = np.asarray(model.mesh_vert[adr:adr + num], dtype=np.float64)
    gadr = int(model.mesh_graphadr[mesh])
    if gadr < 0:
        return vert, np.zeros(num + 1, dtype=np.int64), np.zeros(0, dtype=np.int64)
    graph = np.asarray(model.mesh_graph, dtype=np.int64)
    nv, nf = int(graph[gadr]), int(graph[gadr + 1])
    start = graph[gadr + 2:gadr + 2 + nv]
    ids = graph[gadr + 2 + nv:gadr + 2 + 2 * nv]
    local = graph[gadr + 2 + 2 * nv:gadr + 2 + 2 * nv + nv + 3 * nf]
    ends = np.flatnonzero(local < 0)
    stop = ends[np.searchsorted(ends, start)]  # each vertex's list ends at the first -1 from its start
    count = stop - start
    nbr = local[np.repeat(start, count) + (np.arange(count.sum()) - np.repeat(np.cumsum(count) - count, count))]
    return vert[ids], np.concatenate([[0], np.cumsum(count)]).astype(np.int64), nbr


CELLS = 8  # a cube face's cells along each side: DIRS = 6 CELLS² directions a hull's farthest vertex is kept for
DIRS = 6 * CELLS * CELLS


@njit_inline
def direction_cell(x: float, y: float, z: float) -> int:
    """The cell (``0 .. DIRS - 1``) of the direction ``(x, y, z)`` (any length, not 0) on the cube about the origin:
    its face (the axis of its largest part, signed), then its place on the face in a ``CELLS x CELLS`` grid.
    """  # noqa: D205
    ax, ay, az = abs(x), abs(y), abs(z)
    if ax >= ay and ax >= az:
        face, m, s, t = 0 if x >= 0.0 else 1, ax, y, z
    elif ay >= az:
        face, m, s, t = 2 if y >= 0.0 else 3, ay, z, x
    else:
        face, m, s, t = 4 if z >= 0.0 else 5, az, x, y
    i = min(int((s / m + 1.0) * (0.5 * CELLS)), CELLS - 1)
    j = min(int((t / m + 1.0) * (0.5 * CELLS)), CELLS - 1)
    return (face * CELLS + i) * CELLS + j


def cell_centres() -> Array:
    """The unit directions ``(DIRS, 3)`` through the centres of :func:`direction_cell`'s cells, in its order."""
    mid = -1.0 + (np.arange(CELLS) + 0.5) * (2.0 / CELLS)
    s, t = (a.ravel() for a in np.meshgrid(mid, mid, indexing="ij"))
    one = np.ones(CELLS * CELLS)
    faces = []
    for axis in range(3):
        for sign in (1.0, -1.0):
            d = np.empty((CELLS * CELLS, 3))
            d[:, axis], d[:, (axis + 1) % 3], d[:, (axis + 2) % 3] = sign * one, s, t
            faces.append(d)
    d = np.concatenate(faces)
    return d / np.linalg.norm(d, axis=1, keepdims=True)


def hulls(model: mujoco.MjModel) -> tuple[Index, Index, Array, Index, Index, Index]:
    """The mesh geoms' convex hulls as :class:`Geoms` keeps them: ``hull_adr``, ``hull_num``, ``hull_vert``,
    ``hull_nbr_adr``, ``hull_nbr``, ``hull_dir`` (each mesh's hull once, shared by its geoms).
    """  # noqa: D205
    n = model.ngeom
    adr, num = np.zeros(n, dtype=np.int64), np.zeros(n, dtype=np.int64)
    verts: list[Array] = [np.zeros((0, 3))]
    counts: list[Index] = [np.zeros(0, dtype=np.int64)]
    nbrs: list[Index] = [np.zeros(0, dtype=np.int64)]
    done: dict[int, tuple[int, int, Index]] = {}  # mesh: its hull's first vertex, count, farthest along the cells
    far = np.zeros((n, DIRS), dtype=np.int64)
    centres = cell_centres()
    total = 0
    for g in range(n):
        mesh = int(model.geom_dataid[g])
        if model.geom_type[g] != MESH or mesh < 0:
            continue
        if mesh not in done:
            v, a, nb = _mesh_hull(model, mesh)
            done[mesh] = (total, len(v), total + np.argmax(v @ centres.T, axis=0))
            verts.append(v)
            counts.append(np.diff(a))
            nbrs.append(nb + total)
            total += len(v)
        adr[g], num[g], far[g] = done[mesh]
    nbr_adr = np.concatenate([[0], np.cumsum(np.concatenate(counts))]).astype(np.int64)
    return (adr, num, np.ascontiguousarray(np.concatenate(verts)), nbr_adr,
            np.ascontiguousarray(np.concatenate(nbrs), dtype=np.int64), far)


def contact_pairs(tree: Bodies) -> Index:
    """Geom pairs ``(P, 2)`` MuJoCo's collision tests, each once, ``g1 < g2`` for the pairs it makes itself.

    As ``mj_collision``: a pair of geoms on bodies that are not welded together
    (the world and everything welded to it count as one), nor parent and child
    of each other's weld bodies (unless ``disableflags`` has ``filterparent``),
    whose ``contype``/``conaffinity`` match, and whose bodies are not an
    ``<exclude>`` pair; then every explicit ``<pair>``. Pairs with no MuJoCo
    collision function (plane–plane, plane–height field, height field–height
    field) are left out.
    """
    m = tree.model
    body = np.asarray(m.geom_bodyid, dtype=np.int64)
    weld_of = np.asarray(m.body_weldid, dtype=np.int64)
    weld = weld_of[body]
    parent_weld = weld_of[np.asarray(m.body_parentid)[weld]]
    g1, g2 = np.triu_indices(m.ngeom, 1)
    contype, affinity = np.asarray(m.geom_contype), np.asarray(m.geom_conaffinity)
    ok = ((contype[g1] & affinity[g2]) | (contype[g2] & affinity[g1])) != 0
    ok &= weld[g1] != weld[g2]
    if not m.opt.disableflags & mujoco.mjtDisableBit.mjDSBL_FILTERPARENT:
        both = (weld[g1] != 0) & (weld[g2] != 0)
        ok &= ~(both & ((weld[g1] == parent_weld[g2]) | (parent_weld[g1] == weld[g2])))
    if m.nexclude:  # signature (body1 << 16) + body2, body1 < body2
        lo, hi = np.minimum(body[g1], body[g2]), np.maximum(body[g1], body[g2])
        ok &= ~np.isin((lo << 16) + hi, np.asarray(m.exclude_signature, dtype=np.int64))
    kind = np.asarray(m.geom_type)
    flat = (kind == PLANE) | (kind == HFIELD)
    ok &= ~(flat[g1] & flat[g2])
    pairs = np.stack([g1[ok], g2[ok]], 1)
    if m.npair:
        explicit = np.stack([m.pair_geom1, m.pair_geom2], 1).astype(np.int64)
        explicit = explicit[~(flat[explicit[:, 0]] & flat[explicit[:, 1]])]
        known = {(int(a), int(b)) for a, b in pairs}
        new = [i for i, (a, b) in enumerate(explicit.tolist()) if (a, b) not in known and (b, a) not in known]
        pairs = np.concatenate([pairs, explicit[new]])
    return np.ascontiguousarray(pairs, dtype=np.int64)


@njit
def native(t1: int, t2: int) -> bool:
    """Whether :func:`pair_distance` computes a pair of geom types itself (else it returns NaN)."""
    a, b = min(t1, t2), max(t1, t2)
    return (a == PLANE or SPHERE <= a <= MESH) and SPHERE <= b <= MESH


def native_pairs(geoms: Geoms, pairs: ArrayLike) -> NDArray[np.bool_]:
    """Which pairs ``(P, 2)`` :func:`pair_distance` computes (the others need :func:`fallback_distance`)."""
    p = np.asarray(pairs, dtype=np.int64).reshape(-1, 2)
    return np.array([native(geoms.type[a], geoms.type[b]) for a, b in p], dtype=bool)


@njit_inline
def geom_world(geoms: Geoms, rot: Array, pos: Array, g: int, R: Array, x: Array) -> None:
    """World axes ``R (3, 3)`` and origin ``x (3,)`` of geom ``g`` from FK output 0."""
    bd = geoms.body[g]
    for i in range(3):
        for k in range(3):
            R[i, k] = rot[0, bd, i, 0] * geoms.rot[g, 0, k] + rot[0, bd, i, 1] * geoms.rot[g, 1, k] + (
                rot[0, bd, i, 2] * geoms.rot[g, 2, k])
        x[i] = pos[0, bd, i] + (rot[0, bd, i, 0] * geoms.pos[g, 0] + rot[0, bd, i, 1] * geoms.pos[g, 1]
                                + rot[0, bd, i, 2] * geoms.pos[g, 2])


@njit_inline
def _box_radius(box: Array, g: int) -> float:
    """The radius of the sphere about geom ``g``'s box (``box``, see :class:`Geoms`) through its corners."""
    return np.sqrt(box[g, 3] * box[g, 3] + box[g, 4] * box[g, 4] + box[g, 5] * box[g, 5])


@njit_inline
def _box_gap(W: Array, box: Array, g1: int, g2: int, ax: Array) -> float:
    """A lower bound (m) of the distance between geoms ``g1`` and ``g2``: their boxes' (``box``, placed by ``W``,
    see :func:`near_pairs`) largest separation over the 15 separating axes (0 or less where the boxes overlap).
    """  # noqa: D205
    d0, d1, d2 = W[g2, 9] - W[g1, 9], W[g2, 10] - W[g1, 10], W[g2, 11] - W[g1, 11]  # centre to centre
    for j in range(3):  # the boxes' centres are their geoms' origins moved along the geoms' axes
        d0 += W[g2, j] * box[g2, j] - W[g1, j] * box[g1, j]
        d1 += W[g2, 3 + j] * box[g2, j] - W[g1, 3 + j] * box[g1, j]
        d2 += W[g2, 6 + j] * box[g2, j] - W[g1, 6 + j] * box[g1, j]
    best = -np.inf
    for k in range(15):
        if k < 3:
            for i in range(3):
                ax[i] = W[g1, 3 * i + k]
        elif k < 6:
            for i in range(3):
                ax[i] = W[g2, 3 * i + k - 3]
        else:
            a, b = (k - 6) // 3, (k - 6) % 3
            ax[0] = W[g1, 3 + a] * W[g2, 6 + b] - W[g1, 6 + a] * W[g2, 3 + b]
            ax[1] = W[g1, 6 + a] * W[g2, b] - W[g1, a] * W[g2, 6 + b]
            ax[2] = W[g1, a] * W[g2, 3 + b] - W[g1, 3 + a] * W[g2, b]
            norm = np.sqrt(ax[0] * ax[0] + ax[1] * ax[1] + ax[2] * ax[2])
            if norm < 1e-9:
                continue
            for i in range(3):
                ax[i] /= norm
        sep = abs(d0 * ax[0] + d1 * ax[1] + d2 * ax[2])
        for j in range(3):
            sep -= box[g1, 3 + j] * abs(W[g1, j] * ax[0] + W[g1, 3 + j] * ax[1] + W[g1, 6 + j] * ax[2])
            sep -= box[g2, 3 + j] * abs(W[g2, j] * ax[0] + W[g2, 3 + j] * ax[1] + W[g2, 6 + j] * ax[2])
        if sep > best:
            best = sep
    return best


@njit
def near_pairs(geoms: Geoms, rot: Array, pos: Array, pairs: Index, reach: float, out: Index, low: Array) -> int:
    """Pairs that may come within ``reach`` (m) of each other, for one configuration's FK.

    Writes the indices into ``pairs (P, 2)`` of those pairs to ``out[:k]``, a lower bound (m) of each one's
    distance to ``low[:k]``, and returns ``k``: those whose bounding spheres (about the geom's origin, and
    about its box's centre) come within ``reach`` and whose boxes (MuJoCo's ``geom_aabb`` in each geom's axes)
    too, by the separating axes. Every pair whose geoms are within ``reach`` is among them. A plane (unbounded)
    counts the other geom's bounding sphere's height above it. Pass ``reach`` = the clearance margin plus a
    slack for how far the geoms may move before the next call.
    """
    geoms, rot, pos, pairs, out, low = borrowed((geoms, rot, pos, pairs, out, low))
    ng = geoms.type.shape[0]
    # per geom: world axes (9), origin (3), placed yet (1), its box's centre (3); then an axis. A mesh's origin
    # is often its joint, far from its middle: the sphere about its box's centre is the tighter one (the G1's
    # meshes: a third of the pairs the origin's sphere let through)
    S = on_stack(16 * ng + 3)
    for g in range(ng):
        S[16 * g + 12] = 0.0
    for p in range(pairs.shape[0]):  # each geom placed once, not once per pair
        for g in (pairs[p, 0], pairs[p, 1]):
            if S[16 * g + 12] == 0.0:
                S[16 * g + 12] = 1.0
                geom_world(geoms, rot, pos, g, unshared(S, 16 * g, (3, 3)), unshared(S, 16 * g + 9, (3,)))
                for i in range(3):
                    S[16 * g + 13 + i] = S[16 * g + 9 + i] + (S[16 * g + 3 * i] * geoms.box[g, 0] + S[
                        16 * g + 3 * i + 1] * geoms.box[g, 1] + S[16 * g + 3 * i + 2] * geoms.box[g, 2])
    W = unshared(S, 0, (ng, 16))  # a plane's normal: its z axis, W[g, 2], W[g, 5], W[g, 8]; its origin W[g, 9:12]
    ax = unshared(S, 16 * ng, (3,))
    k = 0
    for p in range(pairs.shape[0]):
        g1, g2 = pairs[p, 0], pairs[p, 1]
        plane = geoms.type[g1] == PLANE or geoms.type[g2] == PLANE
        if plane:
            a, b = (g1, g2) if geoms.type[g1] == PLANE else (g2, g1)  # a: the plane
            gap = W[a, 2] * (W[b, 9] - W[a, 9]) + W[a, 5] * (W[b, 10] - W[a, 10]) + W[a, 8] * (W[b, 11] - W[a, 11])
            gap -= geoms.rbound[b]
        else:
            gap = np.sqrt((W[g2, 9] - W[g1, 9]) ** 2 + (W[g2, 10] - W[g1, 10]) ** 2 + (W[g2, 11] - W[g1, 11]) ** 2) - (
                geoms.rbound[g1] + geoms.rbound[g2])
            if gap <= reach:
                gap = max(gap, np.sqrt((W[g2, 13] - W[g1, 13]) ** 2 + (W[g2, 14] - W[g1, 14]) ** 2 + (
                    W[g2, 15] - W[g1, 15]) ** 2) - _box_radius(geoms.box, g1) - _box_radius(geoms.box, g2))
            if gap <= reach:
                gap = max(gap, _box_gap(W, geoms.box, g1, g2, ax))
        if gap <= reach:
            out[k] = p
            low[k] = gap
            k += 1
    return k
