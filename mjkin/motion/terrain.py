"""The ground a retargeted figure walks on: a scene's world geoms, and the height and slope under points.

A scene is an MJCF file whose world geoms are the ground: a floor with ramps and steps, or a
Menagerie-style ``scene.xml``. :meth:`Terrain.load` keeps what is fixed to the world (geoms of the
world body and of bodies without joints) and drops every moving body with what refers to it
(actuators, sensors, tendons, equalities, keyframes), so an included robot goes; the ground is the
kept geoms that collide (``contype`` or ``conaffinity`` set). Without a scene the ground is the
plane z = 0 (:meth:`Terrain.flat`).

Heights come from MuJoCo's ray casts (``mj_ray`` on the model of the scene alone), straight down
from :data:`HEADROOM` above each point: the first ground surface under it, and its normal. Over
nothing but level planes no ray is needed, and a broad phase (:meth:`Terrain.ceiling`: the tops of
the geoms' world boxes over a point) skips the casts for points above all the ground under them.

A foot is seen by :func:`foot_points`: points in its body frame with a radius each, whose lowest
points (the point less its radius, straight down) bound its collision geoms from below in any pose.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from functools import lru_cache

import mujoco
import numpy as np
from numpy.typing import NDArray

from ..errors import InputError, ModelError
from ..kinematics.assets import check_named_files
from ..kinematics.geoms import BOX, CAPSULE, CYLINDER, ELLIPSOID, MESH, PLANE, SPHERE
from ..kinematics.tree import Tree
from ..runtime import files

Array = NDArray[np.float64]
HEADROOM = 0.5  # m: rays start this far above a point, so ground up to this much above it is found
TEXT_SOURCE = "<xml>"  # a scene's source when it was given as XML text
FAR = 1e9  # m: how far an unbounded plane reaches
SPACING = 0.04  # m between a foot's sample points (a flat foot clears an edge it overlaps by more than this)
UP = np.array([0.0, 0.0, 1.0])
FLAT_XML = '<mujoco model="flat floor"><worldbody><geom name="floor" type="plane" size="0 0 1"/></worldbody></mujoco>'
_STRIPPED = ("actuators", "sensors", "tendons", "equalities", "keys", "excludes", "pairs")
_DEFAULT_RGBA = (0.5, 0.5, 0.5, 1.0)  # MuJoCo's geom rgba: a geom with it and a material takes the material's


@dataclass(frozen=True, eq=False)
class Terrain:
    """The ground: ``model`` holds the scene's fixed geoms alone, ``ground`` the ids of those feet stand on.

    ``source`` is the scene file ("" for the flat floor). ``box_lo``/``box_hi`` ``(G, 3)`` are the ground
    geoms' world boxes (a plane's is its rectangle's, unbounded along a size of 0); ``up (G,)`` marks the
    planes facing straight up, whose heights need no ray; ``floor`` is the height of the highest of them, if any.
    ``colors (ngeom, 4)`` are every geom's RGBA as drawn (a material's where it has one; alpha 0 for the
    groups hidden by default, 3 to 5); the model's own colours only say what rays see (the ground).
    """

    model: mujoco.MjModel
    data: mujoco.MjData
    source: str
    ground: NDArray[np.int64]
    box_lo: Array
    box_hi: Array
    up: NDArray[np.bool_]
    floor: float | None
    colors: NDArray[np.float32]

    @classmethod
    def flat(cls) -> Terrain:
        """The plane z = 0, what the figure walks on without a scene."""
        return _flat()

    @classmethod
    def load(cls, source: str | os.PathLike[str]) -> Terrain:
        """The ground of an MJCF scene file (or XML text); files are read once per change.

        Raises:
            MjkinIOError: the file is missing or unreadable.
            ModelError: MuJoCo cannot compile it.
            InputError: it has no fixed geom that collides (nothing to stand on).
        """
        text = os.fspath(source)
        if text.lstrip().startswith("<"):
            return _build(_strip(_spec(text)), TEXT_SOURCE)
        files.check_input(text, "scene file", files.LIMITS["model"],
                          hint="give an MJCF file whose world geoms are the ground")
        check_named_files(text, "scene file")
        return _load_file(text)

    def _over(self, lo: Array, hi: Array) -> NDArray[np.bool_]:
        """``(N, G)``: which ground geoms' world boxes overlap the boxes from ``lo (N, 2)`` to ``hi (N, 2)`` across."""
        return np.all((self.box_lo[None, :, :2] <= hi[:, None]) & (self.box_hi[None, :, :2] >= lo[:, None]), axis=-1)

    def ceiling(self, lo: Array, hi: Array) -> Array:
        """An upper bound ``(N,)`` of the ground's height over each box from ``lo (N, 2)`` to ``hi (N, 2)``.

        The highest top of the ground geoms whose world boxes overlap it; -inf where none does.
        """
        return np.where(self._over(lo, hi), self.box_hi[None, :, 2], -np.inf).max(axis=1, initial=-np.inf)

    def under(self, points: Array) -> tuple[Array, Array]:
        """Heights ``(N,)`` (m) and normals ``(N, 3)`` of the ground straight under ``points (N, 3)``.

        Each is where a ray cast down from :data:`HEADROOM` above the point first meets a ground
        geom (``mj_ray``; over nothing but planes facing up, their height, with no ray); where none
        does, the height is -inf and the normal straight up.
        """
        pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        start = pts + HEADROOM * UP
        over = self._over(pts[:, :2], pts[:, :2])
        below = over & self.up[None] & (self.box_hi[None, :, 2] <= start[:, 2:])
        height = np.where(below, self.box_hi[None, :, 2], -np.inf).max(axis=1, initial=-np.inf)
        normal = np.tile(UP, (len(pts), 1))
        down, hit, n = -UP, np.zeros(1, np.int32), np.zeros(3)
        m, d = self.model, self.data
        for k in np.flatnonzero((over & ~self.up[None]).any(axis=1)):
            dist = mujoco.mj_ray(m, d, start[k], down, None, 1, -1, hit, n)
            if dist >= 0:
                height[k] = start[k, 2] - dist
                normal[k] = n
        return height, normal

    def planes(self, centres: Array, radius: Array) -> tuple[Array, Array]:
        """A ground plane for each ball ``(centres (N, 3), radius (N,))`` its centre must keep ``radius`` above.

        Points ``(N, 3)`` and unit normals ``(N, 3)``: the tangent plane of the ground under the ball's
        lowest point, moved ``radius`` out; a ball above :meth:`ceiling` gets the level plane there (the
        ground is lower), and one with no ground under it a plane a metre under it (no limit).
        """
        low = centres - radius[:, None] * UP
        top = self.ceiling(low[:, :2], low[:, :2])
        point, normal = low.copy(), np.tile(UP, (len(low), 1))
        point[:, 2] = np.where(np.isfinite(top), top, low[:, 2] - 1.0)
        near = low[:, 2] < top
        if near.any():
            h, n = self.under(low[near])
            found = np.isfinite(h)
            point[near, 2] = np.where(found, h, low[near, 2] - 1.0)
            normal[near] = n
        return point + radius[:, None] * normal, normal

    def lift(self, low: Array) -> Array:
        """How far ``(N,)`` (m, >= 0) each set of points ``low (N, P, 3)`` must rise to be on or above the ground
        straight under each point (the broad phase first: points above every ground they could stand on need no ray).
        """  # noqa: D205
        flat = low.reshape(-1, 3)
        near = np.flatnonzero(flat[:, 2] < self.ceiling(flat[:, :2], flat[:, :2]))
        depth = np.zeros(len(flat))
        depth[near] = self.under(flat[near])[0] - flat[near, 2]
        return np.maximum(depth.reshape(low.shape[:-1]), 0.0).max(axis=-1, initial=0.0)


