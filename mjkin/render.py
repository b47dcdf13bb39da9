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
"""

from __future__ import annotations

import itertools
import os
import sys
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import mujoco
import numpy as np
from numpy.typing import ArrayLike, NDArray

from . import spatial
from .errors import InputError, MjkinIOError
from .files import atomic_path
from .kinematics.qspace import BALL, FREE, HINGE
from .kinematics.tree import Tree
from .progress import track
from .scene import Scene

VIDEO_SUFFIXES = (".mp4", ".gif")
MARGIN = 0.07  # the camera keeps the figure this fraction of the image away from every edge (≥ 5 % asked)
CAMERA_CHUNK = 256  # frames whose bounding points are made at once while placing the camera
SIDE_VIEW = (135.0, -20.0)  # azimuth, elevation (degrees) for figures that are not planar chains
WALK_VIEW = (90.0, -8.0)  # from the figure's right side, world x (the walking direction) to the right
Caption = str | Sequence[str] | Callable[[int], str] | None


@dataclass
class Overlay:
    """Things drawn into the scene: target points, the trail of a frame (site/body) over time, captions.

    ``caption`` is one text for every frame, one per frame, or a function of the
    frame index; it is drawn into the image's top-left corner.
    """

    points: NDArray[np.float64] = field(default_factory=lambda: np.zeros((0, 3)))  # (n, 3), or (T, n, 3) per frame
    point_size: float = 0.02
    point_rgba: tuple[float, float, float, float] = (0.95, 0.2, 0.2, 0.9)
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
def figure_geoms(model: mujoco.MjModel) -> NDArray[np.int64]:
    """Geoms that make up the figure: visible by default (groups 0–2, not transparent), no planes.

    Geoms of the moving bodies, and world geoms only where the figure stands on them
    (a pedestal: the root body's origin lies in the geom's box); the rest of the
    world (floors, arena walls, tables) is stage, not figure.
    """
    rgba = np.where((model.geom_matid >= 0)[:, None], model.mat_rgba[np.maximum(model.geom_matid, 0)],
                    model.geom_rgba) if model.nmat else model.geom_rgba
    keep = (model.geom_type != mujoco.mjtGeom.mjGEOM_PLANE) & (model.geom_group < 3) & (rgba[:, 3] > 0)
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
    """Per-frame bounding points ``(T, P, 3)`` and radii ``(P,)``: the geoms' box corners and ``extra (T, n, 3)``."""
    pts = geom_corners(tree, qs).reshape(len(qs), -1, 3)
    if pts.shape[1] == 0:  # no visible geom: frame the bodies
        pts = tree.fk(qs)[:, 1:, :3, 3]
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


def draw_caption(image: NDArray[np.uint8], text: str) -> NDArray[np.uint8]:
    """``image (H, W, 3)`` with ``text`` (lines split at newlines) on a dark band in its top-left corner.

    The font grows with the image (18 px on 640x480; a wide strip counts by its width).
    """
    if not text:
        return image
    from PIL import Image, ImageDraw, ImageFont

    h = max(image.shape[0], 0.75 * image.shape[1])
    font = ImageFont.load_default(size=max(8, round(h / 26)))
    pil = Image.fromarray(image)
    draw = ImageDraw.Draw(pil, "RGBA")
    pad = max(2, round(h / 80))
    box = draw.multiline_textbbox((2 * pad, 2 * pad), text, font=font)
    draw.rectangle((box[0] - pad, box[1] - pad, box[2] + pad, box[3] + pad), fill=(20, 20, 30, 160))
    draw.multiline_text((2 * pad, 2 * pad), text, font=font, fill=(255, 255, 255, 255))
    return np.asarray(pil)


def _planes_cast_no_shadow(scene: mujoco.MjvScene) -> None:
    """Leave the scene's planes out of the shadow pass (as decoration; they are still drawn and receive shadows)."""
    for g in scene.geoms[:scene.ngeom]:
        if g.type == mujoco.mjtGeom.mjGEOM_PLANE:
            g.category = mujoco.mjtCatBit.mjCAT_DECOR


