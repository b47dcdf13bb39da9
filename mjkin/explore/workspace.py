"""Workspaces (as the Polish lecture notes define them): where a frame can go, and where it can go in many orientations.

The reachable workspace is sampled by batched FK of random configurations
inside the joint limits: a point cloud, its bounding box and the distances from
the chain's base (for a planar chain, the annulus ``inner ≤ r ≤ outer`` in its
plane — ``|L1 − L2| ≤ r ≤ L1 + L2`` for two links). The dexterous part is where
every orientation is reachable. Orientations are cut into bins (16 sectors of
the in-plane angle of a planar chain; otherwise the frame's z axis by the face
of a cube it points through) and each bin has one test orientation (the
sector's middle angle; the face's axis, ±x, ±y, ±z). A point is dexterous when
IK puts the frame there in the test orientation of every bin (or of
``dexterous_fraction`` of them), starting each solve from a nearby sample of
that bin, so it converges in a few steps when the pose is reachable.

Pooling the orientations the samples around a point reach, without IK, is
cheaper but blurs the edges by the pooling radius: on the seeds' 15/10/5 arm it
labelled 54 % of the samples dexterous where the closed form
``|L1 − L2| + L3 ≤ r ≤ L1 + L2 − L3`` gives 40.6 %, out to r = 21.35 and in a disc
around the base. Pooling is kept as the first filter (a point whose
neighbourhood misses a bin is not tried). What remains of the error is between
the test orientations: a point just outside the ring, whose unreachable
orientations all fall between two test angles, still counts (0.5 point too
many on that arm).
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import numpy as np
from numpy.typing import NDArray

from .. import spatial
from ..errors import InputError, MjkinIOError
from ..kinematics.tree import Tree, check_tree
from ..runtime.checks import check_count, check_number
from ..runtime.files import atomic_path

Array = NDArray[np.float64]
FrameKind = Literal["body", "site"]
ORIENTATION_BINS = 16  # planar: the frame's in-plane angle in 16 sectors (3-D: the 6 faces of a cube)
NEIGHBOURHOOD = 50  # nearby samples: in cells of at most 1/50 of the workspace's size (and the adjacent ones)
SAMPLES_PER_CELL = 20  # ... and large enough to hold this many samples on average (fewer samples, larger cells)
RETRIES = 2  # restarts of a confirmation that failed (arm7: without them 4 % of the dexterous points were missed)


@dataclass(frozen=True)
class Workspace:
    """A sampled workspace of one frame.

    Attributes:
        points: ``(n, 3)`` world positions of the frame over random configurations.
        lo, hi: ``(3,)`` corners of the bounding box.
        base: ``(3,)`` the anchor of the first joint that moves the frame.
        inner, outer: smallest and largest distance from ``base`` (in the plane, for a planar chain).
        normal: ``(3,)`` the plane's normal of a planar chain, else None.
        dexterity: ``(n,)`` fraction of orientation bins the samples around each point reach (pooled
            from samples alone: an estimate that blurs the edges, not the IK test).
        dexterous: ``(n,)`` the points where IK reaches the test orientation of every bin (or of the
            ``dexterous_fraction`` asked for).
    """

    points: Array
    lo: Array
    hi: Array
    base: Array
    inner: float
    outer: float
    normal: Array | None
    dexterity: Array
    dexterous: NDArray[np.bool_]

    @property
    def planar(self) -> bool:
        """Whether the chain moves in one plane."""
        return self.normal is not None

    def plane_coords(self, points: Array | None = None) -> Array:
        """Coordinates ``(..., 2)`` in the chain's plane about :attr:`base` (planar chains only)."""
        if self.normal is None:
            raise InputError("plane coordinates exist only for a planar chain")
        u, v = _plane_basis(self.normal)
        rel = (self.points if points is None else points) - self.base
        return np.stack([rel @ u, rel @ v], axis=-1)


