"""Offscreen frames of posed figures with goal markers, effector trails and captions, and videos.

Rendering goes through ``mujoco.Renderer`` (headless: ``MUJOCO_GL=egl``). The
default camera frames every geom of the figure, over all frames, with a margin
(:data:`MARGIN` of the image on each side): it looks at the figure's centre, from
the side for planar chains (along their joint axis), and follows a figure that
travels (a walk) with a smoothed, fixed-distance tracking shot. Markers and the
trail are decoration (no shadows), and so are planes (floors) in the shadow pass:
a floor cannot shadow what stands on it, and its own depth in MuJoCo's shadow map
speckled it with black dots where it shadowed itself. The trail is decimated to at most
``Overlay.trail_points`` points, so every frame costs the same however long the
video. Frames are made one at a time and go straight to the encoder (ffmpeg via
imageio-ffmpeg, for .mp4 and .gif), so memory does not grow with the length of
a clip; the video is written to a temporary file that is renamed when complete.

Every model is staged (:class:`Stage`) in one look, MuJoCo Menagerie's scene.xml, without changing
the model, its poses or contacts: a sky gradient in place of its skybox (or the black of none), a
checker floor sized to the figure in place of its floor planes (at their height; under the figure when
it has none), Menagerie's headlight, and a light from above when it has no light of its own (its own
lights are kept). A body with nothing visible shows its hidden geoms (collision shapes, group 3 and
up), and links still bare get capsule bones between their bodies' origins. These are changes to each
frame's scene, as the markers are; ``Painter(stage=False)`` draws the model exactly as it says.

A figure drawn on a scene (``terrain``: :class:`mjkin.motion.terrain.Terrain`, the ground it was
retargeted onto) stands among the scene's geoms in place of its own model's world geoms: the scene's
highest plane facing up as the checker floor, its other geoms in their colours (meshes and height
fields as their bounding boxes: a frame's scene holds only the figure model's meshes).
"""

from __future__ import annotations

import itertools
import os
import sys
import threading
from collections.abc import Callable, Iterable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import mujoco
import numpy as np
from numpy.typing import ArrayLike, NDArray

from . import spatial
from .errors import InputError, MjkinIOError
from .kinematics.qspace import BALL, FREE, HINGE
from .kinematics.tree import Tree, check_tree
from .runtime.checks import check_count, check_number
from .runtime.files import as_path, atomic_path
from .runtime.progress import track
from .scene import Scene

if TYPE_CHECKING:
    from PIL import ImageFont

    from .motion.terrain import Terrain

VIDEO_SUFFIXES = (".mp4", ".gif")
MARGIN = 0.07  # the camera keeps the figure this fraction of the image away from every edge (≥ 5 % asked)
CAMERA_CHUNK = 256  # frames whose bounding points are made at once while placing the camera
SIDE_VIEW = (135.0, -20.0)  # azimuth, elevation (degrees) for figures that are not planar chains
WALK_VIEW = (90.0, -8.0)  # from the figure's right side, world x (the walking direction) to the right
Caption = str | Sequence[str] | Callable[[int], str] | None
HEADLIGHT = (0.3, 0.6, 0.0)  # ambient, diffuse, specular of the headlight of every staged model (Menagerie's scene.xml)
TOP_LIGHT = 0.7  # diffuse of the light from above a staged model without lights gets (Menagerie's, MuJoCo's default)
FLOOR_RGBA = ((0.2, 0.3, 0.4, 1.0), (0.1, 0.2, 0.3, 1.0))  # checker squares (Menagerie's "groundplane")
FLOOR_GLOW = 0.1  # the floor's emission: lifts its squares where the lights graze it
SKY_RGB = ((0.3, 0.5, 0.7), (0.0, 0.0, 0.0))  # zenith and nadir of the sky gradient (Menagerie's "skybox")
BONE_RGBA = (0.7, 0.7, 0.72, 1.0)  # the colour of bones: Menagerie's "metallic"
SKY_BANDS = 32  # the sky is drawn as this many bands of the image, each of one colour
FLOOR_SQUARES = 200  # at most this many dark squares in the checker (larger squares for a figure that travels far)


@dataclass
class Overlay:
    """Things drawn into the scene: target points and bones between them, the trail of a frame (site/body) over
    time, captions.

    ``bones (k, 2)``: pairs of indices into a frame's ``n`` points, each drawn as a capsule of
    ``bone_radius`` (m) in ``point_rgba`` (a skeleton). ``caption`` is one text for every frame,
    one per frame, or a function of the frame index; it is drawn into the image's top-left corner.
    """  # noqa: D205

    points: NDArray[np.float64] = field(default_factory=lambda: np.zeros((0, 3)))  # (n, 3), or (T, n, 3) per frame
    point_size: float = 0.02
    point_rgba: tuple[float, float, float, float] = (0.95, 0.2, 0.2, 0.9)
    bones: NDArray[np.int64] = field(default_factory=lambda: np.zeros((0, 2), np.int64))
    bone_radius: float = 0.01
    trail: str | None = None  # name of the site or body whose path is drawn
    trail_rgba: tuple[float, float, float, float] = (0.1, 0.5, 0.95, 0.9)
    trail_width: float = 3.0  # line width in pixels on 640x480 (scaled with the frame)
    trail_points: int = 128  # the trail is decimated to at most this many points (+ the newest)
    caption: Caption = None


def _add(scene: mujoco.MjvScene, kind: int, size: ArrayLike, pos: ArrayLike, rgba: ArrayLike) -> mujoco.MjvGeom | None:
    """Append a decoration geom (it casts no shadow); None when the scene is full."""
    if scene.ngeom >= scene.maxgeom:
        return None
    g = scene.geoms[scene.ngeom]
    mujoco.mjv_initGeom(g, kind, np.asarray(size, dtype=np.float64), np.asarray(pos, dtype=np.float64),
                        np.eye(3).ravel(), np.asarray(rgba, dtype=np.float32))
    g.category = mujoco.mjtCatBit.mjCAT_DECOR  # decor geoms are left out of the shadow pass
    scene.ngeom += 1
    return g


def trail_indices(t: int, max_points: int) -> NDArray[np.int64]:
    """Frames ``0..t`` kept in the trail at frame ``t``: every ``s``-th and ``t`` itself, at most ``max_points + 1``.

    The stride ``s`` doubles whenever the count would pass ``max_points``, so the kept
    points stay the same between doublings (the polyline does not shimmer).
    """
    if max_points < 2:
        raise InputError(f"trail_points must be >= 2, got {max_points}")
    stride = 1
    while t // stride + 1 > max_points:
        stride *= 2
    idx = np.arange(0, t + 1, stride)
    return idx if idx[-1] == t else np.append(idx, t)


# ---------------------------------------------------------------------- camera
def shown_geoms(model: mujoco.MjModel) -> NDArray[np.bool_]:
    """``(ngeom,)``: the geoms a staged frame shows, drawn or not by default.

    Those visible by default (groups 0–2, not transparent), and the hidden ones (groups 3 and up,
    collision shapes; not transparent) of every moving body with no geom visible by default: a robot whose
    real shapes are only in its collision geoms shows them.
    """
    rgba = np.where((model.geom_matid >= 0)[:, None], model.mat_rgba[np.maximum(model.geom_matid, 0)],
                    model.geom_rgba) if model.nmat else model.geom_rgba
    opaque = rgba[:, 3] > 0
    visible = opaque & (model.geom_group < 3)
    seen = np.zeros(model.nbody, bool)
    seen[model.geom_bodyid[visible]] = True
    return visible | (opaque & (model.geom_bodyid > 0) & ~seen[model.geom_bodyid])


