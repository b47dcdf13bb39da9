"""Workspaces (seed 000): where a frame can go, and where it can go in many orientations.

The reachable workspace is sampled by batched FK of random configurations
inside the joint limits: a point cloud, its bounding box and the distances from
the chain's base (for a planar chain, the annulus ``inner ≤ r ≤ outer`` in its
plane — ``|L1 − L2| ≤ r ≤ L1 + L2`` for two links). The dexterous part is where
many orientations are reachable: orientations are cut into bins (the angle
in the plane of a planar chain, the direction of the frame's z axis
otherwise), and a point is dexterous when the samples around it (within 1/50
of the workspace's size) saw at least ``dexterous_fraction`` of the bins.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from .errors import InputError, MjkinIOError
from .files import atomic_path
from .tree import Tree

Array = NDArray[np.float64]
ORIENTATION_BINS = 16  # planar: the frame's in-plane angle in 16 sectors (3-D: the 6 faces of a cube)
NEIGHBOURHOOD = 50  # orientations are pooled within 1/50 of the workspace's size around each point


@dataclass(frozen=True)
class Workspace:
    """A sampled workspace of one frame.

    Attributes:
        points: ``(n, 3)`` world positions of the frame over random configurations.
        lo, hi: ``(3,)`` corners of the bounding box.
        base: ``(3,)`` the anchor of the first joint that moves the frame.
        inner, outer: smallest and largest distance from ``base`` (in the plane, for a planar chain).
        normal: ``(3,)`` the plane's normal of a planar chain, else None.
        dexterity: ``(n,)`` fraction of orientation bins reached around each point.
        dexterous: ``(n,)`` the points whose dexterity is at least the threshold.
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

    The dexterous part needs dense samples: with 20 000 on the seeds' three-link arm only 18 % of the
    closed-form dexterous ring came out dexterous (too few samples per neighbourhood to see every
    orientation bin), with the default 100 000 it matches the closed form up to the neighbourhood size.
    """
    from .render import planar_axis

    if int(n) < 2:
        raise InputError(f"a workspace needs at least 2 samples, got {n}")
    if not 0 < dexterous_fraction <= 1:
        raise InputError(f"dexterous_fraction must be in (0, 1], got {dexterous_fraction!r}")
    kind_, idx = tree.frame(frame, kind)  # type: ignore[arg-type]
    body = idx if kind_ == "body" else int(tree.site_body[idx])
    chain = sorted({int(tree.plan.dof_jnt[d]) for d in tree.body_dofs[body]})
    if not chain:
        raise InputError(f"no joint moves {frame!r}: its workspace is a single point")
    q = tree.random_q(np.random.default_rng(seed), int(n))
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
    dexterity = _dexterity(pts, R, normal)
    return Workspace(points=pts, lo=pts.min(0), hi=pts.max(0), base=base, inner=float(dist.min()),
                     outer=float(dist.max()), normal=normal, dexterity=dexterity,
                     dexterous=dexterity >= dexterous_fraction - 1e-12)


def _dexterity(pts: Array, R: Array, normal: Array | None) -> Array:
    """For each point, the fraction of orientation bins seen among the samples around it."""
    if normal is not None:
        u, v = _plane_basis(normal)
        coords = np.stack([pts @ u, pts @ v], axis=-1)
        x = R[:, :, 0]  # the frame's x axis, its angle in the plane
        angle = np.arctan2(x @ v, x @ u)
        orient = np.floor((angle + np.pi) / (2 * np.pi) * ORIENTATION_BINS).astype(np.int64) % ORIENTATION_BINS
        nbins = ORIENTATION_BINS
    else:
        coords = pts
        z = R[:, :, 2]  # the frame's z axis, binned by its dominant component (6 faces of a cube)
        k = np.abs(z).argmax(-1)
        orient = 2 * k + (z[np.arange(len(z)), k] < 0)
        nbins = 6
    from scipy.spatial import cKDTree

    radius = max(float(np.ptp(coords, axis=0).max()), 1e-12) / NEIGHBOURHOOD
    seen = np.zeros((len(coords), nbins), bool)
    for i, near in enumerate(cKDTree(coords).query_ball_point(coords, radius)):
        seen[i, orient[near]] = True
    return seen.sum(-1) / nbins


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