def _plane_basis(normal: Array) -> tuple[Array, Array]:
    """Two unit vectors spanning the plane normal to ``normal`` (world x first when it lies in the plane)."""
    u = np.array([1.0, 0.0, 0.0]) - normal * normal[0]
    if np.linalg.norm(u) < 1e-6:
        u = np.array([0.0, 1.0, 0.0]) - normal * normal[1]
    u /= np.linalg.norm(u)
    return u, np.cross(normal, u)


def workspace(tree: Tree, frame: str, n: int = 100_000, seed: int = 0, dexterous_fraction: float = 1.0,
              kind: str | None = None) -> Workspace:
    """Sample the workspace of ``frame`` (site or body) with ``n`` random configurations (seeded).

    The dexterous test solves IK at the points whose neighbourhood saw every orientation bin, one
    short solve per bin (on the seeds' three-link arm, 100 000 samples take about 10 s of CPU,
    mostly those solves; arm7's 7 joints about 30 s). The samples only need to be dense enough to
    offer a nearby start in every bin: 5 000 already match the closed form of a three-link arm.
    """
    from ..render import planar_axis

    check_tree(tree)
    n = check_count(n, "workspace samples n", 0, whole_floats=True, most=100_000_000)
    if n < 2:
        raise InputError(f"a workspace needs at least 2 samples, got {n}")
    seed = check_count(seed, "workspace seed", 0, whole_floats=True)
    if not 0 < check_number(dexterous_fraction, "dexterous_fraction") <= 1:
        raise InputError(f"dexterous_fraction must be in (0, 1], got {dexterous_fraction!r}")
    kind_, idx = tree.frame(frame, kind)  # type: ignore[arg-type]
    body = idx if kind_ == "body" else int(tree.site_body[idx])
    chain = sorted({int(tree.plan.dof_jnt[d]) for d in tree.body_dofs[body]})
    if not chain:
        raise InputError(f"no joint moves {frame!r}: its workspace is a single point")
    q = tree.random_q(np.random.default_rng(seed), n)
    T = tree.pose(q, frame, kind_)
    pts, R = T[:, :3, 3], T[:, :3, :3]
    first = chain[0]
    T0 = tree.fk(tree.qpos0)[tree.jnt_body[first]]
    base = T0[:3, :3] @ tree.jnt_pos[first] + T0[:3, 3]
    normal = planar_axis(tree)
    rel = pts - base
    if normal is not None:
        rel = rel - np.outer(rel @ normal, normal)
    dist = np.linalg.norm(rel, axis=-1)
    dexterity, dexterous = _dexterous(tree, frame, kind_, q, pts, R, normal, dexterous_fraction)
    return Workspace(points=pts, lo=pts.min(0), hi=pts.max(0), base=base, inner=float(dist.min()),
                     outer=float(dist.max()), normal=normal, dexterity=dexterity, dexterous=dexterous)


def _dexterous(tree: Tree, frame: str, kind: FrameKind, q: Array, pts: Array, R: Array, normal: Array | None,
               fraction: float) -> tuple[Array, NDArray[np.bool_]]:
    """The pooled dexterity ``(n,)`` and the IK-tested dexterous points ``(n,)`` of samples ``q (n, nq)``.

    ``pts (n, 3)``, ``R (n, 3, 3)``: the frame's world poses at ``q``; ``normal``: a planar chain's.
    """
    coords = np.stack([pts @ a for a in _plane_basis(normal)], axis=-1) if normal is not None else pts
    bins, nbins, angle = _orientation_bins(R, normal)
    near, gap = _nearest_in_bins(coords, bins, nbins)
    need = int(np.ceil(fraction * nbins - 1e-9))
    size = max(float(np.ptp(coords, axis=0).max()), 1e-12)
    confirmed = _confirmed(tree, (frame, kind), q, pts, R, angle, normal, near, gap, need, 1e-6 * size)
    return (near >= 0).mean(1), confirmed >= need