def figure_geoms(model: mujoco.MjModel) -> NDArray[np.int64]:
    """Geoms that make up the figure: :func:`shown_geoms`, no planes.

    Geoms of the moving bodies, and world geoms only where the figure stands on them
    (a pedestal: the root body's origin lies in the geom's box); the rest of the
    world (floors, arena walls, tables) is stage, not figure.
    """
    keep = (model.geom_type != mujoco.mjtGeom.mjGEOM_PLANE) & shown_geoms(model)
    roots = model.body_pos[1:][model.body_parentid[1:] == 0]
    for g in np.flatnonzero(keep & (model.geom_bodyid == 0)):
        R = spatial.quat_to_mat(spatial.quat_normalize(model.geom_quat[g]))
        local = (roots - model.geom_pos[g]) @ R - model.geom_aabb[g, :3]  # root origins in the geom's box frame
        half = 1.1 * model.geom_aabb[g, 3:] + 1e-6
        keep[g] = bool((np.abs(local) <= half).all(axis=-1).any())
    return np.flatnonzero(keep)


def geom_corners(tree: Tree, qs: ArrayLike) -> NDArray[np.float64]:
    """World corners of the bounding boxes of the figure's geoms, ``(..., G, 8, 3)``, by mjkin's FK."""
    m = tree.model
    ids = figure_geoms(m)
    aabb = m.geom_aabb[ids]  # centre and half sizes in the geom frame
    signs = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], dtype=np.float64)
    local = aabb[:, None, :3] + signs[None] * aabb[:, None, 3:]  # (G, 8, 3) in the geom frame
    R = spatial.quat_to_mat(spatial.quat_normalize(m.geom_quat[ids]))
    in_body = np.einsum("gij,gkj->gki", R, local) + m.geom_pos[ids][:, None]
    T = tree.fk(qs)[..., m.geom_bodyid[ids], :, :]  # (..., G, 4, 4)
    return np.einsum("...gij,gkj->...gki", T[..., :3, :3], in_body) + T[..., None, :3, 3]


def planar_axis(tree: Tree) -> NDArray[np.float64] | None:
    """The common joint axis (world, at ``qpos0``) of a planar chain — hinges all parallel, no ball or free joint."""
    kinds = tree.jnt_type
    if len(kinds) == 0 or np.isin(kinds, (BALL, FREE)).any() or not (kinds == HINGE).any():
        return None
    T = tree.fk(tree.qpos0)
    axes = np.einsum("jik,jk->ji", T[tree.jnt_body, :3, :3], tree.jnt_axis)
    hinge, slide = axes[kinds == HINGE], axes[kinds != HINGE]
    n = hinge[0] / np.linalg.norm(hinge[0])
    if np.linalg.norm(np.cross(hinge, n), axis=-1).max() > 1e-6 or (slide.size and np.abs(slide @ n).max() > 1e-6):
        return None
    return n


def _view_of(axis: NDArray[np.float64] | None) -> tuple[float, float]:
    """Azimuth and elevation (degrees) looking along ``axis`` (from above, image x along world x when possible)."""
    if axis is None:
        return SIDE_VIEW
    f = -axis if axis[2] > 1e-9 else axis  # look down onto it, or sideways
    if abs(f[2]) > 1 - 1e-9:
        return 90.0, -90.0 if f[2] < 0 else 90.0
    if abs(f[2]) < 1e-9 and np.cross(f, [0.0, 0.0, 1.0])[0] < 0:  # keep world x to the right
        f = -f
    return float(np.degrees(np.arctan2(f[1], f[0]))), float(np.degrees(np.arcsin(np.clip(f[2], -1, 1))))


def _basis(azimuth: float, elevation: float) -> NDArray[np.float64]:
    """Rows forward, right, up of MuJoCo's free camera at this azimuth and elevation."""
    a, e = np.radians(azimuth), np.radians(elevation)
    fwd = np.array([np.cos(e) * np.cos(a), np.cos(e) * np.sin(a), np.sin(e)])
    up = np.array([-np.sin(e) * np.cos(a), -np.sin(e) * np.sin(a), np.cos(e)])
    return np.stack([fwd, np.cross(fwd, up), up])


def _distance(pts: NDArray[np.float64], radius: NDArray[np.float64], lookat: NDArray[np.float64],
              basis: NDArray[np.float64], tan: tuple[float, float]) -> float:
    """The smallest camera distance at which every sphere ``(pts, radius)`` projects inside ``tan`` (x, y)."""
    rel = (pts - lookat) @ basis.T  # depth offset, x, y
    need_x = (np.abs(rel[:, 1]) + radius) / tan[0] - rel[:, 0] + radius
    need_y = (np.abs(rel[:, 2]) + radius) / tan[1] - rel[:, 0] + radius
    return float(max(need_x.max(), need_y.max()))


def _recentre(pts: NDArray[np.float64], radius: NDArray[np.float64], lookat: NDArray[np.float64], d: float,
              basis: NDArray[np.float64]) -> NDArray[np.float64]:
    """Shift ``lookat`` across the view so the projected figure is centred (perspective makes it lopsided)."""
    rel = (pts - lookat) @ basis.T
    z = np.maximum(rel[:, 0] + d, 1e-9)
    shift = np.zeros(3)
    for k in (1, 2):
        lo, hi = ((rel[:, k] - radius) / z).min(), ((rel[:, k] + radius) / z).max()
        shift += 0.5 * (lo + hi) * d * basis[k]
    return lookat + shift


