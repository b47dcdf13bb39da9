"""Signed distances of geom pairs from mjkin's FK, with witness points and gradients.

:func:`pair_distance` is the compiled signed distance of one pair for one
configuration's FK output (negative: penetration depth), with witness points on
each geom; :func:`pair_distance_jacobian` adds its gradient ``n·(J_p2 − J_p1)``
along the unit normal ``n`` from geom 1 to geom 2. Pairs computed here
(:func:`mjkin.kinematics.geoms.native`): any two of sphere, capsule, ellipsoid,
cylinder, box and mesh (its convex hull, as MuJoCo collides it), and a plane with any
of them (planes are half-spaces, as in MuJoCo). Other pairs (height fields, SDFs) go through
:func:`fallback_distance`, which asks ``mujoco.mj_geomDistance`` with the geom
frames taken from mjkin's FK.

Methods: sphere and capsule are a point or a segment swept by a radius, so a
pair's distance is its cores' distance less the radii. Segment–segment is the
closed form of Ericson, *Real-Time Collision Detection* §5.1.9. A segment
clear of a box: the nearest of its ends and the box's edges (exact). A segment
against a cylinder, or into a box, minimises the point's signed distance to the
solid (closed form, convex along the segment) by golden-section search; for a
separated pair this is the exact distance (to ~1e-12 of the segment's length),
for a penetrating capsule it is its deepest point's depth. Box–box: the
separating-axis test (15 axes); separated boxes take the least of the
vertex–box and edge–edge distances (exact), overlapping ones the smallest
overlap along the axes (the penetration depth). Ellipsoids, cylinder–cylinder,
cylinder–box and meshes: :func:`mjkin.kinematics.gjk.gjk`; a sphere or capsule against a mesh
is its core (a point or segment) against the hull, less its radius, so a shallow penetration
is exact.
"""

from __future__ import annotations

from typing import Protocol

import mujoco
import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..runtime.jit import njit, njit_inline
from ..runtime.numba_ext import borrowed, on_stack, unshared
from .fk import Bodies, Kinematics
from .frames import forward, point_jacobian
from .geoms import (
    BOX,
    CAPSULE,
    CYLINDER,
    ELLIPSOID,
    MESH,
    PLANE,
    SPHERE,
    Geoms,
    contact_pairs,
    geom_world,
    native,
    native_pairs,
)
from .gjk import gjk, support, support_any
from .jacobian import jacobian_kernel

Array = NDArray[np.float64]
Index = NDArray[np.int64]


class Measured(Bodies, Protocol):
    """What the batched distance functions read of a tree (a :class:`mjkin.Tree` is one)."""

    @property
    def geoms(self) -> Geoms: ...  # noqa: D102
    @property
    def kin(self) -> Kinematics: ...  # noqa: D102
    def check_q(self, q: ArrayLike, name: str = "q") -> Array: ...  # noqa: D102

GOLDEN = 0.6180339887498949
GOLDEN_STEPS = 60  # golden-section steps along a segment: 0.618^60 ≈ 3e-13 of its length
FALLBACK_DISTMAX = 10.0  # m: mj_geomDistance reports at most this