def _orientation_bins(R: Array, normal: Array | None) -> tuple[NDArray[np.int64], int, Array]:
    """Each sample's orientation bin ``(n,)``, the number of bins, and ``(n,)`` in-plane angles (planar only).

    Planar chains: the angle in the plane of the frame's in-plane axis (x, or y when x is the normal), cut into
    :data:`ORIENTATION_BINS` sectors. Otherwise the frame's z axis by its dominant component (a cube's 6 faces).
    """
    if normal is not None:
        u, v = _plane_basis(normal)
        x = R[:, :, 0] if abs(R[0, :, 0] @ normal) < 0.5 else R[:, :, 1]
        angle = np.arctan2(x @ v, x @ u)
        return (np.floor((angle + np.pi) / (2 * np.pi) * ORIENTATION_BINS).astype(np.int64) % ORIENTATION_BINS,
                ORIENTATION_BINS, angle)
    z = R[:, :, 2]
    k = np.abs(z).argmax(-1)
    return 2 * k + (z[np.arange(len(z)), k] < 0), 6, np.zeros(len(z))


def _nearest_in_bins(coords: Array, bins: NDArray[np.int64], nbins: int) -> tuple[NDArray[np.int64], Array]:
    """For each sample and bin, a sample of that bin nearby (``(n, nbins)``, -1 if none) and its squared distance.

    The workspace's box is cut into ``k`` cells a side (``k`` = :data:`NEIGHBOURHOOD`, or fewer so that a cell
    holds :data:`SAMPLES_PER_CELL` samples on average); each cell keeps one sample per bin, and a sample looks in
    its own cell and the adjacent ones (3x3, or 3x3x3), keeping the nearest.
    """
    n, dim = coords.shape
    k = int(np.clip((n / SAMPLES_PER_CELL) ** (1 / dim), 3, NEIGHBOURHOOD))
    h = max(float(np.ptp(coords, axis=0).max()), 1e-12) / k
    side = k + 3  # a margin of one empty cell on each side: every neighbour cell exists
    cell = np.ravel_multi_index((np.minimum(((coords - coords.min(0)) / h).astype(np.int64), k) + 1).T,
                                (side,) * dim)
    table = np.full(side ** dim * nbins, -1, dtype=np.int64)  # (cell, bin) -> a sample there, the last one written
    table[cell * nbins + bins] = np.arange(n)
    best = np.full((n, nbins), -1, dtype=np.int64)
    dist = np.full((n, nbins), np.inf)
    for offset in np.ndindex(*(3,) * dim):
        step = int(np.ravel_multi_index(offset, (side,) * dim)) - int(np.ravel_multi_index((1,) * dim, (side,) * dim))
        rep = table[((cell + step) * nbins)[:, None] + np.arange(nbins)]
        d = np.where(rep >= 0, ((coords[rep] - coords[:, None]) ** 2).sum(-1), np.inf)
        closer = d < dist
        best[closer], dist[closer] = rep[closer], d[closer]
    return best, dist


def _test_rotations(R: Array, angle: Array, bins: NDArray[np.int64], normal: Array | None, nbins: int) -> Array:
    """The orientation tested for bin ``bins[i]``, made from the sample's own ``R[i]`` ``(n, 3, 3)``.

    Planar: ``R`` turned about the normal to the bin's centre angle (an orientation the chain can take).
    Otherwise any rotation whose z axis is the bin's face direction (only z is asked for).
    """
    if normal is not None:
        centre = -np.pi + (bins + 0.5) * (2 * np.pi / nbins)
        return spatial.axis_angle_to_mat(normal, centre - angle) @ R
    faces = np.zeros((6, 3, 3))
    for k in range(3):
        for sign in (1.0, -1.0):
            z = np.eye(3)[k] * sign
            x = np.eye(3)[(k + 1) % 3]
            faces[2 * k + (sign < 0)] = np.stack([x, np.cross(z, x), z], axis=-1)
    return faces[bins]