def _spheres(tree: Tree, qs: NDArray[np.float64], extra: NDArray[np.float64] | None,
             extra_radius: float) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Per-frame bounding points ``(T, P, 3)`` and radii ``(P,)``: the geoms' box corners, the ends of
    :func:`bare_links` and ``extra (T, n, 3)``.
    """  # noqa: D205
    pts = geom_corners(tree, qs).reshape(len(qs), -1, 3)
    if pts.shape[1] == 0:  # no visible geom: frame the bodies
        pts = tree.fk(qs)[:, 1:, :3, 3]
    elif len(ends := np.unique(bare_links(tree.model))):
        pts = np.concatenate([pts, tree.fk(qs)[:, ends][..., :3, 3]], axis=1)
    radius = np.zeros(pts.shape[1])
    if extra is not None and extra.shape[1]:
        pts = np.concatenate([pts, extra], axis=1)
        radius = np.concatenate([radius, np.full(extra.shape[1], extra_radius)])
    return pts, radius


def _chunks(tree: Tree, qs: NDArray[np.float64], extra: NDArray[np.float64] | None, extra_radius: float,
            ) -> Iterator[tuple[slice, NDArray[np.float64], NDArray[np.float64]]]:
    """:func:`_spheres` of :data:`CAMERA_CHUNK` frames at a time: ``(frames, points, radii)``."""
    for start in range(0, len(qs), CAMERA_CHUNK):
        part = slice(start, start + CAMERA_CHUNK)
        yield (part, *_spheres(tree, qs[part], None if extra is None else extra[part], extra_radius))


def _outline(pts: NDArray[np.float64], radius: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """The points of ``pts (C, P, 3)`` (radii ``(P,)``) that can bound a still shot: each radius's convex hull.

    What the shot needs of the points (the largest distance any needs, the extremes of
    their projections) is convex or linear-fractional in a point, so it is attained on
    the hull: the rest can go, and a long clip costs no more to frame than a short one.
    """
    from scipy.spatial import ConvexHull, QhullError

    flat, rad = pts.reshape(-1, 3), np.tile(radius, len(pts))
    keep = []
    for r in np.unique(radius):
        idx = np.flatnonzero(rad == r)
        if len(idx) > 64:
            try:
                idx = idx[ConvexHull(flat[idx], qhull_options="QJ").vertices]  # joggled: flat sets too
            except QhullError:  # degenerate beyond joggling (all points equal): keep them
                pass
        keep.append(idx)
    k = np.concatenate(keep)
    return flat[k], rad[k]


def camera_path(tree: Tree, qs: ArrayLike, extra: ArrayLike | None = None, aspect: float = 1.0,
                view: tuple[float, float] | None = None, follow: bool | None = None, margin: float = MARGIN,
                extra_radius: float = 0.03) -> list[mujoco.MjvCamera]:
    """One free camera per frame of ``qs (T, nq)`` that keeps every figure geom and ``extra`` point in view.

    Args:
        tree: the figure.
        qs: configurations ``(T, nq)`` (or one ``(nq,)``).
        extra: points to keep in view too, ``(n, 3)`` for all frames or ``(T, n, 3)``.
        aspect: image width / height; the default 1 frames any image at least as wide as tall.
        view: ``(azimuth, elevation)`` in degrees; default along the joint axis of a
            planar chain, else :data:`SIDE_VIEW`.
        follow: track the figure (a smoothed centre at a fixed distance) instead of
            one still shot of everything; default: when it travels further than its size.
        margin: fraction of the image kept free on every side.
        extra_radius: radius (m) kept around each extra point.
    """
    qs = np.atleast_2d(tree.check_q(qs))
    if not (np.isfinite(aspect) and aspect > 0 and 0 <= margin < 0.5):
        raise InputError(f"camera needs aspect > 0 and 0 <= margin < 0.5, got {aspect!r}, {margin!r}")
    az, el = view if view is not None else _view_of(planar_axis(tree))
    basis = _basis(az, el)
    ty = np.tan(np.radians(float(tree.model.vis.global_.fovy)) / 2) * (1 - 2 * margin)
    tan = (ty * aspect, ty)
    e = np.zeros((0, 3)) if extra is None else np.asarray(extra, dtype=np.float64)
    per_frame = e.reshape(len(qs), -1, 3) if e.ndim == 3 else None
    static = np.zeros((0, 3)) if per_frame is not None else e.reshape(-1, 3)  # the same points in every frame
    static_radius = np.full(len(static), extra_radius)
    lo, hi = np.empty((len(qs), 3)), np.empty((len(qs), 3))  # per-frame boxes
    outline = [(static, static_radius)]
    for part, pts, radius in _chunks(tree, qs, per_frame, extra_radius):
        lo[part] = np.minimum(pts.min(axis=1), static.min(axis=0, initial=np.inf))
        hi[part] = np.maximum(pts.max(axis=1), static.max(axis=0, initial=-np.inf))
        outline.append(_outline(pts, radius))
    centres = 0.5 * (lo + hi)
    size = float(np.linalg.norm(hi - lo, axis=-1).max())
    travel = float(np.linalg.norm(np.ptp(centres, axis=0)))
    if follow is None:
        follow = travel > size
    if follow and len(qs) > 1:
        from scipy.ndimage import gaussian_filter1d

        looks = gaussian_filter1d(centres, sigma=min(20.0, len(qs) / 6), axis=0, mode="nearest")
        looks[:, 2] = centres[:, 2].mean()  # no vertical bobbing of the shot
        d = 0.0
        for part, pts, radius in _chunks(tree, qs, per_frame, extra_radius):
            radius = np.concatenate([radius, static_radius])
            for k, p in zip(range(len(qs))[part], pts, strict=True):
                p = np.concatenate([p, static])
                looks[k] = _recentre(p, radius, looks[k], _distance(p, radius, looks[k], basis, tan), basis)
                d = max(d, _distance(p, radius, looks[k], basis, tan))
    else:
        flat, rad = (np.concatenate(a) for a in zip(*outline, strict=True))
        look = 0.5 * (flat.min(0) + flat.max(0))
        for _ in range(2):
            look = _recentre(flat, rad, look, _distance(flat, rad, look, basis, tan), basis)
        looks = np.broadcast_to(look, (len(qs), 3))
        d = _distance(flat, rad, look, basis, tan)
    d = max(d, 1e-3 * max(size, 1e-3))
    cams = []
    for look in looks:
        cam = mujoco.MjvCamera()
        mujoco.mjv_defaultFreeCamera(tree.model, cam)
        cam.lookat[:], cam.distance, cam.azimuth, cam.elevation = look, d, az, el
        cams.append(cam)
    return cams


def default_camera(tree: Tree, qs: NDArray[np.float64], extra: NDArray[np.float64] | None = None, *,
                   aspect: float = 1.0, view: tuple[float, float] | None = None) -> mujoco.MjvCamera:
    """One still free camera that frames every figure geom of every ``q`` in ``qs`` (and ``extra`` points).

    See :func:`camera_path` (this is its shot with ``follow=False``; pass ``aspect`` = width / height
    of the frames for the tightest shot).
    """
    return camera_path(tree, qs, extra, aspect=aspect, view=view, follow=False)[0]


# ---------------------------------------------------------------------- stage
@dataclass(frozen=True, eq=False)
class Floor:
    """A checker floor at height ``z``: dark squares of side ``tile`` centred at ``centres (n, 2)`` (world x, y) on
    a light ground that reaches ``reach`` m from ``middle (2,)`` every way.
    """  # noqa: D205

    z: float
    tile: float
    centres: NDArray[np.float64]
    middle: NDArray[np.float64]
    reach: float


@dataclass(frozen=True, eq=False)
class Stage:
    """How a :class:`Painter` stages a model, drawn into each frame's scene (the model is untouched).

    ``backdrop``: the sky gradient in place of the model's skybox and the checker floor in place of
    its ``floors`` (geom ids: the world's planes facing up, at height ``floor``; None when it has none);
    the headlight is :data:`HEADLIGHT` while a frame's scene is made. ``light``: the model has no light,
    so one from above is added. ``reveal``: hidden geoms drawn (:func:`shown_geoms`). ``bones`` ``(k, 2)``:
    :func:`bare_links`, drawn as capsules of ``radius`` (m) between the two body origins. ``size``: the
    diagonal (m) of the figure's box at ``qpos0``. ``Stage()`` adds nothing.
    """

    light: bool = False
    backdrop: bool = False
    bones: NDArray[np.int64] = field(default_factory=lambda: np.zeros((0, 2), np.int64))
    radius: float = 0.0
    size: float = 1.0
    floor: float | None = None
    floors: NDArray[np.int64] = field(default_factory=lambda: np.zeros(0, np.int64))
    reveal: NDArray[np.int64] = field(default_factory=lambda: np.zeros(0, np.int64))

    @classmethod
    def of(cls, tree: Tree) -> Stage:
        """The stage of ``tree``'s model: the one look, and what its figure lacks (hidden shapes, bones)."""
        m = tree.model
        bones = bare_links(m)
        lo, hi = _figure_box(tree, tree.qpos0[None])
        size = max(float(np.linalg.norm(hi - lo)), 1e-3)
        length = np.linalg.norm(m.body_pos[bones[:, 1]], axis=1)
        radius = min(0.2 * float(np.median(length)), 0.03 * size) if len(bones) else 0.0
        up = spatial.quat_to_mat(spatial.quat_normalize(m.geom_quat))[:, 2, 2] > 1 - 1e-9
        floors = np.flatnonzero((m.geom_type == mujoco.mjtGeom.mjGEOM_PLANE) & (m.geom_bodyid == 0) & up)
        floor = float(m.geom_pos[floors, 2].max()) if len(floors) else None
        reveal = np.flatnonzero(shown_geoms(m) & (m.geom_group >= 3))
        return cls(light=m.nlight == 0, backdrop=True, bones=bones, radius=radius, size=size, floor=floor,
                   floors=floors, reveal=reveal)


def bare_links(model: mujoco.MjModel) -> NDArray[np.int64]:
    """Bones ``(k, 2)``: parent and child body ids of the links with nothing visible to show them.

    A link runs from a (non-world) body's origin to its child's; it is bare when no :func:`figure_geoms`
    visible by default (groups 0–2) of either body reaches its midpoint (the geom's bounding sphere):
    mesh-free models with no geoms, hidden ones, or a dot at the origin. Hidden shapes a body shows
    (:func:`shown_geoms`) are drawn besides the bone: they are often thinner than the link or cover a part.
    """
    ids = figure_geoms(model)
    ids = ids[model.geom_group[ids] < 3]
    child = np.arange(1, model.nbody)
    parent = model.body_parentid[child]
    pos = model.body_pos[child]
    R = spatial.quat_to_mat(spatial.quat_normalize(model.body_quat[child]))
    mid = {"parent": 0.5 * pos, "child": -0.5 * np.einsum("kji,kj->ki", R, pos)}  # in each body's frame
    covered = np.zeros(len(child), bool)
    for side, bodies in (("parent", parent), ("child", child)):
        for k in np.flatnonzero(np.isin(bodies, model.geom_bodyid[ids])):
            own = ids[model.geom_bodyid[ids] == bodies[k]]
            covered[k] |= bool((np.linalg.norm(model.geom_pos[own] - mid[side][k], axis=1)
                                <= model.geom_rbound[own]).any())
    keep = (parent > 0) & ~covered & (np.linalg.norm(pos, axis=1) > 0)
    return np.stack([parent[keep], child[keep]], axis=1).astype(np.int64)


def _figure_box(tree: Tree, qs: NDArray[np.float64], bones: NDArray[np.int64] | None = None,
                radius: float = 0.0) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """World box ``(lo (3,), hi (3,))`` of the figure over ``qs (T, nq)``: its geoms (or body origins) and bones."""
    lo, hi = np.full(3, np.inf), np.full(3, -np.inf)
    for part, pts, _ in _chunks(tree, qs, None, 0.0):
        if bones is not None and len(bones):
            ends = tree.fk(qs[part])[:, np.unique(bones)][..., :3, 3].reshape(-1, 3)
            pts = np.concatenate([pts.reshape(-1, 3), ends - radius, ends + radius])
        lo, hi = np.minimum(lo, pts.reshape(-1, 3).min(0)), np.maximum(hi, pts.reshape(-1, 3).max(0))
    return lo, hi


def _nice(x: float) -> float:
    """The smallest of 1, 2, 5 times a power of ten that is at least ``x > 0``."""
    e = 10.0 ** np.floor(np.log10(x))
    return float(next(f * e for f in (1, 2, 5, 10) if f * e >= x * (1 - 1e-9)))


def fit_floor(tree: Tree, qs: ArrayLike, stage: Stage, z: float | None = None) -> Floor:
    """The floor under the figure in every pose of ``qs (T, nq)``: at ``z``, or at z = 0 when the figure stands on
    it (its lowest point from 5 % of its size below to 10 % above), else at its lowest point; checker squares of
    about a tenth of its size over its path and a figure's size around, the squares larger when the path is long.
    """  # noqa: D205
    qs = np.atleast_2d(tree.check_q(qs))
    lo, hi = _figure_box(tree, qs, stage.bones, stage.radius)
    if z is None:
        z = 0.0 if -0.05 * stage.size <= lo[2] <= 0.1 * stage.size else float(lo[2])
    tile = _nice(stage.size / 10)
    while True:
        first, last = np.floor((lo[:2] - stage.size) / tile), np.ceil((hi[:2] + stage.size) / tile)
        if np.prod(last - first) <= 2 * FLOOR_SQUARES:
            break
        tile = _nice(1.01 * tile)
    i, j = np.meshgrid(np.arange(first[0], last[0]), np.arange(first[1], last[1]), indexing="ij")
    dark = (i + j) % 2 == 1
    centres = (np.stack([i[dark], j[dark]], axis=-1) + 0.5) * tile
    far = float(tree.model.vis.map.zfar * tree.model.stat.extent)
    return Floor(z, tile, centres, 0.5 * (first + last) * tile, far)


_LENDING = threading.Lock()  # one headlight lent at a time: painters of one model in two threads put back the same


@contextmanager
def _headlight(model: mujoco.MjModel, on: bool) -> Iterator[None]:
    """While open: ``model``'s headlight on and :data:`HEADLIGHT` (when ``on``); then as it was."""
    if not on:
        yield
        return
    light = model.vis.headlight
    with _LENDING:
        kept = light.active, light.ambient.copy(), light.diffuse.copy(), light.specular.copy()
        light.active = 1
        light.ambient[:], light.diffuse[:], light.specular[:] = HEADLIGHT
        try:
            yield
        finally:
            light.active, light.ambient[:], light.diffuse[:], light.specular[:] = kept


def _add_top_light(scene: mujoco.MjvScene, floor: Floor, size: float) -> None:
    """A light from straight above the floor's middle (:data:`TOP_LIGHT`, casting shadows, as Menagerie's)."""
    if scene.nlight >= len(scene.lights):
        return
    light = scene.lights[scene.nlight]
    scene.nlight += 1
    light.type, light.headlight, light.castshadow = mujoco.mjtLightType.mjLIGHT_DIRECTIONAL, 0, 1
    light.id, light.texid = -1, -1
    light.pos[:] = [*floor.middle, floor.z + 2 * size]
    light.dir[:] = [0.0, 0.0, -1.0]
    light.ambient[:], light.diffuse[:], light.specular[:] = 0.0, TOP_LIGHT, 0.3
    light.attenuation[:], light.cutoff, light.exponent, light.bulbradius = 0.0, 0.0, 0.0, 0.02
    light.intensity, light.range = 0.0, 10.0 * size


def _hide(scene: mujoco.MjvScene, hidden: NDArray[np.bool_]) -> None:
    """Drop from the drawn scene the model geoms marked in ``hidden (ngeom,)`` (they are not drawn, cast nothing)."""
    for g in scene.geoms[:scene.ngeom]:
        if g.objtype == mujoco.mjtObj.mjOBJ_GEOM and 0 <= g.objid < len(hidden) and hidden[g.objid]:
            g.type = mujoco.mjtGeom.mjGEOM_NONE
            g.category = mujoco.mjtCatBit.mjCAT_DECOR


def _stage_geom(scene: mujoco.MjvScene, kind: int, size: ArrayLike, pos: ArrayLike, mat: ArrayLike,
                rgba: ArrayLike) -> mujoco.MjvGeom | None:
    """Append a stage geom (no shadow, left out of segmentation); None when the scene is full."""
    g = _add(scene, kind, size, pos, rgba)
    if g is not None:
        g.mat[:] = np.asarray(mat, dtype=np.float32).reshape(3, 3)
        g.segid = -1
    return g


def _eye(scene: mujoco.MjvScene) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """Position, forward and up (world, ``(3,)`` each) of the scene's camera as drawn (both eyes' middle)."""
    cam = scene.camera[0]
    pos = 0.5 * (np.asarray(cam.pos, np.float64) + np.asarray(scene.camera[1].pos, np.float64))
    return pos, np.asarray(cam.forward, np.float64), np.asarray(cam.up, np.float64)


def _in_view(scene: mujoco.MjvScene, aspect: float, points: NDArray[np.float64], radius: float) -> NDArray[np.bool_]:
    """``(n,)``: which balls ``(points (n, 3), radius)`` reach into the view of the scene's camera (its frustum)."""
    cam = scene.camera[0]
    pos, fwd, up = _eye(scene)
    rel = points - pos
    d, x, y = rel @ fwd, rel @ np.cross(fwd, up), rel @ up
    half_w = cam.frustum_width or 0.5 * aspect * (cam.frustum_top - cam.frustum_bottom)
    seen = d + radius > cam.frustum_near
    for v, lo, hi in ((x, cam.frustum_center - half_w, cam.frustum_center + half_w),
                      (y, cam.frustum_bottom, cam.frustum_top)):
        for edge, sign in ((hi, 1.0), (lo, -1.0)):  # a side plane: v = slope * d + offset
            slope, offset = (0.0, edge) if cam.orthographic else (edge / cam.frustum_near, 0.0)
            seen &= sign * (v - slope * d - offset) <= radius * np.hypot(1.0, slope)
    return seen


def _add_floor(scene: mujoco.MjvScene, floor: Floor, aspect: float) -> None:
    """The checker: a light ground (top face at ``floor.z``) and the dark squares in view on it, ``floor.tile`` / 500
    higher. It glows by :data:`FLOOR_GLOW` (emission), as if lit from above.
    """  # noqa: D205
    eye = np.eye(3)
    thick = 0.01 * floor.tile
    geoms = [_stage_geom(scene, mujoco.mjtGeom.mjGEOM_BOX, [floor.reach, floor.reach, thick],
                         [*floor.middle, floor.z - thick], eye, FLOOR_RGBA[0])]
    half = [0.5 * floor.tile, 0.5 * floor.tile, thick]
    centres = np.column_stack([floor.centres, np.full(len(floor.centres), floor.z + 0.002 * floor.tile - thick)])
    for c in centres[_in_view(scene, aspect, centres, 0.75 * floor.tile)]:
        geoms.append(_stage_geom(scene, mujoco.mjtGeom.mjGEOM_BOX, half, c, eye, FLOOR_RGBA[1]))
    for g in geoms:
        if g is not None:
            g.emission = FLOOR_GLOW


def _add_sky(scene: mujoco.MjvScene, aspect: float, floor: Floor) -> None:
    """A sky gradient behind everything: :data:`SKY_BANDS` bands across the view, half-way to the far plane.

    Each band has the colour of the sky (:data:`SKY_RGB`, by the sine of the elevation, as a gradient
    skybox) where its centre is seen. It is drawn as emission, so lights barely change it. Bands wholly
    below the ``floor`` (seen from above it) are hidden by it and left out.
    """
    cam = scene.camera[0]
    pos, fwd, up = _eye(scene)
    right = np.cross(fwd, up)
    half_w = cam.frustum_width or 0.5 * aspect * (cam.frustum_top - cam.frustum_bottom)
    edges = np.linspace(1.05 * cam.frustum_bottom, 1.05 * cam.frustum_top, SKY_BANDS + 1)  # on the near plane
    mat = np.stack([right, up, -fwd], axis=1)
    zenith, nadir = np.asarray(SKY_RGB[0]), np.asarray(SKY_RGB[1])
    glow = 100.0  # emission; the colour is divided by it, so lit it changes by (light / glow) of itself
    for k, (a, b) in enumerate(itertools.pairwise(edges)):
        y = 0.5 * (a + b)
        ray = fwd if cam.orthographic else fwd * cam.frustum_near + y * up + cam.frustum_center * right
        rgb = nadir + 0.5 * (1 + ray[2] / np.linalg.norm(ray)) * (zenith - nadir)
        dist = (0.5 + 2e-3 * k) * cam.frustum_far  # each band a little further: where they overlap, one shows
        scale = 1.0 if cam.orthographic else dist / cam.frustum_near  # from the near plane out to the band
        size = [1.1 * half_w * scale, 0.6 * (b - a) * scale, 1e-4 * dist]  # bands overlap: no cracks
        centre = pos + dist * fwd + scale * (y * up + cam.frustum_center * right)
        if pos[2] > floor.z > centre[2] + size[0] * abs(right[2]) + size[1] * abs(up[2]):
            continue
        g = _stage_geom(scene, mujoco.mjtGeom.mjGEOM_BOX, size, centre, mat, [*(rgb / glow), 1.0])
        if g is not None:
            g.emission, g.specular = glow, 0.0


TerrainGeom = tuple[int, NDArray[np.float64], NDArray[np.float64], NDArray[np.float64], NDArray[np.float32]]
TERRAIN_REACH = 50.0  # m: how far an unbounded plane of a scene is drawn


def terrain_geoms(terrain: Terrain) -> list[TerrainGeom]:
    """The scene's geoms to draw: ``(type, size, pos, mat (9,), rgba)`` each, the floor (drawn as the checker)
    and hidden geoms left out, meshes and height fields as their bounding boxes, unbounded planes
    :data:`TERRAIN_REACH` across.
    """  # noqa: D205
    m, d = terrain.model, terrain.data
    out: list[TerrainGeom] = []
    for g in np.flatnonzero(terrain.colors[:, 3] > 0):
        kind, size, pos = int(m.geom_type[g]), m.geom_size[g].copy(), d.geom_xpos[g].copy()
        mat = d.geom_xmat[g].reshape(3, 3)
        if kind == mujoco.mjtGeom.mjGEOM_PLANE:
            if terrain.floor is not None and mat[2, 2] > 1 - 1e-9 and abs(pos[2] - terrain.floor) < 1e-9:
                continue
            size[:2] = np.where(size[:2] > 0, size[:2], TERRAIN_REACH)
        elif kind in (mujoco.mjtGeom.mjGEOM_MESH, mujoco.mjtGeom.mjGEOM_HFIELD):
            kind, size, pos = int(mujoco.mjtGeom.mjGEOM_BOX), m.geom_aabb[g, 3:].copy(), pos + mat @ m.geom_aabb[g, :3]
        out.append((kind, size, pos, mat.ravel().copy(), terrain.colors[g]))
    return out


def _add_terrain(scene: mujoco.MjvScene, geoms: Sequence[TerrainGeom]) -> None:
    """The scene's geoms (:func:`terrain_geoms`), casting shadows as a model's static geoms do."""
    for kind, size, pos, mat, rgba in geoms:
        g = _stage_geom(scene, kind, size, pos, mat, rgba)
        if g is not None:
            g.category = mujoco.mjtCatBit.mjCAT_STATIC


def _connect(scene: mujoco.MjvScene, kind: int, width: float, ends: NDArray[np.float64],
             rgba: ArrayLike) -> list[mujoco.MjvGeom]:
    """Decoration geoms of ``kind`` (capsule: ``width`` = radius in m; line: in px) joining each pair of world
    points ``ends (k, 2, 3)``; those that fit in the scene.
    """  # noqa: D205
    added = []
    for a, b in ends:
        g = _add(scene, kind, [0, 0, 0], a, rgba)
        if g is not None:
            mujoco.mjv_connector(g, kind, width, a, b)
            added.append(g)
    return added


def _add_bones(scene: mujoco.MjvScene, xpos: NDArray[np.float64], stage: Stage) -> None:
    """Capsules of ``stage.radius`` between the world origins ``xpos (nbody, 3)`` of each bone's two bodies."""
    for g in _connect(scene, mujoco.mjtGeom.mjGEOM_CAPSULE, stage.radius, xpos[stage.bones], BONE_RGBA):
        g.category, g.segid = mujoco.mjtCatBit.mjCAT_DYNAMIC, -1  # a part of the figure: it casts a shadow


# ---------------------------------------------------------------------- frames
def caption_at(caption: Caption, t: int) -> str:
    """The caption text of frame ``t`` ('' for none)."""
    if caption is None:
        return ""
    if isinstance(caption, str):
        return caption
    if callable(caption):
        return str(caption(t))
    return str(caption[t]) if t < len(caption) else ""


def _caption_layout(height: int, width: int) -> tuple[ImageFont.FreeTypeFont | ImageFont.ImageFont, int]:
    """The caption's font and padding (px) on a ``width`` x ``height`` image: 18 px type on 640x480, growing with it
    (a wide strip counts by its width).
    """  # noqa: D205
    from PIL import ImageFont

    h = max(height, 0.75 * width)
    return ImageFont.load_default(size=max(8, round(h / 26))), max(2, round(h / 80))


def caption_box(height: int, width: int, text: str) -> tuple[float, float, float, float] | None:
    """Pixels ``(left, top, right, bottom)`` of the dark band :func:`draw_caption` puts under ``text``; None for ''."""
    if not text:
        return None
    from PIL import Image, ImageDraw

    font, pad = _caption_layout(height, width)
    box = ImageDraw.Draw(Image.new("RGB", (1, 1))).multiline_textbbox((2 * pad, 2 * pad), text, font=font)
    return box[0] - pad, box[1] - pad, box[2] + pad, box[3] + pad


def draw_caption(image: NDArray[np.uint8], text: str) -> NDArray[np.uint8]:
    """``image (H, W, 3)`` with ``text`` (lines split at newlines) on a dark band in its top-left corner
    (:func:`caption_box`).
    """  # noqa: D205
    box = caption_box(image.shape[0], image.shape[1], text)
    if box is None:
        return image
    from PIL import Image, ImageDraw

    font, pad = _caption_layout(image.shape[0], image.shape[1])
    pil = Image.fromarray(image)
    draw = ImageDraw.Draw(pil, "RGBA")
    draw.rectangle(box, fill=(20, 20, 30, 160))
    draw.multiline_text((2 * pad, 2 * pad), text, font=font, fill=(255, 255, 255, 255))
    return np.asarray(pil)


def project(tree: Tree, camera: mujoco.MjvCamera, points: ArrayLike, width: int, height: int) -> NDArray[np.float64]:
    """Pixels ``(n, 2)`` (x right, y down, from the top-left corner) where a free ``camera`` shows world
    ``points (n, 3)`` in a ``width`` x ``height`` frame (the model's vertical field of view, perspective).
    """  # noqa: D205
    fwd, right, up = _basis(camera.azimuth, camera.elevation)
    rel = np.asarray(points, dtype=np.float64).reshape(-1, 3) - (np.asarray(camera.lookat) - camera.distance * fwd)
    focal = 0.5 * height / np.tan(np.radians(float(tree.model.vis.global_.fovy)) / 2)  # px per unit of x/depth
    depth = rel @ fwd
    return np.column_stack([0.5 * width + focal * (rel @ right) / depth, 0.5 * height - focal * (rel @ up) / depth])


def _planes_cast_no_shadow(scene: mujoco.MjvScene) -> None:
    """Leave the scene's planes out of the shadow pass (as decoration; they are still drawn and receive shadows)."""
    for g in scene.geoms[:scene.ngeom]:
        if g.type == mujoco.mjtGeom.mjGEOM_PLANE:
            g.category = mujoco.mjtCatBit.mjCAT_DECOR


MAX_SIDE = 16_384  # pixels: GL's largest offscreen framebuffer side on common drivers


def _check_size(width: int, height: int) -> None:
    """Raise :class:`InputError` unless both sides are whole numbers > 0."""
    check_count(width, "frame width", 1, most=MAX_SIDE)
    check_count(height, "frame height", 1, most=MAX_SIDE)


def _pixels(value: Any) -> NDArray:
    """``value`` as an array for the image checks (a ragged list as an empty one, which they refuse)."""
    try:
        return np.asarray(value)
    except ValueError:
        return np.zeros(0)


def headless_gl() -> None:
    """Render through EGL when nothing chose a GL backend: ``MUJOCO_GL`` unset on Linux without a display.

    ``import mjkin`` leaves ``MUJOCO_GL`` alone; this is called where a renderer is made.
    """
    if os.environ.get("MUJOCO_GL") or os.environ.get("DISPLAY") or sys.platform != "linux":
        return
    from mujoco.rendering.classic import gl_context

    try:
        from mujoco.egl import GLContext
    except ImportError:  # no EGL (or PyOpenGL set to another platform): MuJoCo's own choice stands
        return
    gl_context.GLContext = GLContext

class Painter:
    """A reusable offscreen renderer for one tree: draws a configuration with overlays.

    Keep one for many frames (an environment, a video); call :meth:`close` (or use
    ``with``) to free the GL context. :attr:`added` is the number of overlay geoms
    the last :meth:`draw` put into the scene. :attr:`stage` is what it adds to a
    model that lacks it (a light, floor and sky, bones: :class:`Stage`; none with
    ``stage=False``), and :attr:`floor` the floor it draws, fitted to ``qpos0`` until
    :meth:`fit` (or :meth:`cameras`) fits it to the poses of a video. With a ``terrain`` the figure
    stands on that scene instead of its model's world geoms (see the module).
    """

    def __init__(self, tree: Tree, width: int = 640, height: int = 480, stage: bool = True,
                 terrain: Terrain | None = None) -> None:
        _check_size(width, height)
        model = tree.model
        self.tree, self.scene, self.added = tree, Scene(tree), 0
        self.width, self.height = width, height
        self.stage = Stage.of(tree) if stage else Stage()
        self.terrain = terrain
        self.option = mujoco.MjvOption()  # with a terrain, the model's static geoms are not drawn
        self.option.flags[mujoco.mjtVisFlag.mjVIS_STATIC] = terrain is None
        self._hidden = np.zeros(model.ngeom, bool)  # model geoms drawn over by the stage, or hidden and not revealed
        self._hidden[self.stage.floors] = True
        if len(self.stage.reveal):
            self.option.geomgroup[3:] = 1
            self._hidden |= model.geom_group >= 3
            self._hidden[self.stage.reveal] = False
        self._terrain = [] if terrain is None else terrain_geoms(terrain)
        self.floor: Floor | None = None
        self.fit(tree.qpos0)
        # the offscreen buffer (and its multisample resolve) is sized to the frame, not to the model's
        # offwidth x offheight, and the shadow map to what the frame can show (software GL pays for
        # every texel of MuJoCo's default 4096²); the model's settings are put back once the context exists
        vis, quality = model.vis.global_, model.vis.quality
        kept = vis.offwidth, vis.offheight, quality.shadowsize
        vis.offwidth, vis.offheight = width, height
        quality.shadowsize = min(kept[2], 2048 if max(width, height) > 512 else 1024)
        try:
            headless_gl()
            self.renderer = mujoco.Renderer(model, height, width)
        except Exception as e:  # no GL context: say how to get one
            raise MjkinIOError(f"cannot start offscreen rendering ({' '.join(str(e).split())}); on a machine "
                               f"without a display set MUJOCO_GL=egl before mujoco is imported "
                               f"(now {os.environ.get('MUJOCO_GL')!r})") from None
        finally:
            vis.offwidth, vis.offheight, quality.shadowsize = max(kept[0], width), max(kept[1], height), kept[2]
        self.renderer.scene.flags[mujoco.mjtRndFlag.mjRND_SKYBOX] = not self.stage.backdrop  # the stage's sky instead

    def camera(self, camera: mujoco.MjvCamera | str | None, qs: NDArray[np.float64],
               points: NDArray[np.float64] | None = None) -> mujoco.MjvCamera | int:
        """A camera: as given, a model camera by name, or :func:`default_camera` for ``qs`` and ``points``."""
        return self.cameras(camera, qs, points, follow=False)[0]

    def cameras(self, camera: mujoco.MjvCamera | str | None, qs: NDArray[np.float64],
                points: NDArray[np.float64] | None = None, view: tuple[float, float] | None = None,
                follow: bool | None = None) -> list[mujoco.MjvCamera | int]:
        """One camera per frame: the one given, a model camera by name, or :func:`camera_path` (tracking).

        The floor is fitted to ``qs`` too (:meth:`fit`), so a still matches its frame of the video.
        """
        self.fit(qs)
        return cameras(self.tree, camera, qs, points, self.width / self.height, view, follow)

    def fit(self, qs: ArrayLike) -> None:
        """Place the floor (when the stage has one) under the figure in all poses ``qs (T, nq)``: :func:`fit_floor`
        (at the terrain's floor, when there is a terrain).
        """  # noqa: D205
        if self.terrain is not None:
            z = self.terrain.floor
            self.floor = None if z is None else fit_floor(self.tree, qs, self.stage, z)
        elif self.stage.backdrop:
            self.floor = fit_floor(self.tree, qs, self.stage, self.stage.floor)

    def draw(self, q: NDArray[np.float64], camera: mujoco.MjvCamera | int, points: ArrayLike = (),
             trail: NDArray[np.float64] | None = None, overlay: Overlay | None = None,
             caption: str = "", lines: Sequence[tuple[ArrayLike, Sequence[float]]] = ()) -> NDArray[np.uint8]:
        """One RGB frame ``(height, width, 3)`` of ``q``: target ``points (n, 3)`` (and ``overlay.bones`` between them),
        a ``trail (k, 3)``, a caption, and ``lines``: polylines ``(k, 3)`` each with its RGBA; on the :attr:`stage`
        (light, :attr:`floor`, sky, bones).
        """  # noqa: D205
        ov = overlay or Overlay()
        r = self.renderer
        data = self.scene.set(q)
        with _headlight(self.tree.model, self.stage.backdrop):
            r.update_scene(data, camera, self.option)
        _planes_cast_no_shadow(r.scene)
        _hide(r.scene, self._hidden)
        if self.floor is not None:
            _add_floor(r.scene, self.floor, self.width / self.height)
            if self.stage.backdrop:
                _add_sky(r.scene, self.width / self.height, self.floor)
            if self.stage.light:
                _add_top_light(r.scene, self.floor, self.stage.size)
        _add_terrain(r.scene, self._terrain)
        _add_bones(r.scene, data.xpos, self.stage)
        first = r.scene.ngeom
        pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        for p in pts:
            _add(r.scene, mujoco.mjtGeom.mjGEOM_SPHERE, [ov.point_size, 0, 0], p, ov.point_rgba)
        _connect(r.scene, mujoco.mjtGeom.mjGEOM_CAPSULE, ov.bone_radius, pts[ov.bones], ov.point_rgba)
        width = max(1.0, ov.trail_width * max(self.height, 0.75 * self.width) / 480)
        for path, rgba in ([] if trail is None else [(trail, ov.trail_rgba)]) + list(lines):
            path = np.asarray(path, dtype=np.float64).reshape(-1, 3)  # lines: a capsule a segment costs ~1 ms (soft GL)
            _connect(r.scene, mujoco.mjtGeom.mjGEOM_LINE, width, np.stack([path[:-1], path[1:]], axis=1), rgba)
        self.added = r.scene.ngeom - first
        return draw_caption(r.render(), caption)

    def close(self) -> None:
        """Free the GL context."""
        self.renderer.close()

    def __enter__(self) -> Painter:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def cameras(tree: Tree, camera: mujoco.MjvCamera | str | None, qs: NDArray[np.float64],
            points: NDArray[np.float64] | None = None, aspect: float = 1.0, view: tuple[float, float] | None = None,
            follow: bool | None = None) -> list[mujoco.MjvCamera | int]:
    """One camera per frame of ``qs (T, nq)``: the one given, a model camera by name, or :func:`camera_path`.

    Raises :class:`InputError` for a camera name the model does not have (the message lists its cameras).
    """
    if isinstance(camera, str):
        model = tree.model
        cam_id = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_CAMERA, camera)
        if cam_id < 0:
            names = [model.camera(i).name for i in range(model.ncam)]
            raise InputError(f"unknown camera {camera!r}; the model's cameras: {', '.join(names) or 'none'}")
        return [cam_id] * len(qs)
    if isinstance(camera, (int, np.integer)) and not isinstance(camera, bool):
        if not 0 <= camera < tree.model.ncam:
            raise InputError(f"camera id {camera} is not one of the model's {tree.model.ncam} cameras")
        return [int(camera)] * len(qs)
    if camera is not None and not isinstance(camera, mujoco.MjvCamera):
        raise InputError(f"camera must be a mujoco.MjvCamera, a camera's name or id, or None, got {camera!r:.40}")
    if camera is not None:
        return [camera] * len(qs)
    return list(camera_path(tree, qs, points, aspect=aspect, view=view, follow=follow))