@njit
def segments_closest(a: Array, u: Array, b: Array, w: Array) -> tuple[float, float]:
    """Parameters ``(s, t)`` in ``[0, 1]`` of the closest points of segments ``a + s u`` and ``b + t w``.

    Ericson §5.1.9, zero-length segments allowed; for parallel segments one of the closest pairs.
    """
    A = u[0] * u[0] + u[1] * u[1] + u[2] * u[2]
    E = w[0] * w[0] + w[1] * w[1] + w[2] * w[2]
    B = u[0] * w[0] + u[1] * w[1] + u[2] * w[2]
    d0, d1, d2 = a[0] - b[0], a[1] - b[1], a[2] - b[2]
    C = u[0] * d0 + u[1] * d1 + u[2] * d2
    F = w[0] * d0 + w[1] * d1 + w[2] * d2
    tiny = 1e-300
    if A <= tiny and E <= tiny:
        return 0.0, 0.0
    if A <= tiny:
        return 0.0, min(max(F / E, 0.0), 1.0)
    if E <= tiny:
        return min(max(-C / A, 0.0), 1.0), 0.0
    # s = (B F - C E) / (A E - B²) = -n·(d × w) / |n|² with n = u × w, d = a - b (Lagrange's identity): the
    # cross products keep their accuracy where A E - B² cancels (near-parallel segments crossing put 1.6e-9
    # between segments that meet, with 2 m segments 6e-8 rad apart)
    n0, n1, n2 = u[1] * w[2] - u[2] * w[1], u[2] * w[0] - u[0] * w[2], u[0] * w[1] - u[1] * w[0]
    denom = n0 * n0 + n1 * n1 + n2 * n2
    # only exactly parallel segments take s = 0: a cut-off (1e-14 A E) put two segments crossing at a hair's
    # angle 1e-7 apart, while a near-parallel pair's s, clamped, still gives a closest pair
    s = min(max(-(n0 * (d1 * w[2] - d2 * w[1]) + n1 * (d2 * w[0] - d0 * w[2]) + n2 * (d0 * w[1] - d1 * w[0]))
                / denom, 0.0), 1.0) if denom > 0.0 else 0.0
    t = (B * s + F) / E
    if t < 0.0:
        return min(max(-C / A, 0.0), 1.0), 0.0
    if t > 1.0:
        return min(max((B - C) / A, 0.0), 1.0), 1.0
    return s, t


@njit
def solid_distance(kind: int, size: Array, R: Array, c: Array, p: Array, y: Array, n: Array) -> float:
    """Signed distance of the point ``p`` from a box or cylinder (axes ``R``, centre ``c``); closest surface point
    ``y`` and outward unit normal ``n`` there (world), ``p = y + d n``.
    """  # noqa: D205
    S = on_stack(9)  # p in the solid's frame x; yl, nl: y and n there
    x, yl, nl = unshared(S, 0, (3,)), unshared(S, 3, (3,)), unshared(S, 6, (3,))
    nl[0] = nl[1] = nl[2] = 0.0
    for i in range(3):
        x[i] = R[0, i] * (p[0] - c[0]) + R[1, i] * (p[1] - c[1]) + R[2, i] * (p[2] - c[2])
    if kind == BOX:
        out = 0.0
        for i in range(3):
            yl[i] = min(max(x[i], -size[i]), size[i])
            out += (x[i] - yl[i]) ** 2
        if out > 0.0:
            d = np.sqrt(out)
            for i in range(3):
                nl[i] = (x[i] - yl[i]) / d
        else:  # inside: out through the nearest face
            k, d = 0, -np.inf
            for i in range(3):
                if abs(x[i]) - size[i] > d:
                    k, d = i, abs(x[i]) - size[i]
            sg = 1.0 if x[k] >= 0.0 else -1.0
            yl[k] = sg * size[k]
            nl[k] = sg
    else:  # cylinder: radius size[0], half-height size[1] along z
        r, h = size[0], size[1]
        rho = np.sqrt(x[0] * x[0] + x[1] * x[1])
        ex, ey = (x[0] / rho, x[1] / rho) if rho > 0.0 else (1.0, 0.0)
        qr, qz = rho - r, abs(x[2]) - h
        sz = 1.0 if x[2] >= 0.0 else -1.0
        if qr > 0.0 or qz > 0.0:
            rr = min(rho, r)
            yl[0], yl[1], yl[2] = rr * ex, rr * ey, min(max(x[2], -h), h)
            d = np.sqrt(max(qr, 0.0) ** 2 + max(qz, 0.0) ** 2)
            for i in range(3):
                nl[i] = (x[i] - yl[i]) / d
        elif qr > qz:  # inside, nearer the side
            d = qr
            yl[0], yl[1], yl[2] = r * ex, r * ey, x[2]
            nl[0], nl[1] = ex, ey
        else:  # inside, nearer a cap
            d = qz
            yl[0], yl[1], yl[2] = x[0], x[1], sz * h
            nl[2] = sz
    for i in range(3):
        y[i] = c[i] + R[i, 0] * yl[0] + R[i, 1] * yl[1] + R[i, 2] * yl[2]
        n[i] = R[i, 0] * nl[0] + R[i, 1] * nl[1] + R[i, 2] * nl[2]
    return d