@lru_cache(maxsize=1)
def _flat() -> Terrain:
    return _build(_spec(FLAT_XML), "")


@files.per_file(maxsize=8)
def _load_file(path: str) -> Terrain:
    return _build(_strip(_spec(path)), path)


def _spec(source: str) -> mujoco.MjSpec:
    """The scene's spec from a file path or XML text; a one-line :class:`ModelError` if MuJoCo cannot read it."""
    try:
        return (mujoco.MjSpec.from_string(source) if source.lstrip().startswith("<")
                else mujoco.MjSpec.from_file(source))
    except (ValueError, mujoco.FatalError) as e:
        raise ModelError(f"cannot read scene {_name(source)}: {' '.join(str(e).split())}") from None


def _name(source: str) -> str:
    return repr(source if not source.lstrip().startswith("<") else source.lstrip()[:40] + "...")


def _strip(spec: mujoco.MjSpec) -> mujoco.MjSpec:
    """``spec`` without its moving bodies (any with a joint or mocap, and what hangs from them) and what refers to
    them.
    """  # noqa: D205
    for kind in _STRIPPED:
        for element in list(getattr(spec, kind)):
            spec.delete(element)

    def prune(body: mujoco.MjsBody) -> None:
        for child in list(body.bodies):
            if child.joints or child.mocap:
                spec.delete(child)
            else:
                prune(child)

    prune(spec.worldbody)
    used = {g.meshname for g in spec.geoms}
    for mesh in list(spec.meshes):  # a dropped robot's meshes need not be read
        if mesh.name not in used:
            spec.delete(mesh)
    return spec