def frames(tree: Tree, qs: ArrayLike, width: int = 640, height: int = 480, camera: mujoco.MjvCamera | str | None = None,
           overlay: Overlay | None = None, desc: str = "render", view: tuple[float, float] | None = None,
           follow: bool | None = None, terrain: Terrain | None = None) -> Iterator[NDArray[np.uint8]]:
    """RGB frames ``(height, width, 3)`` of configurations ``qs (T, nq)``, made one at a time as they are taken.

    Memory does not grow with ``T`` (pass the iterator to :func:`write_video`);
    ``np.stack(list(frames(...)))`` gives the array ``(T, height, width, 3)``.
    The arguments are checked (and the cameras placed) at the call; the GL
    context opens with the first frame and closes after the last (or when the
    iterator is dropped).

    ``camera``: a :class:`mujoco.MjvCamera`, the name of a model camera, or None
    for :func:`camera_path` (``view`` = its azimuth and elevation, ``follow`` = track
    the figure; default: when it travels). ``overlay.points``
    are ``(n, 3)`` for every frame or ``(T, n, 3)`` per frame; the trail grows frame
    by frame, decimated to ``overlay.trail_points``; ``overlay.bones`` index the ``n`` points. The figure is
    staged (:class:`Stage`), its floor under it in every frame, or stands on ``terrain`` (the scene it was
    retargeted onto).
    """
    qs = check_tree(tree).check_q(qs)
    if qs.ndim == 1:
        qs = qs[None]
    _check_size(width, height)
    ov = overlay or Overlay()
    points = np.asarray(ov.points, dtype=np.float64)
    if np.asarray(ov.bones).size and not 0 <= np.min(ov.bones) <= np.max(ov.bones) < points.shape[-2]:
        raise InputError(f"overlay bones must index the {points.shape[-2]} points, got indices from "
                         f"{np.min(ov.bones)} to {np.max(ov.bones)}")
    trail = tree.pose(qs, ov.trail)[:, :3, 3] if ov.trail else None
    seen = points  # what the default camera keeps in view besides the figure: markers and the trail
    if trail is not None:
        seen = (np.concatenate([points, trail[:, None]], axis=1) if points.ndim == 3
            else np.concatenate([points.reshape(-1, 3), trail]))
    cams = cameras(tree, camera, qs, seen, width / height, view, follow)

    def draw() -> Iterator[NDArray[np.uint8]]:
        with Painter(tree, width, height, terrain=terrain) as painter:
            painter.fit(qs)
            for t in track(range(len(qs)), desc, total=len(qs)):
                yield painter.draw(qs[t], cams[t], points[t] if points.ndim == 3 else points,
                                   None if trail is None else trail[trail_indices(t, ov.trail_points)], ov,
                                   caption_at(ov.caption, t))

    return draw()


