"""Capability maps (which orientations a frame reaches where) and base placement from them.

:func:`reachability` cuts the box a frame can reach into voxels and, at each voxel
centre, asks IK for a fixed set of orientations — all of them in one batched
:func:`mjkin.solve`, each started from the sampled configuration nearest the
voxel in position and direction. Voxels beyond the chain's reach bound
(:func:`mjkin.ik.reasons.reach_bound`, a proof) are not solved. The map is cached
in a file keyed by the model's fingerprint and every parameter.

:func:`place_base` moves the target poses into the frame of each candidate base
placement (a position in a floor rectangle and a yaw): the same as moving the
base. Candidates are ranked on the map first (cheap), then the best are verified
by IK on the full poses and ranked by how many poses they reach, then by
manipulability.
"""

from __future__ import annotations

import hashlib
import os
import time
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .. import goals as G
from .. import spatial
from ..errors import InputError, MjkinIOError
from ..ik.evaluate import singular_values
from ..ik.method import MAX_RESTARTS
from ..ik.reasons import reach_bound
from ..ik.solve import solve
from ..kinematics.tree import FAR, Tree, check_tree, fingerprint
from ..runtime import files
from ..runtime.checks import check_count, check_number, shown
from ..runtime.files import atomic_path

Array = NDArray[np.float64]
VERSION = 1  # of the cache files' contents
MAX_PLACEMENTS = 1_000_000  # base placements (grid cells x yaws) place_base scores at most
MAX_SCORED = 20_000_000  # target points place_base scores at most (placements x poses; 24 bytes each, ~0.5 GB)
MAX_VERIFIED = 1_000_000  # IK solves place_base verifies with at most (verify x poses; seconds to a minute)
MAX_ORIENTATIONS = 10_000  # orientations a map tries per voxel at most (each voxel solves all of them at once)
MAX_VOXELS = 1_000_000  # voxels a capability map holds at most (each one a batch of solves)
SAMPLES = 20_000  # random configurations: the box, and the start of each voxel's solves
NEAREST = 8  # of the samples nearest a voxel, the start is the one whose z axis is nearest the asked direction
# restarts of a voxel's solve: on the Panda's map (0.15 m, 12 directions) agreement with brute-force IK (64 restarts)
# on 1000 random entries was 98.7 % with 2, 99.8 % with 6 (build 9 s -> 11 s)
RESTARTS = 6
TOL, ROT_TOL = 1e-4, 1e-3  # a capability map's tolerances (m, rad), as mjkin bench ik's


@dataclass(frozen=True)
class ReachabilityMap:
    """Which of a fixed set of orientations a frame reaches at each voxel centre.

    Attributes:
        frame: the frame mapped (a site or body name).
        origin: ``(3,)`` world position of voxel ``(0, 0, 0)``'s centre.
        resolution: voxel edge (m).
        reached: ``(nx, ny, nz, K)`` whether IK put the frame at the voxel centre in orientation ``k``.
        orientations: ``(K, 3, 3)`` the world rotations tried.
        axes: ``"z"``: only each rotation's z axis was asked for (roll free); ``"xyz"``: the whole rotation.
        seconds: time the map took to build (0 when it came from the cache... as it was built).
    """

    frame: str
    origin: Array
    resolution: float
    reached: NDArray[np.bool_]
    orientations: Array
    axes: str
    seconds: float

    @property
    def shape(self) -> tuple[int, int, int]:
        """Voxels along x, y, z."""
        return self.reached.shape[:3]  # type: ignore[return-value]

    @property
    def share(self) -> Array:
        """``(nx, ny, nz)`` share of the orientations reached (the capability)."""
        return self.reached.mean(-1)

    def centres(self) -> Array:
        """World centres ``(nx, ny, nz, 3)`` of the voxels."""
        idx = np.stack(np.meshgrid(*(np.arange(n) for n in self.shape), indexing="ij"), -1)
        return self.origin + self.resolution * idx

    def index(self, points: ArrayLike) -> tuple[NDArray[np.int64], NDArray[np.bool_]]:
        """Voxel indices ``(..., 3)`` of world ``points (..., 3)`` and whether each is inside the box."""
        p = np.asarray(points, dtype=np.float64)
        if p.shape[-1:] != (3,) or not np.all(np.isfinite(p)):
            raise InputError(f"points must be finite (..., 3) world positions, got shape {p.shape}")
        i = np.rint((p - self.origin) / self.resolution).astype(np.int64)
        inside = np.all((i >= 0) & (i < np.array(self.shape)), axis=-1)
        return np.where(inside[..., None], i, 0), inside

    def at(self, points: ArrayLike) -> Array:
        """Capability ``(...)`` at world ``points (..., 3)``: the share of its voxel, 0 outside the box."""
        i, inside = self.index(points)
        return np.where(inside, self.share[i[..., 0], i[..., 1], i[..., 2]], 0.0)


