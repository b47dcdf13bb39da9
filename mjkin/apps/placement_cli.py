"""``mjkin reachability`` (a capability map, one slice plotted) and ``mjkin place-base`` (a base placement heat map).

The library (:mod:`mjkin.explore.reachability`) and matplotlib are imported only when one
of these commands runs.
"""

from __future__ import annotations

import argparse
import json
import os
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from ..errors import InputError, MjkinIOError
from ..runtime import files
from ..runtime.files import atomic_path, check_writable
from .argtypes import positive_float, positive_int

if TYPE_CHECKING:
    from ..explore.reachability import Placement, ReachabilityMap

IMAGES = (".png", ".jpg", ".jpeg")
AXES = "xyz"


def default_cache() -> Path:
    """Where the command keeps its maps: ``$XDG_CACHE_HOME/mjkin`` (default ``~/.cache/mjkin``)."""
    return Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "mjkin"


def _map_options(s: argparse.ArgumentParser) -> None:
    s.add_argument("model", help="MJCF/URDF file or a bundled model name")
    s.add_argument("--frame", required=True, help="the site or body to map")
    s.add_argument("--resolution", type=positive_float, default=0.1, help="voxel edge, m (default 0.1)")
    s.add_argument("--orientations", type=positive_int, default=16,
                   help="directions of the frame's z axis tried per voxel (default 16)")
    s.add_argument("--cache", default=None, help=f"folder for the cached maps (default {default_cache()}); "
                   "'none' builds without one")


def reachability_arguments(s: argparse.ArgumentParser) -> None:
    """``mjkin reachability``'s options."""
    _map_options(s)
    s.add_argument("--slice", default=None, metavar="AXIS=VALUE",
                   help="the plotted slice, e.g. z=0.3 (m; default: z through the best voxel)")
    s.add_argument("-o", "--output", default="reachability.png", help="image file (default reachability.png)")


def place_base_arguments(s: argparse.ArgumentParser) -> None:
    """``mjkin place-base``'s options."""
    _map_options(s)
    s.add_argument("--poses", required=True, help='JSON file: [[x, y, z, qw, qx, qy, qz], ...] or {"poses": ...}')
    s.add_argument("--region", required=True, metavar="XMIN,YMIN,XMAX,YMAX", help="where the base may stand (m)")
    s.add_argument("--yaws", type=positive_int, default=8, help="base turns tried (default 8)")
    s.add_argument("--step", type=positive_float, help="grid step over the region, m (default: --resolution)")
    s.add_argument("-o", "--output", default="place-base.png", help="heat map image (default place-base.png)")


def _cache(args: argparse.Namespace) -> Path | None:
    if args.cache is not None and args.cache.lower() == "none":
        return None
    folder = default_cache() if args.cache is None else Path(args.cache)
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise MjkinIOError(f"cannot use the cache folder {str(folder)!r}: {e.strerror}") from None
    return folder


def _slice(text: str | None, m: ReachabilityMap) -> tuple[int, int]:
    """The axis (0, 1, 2) and the voxel layer of ``--slice AXIS=VALUE`` (default: z through the best voxel)."""
    if text is None:
        best = np.unravel_index(int(np.argmax(m.share)), m.shape)
        return 2, int(best[2])
    axis, _, value = text.partition("=")
    try:
        at = float(value)
    except ValueError:
        at = np.nan
    if axis not in AXES or not np.isfinite(at):
        raise InputError(f"--slice must be AXIS=VALUE with AXIS one of x, y, z and VALUE in metres, got {text!r}")
    k = AXES.index(axis)
    layer = int(np.rint((at - m.origin[k]) / m.resolution))
    top = m.origin[k] + m.resolution * (m.shape[k] - 1)
    if not 0 <= layer < m.shape[k]:
        raise InputError(f"--slice {axis}={at:g} is outside the map, which spans {axis} = "
                         f"{m.origin[k]:.3g} .. {top:.3g}")
    return k, layer


def _pyplot() -> Any:
    try:
        import matplotlib
    except ImportError:
        raise MjkinIOError("plotting needs matplotlib: pip install 'mjkin[plot]'") from None
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _save(fig: Any, path: str) -> None:
    target = Path(path)
    with atomic_path(target) as tmp:
        fig.savefig(tmp, dpi=100, format=target.suffix.lstrip(".").lower())