@njit_inline
def _local_distance(kind: int, size: Array, x0: float, x1: float, x2: float) -> float:
    """:func:`solid_distance`'s value alone, for a point ``(x0, x1, x2)`` in the solid's frame."""
    if kind == BOX:
        q0, q1, q2 = abs(x0) - size[0], abs(x1) - size[1], abs(x2) - size[2]
    else:
        q0, q1, q2 = np.sqrt(x0 * x0 + x1 * x1) - size[0], abs(x2) - size[1], -np.inf
    out = max(q0, 0.0) ** 2 + max(q1, 0.0) ** 2 + max(q2, 0.0) ** 2
    return np.sqrt(out) if out > 0.0 else max(q0, q1, q2)


@njit_inline
def _along(kind: int, size: Array, R: Array, c: Array, a: Array, u: Array, t: float) -> float:
    """:func:`solid_distance` of the point ``a + t u``, its value alone."""
    p0, p1, p2 = a[0] + t * u[0] - c[0], a[1] + t * u[1] - c[1], a[2] + t * u[2] - c[2]
    return _local_distance(kind, size, R[0, 0] * p0 + R[1, 0] * p1 + R[2, 0] * p2,
                           R[0, 1] * p0 + R[1, 1] * p1 + R[2, 1] * p2, R[0, 2] * p0 + R[1, 2] * p1 + R[2, 2] * p2)


@njit
def _segment_hits_box(a: Array, u: Array, size: Array, R: Array, c: Array) -> bool:
    """Whether the segment ``a + t u`` meets the box (slab clipping in the box's frame)."""
    lo, hi = 0.0, 1.0
    for i in range(3):
        x = R[0, i] * (a[0] - c[0]) + R[1, i] * (a[1] - c[1]) + R[2, i] * (a[2] - c[2])
        v = R[0, i] * u[0] + R[1, i] * u[1] + R[2, i] * u[2]
        if v == 0.0:
            if abs(x) > size[i]:
                return False
            continue
        t1, t2 = (-size[i] - x) / v, (size[i] - x) / v
        lo, hi = max(lo, min(t1, t2)), min(hi, max(t1, t2))
        if lo > hi:
            return False
    return True


@njit
def _segment_box_apart(a: Array, u: Array, size: Array, R: Array, c: Array, p: Array, y: Array,
                       n: Array) -> float:
    """:func:`segment_solid` for a segment clear of a box: the nearest of its ends and the box's edges (exact)."""
    d, best = _along(BOX, size, R, c, a, u, 0.0), 0.0  # best: the segment's end t (0, 1), or -1 - edge k
    f = _along(BOX, size, R, c, a, u, 1.0)
    if f < d:
        d, best = f, 1.0
    S = on_stack(6)
    e, w = unshared(S, 0, (3,)), unshared(S, 3, (3,))
    for k in range(12):
        _box_edge(size, R, c, k, e, w)
        s, t = segments_closest(a, u, e, w)
        f = np.sqrt((e[0] + t * w[0] - a[0] - s * u[0]) ** 2 + (e[1] + t * w[1] - a[1] - s * u[1]) ** 2
                    + (e[2] + t * w[2] - a[2] - s * u[2]) ** 2)
        if f < d:
            d, best = f, -1.0 - k
    if best >= 0.0:
        for i in range(3):
            p[i] = a[i] + best * u[i]
        return solid_distance(BOX, size, R, c, p, y, n)
    _box_edge(size, R, c, int(-1.0 - best), e, w)
    s, t = segments_closest(a, u, e, w)
    for i in range(3):
        p[i], y[i] = a[i] + s * u[i], e[i] + t * w[i]
        n[i] = (p[i] - y[i]) / d
    return d


