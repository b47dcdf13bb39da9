"""Centre of mass: a soft target for the whole figure's CoM, and balance over support frames (a hard constraint).

:func:`CenterOfMass` makes the goals: :class:`ComTarget` (soft, ``xyz``) and/or
:class:`Balance` (hard, ``support``). A kind is either soft or hard, so both at once
are two goals, returned as a list (``mjkin.solve`` takes nested lists).
"""

from __future__ import annotations

import itertools
from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, ClassVar

import numpy as np
from numpy.typing import ArrayLike

from ..errors import GoalError
from ..kinematics.com import com_kernel
from ..kinematics.geoms import BOX, CAPSULE, CYLINDER, ELLIPSOID, PLANE, SPHERE
from ..kinematics.jacobian import jacobian_kernel
from ..runtime.jit import njit, njit_ir_inline
from .base import METRES, Array, Goal, Units, array, number, point
from .residuals import owned

if TYPE_CHECKING:
    from ..kinematics.fk import Kinematics
    from ..kinematics.tree import Tree
    from .residuals import GoalArrays

Support = Sequence[str | tuple[str, ArrayLike]]
INERT = 1.0  # m: the value of a spare balance row (with a zero gradient)
SAME = 1e-3  # m: support points this close in the floor plane at the rest pose count once (the lowest kept)
CORNERS = np.array(list(itertools.product((-1.0, 1.0), repeat=3)))  # (8, 3): a unit box's corner signs
EXTREMES = np.vstack([np.eye(3), -np.eye(3)])  # (6, 3): along each axis, both ways


@dataclass(frozen=True)
class ComTarget(Goal):
    """Put the whole figure's centre of mass at ``xyz (3,)`` or ``(B, 3)`` (world, m): ``g = c - xyz``."""

    xyz: ArrayLike = (0.0, 0.0, 0.0)
    rows: ClassVar[int] = 3
    units: ClassVar[Units] = METRES
    _batched: ClassVar[tuple[str, ...]] = ("xyz",)
    _cores: ClassVar[tuple[int, ...]] = (1,)

    def _validate(self) -> list[Array]:
        return [point(self.xyz, "CenterOfMass xyz")]

    def encode(self, tree: Tree, data: Array, rest: Array) -> None:  # noqa: D102
        data[:, 0:3] = self.targets()[0]


@dataclass(frozen=True)
class Balance(Goal):
    """The centre of mass's projection along gravity inside the support polygon, shrunk by ``margin`` (m); hard.

    ``support``: frames (site or body names, a site first) or ``(frame, offset)`` for a point
    fixed in a frame, at least two entries. A name stands for the sole of its body (see
    :func:`sole`): the points of the body's geoms that bound their footprint, or the frame's
    origin when the body has no geoms; an ``(frame, offset)`` is that one point. Points that
    fall within :data:`SAME` of a lower one along gravity at the rest pose (``qpos0``) count
    once (a level box's top corners over its bottom ones). The polygon is the convex hull of
    the points projected on the plane orthogonal to ``tree.model.opt.gravity`` (``-z`` when
    gravity is zero), taken at the current configuration (the support moves too). One row per
    hull edge, ``s = `` the CoM's signed distance inside that edge ``- margin``; when the
    points lie on a line the hull is a segment: four rows, two sides (``±`` distance from its
    line ``- margin``) and two ends, so two points with ``margin > 0`` are refused.
    ``max(points, 4)`` rows; spare rows read ``INERT`` with a zero gradient.
    """

    support: Support = ()
    margin: float = 0.0
    rows: ClassVar[int] = -1
    units: ClassVar[Units] = METRES
    hard: ClassVar[bool] = True

    def __post_init__(self) -> None:
        super().__post_init__()
        number(self.margin, "CenterOfMass margin (m)")
        self.frames()

    def frames(self) -> list[tuple[str, tuple[float, ...] | None]]:
        """The support as ``(frame, offset)`` pairs, ``offset`` None for a name (its body's sole).

        Raises:
            GoalError: fewer than two, or an entry that is not a name or ``(name, (x, y, z))``.
        """
        if isinstance(self.support, str) or not isinstance(self.support, Sequence) or len(self.support) < 2:
            raise GoalError(f"CenterOfMass support must be a list of at least 2 frame names, got {self.support!r}")
        out: list[tuple[str, tuple[float, ...] | None]] = []
        for s in self.support:
            if isinstance(s, str):
                out.append((s, None))
            elif isinstance(s, tuple) and len(s) == 2 and isinstance(s[0], str):
                out.append((s[0], tuple(float(x) for x in array(s[1], (3,), f"CenterOfMass offset of {s[0]}"))))
            else:
                raise GoalError(f"CenterOfMass support entries are frame names or (name, (x, y, z)), got {s!r}")
        return out

    def key(self) -> tuple:  # noqa: D102
        return super().key() + (tuple(self.frames()),)

    def nrows(self, tree: Tree) -> int:
        """One row per support point, at least four (a segment's two sides and two ends)."""
        return max(len(self.support_points(tree)), 4)

    def support_points(self, tree: Tree) -> Array:
        """``(S, 4)``: each support point's body and its position in that body (m).

        Raises:
            UnknownNameError: a frame the model does not have.
            GoalError: ``margin > 0`` over fewer than three points (a segment holds nothing inside).
        """
        out = []
        for name, offset in self.frames():
            body, T = tree.frame_body(name)
            local = sole(tree, body) if offset is None else np.zeros((0, 3))
            if not len(local):  # one point: the offset, or the frame's origin when its body has no geoms
                local = (T[:3, 3] + T[:3, :3] @ np.asarray(offset or (0.0, 0.0, 0.0)))[None]
            out.append(np.column_stack([np.full(len(local), body), local]))
        points = distinct(tree, np.concatenate(out))
        if len(points) < 3 and self.margin > 0:
            raise GoalError(f"CenterOfMass support {list(self.support)!r} has {len(points)} distinct points, no "
                            f"area to be {self.margin} m inside; give frames whose bodies have geoms, corners, or "
                            "margin <= 0")
        return points

    def points(self, tree: Tree, q: ArrayLike) -> Array:
        """World positions ``(S, 3)`` of the support points at ``q (nq,)``."""
        return world(self.support_points(tree), tree.fk(q))

    def encode(self, tree: Tree, data: Array, rest: Array) -> None:
        """``[margin, e1 (3), e2 (3)]``: the margin and a basis of the plane orthogonal to gravity."""
        data[:, 0] = float(self.margin)
        data[:, 1:7] = floor_basis(tree)[1:].reshape(-1)