def orientation_set(n: int) -> Array:
    """``n`` rotations ``(n, 3, 3)`` whose z axes are spread evenly over the sphere (a Fibonacci lattice)."""
    k = np.arange(n) + 0.5
    z = 1 - 2 * k / n
    phi = np.pi * (1 + 5 ** 0.5) * k
    r = np.sqrt(1 - z * z)
    zs = np.stack([r * np.cos(phi), r * np.sin(phi), z], -1)
    helper = np.where(np.abs(zs[:, :1]) < 0.9, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]])
    x = np.cross(helper, zs)
    x /= np.linalg.norm(x, axis=-1, keepdims=True)
    return np.stack([x, np.cross(zs, x), zs], -1)


def _orientations(orientations: int | ArrayLike) -> tuple[Array, str]:
    """Rotations ``(K, 3, 3)`` and the axes they constrain, from a count (z directions) or quaternions ``(K, 4)``."""
    if isinstance(orientations, (int, np.integer)) and not isinstance(orientations, bool):
        return orientation_set(check_count(orientations, "orientations", most=MAX_ORIENTATIONS)), "z"
    quat = np.asarray(orientations, dtype=np.float64)
    if quat.ndim != 2 or quat.shape[1] != 4 or not len(quat) or not np.all(np.isfinite(quat)) or np.any(
            np.linalg.norm(quat, axis=-1) < 1e-9):
        raise InputError(f"orientations must be a count or (K, 4) quaternions (w, x, y, z), got {shown(orientations)}")
    if len(quat) > MAX_ORIENTATIONS:
        raise InputError(f"orientations must be at most {MAX_ORIENTATIONS} quaternions, got {len(quat)}")
    return spatial.quat_to_mat(spatial.quat_normalize(quat)), "xyz"


def _cache_file(folder: str | os.PathLike[str], tree: Tree, parts: tuple) -> Path:
    """The cache file for ``tree`` and the build parameters ``parts``."""
    digest = hashlib.sha256(repr((VERSION, fingerprint(tree), parts[:-1])).encode())
    digest.update(np.ascontiguousarray(parts[-1]).tobytes())
    return Path(folder) / f"reachability-{digest.hexdigest()[:20]}.npz"