def _build(spec: mujoco.MjSpec, source: str) -> Terrain:
    """Compile the stripped scene and find its ground and the ground's world boxes."""
    try:
        model = spec.compile()
    except (ValueError, mujoco.FatalError) as e:
        raise ModelError(f"cannot compile scene {_name(source)}: {' '.join(str(e).split())}") from None
    data = mujoco.MjData(model)
    mujoco.mj_kinematics(model, data)
    fixed = model.body_weldid[model.geom_bodyid] == 0
    ground = np.flatnonzero(fixed & ((model.geom_contype != 0) | (model.geom_conaffinity != 0))).astype(np.int64)
    if not len(ground):
        raise InputError(f"scene {_name(source)} has no ground: give it world geoms that collide (contype or "
                         "conaffinity not 0), such as a plane or boxes")
    R = data.geom_xmat[ground].reshape(-1, 3, 3)
    aabb = model.geom_aabb[ground].copy()  # centre and half sizes in the geom's frame
    plane = model.geom_type[ground] == PLANE
    size = model.geom_size[ground]
    aabb[plane] = np.column_stack([np.zeros((plane.sum(), 3)), np.where(size[plane, :2] > 0, size[plane, :2], FAR),
                                   np.zeros(plane.sum())])  # a plane is its rectangle; size 0: unbounded that way
    half = np.einsum("gij,gj->gi", np.abs(R), aabb[:, 3:])
    centre = data.geom_xpos[ground] + np.einsum("gij,gj->gi", R, aabb[:, :3])
    lo, hi = centre - half, centre + half
    up = plane & (R[:, 2, 2] > 1 - 1e-9)  # a plane's normal is its z axis
    floor = float(hi[up, 2].max()) if up.any() else None
    colors = model.geom_rgba.copy()
    own = (model.geom_matid >= 0) & np.all(np.isclose(colors, _DEFAULT_RGBA), axis=1)  # as MuJoCo draws them
    colors[own] = model.mat_rgba[model.geom_matid[own]]
    colors[model.geom_group >= 3, 3] = 0.0
    # the ray model sees the ground alone: every other geom invisible to mj_ray, the ground opaque
    model.geom_matid[:] = -1
    model.geom_rgba[:, 3] = 0.0
    model.geom_rgba[ground, 3] = 1.0
    return Terrain(model, data, source, ground, lo, hi, up, floor, colors)


# ---------------------------------------------------------------------------------------------- the feet
def _geom_points(kind: int, size: Array, vert: Array | None, spacing: float) -> tuple[Array, Array]:
    """Points ``(P, 3)`` in a geom's frame and radii ``(P,)`` whose balls' lowest points bound it from below."""
    def steps(half: float) -> Array:
        return np.linspace(-half, half, int(np.ceil(2 * half / spacing)) + 1)

    if kind == SPHERE:
        return np.zeros((1, 3)), size[:1].copy()
    if kind == CAPSULE:
        z = steps(size[1])
        return np.column_stack([np.zeros_like(z), np.zeros_like(z), z]), np.full(len(z), size[0])
    if kind == BOX:  # every face's grid, corners included
        pts = []
        for a in range(3):
            b, c = [i for i in range(3) if i != a]
            u, v = np.meshgrid(steps(size[b]), steps(size[c]), indexing="ij")
            for sign in (-1.0, 1.0):
                face = np.zeros((u.size, 3))
                face[:, a], face[:, b], face[:, c] = sign * size[a], u.ravel(), v.ravel()
                pts.append(face)
        box = np.unique(np.concatenate(pts), axis=0)
        return box, np.zeros(len(box))
    if kind == CYLINDER:
        turn = np.linspace(0.0, 2 * np.pi, max(8, int(np.ceil(2 * np.pi * size[0] / spacing))), endpoint=False)
        rim = np.column_stack([size[0] * np.cos(turn), size[0] * np.sin(turn)])
        z = steps(size[1])
        cyl = np.concatenate([np.column_stack([np.tile(rim, (len(z), 1)), np.repeat(z, len(rim))]),
                              np.column_stack([np.zeros((2, 2)), [-size[1], size[1]]])])
        return cyl, np.zeros(len(cyl))
    if kind == ELLIPSOID:  # a Fibonacci sphere, stretched
        n = max(16, int(np.ceil(4 * np.pi * size.max() ** 2 / spacing ** 2)))
        z = 1 - (2 * np.arange(n) + 1) / n
        turn = np.pi * (3 - np.sqrt(5)) * np.arange(n)
        r = np.sqrt(1 - z ** 2)
        return np.column_stack([r * np.cos(turn), r * np.sin(turn), z]) * size, np.zeros(n)
    if kind == MESH and vert is not None:
        return vert, np.zeros(len(vert))
    raise InputError(f"a foot geom of type {mujoco.mjtGeom(kind).name} cannot be stood on; give the foot boxes, "
                     "spheres, capsules, cylinders, ellipsoids or meshes")