def floor_basis(tree: Tree) -> Array:
    """``[up, e1, e2] (3, 3)``: up (against gravity; ``z`` when there is none) and a basis of the floor plane."""
    grav = np.asarray(tree.model.opt.gravity, dtype=np.float64)
    up = -grav / np.linalg.norm(grav) if np.linalg.norm(grav) > 0 else np.array([0.0, 0.0, 1.0])
    e1 = np.cross(up, np.eye(3)[int(np.argmin(np.abs(up)))])
    e1 /= np.linalg.norm(e1)
    return np.array([up, e1, np.cross(up, e1)])


def sole(tree: Tree, body: int) -> Array:
    """The points ``(K, 3)`` (body frame, m) bounding the footprint of ``body``'s geoms (none: ``(0, 3)``).

    The geoms that collide (``contype`` or ``conaffinity`` set), or all when none do;
    planes are ground, left out. Per geom, in its frame: a sphere its centre (it touches at
    one point); a box its eight corners; a capsule or cylinder its two end centres offset
    by the radius along its ``x`` and ``y`` axes; an ellipsoid its six extremes; a mesh,
    height field or SDF the corners of its bounding box (MuJoCo's ``geom_aabb``).
    """
    m, geoms = tree.model, tree.geoms
    own = np.flatnonzero((geoms.body == body) & (geoms.type != PLANE))
    touching = own[(m.geom_contype[own] != 0) | (m.geom_conaffinity[own] != 0)]
    out = [geoms.pos[g] + _local(int(geoms.type[g]), geoms.size[g], m.geom_aabb[g]) @ geoms.rot[g].T
           for g in (touching if len(touching) else own)]
    return np.concatenate(out) if out else np.zeros((0, 3))


def _local(kind: int, size: Array, aabb: Array) -> Array:
    """The points ``(K, 3)`` bounding the footprint of a geom of type ``kind`` in its own frame (see :func:`sole`)."""
    if kind == SPHERE:
        return np.zeros((1, 3))
    if kind == BOX:
        return CORNERS * size
    if kind in (CAPSULE, CYLINDER):
        ring = EXTREMES[[0, 1, 3, 4]] * size[0]
        return np.vstack([ring - [0.0, 0.0, size[1]], ring + [0.0, 0.0, size[1]]])
    if kind == ELLIPSOID:
        return EXTREMES * size
    return aabb[:3] + CORNERS * aabb[3:]


def world(points: Array, T: Array) -> Array:
    """World positions ``(S, 3)`` of ``points (S, 4)`` (``[body, x, y, z]``); ``T (nbody, 4, 4)`` the body poses."""
    Tb = T[points[:, 0].astype(np.int64)]
    return np.einsum("sij,sj->si", Tb[:, :3, :3], points[:, 1:]) + Tb[:, :3, 3]