def reachability(tree: Tree, frame: str, *, resolution: float = 0.1, orientations: int | ArrayLike = 16,
                 kind: str | None = None, samples: int = SAMPLES, seed: int = 0,
                 cache: str | os.PathLike[str] | None = None, tol: float = TOL, rot_tol: float = ROT_TOL,
                 restarts: int = RESTARTS, **options: Any) -> ReachabilityMap:
    """The capability map of ``frame``: for each voxel, which of a fixed set of orientations IK reaches.

    Args:
        tree: the kinematic tree (its world frame is the base).
        frame: a site or body name.
        kind: ``"site"`` or ``"body"`` when ``frame`` names both (None: the site).
        resolution: voxel edge (m).
        orientations: a count ``K`` of directions for the frame's z axis, spread evenly
            over the sphere, rotation about it free (a 5-D map, as Zacharias et al.'s
            capability maps); or ``(K, 4)`` quaternions: whole orientations.
        samples: random configurations that give the box and the starts.
        seed: seeds those samples and the solver's restarts.
        cache: a folder: the map is read from there when it was built before with the same
            model and parameters, else built and written there (atomically).
        tol: what counts as reached, position (m).
        rot_tol: what counts as reached, rotation (rad).
        restarts: restarts of each voxel's solve after its start stalls.
        **options: more :func:`mjkin.solve` options (``method``, ``max_iters``, ...).

    Raises:
        InputError: bad options, or no joint moves ``frame``.
        MjkinIOError: the cache folder cannot be read or written.
    """
    res = check_number(resolution, "resolution (m)", 0, strict=True)
    if res > FAR * (float(check_tree(tree).model.stat.extent) or 1.0):
        raise InputError(f"resolution (m) must be at most {FAR:g} model extents, got {res:g}")
    rots, axes = _orientations(orientations)
    n = check_count(samples, "samples", 2)
    seed = check_count(seed, "seed", 0)
    restarts = check_count(restarts, "restarts", 0, most=MAX_RESTARTS)
    tol, rot_tol = check_number(tol, "tol", 0, strict=True), check_number(rot_tol, "rot_tol", 0, strict=True)
    kind_, idx = tree.frame(frame, kind)  # type: ignore[arg-type]
    parts = (frame, kind_, res, axes, n, seed, float(tol), float(rot_tol), int(restarts),
             sorted(options.items()), rots)
    path = None if cache is None else _cache_file(cache, tree, parts)
    if path is not None and path.is_file():
        return _load(path, frame)
    if path is not None and not path.parent.is_dir():  # before minutes of work, not after them
        raise MjkinIOError(f"the reachability cache folder {str(cache)!r} does not exist: create it, or give another")
    started = time.perf_counter()
    body = idx if kind_ == "body" else int(tree.site_body[idx])
    point = np.zeros(3) if kind_ == "body" else tree.site_pos[idx]
    active = np.zeros(tree.nv, dtype=bool)
    active[tree.body_dofs[body]] = True
    if not active.any():
        raise InputError(f"no joint moves {frame!r}: it has no workspace to map")
    rng = np.random.default_rng(seed)
    q = tree.random_q(rng, n)
    T = tree.pose(q, frame, kind_)
    pts = T[:, :3, 3]
    origin = pts.min(0) - res
    with np.errstate(over="ignore"):  # 5e-324 m: inf voxels, refused below
        cells = np.ceil((pts.max(0) + res - origin) / res) + 1  # per axis, float: no int overflow
        voxels = np.prod(cells)
    if not voxels <= MAX_VOXELS:  # a resolution of 1e-5 m tried to allocate 69 TiB
        raise InputError(f"resolution {res:g} m gives {voxels:.3g} voxels over the frame's reach, more than "
                         f"{MAX_VOXELS:,}: a coarser resolution")
    shape = tuple(int(s) for s in cells)
    centres = origin + res * np.stack(np.meshgrid(*(np.arange(s) for s in shape), indexing="ij"), -1).reshape(-1, 3)
    anchor, bound = reach_bound(tree, body, point, active, tree.qpos0[None])
    inside = np.linalg.norm(centres - anchor[0], axis=-1) <= bound[0] + tol
    reached = np.zeros((len(centres), len(rots)), dtype=bool)
    todo = np.flatnonzero(inside)
    if len(todo):
        reached[todo] = _solve_voxels(tree, (frame, kind_), centres[todo], rots, axes, q, T,
                                      dict(options, tol=tol, rot_tol=rot_tol, restarts=restarts, seed=seed))
    out = ReachabilityMap(frame=frame, origin=origin, resolution=res, reached=reached.reshape(shape + (len(rots),)),
                          orientations=rots, axes=axes, seconds=time.perf_counter() - started)
    if path is not None:
        _save(path, out)
    return out