@njit
def segment_solid(a: Array, u: Array, kind: int, size: Array, R: Array, c: Array, p: Array, y: Array,
                  n: Array) -> float:
    """Least signed distance of the segment ``a + t u`` (``t`` in ``[0, 1]``) from a box or cylinder.

    Golden-section search of the convex function ``t -> solid_distance`` (a segment
    clear of a box: its ends and the box's edges, exact); writes the segment's point
    ``p``, the solid's closest point ``y`` and its normal ``n`` there.
    """
    best = 0.0
    if kind == BOX and not _segment_hits_box(a, u, size, R, c):
        return _segment_box_apart(a, u, size, R, c, p, y, n)
    if u[0] * u[0] + u[1] * u[1] + u[2] * u[2] > 0.0:
        lo, hi = 0.0, 1.0
        x1, x2 = hi - GOLDEN, GOLDEN
        f1, f2 = _along(kind, size, R, c, a, u, x1), _along(kind, size, R, c, a, u, x2)
        for _ in range(GOLDEN_STEPS):
            if f1 <= f2:
                hi, x2, f2 = x2, x1, f1
                x1 = hi - GOLDEN * (hi - lo)
                f1 = _along(kind, size, R, c, a, u, x1)
            else:
                lo, x1, f1 = x1, x2, f2
                x2 = lo + GOLDEN * (hi - lo)
                f2 = _along(kind, size, R, c, a, u, x2)
        best = 0.5 * (lo + hi)
        fb = _along(kind, size, R, c, a, u, best)
        for t in (0.0, 1.0):
            f = _along(kind, size, R, c, a, u, t)
            if f < fb:
                best, fb = t, f
    for i in range(3):
        p[i] = a[i] + best * u[i]
    return solid_distance(kind, size, R, c, p, y, n)


@njit
def _box_corner(size: Array, R: Array, c: Array, k: int, v: Array) -> None:
    """Corner ``k`` (bits: signs along the box axes) of a box."""
    for i in range(3):
        v[i] = c[i]
        for j in range(3):
            v[i] += (size[j] if (k >> j) & 1 else -size[j]) * R[i, j]


@njit
def _box_edge(size: Array, R: Array, c: Array, e: int, a: Array, u: Array) -> None:
    """Edge ``e`` (0..11) of a box as the segment ``a + t u``: along axis ``e // 4``, signs ``e % 4`` on the others."""
    j = e // 4
    j1, j2 = (j + 1) % 3, (j + 2) % 3
    s1 = size[j1] if e & 1 else -size[j1]
    s2 = size[j2] if e & 2 else -size[j2]
    for i in range(3):
        a[i] = c[i] + s1 * R[i, j1] + s2 * R[i, j2] - size[j] * R[i, j]
        u[i] = 2.0 * size[j] * R[i, j]