def _confirmed(tree: Tree, frame: tuple[str, FrameKind], q: Array, pts: Array, R: Array, angle: Array,
               normal: Array | None, near: NDArray[np.int64], dist: Array, need: int, tol: float) -> NDArray[np.int64]:
    """How many bins' test orientations IK reaches at each point (within ``tol`` m), until ``need`` or too many misses.

    Bin ``b`` at point ``i`` is tried from the configuration of ``near[i, b]`` (a nearby sample of that bin),
    farthest neighbour first (the bin most likely to fail at the workspace's edge), so non-dexterous points stop
    early. A point whose neighbourhood lacks more than ``nbins - need`` bins is never tried.
    """
    from .. import goals as G
    from ..ik.solve import solve

    name, kind = frame
    nbins = near.shape[1]
    order = np.argsort(np.where(near >= 0, -dist, np.inf), axis=1, kind="stable")
    done, missed = np.zeros(len(q), np.int64), (near < 0).sum(1)
    for turn in range(nbins):
        there = near[np.arange(len(q)), order[:, turn]] >= 0  # a neighbourhood's missing bins come last
        alive = np.flatnonzero((done < need) & (missed <= nbins - need) & there)
        if not len(alive):
            break
        b = order[alive, turn]
        src = near[alive, b]
        goals = [G.Position(name, pts[alive], kind=kind),
                 G.Orientation(name, _test_rotations(R[src], angle[src], b, normal, nbins), kind=kind,
                               axes="xyz" if normal is not None else "z")]
        res = solve(tree, goals, q0=q[src], tol=tol, rot_tol=1e-5, restarts=RETRIES)
        ok = np.asarray(res.success, dtype=bool)
        done[alive] += ok
        missed[alive] += ~ok
    return done


def plot(ws: Workspace, path: str | os.PathLike[str], title: str = "") -> Path:
    """Draw the workspace to a PNG: reachable points, dexterous ones, and the annulus of a planar chain.

    Raises:
        MjkinIOError: matplotlib is not installed (the ``plot`` extra).
    """
    try:
        import matplotlib
    except ImportError:
        raise MjkinIOError("plotting a workspace needs matplotlib: pip install 'mjkin[plot]'") from None
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    target = Path(path)
    reach, dex = ~ws.dexterous, ws.dexterous
    if ws.planar:
        fig, ax = plt.subplots(figsize=(5.5, 5.5))
        xy = ws.plane_coords()
        ax.scatter(xy[reach, 0], xy[reach, 1], s=1, c="tab:blue", alpha=0.3, label="reachable", rasterized=True)
        ax.scatter(xy[dex, 0], xy[dex, 1], s=1, c="tab:orange", alpha=0.5, label="dexterous (every orientation)",
                   rasterized=True)
        phi = np.linspace(0, 2 * np.pi, 200)
        for r, name in ((ws.inner, "inner"), (ws.outer, "outer")):
            ax.plot(r * np.cos(phi), r * np.sin(phi), "k--", lw=0.8)
            ax.annotate(f"{name} r = {r:.3g}", (r * np.cos(0.8), r * np.sin(0.8)), fontsize=8)
        ax.set_aspect("equal")
        ax.set_xlabel("in-plane x (m)")
        ax.set_ylabel("in-plane y (m)")
        axes = [ax]
    else:
        fig, axes = plt.subplots(1, 2, figsize=(10, 5))
        for ax, (i, j, names) in zip(axes, ((0, 1, "xy"), (0, 2, "xz")), strict=True):
            ax.scatter(ws.points[reach, i], ws.points[reach, j], s=1, c="tab:blue", alpha=0.2, label="reachable",
                       rasterized=True)
            ax.scatter(ws.points[dex, i], ws.points[dex, j], s=1, c="tab:orange", alpha=0.4,
                       label="dexterous (every z direction)", rasterized=True)
            ax.set_aspect("equal")
            ax.set_xlabel(f"{names[0]} (m)")
            ax.set_ylabel(f"{names[1]} (m)")
    axes[0].legend(loc="upper right", fontsize=8, markerscale=6)
    fig.suptitle(title or f"workspace: {len(ws.points)} samples", fontsize=10)
    fig.tight_layout()
    with atomic_path(target) as tmp:
        fig.savefig(tmp, dpi=100, format=target.suffix.lstrip(".").lower() or "png")
    plt.close(fig)
    return target
