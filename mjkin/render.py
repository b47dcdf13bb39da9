"""Offscreen frames of posed figures with goal markers and effector trails, and videos.

Rendering goes through ``mujoco.Renderer`` (headless: ``MUJOCO_GL=egl``). The
default camera frames the whole figure over all frames, and its targets,
without configuration. Videos are written with imageio (mp4 via
imageio-ffmpeg, or gif) to a temporary file that is renamed when complete.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import mujoco
import numpy as np
from numpy.typing import ArrayLike, NDArray

from .errors import InputError, MjkinIOError
from .files import atomic_path
from .progress import track
from .scene import Scene
from .tree import Tree

VIDEO_SUFFIXES = (".mp4", ".gif")


@dataclass
class Overlay:
    """Things drawn into the scene: target points, and the trail of a frame (site/body) over time."""

    points: NDArray[np.float64] = field(default_factory=lambda: np.zeros((0, 3)))  # (n, 3), or (T, n, 3) per frame
    point_size: float = 0.02
    point_rgba: tuple[float, float, float, float] = (0.95, 0.2, 0.2, 0.9)
    trail: str | None = None  # name of the site or body whose path is drawn
    trail_rgba: tuple[float, float, float, float] = (0.1, 0.5, 0.95, 0.9)
    trail_width: float = 0.006


def _add(scene: mujoco.MjvScene, kind: int, size: ArrayLike, pos: ArrayLike, rgba: ArrayLike) -> mujoco.MjvGeom | None:
    if scene.ngeom >= scene.maxgeom:
        return None
    g = scene.geoms[scene.ngeom]
    mujoco.mjv_initGeom(g, kind, np.asarray(size, dtype=np.float64), np.asarray(pos, dtype=np.float64),
                        np.eye(3).ravel(), np.asarray(rgba, dtype=np.float32))
    scene.ngeom += 1
    return g


def default_camera(tree: Tree, qs: NDArray[np.float64], extra: NDArray[np.float64] | None = None) -> mujoco.MjvCamera:
    """A free camera looking at the box around every body over all frames (and ``extra`` points)."""
    pos = tree.fk(qs)[..., 1:, :3, 3].reshape(-1, 3)
    if extra is not None and extra.size:
        pos = np.concatenate([pos, extra.reshape(-1, 3)])
    lo, hi = pos.min(0), pos.max(0)
    cam = mujoco.MjvCamera()
    mujoco.mjv_defaultFreeCamera(tree.model, cam)
    cam.lookat[:] = 0.5 * (lo + hi)
    span = float(np.linalg.norm(hi - lo))
    cam.distance = max(1.3 * span, 0.5 * float(tree.model.stat.extent), 1e-3)
    planar = np.ptp(pos[:, 2]) < 1e-6 * max(span, 1e-9)
    cam.elevation = -70.0 if planar else -20.0
    cam.azimuth = 90.0 if planar else 135.0
    return cam


class Painter:
    """A reusable offscreen renderer for one tree: draws a configuration with overlays.

    Keep one for many frames (an environment, a video); call :meth:`close` (or use
    ``with``) to free the GL context.
    """

    def __init__(self, tree: Tree, width: int = 640, height: int = 480) -> None:
        if width <= 0 or height <= 0:
            raise InputError(f"frame size must be positive, got {width}x{height}")
        model = tree.model
        model.vis.global_.offwidth = max(width, model.vis.global_.offwidth)
        model.vis.global_.offheight = max(height, model.vis.global_.offheight)
        self.tree, self.scene = tree, Scene(tree)
        try:
            self.renderer = mujoco.Renderer(model, height, width)
        except Exception as e:  # no GL context: say how to get one
            raise MjkinIOError(f"cannot start offscreen rendering ({' '.join(str(e).split())}); on a machine "
                               f"without a display set MUJOCO_GL=egl (now {os.environ.get('MUJOCO_GL')!r})") from None

    def camera(self, camera: mujoco.MjvCamera | str | None, qs: NDArray[np.float64],
               points: NDArray[np.float64] | None = None) -> mujoco.MjvCamera | int:
        """A camera: as given, a model camera by name, or :func:`default_camera` for ``qs`` and ``points``."""
        if isinstance(camera, str):
            model = self.tree.model
            cam_id = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_CAMERA, camera)
            if cam_id < 0:
                names = [model.camera(i).name for i in range(model.ncam)]
                raise InputError(f"unknown camera {camera!r}; the model's cameras: {', '.join(names) or 'none'}")
            return cam_id
        return camera if camera is not None else default_camera(self.tree, qs, points)

    def draw(self, q: NDArray[np.float64], camera: mujoco.MjvCamera | int, points: ArrayLike = (),
             trail: NDArray[np.float64] | None = None, overlay: Overlay | None = None) -> NDArray[np.uint8]:
        """One RGB frame ``(height, width, 3)`` of ``q`` with target ``points (n, 3)`` and a ``trail (k, 3)``."""
        ov = overlay or Overlay()
        r = self.renderer
        r.update_scene(self.scene.set(q), camera)
        for p in np.asarray(points, dtype=np.float64).reshape(-1, 3):
            _add(r.scene, mujoco.mjtGeom.mjGEOM_SPHERE, [ov.point_size, 0, 0], p, ov.point_rgba)
        if trail is not None:
            for a, b in zip(trail[:-1], trail[1:], strict=True):
                g = _add(r.scene, mujoco.mjtGeom.mjGEOM_CAPSULE, [0, 0, 0], a, ov.trail_rgba)
                if g is not None:
                    mujoco.mjv_connector(g, mujoco.mjtGeom.mjGEOM_CAPSULE, ov.trail_width, a, b)
        return r.render()

    def close(self) -> None:
        """Free the GL context."""
        self.renderer.close()

    def __enter__(self) -> Painter:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def frames(tree: Tree, qs: ArrayLike, width: int = 640, height: int = 480, camera: mujoco.MjvCamera | str | None = None,
           overlay: Overlay | None = None, desc: str = "render") -> NDArray[np.uint8]:
    """RGB frames ``(T, height, width, 3)`` of configurations ``qs (T, nq)``.

    ``camera``: a :class:`mujoco.MjvCamera`, the name of a model camera, or None
    for :func:`default_camera`. ``overlay.points`` are ``(n, 3)`` for every frame
    or ``(T, n, 3)`` per frame; the trail grows frame by frame.
    """
    qs = tree.check_q(qs)
    if qs.ndim == 1:
        qs = qs[None]
    ov = overlay or Overlay()
    points = np.asarray(ov.points, dtype=np.float64)
    trail = tree.pose(qs, ov.trail)[:, :3, 3] if ov.trail else None
    out = np.empty((len(qs), height, width, 3), dtype=np.uint8)
    with Painter(tree, width, height) as painter:
        cam = painter.camera(camera, qs, points)
        for t in track(range(len(qs)), desc, total=len(qs)):
            out[t] = painter.draw(qs[t], cam, points[t] if points.ndim == 3 else points,
                                  None if trail is None else trail[:t + 1], ov)
    return out


def write_video(images: NDArray[np.uint8] | Sequence[NDArray[np.uint8]], path: str | os.PathLike[str],
                fps: float = 30.0) -> Path:
    """Write frames to ``.mp4`` or ``.gif`` atomically (a temporary file, renamed when complete)."""
    target = Path(path)
    if target.suffix.lower() not in VIDEO_SUFFIXES:
        raise InputError(f"video file must end in {' or '.join(VIDEO_SUFFIXES)}, got {str(target)!r}")
    if len(images) == 0:
        raise InputError("no frames to write")
    import imageio.v2 as imageio

    with atomic_path(target) as tmp:
        try:
            if target.suffix.lower() == ".gif":
                imageio.mimsave(tmp, list(images), duration=1.0 / fps, loop=0)
            else:
                with imageio.get_writer(tmp, fps=fps, codec="libx264", quality=7, macro_block_size=8) as w:
                    for im in images:
                        w.append_data(np.asarray(im))  # type: ignore[attr-defined]
        except OSError as e:
            raise MjkinIOError(f"cannot write {str(target)!r}: {e}") from None
    return target


def write_image(image: NDArray[np.uint8], path: str | os.PathLike[str]) -> Path:
    """Write one frame as PNG (or any format imageio knows by the suffix), atomically."""
    import imageio.v2 as imageio

    target = Path(path)
    with atomic_path(target) as tmp:
        imageio.imwrite(tmp, image)
    return target