@njit
def box_box(s1: Array, R1: Array, c1: Array, s2: Array, R2: Array, c2: Array, p1: Array, p2: Array,
            n: Array) -> float:
    """Signed distance of two boxes; witness points ``p1``, ``p2`` and the unit normal ``n`` from box 1 to box 2."""
    S = on_stack(33)  # D, ax, the edge lines q1, u1, q2, u2 and the separated search's v, a, u, b, w
    D, ax = unshared(S, 0, (3,)), unshared(S, 3, (3,))
    for i in range(3):
        D[i] = c2[i] - c1[i]
    best, kbest = -np.inf, 0
    for k in range(15):  # separating axes: 3 + 3 face normals, 9 edge crosses
        if k < 3:
            for i in range(3):
                ax[i] = R1[i, k]
        elif k < 6:
            for i in range(3):
                ax[i] = R2[i, k - 3]
        else:
            ia, ib = (k - 6) // 3, (k - 6) % 3
            ax[0] = R1[1, ia] * R2[2, ib] - R1[2, ia] * R2[1, ib]
            ax[1] = R1[2, ia] * R2[0, ib] - R1[0, ia] * R2[2, ib]
            ax[2] = R1[0, ia] * R2[1, ib] - R1[1, ia] * R2[0, ib]
            norm = np.sqrt(ax[0] * ax[0] + ax[1] * ax[1] + ax[2] * ax[2])
            if norm < 1e-9:
                continue
            for i in range(3):
                ax[i] /= norm
        proj = D[0] * ax[0] + D[1] * ax[1] + D[2] * ax[2]
        reach = 0.0
        for j in range(3):
            reach += s1[j] * abs(R1[0, j] * ax[0] + R1[1, j] * ax[1] + R1[2, j] * ax[2])
            reach += s2[j] * abs(R2[0, j] * ax[0] + R2[1, j] * ax[1] + R2[2, j] * ax[2])
        sep = abs(proj) - reach
        if sep > best:
            best, kbest = sep, k
            sg = 1.0 if proj >= 0.0 else -1.0
            for i in range(3):
                n[i] = sg * ax[i]
    if best <= 0.0:  # overlap by the least overlap along n: witnesses on the features that meet
        if kbest < 3:  # box 2's deepest corner under box 1's face
            for i in range(3):
                ax[i] = -n[i]
            support(BOX, s2, R2, c2, ax, p2)
            for i in range(3):
                p1[i] = p2[i] - best * n[i]
        elif kbest < 6:  # box 1's deepest corner under box 2's face
            support(BOX, s1, R1, c1, n, p1)
            for i in range(3):
                p2[i] = p1[i] + best * n[i]
        else:  # edge against edge: the closest points of the lines through box 1's edge along a and box 2's
            # along b (p2 - p1 = d n even where the edges' own closest points would be their ends)
            ia, ib = (kbest - 6) // 3, (kbest - 6) % 3
            q1, u1, q2, u2 = unshared(S, 6, (3,)), unshared(S, 9, (3,)), unshared(S, 12, (3,)), unshared(S, 15, (3,))
            for i in range(3):
                ax[i] = -n[i]
            support(BOX, s1, R1, c1, n, q1)
            support(BOX, s2, R2, c2, ax, q2)
            for i in range(3):  # the lines through the supporting corners along the edges' axes
                u1[i], u2[i] = R1[i, ia], R2[i, ib]
            A = u1[0] * u1[0] + u1[1] * u1[1] + u1[2] * u1[2]
            E = u2[0] * u2[0] + u2[1] * u2[1] + u2[2] * u2[2]
            B = u1[0] * u2[0] + u1[1] * u2[1] + u1[2] * u2[2]
            C = u1[0] * (q1[0] - q2[0]) + u1[1] * (q1[1] - q2[1]) + u1[2] * (q1[2] - q2[2])
            F = u2[0] * (q1[0] - q2[0]) + u2[1] * (q1[1] - q2[1]) + u2[2] * (q1[2] - q2[2])
            denom = A * E - B * B  # > 0: the edges are not parallel (their cross product is the axis)
            s, t = (B * F - C * E) / denom, (A * F - B * C) / denom
            for i in range(3):
                p1[i], p2[i] = q1[i] + s * u1[i], q2[i] + t * u2[i]
        return best
    d = np.inf  # separated: the nearest of the corner-box and edge-edge pairs, found by value, then placed
    which = 0  # 0..7 box 1's corners, 8..15 box 2's, 16 + 12 e1 + e2 the edge pairs
    v, a, u, b, w = (unshared(S, 18, (3,)), unshared(S, 21, (3,)), unshared(S, 24, (3,)), unshared(S, 27, (3,)),
                     unshared(S, 30, (3,)))
    for k in range(8):  # (a corner is the segment's start, t = 0)
        _box_corner(s1, R1, c1, k, v)
        dk = _along(BOX, s2, R2, c2, v, D, 0.0)
        if dk < d:
            d, which = dk, k
        _box_corner(s2, R2, c2, k, v)
        dk = _along(BOX, s1, R1, c1, v, D, 0.0)
        if dk < d:
            d, which = dk, 8 + k
    for e1 in range(12):
        _box_edge(s1, R1, c1, e1, a, u)
        for e2 in range(12):
            _box_edge(s2, R2, c2, e2, b, w)
            s, t = segments_closest(a, u, b, w)
            dk = np.sqrt((b[0] + t * w[0] - a[0] - s * u[0]) ** 2 + (b[1] + t * w[1] - a[1] - s * u[1]) ** 2
                         + (b[2] + t * w[2] - a[2] - s * u[2]) ** 2)
            if dk < d:
                d, which = dk, 16 + 12 * e1 + e2
    if which < 8:
        _box_corner(s1, R1, c1, which, p1)
        d = solid_distance(BOX, s2, R2, c2, p1, p2, n)
    elif which < 16:
        _box_corner(s2, R2, c2, which - 8, p2)
        d = solid_distance(BOX, s1, R1, c1, p2, p1, n)
    else:
        _box_edge(s1, R1, c1, (which - 16) // 12, a, u)
        _box_edge(s2, R2, c2, (which - 16) % 12, b, w)
        s, t = segments_closest(a, u, b, w)
        for i in range(3):
            p1[i], p2[i] = a[i] + s * u[i], b[i] + t * w[i]
    for i in range(3):
        n[i] = (p2[i] - p1[i]) / d
    return d


@njit
def _core(kind: int, size: Array, R: Array, c: Array, a: Array, u: Array) -> float:
    """A sphere or capsule as its core segment ``a + t u`` and radius (returned)."""
    h = size[1] if kind == CAPSULE else 0.0
    for i in range(3):
        a[i] = c[i] - h * R[i, 2]
        u[i] = 2.0 * h * R[i, 2]
    return size[0]


@njit
def pair_distance_normal(geoms: Geoms, rot: Array, pos: Array, g1: int, g2: int, p1: Array, p2: Array,
                         n: Array, cutoff: float) -> float:
    """:func:`pair_distance`, also writing the unit normal ``n (3,)`` from geom 1 to geom 2 (``p2 - p1 = d n``).

    A pair measured by :func:`~mjkin.kinematics.gjk.gjk` and found farther apart than ``cutoff`` (m; ``np.inf``:
    never) reads a lower bound of its distance above ``cutoff``, its points and normal unwritten.
    """
    # views without reference counts (mjkin.jit): each counted view or array passed on cost two atomic updates,
    # and a sphere pair took 0.4 µs, nearly all of it counting
    geoms, rot, pos, p1, p2, n = borrowed((geoms, rot, pos, p1, p2, n))
    swap = geoms.type[g1] > geoms.type[g2]  # order by type, as MuJoCo does
    ga, gb = (g2, g1) if swap else (g1, g2)
    qa, qb = (p2, p1) if swap else (p1, p2)
    ta, tb = geoms.type[ga], geoms.type[gb]
    S = on_stack(39)  # two frames, then seven points
    Ra, Rb, ca, cb = unshared(S, 0, (3, 3)), unshared(S, 9, (3, 3)), unshared(S, 18, (3,)), unshared(S, 21, (3,))
    geom_world(geoms, rot, pos, ga, Ra, ca)
    geom_world(geoms, rot, pos, gb, Rb, cb)
    sa, sb = geoms.size[ga], geoms.size[gb]
    d = np.nan
    if not native(ta, tb):
        for i in range(3):
            qa[i] = qb[i] = n[i] = np.nan
        return d
    if ta == PLANE:  # the other geom's deepest point below the plane z = 0
        v = unshared(S, 24, (3,))
        for i in range(3):
            n[i] = Ra[i, 2]
            v[i] = -n[i]
        support_any(geoms, gb, tb, sb, Rb, cb, v, qb, -1)
        d = n[0] * (qb[0] - ca[0]) + n[1] * (qb[1] - ca[1]) + n[2] * (qb[2] - ca[2])
        for i in range(3):
            qa[i] = qb[i] - d * n[i]
    elif tb == BOX and ta == BOX:
        d = box_box(sa, Ra, ca, sb, Rb, cb, qa, qb, n)
    elif tb == MESH and (ta == SPHERE or ta == CAPSULE):  # the core against the hull, less the radius
        core = unshared(S, 27, (3,))
        core[0], core[1], core[2] = 0.0, sa[1] if ta == CAPSULE else 0.0, 0.0
        d = gjk(CAPSULE, core, Ra, ca, tb, sb, Rb, cb, qa, qb, n, geoms, ga, gb, cutoff + sa[0]) - sa[0]
        if d > cutoff:
            return d
        for i in range(3):
            qa[i] += sa[0] * n[i]
    elif ta == ELLIPSOID or tb == ELLIPSOID or ta == CYLINDER or tb == MESH:  # cylinder-cylinder, cylinder-box
        d = gjk(ta, sa, Ra, ca, tb, sb, Rb, cb, qa, qb, n, geoms, ga, gb, cutoff)
        if d > cutoff:
            return d
    else:  # a sphere or capsule against a sphere, capsule, cylinder or box
        a, u = unshared(S, 27, (3,)), unshared(S, 30, (3,))
        ra = _core(ta, sa, Ra, ca, a, u)
        if tb == SPHERE or tb == CAPSULE:
            b, w = unshared(S, 33, (3,)), unshared(S, 36, (3,))
            rb = _core(tb, sb, Rb, cb, b, w)
            s, t = segments_closest(a, u, b, w)
            for i in range(3):
                qa[i], qb[i] = a[i] + s * u[i], b[i] + t * w[i]
            core = np.sqrt((qb[0] - qa[0]) ** 2 + (qb[1] - qa[1]) ** 2 + (qb[2] - qa[2]) ** 2)
            if core > 1e-12:
                for i in range(3):
                    n[i] = (qb[i] - qa[i]) / core
            else:  # the cores meet: any direction across them
                n[0], n[1], n[2] = Ra[0, 0], Ra[1, 0], Ra[2, 0]
            d = core - ra - rb
            for i in range(3):
                qa[i] += ra * n[i]
                qb[i] -= rb * n[i]
        else:
            core = segment_solid(a, u, tb, sb, Rb, cb, qa, qb, n)
            d = core - ra
            for i in range(3):
                n[i] = -n[i]
                qa[i] += ra * n[i]
    if swap:
        for i in range(3):
            n[i] = -n[i]
    return d


@njit
def pair_distance(geoms: Geoms, rot: Array, pos: Array, g1: int, g2: int, p1: Array, p2: Array) -> float:
    """Signed distance (m, negative = penetration depth) of geoms ``g1``, ``g2`` for one configuration's FK.

    ``rot``, ``pos``: :func:`mjkin.kinematics.fk.fk_kernel` outputs (leading axis 1).
    Writes the witness points ``p1 (3,)`` on ``g1`` and ``p2 (3,)`` on ``g2`` (world);
    NaN everywhere for a pair it does not compute (see :func:`native`).
    """
    return pair_distance_normal(geoms, rot, pos, g1, g2, p1, p2, on_stack(3), np.inf)


@njit_inline
def _add_point_rate(kin: Kinematics, rot: Array, pos: Array, irot: Array, ipos: Array, body: int, p: Array,
                    n: Array, sign: float, J6: Array, out: Array) -> None:
    """``out += sign · nᵀ J_p`` for the world point ``p (1, 3)`` fixed to ``body``."""
    p0, p1 = kin.body_dof_ptr[body], kin.body_dof_ptr[body + 1]
    jacobian_kernel(rot, pos, irot, ipos, kin.body_dof_idx[p0:p1], kin.dof_body, kin.dof_inner, kin.dof_axis,
                    kin.dof_world, kin.dof_rot, kin.dof_anchor, p, J6)
    for k in range(p0, p1):
        d = kin.body_dof_idx[k]
        out[d] += sign * (n[0] * J6[0, 0, d] + n[1] * J6[0, 1, d] + n[2] * J6[0, 2, d])


@njit
def distance_gradient(kin: Kinematics, rot: Array, pos: Array, irot: Array, ipos: Array, body1: int, body2: int,
                      p1: Array, p2: Array, n: Array, out: Array) -> None:
    """A pair's distance gradient ``out (nv,) = nᵀ (J_p2 − J_p1)`` from its witness points and normal.

    ``p1 (1, 3)``, ``p2 (1, 3)``: the witness points (world) fixed to ``body1`` and ``body2``;
    ``n (3,)``: the unit normal from the first to the second (:func:`pair_distance_normal`).
    """
    kin, rot, pos, irot, ipos, p1, p2, n, out = borrowed((kin, rot, pos, irot, ipos, p1, p2, n, out))
    for k in range(out.shape[0]):
        out[k] = 0.0
    J6 = unshared(on_stack(6 * out.shape[0]), 0, (1, 6, out.shape[0]))  # jacobian_kernel writes the columns read
    _add_point_rate(kin, rot, pos, irot, ipos, body2, p2, n, 1.0, J6, out)
    _add_point_rate(kin, rot, pos, irot, ipos, body1, p1, n, -1.0, J6, out)


@njit
def pair_distance_jacobian(kin: Kinematics, geoms: Geoms, rot: Array, pos: Array, irot: Array, ipos: Array,
                           g1: int, g2: int, out: Array) -> float:
    """Signed distance of geoms ``g1``, ``g2`` (as :func:`pair_distance`) and its gradient ``out (nv,)``.

    ``out = nᵀ (J_p2 − J_p1)``, the distance's rate per unit velocity, with ``J`` the
    point Jacobians at the witness points fixed to each geom's body and ``n`` the unit
    normal from ``g1`` to ``g2``. NaN and a zero row for a pair it does not compute.
    """
    S = on_stack(9)
    P1, P2, n = unshared(S, 0, (1, 3)), unshared(S, 3, (1, 3)), unshared(S, 6, (3,))
    d = pair_distance_normal(geoms, rot, pos, g1, g2, P1[0], P2[0], n, np.inf)
    if np.isnan(d):
        for k in range(out.shape[0]):
            out[k] = 0.0
        return d
    distance_gradient(kin, rot, pos, irot, ipos, geoms.body[g1], geoms.body[g2], P1, P2, n, out)
    return d


@njit
def _distances(geoms: Geoms, rot: Array, pos: Array, pairs: Index, out: Array) -> None:
    p1, p2 = np.empty(3), np.empty(3)
    for b in range(out.shape[0]):
        for p in range(pairs.shape[0]):
            out[b, p] = pair_distance(geoms, rot[b:b + 1], pos[b:b + 1], pairs[p, 0], pairs[p, 1], p1, p2)


def geom_frames(tree: Measured, rot: Array, pos: Array, geoms: ArrayLike) -> tuple[Array, Array]:
    """World axes ``(len(geoms), 3, 3)`` and origins ``(len(geoms), 3)`` of geoms from one FK output."""
    ids = np.asarray(geoms, dtype=np.int64)
    gs = tree.geoms
    bd = gs.body[ids]
    R = np.einsum("nij,njk->nik", rot[0, bd], gs.rot[ids])
    x = pos[0, bd] + np.einsum("nij,nj->ni", rot[0, bd], gs.pos[ids])
    return R, x


def fallback_distance(tree: Measured, q: ArrayLike, g1: int, g2: int, distmax: float = FALLBACK_DISTMAX,
                      data: mujoco.MjData | None = None) -> tuple[float, Array]:
    """Signed distance of any two geoms by ``mujoco.mj_geomDistance``, and its gradient ``(nv,)``, at ``q (nq,)``.

    The geoms' world frames come from mjkin's FK (written into ``data.geom_xpos``/``geom_xmat``;
    MuJoCo's own kinematics is not run). The gradient is ``nᵀ (J_p2 − J_p1)`` at MuJoCo's
    witness points (``fromto``). Beyond ``distmax`` MuJoCo reports ``distmax`` and the gradient is 0.
    Pass ``data`` (an ``MjData`` of ``tree.model``) to reuse one across calls.
    """
    f = forward(tree, tree.check_q(q).reshape(1, -1))
    d = mujoco.MjData(tree.model) if data is None else data
    R, x = geom_frames(tree, f.rot, f.pos, [g1, g2])
    for k, g in enumerate((g1, g2)):
        d.geom_xpos[g] = x[k]
        d.geom_xmat[g] = R[k].reshape(9)
    fromto = np.zeros(6)
    dist = float(mujoco.mj_geomDistance(tree.model, d, g1, g2, distmax, fromto))
    grad = np.zeros(tree.nv)
    gap = fromto[3:] - fromto[:3]
    length = float(np.linalg.norm(gap))
    if dist >= distmax or length == 0.0:
        return dist, grad
    n = gap / length * (1.0 if dist >= 0 else -1.0)
    b1, b2 = int(tree.geoms.body[g1]), int(tree.geoms.body[g2])
    grad += n @ point_jacobian(f, b2, fromto[None, 3:])[0, :3]
    grad -= n @ point_jacobian(f, b1, fromto[None, :3])[0, :3]
    return dist, grad


def distances(tree: Measured, q: ArrayLike, pairs: ArrayLike | None = None) -> Array:
    """Signed distances ``(..., P)`` of geom pairs (default :func:`contact_pairs`) at ``q (..., nq)``.

    mjkin's own where :func:`native`, else :func:`fallback_distance` (MuJoCo's, from mjkin's FK).
    """
    qs = tree.check_q(q)
    p = contact_pairs(tree) if pairs is None else np.ascontiguousarray(np.asarray(pairs, dtype=np.int64))
    p = p.reshape(-1, 2)
    f = forward(tree, qs)
    B = f.rot.shape[0]
    out = np.empty((B, len(p)))
    _distances(tree.geoms, f.rot, f.pos, p, out)
    slow = np.flatnonzero(~native_pairs(tree.geoms, p))
    if len(slow):
        flat = qs.reshape(B, -1)
        data = mujoco.MjData(tree.model)
        for b in range(B):
            for i in slow:
                out[b, i] = fallback_distance(tree, flat[b], int(p[i, 0]), int(p[i, 1]), data=data)[0]
    return out.reshape(f.batch + (len(p),))