def check_video_size(path: str | os.PathLike[str], width: int, height: int, what: str = "frame size") -> None:
    """Raise :class:`InputError` for a size the video format cannot hold as it is (odd sides in an .mp4).

    H.264 in yuv420p (what players expect) needs even sides, and mjkin writes
    exactly the size asked for: it neither pads nor scales frames.
    """
    if Path(path).suffix.lower() == ".mp4" and (width % 2 or height % 2):
        raise InputError(f"{what} of an .mp4 must be even (H.264 yuv420p), got {width}x{height}; "
                         "use an even size or .gif")


GIF_FILTER = "split[a][b];[a]palettegen=stats_mode=single[p];[b][p]paletteuse=new=1:dither=none"  # per frame


def write_video(images: Iterable[ArrayLike], path: str | os.PathLike[str], fps: float = 30.0) -> Path:
    """Write RGB frames ``(H, W, 3)`` to ``.mp4`` (H.264) or ``.gif``, at their size, as they come.

    ``images`` is any iterable (an array ``(T, H, W, 3)``, a list, :func:`frames`);
    each frame goes to ffmpeg as it is taken, so memory does not grow with the
    clip. The file is written atomically: a temporary file, renamed when the last
    frame is in; an error or an interrupt on the way leaves no file. A GIF gets a
    palette per frame.

    Raises:
        InputError: no frames, a frame that is not ``(H, W, 3)`` of the first frame's
            size, or odd sides in an ``.mp4`` (:func:`check_video_size`, checked on the first frame).
        MjkinIOError: the file cannot be written.
    """
    target = as_path(path, "video path")
    gif = target.suffix.lower() == ".gif"
    if target.suffix.lower() not in VIDEO_SUFFIXES:
        raise InputError(f"video file must end in {' or '.join(VIDEO_SUFFIXES)}, got {str(target)!r}")
    fps = check_number(fps, "fps", 0.0, strict=True)
    try:
        it = iter(images)
    except TypeError:
        raise InputError(f"images must be an iterable of frames, got {type(images).__name__}") from None
    first = next(it, None)
    if first is None:
        raise InputError("no frames to write")
    first = _pixels(first)
    shape = first.shape
    if len(shape) != 3 or shape[2] != 3 or first.dtype != np.uint8:
        raise InputError(f"video frames must be RGB images (height, width, 3) of uint8, got {shape} of {first.dtype}")
    check_video_size(target, shape[1], shape[0])
    import imageio_ffmpeg

    with atomic_path(target) as tmp:
        writer = imageio_ffmpeg.write_frames(
            str(tmp), (int(shape[1]), int(shape[0])), fps=fps, macro_block_size=1, ffmpeg_log_level="error",
            **({"codec": "gif", "pix_fmt_out": "pal8", "quality": None,
                "output_params": ["-filter_complex", GIF_FILTER, "-loop", "0"]} if gif else
               {"codec": "libx264", "pix_fmt_out": "yuv420p", "quality": 7}))
        try:
            writer.send(None)  # starts ffmpeg
            for k, image in enumerate(itertools.chain([first], it)):
                frame = np.ascontiguousarray(image)
                if frame.shape != shape or frame.dtype != np.uint8:
                    raise InputError(f"video frame {k} is {frame.shape} of {frame.dtype}, the first {shape} of uint8: "
                                     "every frame must have the same size")
                writer.send(frame)
        except OSError as e:
            raise MjkinIOError(f"cannot write {str(target)!r}: {' '.join(str(e).split())[:300]}") from None
        finally:
            writer.close()  # ffmpeg finishes the file (or is stopped); atomic_path keeps or drops it
    return target


def write_image(image: NDArray[np.uint8], path: str | os.PathLike[str]) -> Path:
    """Write one frame as PNG (or any format imageio knows by the suffix), atomically."""
    import imageio.v2 as imageio

    a = _pixels(image)
    if a.ndim != 3 or a.shape[2] not in (3, 4) or a.dtype != np.uint8:
        raise InputError(f"an image must be RGB or RGBA (height, width, 3 or 4) of uint8, got {a.shape} of {a.dtype}")
    target = as_path(path, "image path")
    with atomic_path(target) as tmp:
        imageio.imwrite(tmp, a)
    return target