def _solve_voxels(tree: Tree, frame: tuple[str, str], centres: Array, rots: Array, axes: str, q: Array, T: Array,
                  options: dict) -> NDArray[np.bool_]:
    """Which orientation ``(V, K)`` IK reaches at each voxel centre ``(V, 3)``: one batch of ``V·K`` solves.

    ``q (n, nq)`` are sampled configurations and ``T (n, 4, 4)`` the frame's poses there: each solve
    starts from the sample, among the :data:`NEAREST` nearest the centre, whose z axis is closest to the asked one.
    """
    from scipy.spatial import cKDTree

    name, kind = frame
    V, K = len(centres), len(rots)
    _, near = cKDTree(T[:, :3, 3]).query(centres, k=min(NEAREST, len(q)))
    near = near.reshape(V, -1)
    fit = np.einsum("vmi,ki->vkm", T[near, :3, 2], rots[:, :, 2])  # z axis of each neighbour against each ask
    start = near[np.arange(V)[:, None], fit.argmax(-1)]  # (V, K)
    goals = [G.Position(name, np.repeat(centres, K, axis=0), kind=kind),  # type: ignore[arg-type]
             G.Orientation(name, np.tile(rots, (V, 1, 1)), axes=axes, kind=kind)]  # type: ignore[arg-type]
    res = solve(tree, goals, q0=q[start.reshape(-1)], **options)
    return np.asarray(res.success, dtype=bool).reshape(V, K)


def _save(path: Path, m: ReachabilityMap) -> None:
    """Write map ``m`` to ``path`` (``.npz``) atomically; a write that fails (a full disk) is a warning, never an
    error: the map is built, only not cached.
    """  # noqa: D205
    try:
        with atomic_path(path) as tmp:
            np.savez_compressed(tmp, origin=m.origin, resolution=m.resolution, reached=m.reached,
                                orientations=m.orientations, axes=m.axes, seconds=m.seconds)
    except OSError as e:  # MjkinIOError too: atomic_path's own
        warnings.warn(f"cannot write the reachability cache {str(path)!r}: {' '.join(str(e).split())}; the map is "
                      "kept, not cached", stacklevel=3)


def _load(path: Path, frame: str) -> ReachabilityMap:
    """The map cached in ``path``."""
    try:
        with files.open_input(path, "reachability cache", files.LIMITS["npz clip"]) as fh, np.load(fh) as f:
            return ReachabilityMap(frame=frame, origin=f["origin"], resolution=float(f["resolution"]),
                                   reached=f["reached"], orientations=f["orientations"], axes=str(f["axes"]),
                                   seconds=float(f["seconds"]))
    except MjkinIOError:  # what the file is (a FIFO, too big) said in one line already
        raise
    except (OSError, KeyError, ValueError) as e:
        raise MjkinIOError(f"cannot read the reachability cache {str(path)!r}: {e}") from None


# ------------------------------------------------------------------ base placement
@dataclass(frozen=True)
class Placement:
    """Base placements ranked for a set of target poses (best first), each verified by IK.

    Attributes:
        xy: ``(m, 2)`` base positions (world x, y; the base keeps its height).
        yaw: ``(m,)`` base turn about world z (rad).
        reached: ``(m, n)`` which target poses IK reaches from each placement.
        q: ``(m, n, nq)`` the configurations found (inside the limits; reached or the closest found).
        manipulability: ``(m,)`` mean Yoshikawa manipulability over the reached poses.
        grid_x, grid_y: ``(gx,)``, ``(gy,)`` the region's grid; heat: ``(gx, gy)`` the map's score there
            (poses with capability > 0, plus their mean capability; best yaw), what ranked the candidates.
    """

    xy: Array
    yaw: Array
    reached: NDArray[np.bool_]
    q: Array
    manipulability: Array
    grid_x: Array
    grid_y: Array
    heat: Array

    @property
    def count(self) -> NDArray[np.int64]:
        """``(m,)`` poses reached from each placement."""
        return self.reached.sum(-1)

    def base(self, i: int = 0) -> Array:
        """World pose ``(4, 4)`` of placement ``i``'s base."""
        return _base_poses(self.xy[i:i + 1], self.yaw[i:i + 1])[0]