def distinct(tree: Tree, points: Array) -> Array:
    """``points (S, 4)`` without those within :data:`SAME` in the plane of a lower one at ``qpos0``, in order."""
    basis = floor_basis(tree)
    w = world(points, tree.fk(tree.qpos0)) @ basis.T  # [height, x, y]
    kept: list[int] = []
    for k in np.argsort(w[:, 0], kind="stable"):
        if all(np.hypot(*(w[k, 1:] - w[j, 1:])) > SAME for j in kept):
            kept.append(int(k))
    return points[sorted(kept)]


def CenterOfMass(xyz: ArrayLike | None = None, support: Support | None = None, margin: float = 0.0, *,  # noqa: N802
                 weight: float = 1.0, priority: int = 0) -> Goal | list[Goal]:
    """A soft centre-of-mass target ``xyz`` (:class:`ComTarget`) and/or hard balance over ``support``.

    Both given: the two goals as a list (pass it among the goals; lists nest).

    Raises:
        GoalError: neither given, or either malformed.
    """
    out: list[Goal] = []
    if xyz is not None:
        out.append(ComTarget(xyz, weight=weight, priority=priority))
    if support is not None:
        out.append(Balance(support, margin, weight=weight, priority=priority))
    if not out:
        raise GoalError("CenterOfMass needs xyz (a target) and/or support (frames to balance over)")
    return out[0] if len(out) == 1 else out


@njit
def _edge_row(c: Array, Jc: Array, P: Array, JP: Array, a: int, b: int, along: bool, e1: Array, e2: Array,
              margin: float, g: Array, J: Array, r: int) -> None:
    """Row ``r``: ``u · (c - P[a]) - margin`` in the plane, ``u`` the left normal of ``a → b`` (or its direction).

    ``u`` turns with the edge: ``dn = -t (n·dd)/L``, ``dt = n (n·dd)/L`` for ``d = P[b] - P[a]``.
    """
    dx, dy, wx, wy = 0.0, 0.0, 0.0, 0.0
    for k in range(3):
        dx += (P[b, k] - P[a, k]) * e1[k]
        dy += (P[b, k] - P[a, k]) * e2[k]
        wx += (c[k] - P[a, k]) * e1[k]
        wy += (c[k] - P[a, k]) * e2[k]
    L = np.sqrt(dx * dx + dy * dy)
    tx, ty = dx / L, dy / L
    nx, ny = -ty, tx
    if along:
        ux, uy, kappa = tx, ty, (wx * nx + wy * ny) / L
    else:
        ux, uy, kappa = nx, ny, -(wx * tx + wy * ty) / L
    g[r] = ux * wx + uy * wy - margin
    for j in range(J.shape[1]):
        du, dn = 0.0, 0.0
        for k in range(3):
            u3, n3 = ux * e1[k] + uy * e2[k], nx * e1[k] + ny * e2[k]
            du += u3 * (Jc[k, j] - JP[a, k, j])
            dn += n3 * (JP[b, k, j] - JP[a, k, j])
        J[r, j] = du + kappa * dn


@njit
def _hull(x: Array, y: Array, out: np.ndarray) -> int:
    """Gift wrapping: the convex hull of ``(x, y)`` counter-clockwise into ``out``; returns its size (1: one point)."""
    n = x.shape[0]
    start = 0
    for k in range(n):
        if x[k] < x[start] or (x[k] == x[start] and y[k] < y[start]):
            start = k
    h, cur = 0, start
    while h < n:
        out[h] = cur
        h += 1
        nxt = cur
        for j in range(n):
            if j == cur:
                continue
            cross = (x[nxt] - x[cur]) * (y[j] - y[cur]) - (y[nxt] - y[cur]) * (x[j] - x[cur])
            far = (x[j] - x[cur]) ** 2 + (y[j] - y[cur]) ** 2 > (x[nxt] - x[cur]) ** 2 + (y[nxt] - y[cur]) ** 2
            if nxt == cur or cross < 0.0 or (cross == 0.0 and far):
                nxt = j
        if nxt == start or (x[nxt] == x[cur] and y[nxt] == y[cur]):
            break
        cur = nxt
    return h