def _check_size(width: int, height: int) -> None:
    """Raise :class:`InputError` unless both sides are positive."""
    if width <= 0 or height <= 0:
        raise InputError(f"frame size must be positive, got {width}x{height}")



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
    the last :meth:`draw` put into the scene.
    """

    def __init__(self, tree: Tree, width: int = 640, height: int = 480) -> None:
        _check_size(width, height)
        model = tree.model
        self.tree, self.scene, self.added = tree, Scene(tree), 0
        self.width, self.height = width, height
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

    def camera(self, camera: mujoco.MjvCamera | str | None, qs: NDArray[np.float64],
               points: NDArray[np.float64] | None = None) -> mujoco.MjvCamera | int:
        """A camera: as given, a model camera by name, or :func:`default_camera` for ``qs`` and ``points``."""
        return self.cameras(camera, qs, points, follow=False)[0]

    def cameras(self, camera: mujoco.MjvCamera | str | None, qs: NDArray[np.float64],
                points: NDArray[np.float64] | None = None, view: tuple[float, float] | None = None,
                follow: bool | None = None) -> list[mujoco.MjvCamera | int]:
        """One camera per frame: the one given, a model camera by name, or :func:`camera_path` (tracking)."""
        return cameras(self.tree, camera, qs, points, self.width / self.height, view, follow)

    def draw(self, q: NDArray[np.float64], camera: mujoco.MjvCamera | int, points: ArrayLike = (),
             trail: NDArray[np.float64] | None = None, overlay: Overlay | None = None,
             caption: str = "", lines: Sequence[tuple[ArrayLike, Sequence[float]]] = ()) -> NDArray[np.uint8]:
        """One RGB frame ``(height, width, 3)`` of ``q``: target ``points (n, 3)``, a ``trail (k, 3)``, a caption,
        and ``lines``: polylines ``(k, 3)`` each with its RGBA.
        """  # noqa: D205
        ov = overlay or Overlay()
        r = self.renderer
        r.update_scene(self.scene.set(q), camera)
        _planes_cast_no_shadow(r.scene)
        first = r.scene.ngeom
        for p in np.asarray(points, dtype=np.float64).reshape(-1, 3):
            _add(r.scene, mujoco.mjtGeom.mjGEOM_SPHERE, [ov.point_size, 0, 0], p, ov.point_rgba)
        width = max(1.0, ov.trail_width * max(self.height, 0.75 * self.width) / 480)
        for path, rgba in ([] if trail is None else [(trail, ov.trail_rgba)]) + list(lines):
            path = np.asarray(path, dtype=np.float64).reshape(-1, 3)
            for a, b in zip(path[:-1], path[1:], strict=True):  # lines: a capsule per segment costs ~1 ms (soft GL)
                g = _add(r.scene, mujoco.mjtGeom.mjGEOM_LINE, [0, 0, 0], a, rgba)
                if g is not None:
                    mujoco.mjv_connector(g, mujoco.mjtGeom.mjGEOM_LINE, width, a, b)
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
    if camera is not None:
        return [camera] * len(qs)
    return list(camera_path(tree, qs, points, aspect=aspect, view=view, follow=follow))


def frames(tree: Tree, qs: ArrayLike, width: int = 640, height: int = 480, camera: mujoco.MjvCamera | str | None = None,
           overlay: Overlay | None = None, desc: str = "render", view: tuple[float, float] | None = None,
           follow: bool | None = None) -> Iterator[NDArray[np.uint8]]:
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
    by frame, decimated to ``overlay.trail_points``.
    """
    qs = tree.check_q(qs)
    if qs.ndim == 1:
        qs = qs[None]
    _check_size(width, height)
    ov = overlay or Overlay()
    points = np.asarray(ov.points, dtype=np.float64)
    trail = tree.pose(qs, ov.trail)[:, :3, 3] if ov.trail else None
    seen = points  # what the default camera keeps in view besides the figure: markers and the trail
    if trail is not None:
        seen = np.concatenate([points, trail[:, None]], axis=1) if points.ndim == 3 \
            else np.concatenate([points.reshape(-1, 3), trail])
    cams = cameras(tree, camera, qs, seen, width / height, view, follow)

    def draw() -> Iterator[NDArray[np.uint8]]:
        with Painter(tree, width, height) as painter:
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
    target = Path(path)
    gif = target.suffix.lower() == ".gif"
    if target.suffix.lower() not in VIDEO_SUFFIXES:
        raise InputError(f"video file must end in {' or '.join(VIDEO_SUFFIXES)}, got {str(target)!r}")
    it = iter(images)
    first = next(it, None)
    if first is None:
        raise InputError("no frames to write")
    first = np.asarray(first)
    shape = first.shape
    if len(shape) != 3 or shape[2] != 3 or first.dtype != np.uint8:
        raise InputError(f"video frames must be RGB images (height, width, 3) of uint8, got {shape} of {first.dtype}")
    check_video_size(target, shape[1], shape[0])
    import imageio_ffmpeg

    with atomic_path(target) as tmp:
        writer = imageio_ffmpeg.write_frames(
            str(tmp), (int(shape[1]), int(shape[0])), fps=float(fps), macro_block_size=1, ffmpeg_log_level="error",
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

    target = Path(path)
    with atomic_path(target) as tmp:
        imageio.imwrite(tmp, image)
    return target