def _base_poses(xy: Array, yaw: Array) -> Array:
    """Base poses ``(m, 4, 4)``: a turn ``yaw (m,)`` about world z, then a move to ``xy (m, 2)``."""
    B = np.broadcast_to(np.eye(4), (len(xy), 4, 4)).copy()
    c, s = np.cos(yaw), np.sin(yaw)
    B[:, 0, 0], B[:, 0, 1], B[:, 1, 0], B[:, 1, 1] = c, -s, s, c
    B[:, :2, 3] = xy
    return B


def _poses(poses: ArrayLike) -> Array:
    """Target poses ``(n, 4, 4)`` from 4x4 matrices or ``(n, 7)`` rows ``x, y, z, qw, qx, qy, qz``."""
    try:
        p = np.asarray(poses, dtype=np.float64)
    except (TypeError, ValueError):
        p = np.zeros(0)
    if p.ndim == 2 and p.shape[1] == 7 and len(p) and np.all(np.isfinite(p)):
        if np.any(np.linalg.norm(p[:, 3:], axis=-1) < 1e-9):
            raise InputError("a target pose has a zero quaternion; use (1, 0, 0, 0) for no rotation")
        return spatial.make_transform(spatial.quat_to_mat(spatial.quat_normalize(p[:, 3:])), p[:, :3])
    if p.ndim == 3 and p.shape[1:] == (4, 4) and len(p) and np.all(np.isfinite(p)):
        return p
    raise InputError(f"poses must be (n, 4, 4) matrices or (n, 7) rows x, y, z, qw, qx, qy, qz; got shape {p.shape}")