def run_reachability(args: argparse.Namespace) -> int:
    """Build (or read) the map, plot one slice of its capability, print a summary."""
    from ..explore.reachability import reachability
    from ..kinematics.tree import load

    check_writable(args.output, IMAGES, "--output")
    tree = load(args.model)
    m = reachability(tree, args.frame, resolution=args.resolution, orientations=args.orientations,
                     cache=_cache(args))
    axis, layer = _slice(args.slice, m)
    plt = _pyplot()
    u, v = [a for a in range(3) if a != axis]
    share = np.take(m.share, layer, axis=axis)
    lo = m.origin - m.resolution / 2
    hi = lo + m.resolution * np.array(m.shape)
    fig, ax = plt.subplots(figsize=(6, 5))
    im = ax.imshow(share.T, origin="lower", extent=(lo[u], hi[u], lo[v], hi[v]), vmin=0, vmax=1, cmap="viridis")
    fig.colorbar(im, ax=ax, label="share of orientations reached")
    ax.set_xlabel(f"{AXES[u]} (m)")
    ax.set_ylabel(f"{AXES[v]} (m)")
    at = m.origin[axis] + layer * m.resolution
    ax.set_title(f"{tree.name} · {args.frame}: capability at {AXES[axis]} = {at:.3g} m", fontsize=10)
    fig.tight_layout()
    _save(fig, args.output)
    plt.close(fig)
    reach = m.share > 0
    print(f"wrote {args.output}: {m.shape[0]}x{m.shape[1]}x{m.shape[2]} voxels of {m.resolution:g} m, "
          f"{reach.mean():.0%} reachable, {(m.share == 1).mean():.0%} in every orientation; built in {m.seconds:.1f} s")
    return 0


def _read_poses(path: str) -> np.ndarray:
    text = files.read_input_text(path, "--poses file", files.LIMITS["json"])
    try:
        data = json.loads(text)
    except (ValueError, RecursionError) as e:
        raise InputError(f"--poses {path!r} is not JSON: {e}") from None
    rows = data.get("poses") if isinstance(data, dict) else data
    try:
        poses = np.asarray(rows, dtype=np.float64)
    except (TypeError, ValueError):
        poses = np.zeros((0,))
    if poses.ndim != 2 or poses.shape[1] != 7 or not len(poses):
        raise InputError(f"--poses {path!r} must hold a list of [x, y, z, qw, qx, qy, qz] rows")
    return poses


def _region(text: str) -> np.ndarray:
    try:
        box = np.array([float(v) for v in text.split(",")])
    except ValueError:
        box = np.zeros(0)
    if box.shape != (4,) or not np.all(np.isfinite(box)) or box[2] < box[0] or box[3] < box[1]:
        raise InputError(f"--region must be XMIN,YMIN,XMAX,YMAX (m) with min <= max, got {text!r}")
    return box


def _plot_heat(p: Placement, path: str, title: str) -> None:
    plt = _pyplot()
    h = (p.grid_x[1] - p.grid_x[0]) / 2 if len(p.grid_x) > 1 else 0.05
    k = (p.grid_y[1] - p.grid_y[0]) / 2 if len(p.grid_y) > 1 else 0.05
    fig, ax = plt.subplots(figsize=(6, 5))
    im = ax.imshow(p.heat.T, origin="lower", cmap="magma",
                   extent=(p.grid_x[0] - h, p.grid_x[-1] + h, p.grid_y[0] - k, p.grid_y[-1] + k))
    fig.colorbar(im, ax=ax, label="poses on the map (best yaw)")
    x, y = p.xy[0]
    ax.plot([x], [y], "c*", ms=14, label=f"chosen: {p.count[0]}/{p.reached.shape[1]} reached (IK)")
    ax.arrow(x, y, 0.1 * np.cos(p.yaw[0]), 0.1 * np.sin(p.yaw[0]), color="c", width=0.005)
    ax.set_xlabel("base x (m)")
    ax.set_ylabel("base y (m)")
    ax.legend(loc="upper right", fontsize=8)
    ax.set_title(title, fontsize=10)
    fig.tight_layout()
    _save(fig, path)
    plt.close(fig)


def run_place_base(args: argparse.Namespace) -> int:
    """Rank base placements for the poses, verify the best by IK, plot the region's heat map."""
    from ..explore.reachability import place_base, reachability
    from ..kinematics.tree import load

    check_writable(args.output, IMAGES, "--output")
    poses, region = _read_poses(args.poses), _region(args.region)
    tree = load(args.model)
    m = reachability(tree, args.frame, resolution=args.resolution, orientations=args.orientations,
                     cache=_cache(args))
    p = place_base(tree, args.frame, poses, region, step=args.step, yaws=args.yaws, capability=m)
    _plot_heat(p, args.output, f"{tree.name} · {args.frame}: {len(poses)} poses")
    x, y = p.xy[0]
    print(f"wrote {args.output}: base at x={x:.3f} y={y:.3f} yaw={np.degrees(p.yaw[0]):.0f} deg reaches "
          f"{p.count[0]}/{len(poses)} poses (verified by IK), manipulability {p.manipulability[0]:.3g}")
    return 0