@njit
def balance_rows(kin: Kinematics, support: np.ndarray, support_pos: Array, i: int, rot: Array, pos: Array,
                 irot: Array, ipos: Array, margin: float, e1: Array, e2: Array, g: Array, J: Array, r0: int,
                 k: int) -> None:
    """Rows ``r0:r0+k`` of goal ``i``'s balance (see :class:`Balance`).

    ``support (S, 2)``: ``[goal, body]`` of every support point, each goal's contiguous;
    ``support_pos (S, 3)`` their positions in their bodies.
    """
    lo, hi = owned(support[:, 0], i)
    n, nv = hi - lo, J.shape[1]
    c, Jc = np.empty(3), np.empty((3, nv))
    com_kernel(kin, rot, pos, irot, ipos, c, Jc)
    P, JP, J6 = np.empty((n, 3)), np.empty((n, 3, nv)), np.empty((1, 6, nv))
    x, y, pt = np.empty(n), np.empty(n), np.empty((1, 3))
    for s in range(n):
        bd = support[lo + s, 1]
        for a in range(3):
            pt[0, a] = pos[0, bd, a] + (rot[0, bd, a, 0] * support_pos[lo + s, 0]
                                        + rot[0, bd, a, 1] * support_pos[lo + s, 1]
                                        + rot[0, bd, a, 2] * support_pos[lo + s, 2])
            P[s, a] = pt[0, a]
        J6[:] = 0.0
        jacobian_kernel(rot, pos, irot, ipos, kin.body_dof_idx[kin.body_dof_ptr[bd]:kin.body_dof_ptr[bd + 1]],
                        kin.dof_body, kin.dof_inner, kin.dof_axis, kin.dof_world, kin.dof_rot, kin.dof_anchor, pt, J6)
        JP[s] = J6[0, :3]
        x[s] = P[s, 0] * e1[0] + P[s, 1] * e1[1] + P[s, 2] * e1[2]
        y[s] = P[s, 0] * e2[0] + P[s, 1] * e2[1] + P[s, 2] * e2[2]
    hull = np.empty(n, dtype=np.int64)
    h = _hull(x, y, hull)
    for r in range(r0, r0 + k):
        g[r] = INERT
        for j in range(nv):
            J[r, j] = 0.0
    if h >= 3:
        for e in range(h):
            _edge_row(c, Jc, P, JP, hull[e], hull[(e + 1) % h], False, e1, e2, margin, g, J, r0 + e)
    elif h == 2:
        a, b = hull[0], hull[1]
        _edge_row(c, Jc, P, JP, a, b, False, e1, e2, margin, g, J, r0)
        _edge_row(c, Jc, P, JP, b, a, False, e1, e2, margin, g, J, r0 + 1)
        _edge_row(c, Jc, P, JP, a, b, True, e1, e2, margin, g, J, r0 + 2)
        _edge_row(c, Jc, P, JP, b, a, True, e1, e2, margin, g, J, r0 + 3)
    else:  # every point in one place: minus the distance from it
        a = hull[0]
        wx = (c[0] - P[a, 0]) * e1[0] + (c[1] - P[a, 1]) * e1[1] + (c[2] - P[a, 2]) * e1[2]
        wy = (c[0] - P[a, 0]) * e2[0] + (c[1] - P[a, 1]) * e2[1] + (c[2] - P[a, 2]) * e2[2]
        d = np.sqrt(wx * wx + wy * wy)
        g[r0] = -d - margin
        for j in range(nv):
            for q3 in range(3):
                u3 = (wx * e1[q3] + wy * e2[q3]) / d if d > 0.0 else 0.0
                J[r0, j] -= u3 * (Jc[q3, j] - JP[a, q3, j])


@njit_ir_inline
def residual(kin: Kinematics, ga: GoalArrays, ws: tuple, rot: Array, pos: Array, irot: Array, ipos: Array, i: int,
             b: int, q: Array, g: Array, J: Array, r0: int, err: Array) -> None:
    """``w (c - xyz)``, three rows; the error is the distance (m)."""
    c, Jc = ws[5], np.empty((3, J.shape[1]))
    com_kernel(kin, rot, pos, irot, ipos, c, Jc)
    w = ga.sqrt_w[i]
    for a in range(3):
        g[r0 + a] = w * (c[a] - ga.data[b, i, a])
        for j in range(J.shape[1]):
            J[r0 + a, j] = w * Jc[a, j]
    err[i, 0] = np.sqrt((c[0] - ga.data[b, i, 0]) ** 2 + (c[1] - ga.data[b, i, 1]) ** 2
                        + (c[2] - ga.data[b, i, 2]) ** 2)


@njit_ir_inline
def balance_residual(kin: Kinematics, ga: GoalArrays, ws: tuple, rot: Array, pos: Array, irot: Array, ipos: Array,
                     i: int, b: int, q: Array, g: Array, J: Array, r0: int, err: Array) -> None:
    """The support polygon's edge rows ``s`` (m), unweighted, and their gradients."""
    balance_rows(kin, ga.support, ga.support_pos, i, rot, pos, irot, ipos, ga.data[b, i, 0], ga.data[b, i, 1:4],
                 ga.data[b, i, 4:7], g, J, r0, ga.row[i + 1] - ga.row[i])