def place_base(tree: Tree, frame: str, poses: ArrayLike, region: ArrayLike, *, step: float | None = None,
               yaws: int = 8, verify: int = 10, capability: ReachabilityMap | None = None, kind: str | None = None,
               tol: float = TOL, rot_tol: float = ROT_TOL, **options: Any) -> Placement:
    """Where to put the base so that ``frame`` reaches the target ``poses``: placements ranked, each verified by IK.

    The base (the model's world frame) may move to any ``(x, y)`` of ``region`` and turn
    about world z. Moving it by ``B`` is the same as moving the targets by ``B⁻¹``, so
    each candidate is scored on the capability map (``capability``, else
    :func:`reachability` with ``options``' ``resolution``/``orientations``/``cache``)
    at the moved targets; the ``verify`` best are solved by IK on the full poses,
    then ranked by poses reached, then by manipulability.

    Args:
        tree: the kinematic tree.
        frame: the site or body that must reach the poses.
        poses: ``(n, 4, 4)`` world poses, or ``(n, 7)`` rows ``x, y, z, qw, qx, qy, qz``.
        region: ``(x_min, y_min, x_max, y_max)`` (m) where the base may stand.
        step: grid step over the region (m); default the map's resolution.
        yaws: base turns tried, evenly over a full turn.
        verify: candidates solved by IK.
        capability: a map of ``frame`` to rank with (default: built here).
        kind: ``"site"`` or ``"body"`` when ``frame`` names both (None: the site).
        tol: what counts as reached, position (m).
        rot_tol: what counts as reached, rotation (rad).
        **options: :func:`reachability` options for the map it builds, and :func:`mjkin.solve` options.

    Raises:
        InputError: malformed poses or region, bad options; more than :data:`MAX_PLACEMENTS` placements,
            :data:`MAX_SCORED` placements x poses or :data:`MAX_VERIFIED` verify x poses.
    """
    targets = _poses(poses)
    try:
        box = np.asarray(region, dtype=np.float64)
    except (TypeError, ValueError):
        box = np.zeros(0)
    if box.shape != (4,) or not np.all(np.isfinite(box)) or box[2] < box[0] or box[3] < box[1]:
        raise InputError(f"region must be x_min, y_min, x_max, y_max with min <= max, got {shown(region)}")
    map_keys = ("resolution", "orientations", "samples", "seed", "cache", "restarts")
    map_options = {k: options.pop(k) for k in map_keys if k in options}
    cap = capability or reachability(tree, frame, kind=kind, tol=tol, rot_tol=rot_tol, **map_options)
    h = cap.resolution if step is None else check_number(step, "step (m)", 0, strict=True)
    with np.errstate(over="ignore"):  # a region of 1e308 m at 1e-300: inf placements, refused below
        cells = ((box[2] - box[0]) / h + 1) * ((box[3] - box[1]) / h + 1) * check_count(yaws, "yaws")
    if cells > MAX_PLACEMENTS:  # a region of 2e6 m at 0.1 m tried to allocate a 22.7 PiB grid
        raise InputError(f"region and step give {cells:.3g} base placements (x, y, yaw), more than {MAX_PLACEMENTS:,}: "
                         "a smaller region, a coarser step or fewer yaws")
    gx = np.arange(box[0], box[2] + 0.5 * h, h) if box[2] > box[0] else box[:1]
    gy = np.arange(box[1], box[3] + 0.5 * h, h) if box[3] > box[1] else box[1:2]
    turns = np.arange(check_count(yaws, "yaws")) * (2 * np.pi / yaws)
    X, Y, Z = np.meshgrid(gx, gy, turns, indexing="ij")
    xy, yaw = np.stack([X.ravel(), Y.ravel()], -1), Z.ravel()
    n, verify = len(targets), check_count(verify, "verify")
    for count, most, what in ((len(yaw) * n, MAX_SCORED, "target points to score (placements x poses)"),
                              (min(verify, len(yaw)) * n, MAX_VERIFIED, "IK solves to verify (verify x poses)")):
        if count > most:
            raise InputError(f"{n:,} poses give {count:,} {what}, more than {most:,}: fewer poses, or a smaller "
                             "region, a coarser step, fewer yaws or a smaller verify")
    inv = np.linalg.inv(_base_poses(xy, yaw))  # (c, 4, 4): world to each candidate base
    share = cap.at(np.einsum("cij,nj->cni", inv[:, :3, :3], targets[:, :3, 3]) + inv[:, None, :3, 3])
    score = (share > 0).sum(-1) + share.mean(-1)
    heat = score.reshape(X.shape).max(-1)
    best = np.argsort(-score, kind="stable")[:verify]
    c = len(best)
    local = inv[best][:, None] @ targets[None]  # (c, n, 4, 4): the targets in each verified base's frame
    goal = G.Pose(frame, local.reshape(-1, 4, 4), kind=kind)  # type: ignore[arg-type]
    found = solve(tree, goal, tol=tol, rot_tol=rot_tol, **options)
    reached = np.asarray(found.success, dtype=bool).reshape(c, n)
    q = np.asarray(found.q).reshape(c, n, tree.nq)
    s = singular_values(tree, goal, found.q).reshape(c, n, -1)
    manip = np.where(reached, np.prod(s, -1), 0).sum(-1) / np.maximum(reached.sum(-1), 1)
    order = np.lexsort((-manip, -reached.sum(-1)))
    chosen = best[order]
    return Placement(xy=xy[chosen], yaw=yaw[chosen], reached=reached[order], q=q[order],
                     manipulability=manip[order], grid_x=gx, grid_y=gy, heat=heat)