def foot_points(tree: Tree, body: str, spacing: float = SPACING) -> tuple[Array, Array]:
    """A foot body's collision geoms as balls: centres ``(P, 3)`` in its frame and radii ``(P,)`` (m).

    Spheres and capsules are their centres (along the axis) with their radius; boxes, cylinders,
    ellipsoids and meshes points on their surface (meshes their vertices), radius 0, thinned to one
    a ``spacing`` cell (the lowest); only the lower half (in the body frame: a foot is never upside
    down). In any pose within a quarter turn of its own, the lowest of ``centre - radius * z`` is the
    geoms' lowest point (up to the spacing on round surfaces). Without a colliding geom, the body's
    visible geoms are taken.

    Raises:
        InputError: the body has no geom, or one of a kind a foot cannot stand on (a plane, a height field).
    """
    m = tree.model
    bid = tree.id(body, "body")
    mine = np.flatnonzero(m.geom_bodyid == bid)
    colliding = mine[(m.geom_contype[mine] != 0) | (m.geom_conaffinity[mine] != 0)]
    geoms = colliding if len(colliding) else mine
    if not len(geoms):
        raise InputError(f"foot {body!r} has no geom to stand on")
    centres, radii = [], []
    for g in geoms:
        kind = int(m.geom_type[g])
        vert = None
        if kind == MESH:
            a = m.mesh_vertadr[m.geom_dataid[g]]
            vert = np.asarray(m.mesh_vert[a:a + m.mesh_vertnum[m.geom_dataid[g]]], dtype=np.float64)
        p, r = _geom_points(kind, np.asarray(m.geom_size[g], dtype=np.float64), vert, spacing)
        R = np.empty(9)
        mujoco.mju_quat2Mat(R, m.geom_quat[g])
        centres.append(p @ R.reshape(3, 3).T + m.geom_pos[g])
        radii.append(r)
    pts, rad = np.concatenate(centres), np.concatenate(radii)
    surface = np.flatnonzero(rad == 0)  # balls are few and kept; surface points thinned, the lowest a cell kept
    cell = np.floor(pts[surface] / spacing).astype(np.int64)
    order = np.lexsort((pts[surface, 2], *cell.T[::-1]))  # by cell, lowest first in each
    _, first = np.unique(cell[order], axis=0, return_index=True)
    keep = np.sort(np.concatenate([np.flatnonzero(rad > 0), surface[order[first]]]))
    low, high = pts[keep, 2] - rad[keep], pts[keep, 2] + rad[keep]
    keep = keep[low <= 0.5 * (low.min() + high.max())]
    return pts[keep], rad[keep]


def sole_corners(points: Array, radius: Array, band: float = 1e-3) -> tuple[Array, Array]:
    """The sole's corners, at most four of :func:`foot_points`' balls: the lowest layer's extremes.

    Of the balls whose lowest points lie within ``band`` (m) of the lowest (body frame), those
    furthest front-left, front-right, back-left and back-right, each once.
    """
    low = points[:, 2] - radius
    layer = np.flatnonzero(low <= low.min() + band)
    xy = points[layer, :2]
    picks = [layer[np.argmax(xy @ np.array(d))] for d in ((1.0, 1.0), (1.0, -1.0), (-1.0, 1.0), (-1.0, -1.0))]
    keep = list(dict.fromkeys(picks))
    return points[keep], radius[keep]


def lowest(T: Array, points: Array, radius: Array) -> Array:
    """World lowest points ``(..., P, 3)`` of balls (``points (P, 3)`` in a body, ``radius (P,)``) on bodies posed
    ``T (..., 4, 4)``.
    """  # noqa: D205
    out = np.einsum("...ij,pj->...pi", T[..., :3, :3], points) + T[..., None, :3, 3]
    out[..., 2] -= radius
    return out
