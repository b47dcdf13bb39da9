"""Distance between two convex primitives from their support points (Gilbert–Johnson–Keerthi).

For the pairs without a closed form in :mod:`mjkin.kinematics.distance`:
ellipsoids, cylinder–cylinder, cylinder–box, and meshes (their convex hulls, as MuJoCo collides
them: a hull's support point is found by climbing its vertex graph, :func:`hull_support`).
GJK walks a simplex of support points of the Minkowski difference towards the origin; apart shapes get their
distance to :data:`GJK_TOL` with the closest points. Overlapping shapes get the
deepest separation over their axes and the axes' cross products, an estimate at
least as deep as the true penetration.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from ..runtime.jit import njit
from ..runtime.numba_ext import on_stack, unshared, unshared_int64
from .geoms import BOX, CAPSULE, CYLINDER, MESH, SPHERE, Geoms, direction_cell

Array = NDArray[np.float64]

GJK_STEPS = 100  # support-point iterations, at most
GJK_TOL = 1e-10  # m: GJK stops when the distance is known to this


@njit
def support(kind: int, size: Array, R: Array, c: Array, v: Array, z: Array) -> None:
    """The point ``z`` of a sphere, capsule, ellipsoid, cylinder or box farthest along ``v`` (unit, world)."""
    for i in range(3):
        z[i] = c[i]
    if kind == SPHERE:
        for i in range(3):
            z[i] += size[0] * v[i]
    elif kind == CAPSULE or kind == CYLINDER:
        k = R[0, 2] * v[0] + R[1, 2] * v[1] + R[2, 2] * v[2]
        sg = 1.0 if k >= 0.0 else -1.0
        for i in range(3):
            z[i] += sg * size[1] * R[i, 2]
        if kind == CAPSULE:
            for i in range(3):
                z[i] += size[0] * v[i]
        else:  # the rim, along v's part across the axis
            wn = np.sqrt(max(1.0 - k * k, 0.0))
            if wn > 1e-12:
                for i in range(3):
                    z[i] += size[0] * (v[i] - k * R[i, 2]) / wn
    elif kind == BOX:
        for j in range(3):
            sg = 1.0 if R[0, j] * v[0] + R[1, j] * v[1] + R[2, j] * v[2] >= 0.0 else -1.0
            for i in range(3):
                z[i] += sg * size[j] * R[i, j]
    else:  # ellipsoid: c + R S² Rᵀv / |S Rᵀv|
        sv = on_stack(3)
        norm = 0.0
        for j in range(3):
            sv[j] = size[j] * (R[0, j] * v[0] + R[1, j] * v[1] + R[2, j] * v[2])
            norm += sv[j] * sv[j]
        norm = np.sqrt(norm)
        for j in range(3):
            for i in range(3):
                z[i] += R[i, j] * size[j] * sv[j] / norm


@njit
def hull_support(geoms: Geoms, g: int, R: Array, c: Array, v: Array, z: Array, start: int) -> int:
    """The vertex ``z`` (world) of mesh geom ``g``'s convex hull farthest along ``v`` (world); returns its id.

    Climbs the hull's vertex graph to a vertex no neighbour of which is farther: on a convex hull that is the
    farthest (a hull without a graph is searched vertex by vertex). The climb starts from the farther of
    vertex ``start`` (an id in ``g``'s hull, e.g. the last answer for a direction that changed little; -1:
    none) and the hull's farthest along the centre of ``v``'s direction cell
    (:data:`~mjkin.kinematics.geoms.Geoms.hull_dir`), a few edges from the answer.
    """
    lv0 = R[0, 0] * v[0] + R[1, 0] * v[1] + R[2, 0] * v[2]  # v in the geom's frame
    lv1 = R[0, 1] * v[0] + R[1, 1] * v[1] + R[2, 1] * v[2]
    lv2 = R[0, 2] * v[0] + R[1, 2] * v[1] + R[2, 2] * v[2]
    a, n = geoms.hull_adr[g], geoms.hull_num[g]
    V, adr, nbr = geoms.hull_vert, geoms.hull_nbr_adr, geoms.hull_nbr
    best = geoms.hull_dir[g, direction_cell(lv0, lv1, lv2)]
    top = V[best, 0] * lv0 + V[best, 1] * lv1 + V[best, 2] * lv2
    if a <= start < a + n:
        x = V[start, 0] * lv0 + V[start, 1] * lv1 + V[start, 2] * lv2
        if x > top:
            best, top = start, x
    if adr[a + n] == adr[a]:  # no graph: every vertex
        for k in range(a, a + n):
            x = V[k, 0] * lv0 + V[k, 1] * lv1 + V[k, 2] * lv2
            if x > top:
                best, top = k, x
    else:
        moved = True
        while moved:
            moved = False
            for e in range(adr[best], adr[best + 1]):
                k = nbr[e]
                x = V[k, 0] * lv0 + V[k, 1] * lv1 + V[k, 2] * lv2
                if x > top:
                    best, top, moved = k, x, True
    for i in range(3):
        z[i] = c[i] + R[i, 0] * V[best, 0] + R[i, 1] * V[best, 1] + R[i, 2] * V[best, 2]
    return best


@njit
def support_any(geoms: Geoms, g: int, kind: int, size: Array, R: Array, c: Array, v: Array, z: Array,
                start: int) -> int:
    """:func:`support` of a primitive or :func:`hull_support` of mesh geom ``g`` (returns its vertex id, else -1)."""
    if kind == MESH:
        return hull_support(geoms, g, R, c, v, z, start)
    support(kind, size, R, c, v, z)
    return -1


@njit
def _solve_small(G: Array, r: Array, m: int, out: Array) -> bool:
    """Solve the ``m x m`` (``m <= 3``) system ``G out = r`` by Cramer's rule; False when it is singular."""
    if m == 0:
        return True
    if m == 1:
        if G[0, 0] <= 1e-300:
            return False
        out[0] = r[0] / G[0, 0]
        return True
    if m == 2:
        det = G[0, 0] * G[1, 1] - G[0, 1] * G[1, 0]
        if abs(det) <= 1e-14 * G[0, 0] * G[1, 1]:
            return False
        out[0] = (r[0] * G[1, 1] - G[0, 1] * r[1]) / det
        out[1] = (G[0, 0] * r[1] - r[0] * G[1, 0]) / det
        return True
    det = (G[0, 0] * (G[1, 1] * G[2, 2] - G[1, 2] * G[2, 1]) - G[0, 1] * (G[1, 0] * G[2, 2] - G[1, 2] * G[2, 0])
           + G[0, 2] * (G[1, 0] * G[2, 1] - G[1, 1] * G[2, 0]))
    if abs(det) <= 1e-14 * G[0, 0] * G[1, 1] * G[2, 2]:
        return False
    for k in range(3):  # column k replaced by r
        M00, M10, M20 = (r[0], r[1], r[2]) if k == 0 else (G[0, 0], G[1, 0], G[2, 0])
        M01, M11, M21 = (r[0], r[1], r[2]) if k == 1 else (G[0, 1], G[1, 1], G[2, 1])
        M02, M12, M22 = (r[0], r[1], r[2]) if k == 2 else (G[0, 2], G[1, 2], G[2, 2])
        out[k] = (M00 * (M11 * M22 - M12 * M21) - M01 * (M10 * M22 - M12 * M20)
                  + M02 * (M10 * M21 - M11 * M20)) / det
    return True


@njit
def _simplex_closest(W: Array, A: Array, B: Array, lam: Array, k: int, v: Array) -> int:
    """Reduce the simplex ``W[:k]`` (its support points ``A``, ``B``) to the face nearest the origin.

    Every face with the newest point ``W[k - 1]`` is tried (at most 8): the nearest point of its affine
    hull, kept if its barycentric weights are all non-negative; the nearest kept point is the simplex's
    (Gilbert, Johnson and Keerthi's sub-algorithm, by enumeration). The faces without it are left out: the
    simplex before it already had its nearest point on them, and the newest point is nearer the origin along
    ``v`` than that (else GJK had stopped). Writes it to ``v`` and its weights to ``lam``, keeps only the
    face's rows; returns the face's size.
    """
    best, best_mask = np.inf, 1 << (k - 1)
    S = on_stack(26)  # scratch on the stack, views without reference counts (see mjkin.runtime.jit)
    G, r = unshared(S, 0, (3, 3)), unshared(S, 9, (3,))
    mu, weights, x = unshared(S, 12, (3,)), unshared(S, 15, (4,)), unshared(S, 19, (3,))
    idx = unshared_int64(S, 22, (4,))
    for mask in range(1 << (k - 1), 1 << k):  # the faces with the newest point
        m = 0
        for i in range(k):
            if (mask >> i) & 1:
                idx[m] = i
                m += 1
        o = idx[0]
        for i in range(1, m):  # weights mu of the edges from the face's first point
            for j in range(1, m):
                G[i - 1, j - 1] = ((W[idx[i], 0] - W[o, 0]) * (W[idx[j], 0] - W[o, 0])
                                   + (W[idx[i], 1] - W[o, 1]) * (W[idx[j], 1] - W[o, 1])
                                   + (W[idx[i], 2] - W[o, 2]) * (W[idx[j], 2] - W[o, 2]))
            r[i - 1] = -(W[o, 0] * (W[idx[i], 0] - W[o, 0]) + W[o, 1] * (W[idx[i], 1] - W[o, 1])
                         + W[o, 2] * (W[idx[i], 2] - W[o, 2]))
        if not _solve_small(G, r, m - 1, mu):
            continue
        inside = True
        w0 = 1.0
        for i in range(m - 1):
            w0 -= mu[i]
            inside = inside and mu[i] >= 0.0
        if not inside or w0 < 0.0:
            continue
        for c in range(3):
            x[c] = W[o, c]
            for i in range(1, m):
                x[c] += mu[i - 1] * (W[idx[i], c] - W[o, c])
        dist = x[0] * x[0] + x[1] * x[1] + x[2] * x[2]
        if dist < best:
            best, best_mask = dist, mask
            weights[0] = w0
            for i in range(m - 1):
                weights[i + 1] = mu[i]
    m = 0
    for i in range(k):
        if (best_mask >> i) & 1:
            for c in range(3):
                W[m, c], A[m, c], B[m, c] = W[i, c], A[i, c], B[i, c]
            lam[m] = weights[m]
            m += 1
    for c in range(3):
        v[c] = 0.0
        for i in range(m):
            v[c] += lam[i] * W[i, c]
    return m


@njit
def _overlap(ta: int, sa: Array, Ra: Array, ca: Array, tb: int, sb: Array, Rb: Array, cb: Array, p1: Array,
             p2: Array, n: Array, geoms: Geoms, ga: int, gb: int) -> float:
    """Signed distance of two overlapping convex geoms, estimated by separating axes (their own and crosses).

    The largest separation ``n·(p2 - p1)`` over the candidate axes, with ``p1``, ``p2`` the
    supports along ``±n``: negative, and at least as deep as the true penetration.
    """
    best = -np.inf
    S = on_stack(15)
    ax, u, m, za, zb = (unshared(S, 0, (3,)), unshared(S, 3, (3,)), unshared(S, 6, (3,)), unshared(S, 9, (3,)),
                        unshared(S, 12, (3,)))
    for k in range(16):
        if k < 3:
            for i in range(3):
                ax[i] = Ra[i, k]
        elif k < 6:
            for i in range(3):
                ax[i] = Rb[i, k - 3]
        elif k < 15:
            ia, ib = (k - 6) // 3, (k - 6) % 3
            ax[0] = Ra[1, ia] * Rb[2, ib] - Ra[2, ia] * Rb[1, ib]
            ax[1] = Ra[2, ia] * Rb[0, ib] - Ra[0, ia] * Rb[2, ib]
            ax[2] = Ra[0, ia] * Rb[1, ib] - Ra[1, ia] * Rb[0, ib]
        else:
            for i in range(3):
                ax[i] = cb[i] - ca[i]
        norm = np.sqrt(ax[0] * ax[0] + ax[1] * ax[1] + ax[2] * ax[2])
        if norm < 1e-9:
            continue
        for sg in (1.0, -1.0):  # both ways along the axis: u = sg ax / |ax|, m = -u
            for i in range(3):
                u[i] = sg * ax[i] / norm
                m[i] = -u[i]
            support_any(geoms, ga, ta, sa, Ra, ca, u, za, -1)
            support_any(geoms, gb, tb, sb, Rb, cb, m, zb, -1)
            sep = u[0] * (zb[0] - za[0]) + u[1] * (zb[1] - za[1]) + u[2] * (zb[2] - za[2])
            if sep > best:
                best = sep
                for i in range(3):
                    p1[i], p2[i], n[i] = za[i], zb[i], u[i]
    return best


@njit
def gjk(ta: int, sa: Array, Ra: Array, ca: Array, tb: int, sb: Array, Rb: Array, cb: Array, p1: Array, p2: Array,
        n: Array, geoms: Geoms, ga: int, gb: int, cutoff: float) -> float:
    """Signed distance of two convex geoms (sphere, capsule, ellipsoid, cylinder, box, mesh) by their support points.

    Gilbert–Johnson–Keerthi on the Minkowski difference: separated geoms get their distance
    (to :data:`GJK_TOL`) with the closest points ``p1``, ``p2``; overlapping ones
    :func:`_overlap`'s estimate. Geoms found farther apart than ``cutoff`` (m; ``np.inf``:
    never) stop there: the value is then a lower bound of the distance above ``cutoff``,
    ``p1``, ``p2`` and ``n`` are not written. ``geoms``, ``ga``, ``gb``: where a mesh's hull is
    (read for ``ta`` or ``tb`` :data:`MESH` only).
    """
    S = on_stack(49)
    W, A, B = unshared(S, 0, (4, 3)), unshared(S, 12, (4, 3)), unshared(S, 24, (4, 3))
    lam, v, dir_a, dir_b = unshared(S, 36, (4,)), unshared(S, 40, (3,)), unshared(S, 43, (3,)), unshared(S, 46, (3,))
    for i in range(3):
        v[i] = ca[i] - cb[i]
    vv = v[0] * v[0] + v[1] * v[1] + v[2] * v[2]
    if vv == 0.0:
        v[0], vv = 1.0, 1.0
    k = 0
    wa, wb = -1, -1  # the hulls' last support vertices: the next climb starts there
    for _ in range(GJK_STEPS):
        norm = np.sqrt(vv)
        for i in range(3):
            dir_a[i], dir_b[i] = -v[i] / norm, v[i] / norm
        wa = support_any(geoms, ga, ta, sa, Ra, ca, dir_a, A[k], wa)
        wb = support_any(geoms, gb, tb, sb, Rb, cb, dir_b, B[k], wb)
        vw = 0.0
        for i in range(3):
            W[k, i] = A[k, i] - B[k, i]
            vw += v[i] * W[k, i]
        if vw > cutoff * norm:  # the geoms are apart along v by more than the cutoff: a lower bound
            return vw / norm
        if k > 0 and vv - vw <= GJK_TOL * norm:  # the support no nearer: |v| is within GJK_TOL of the distance
            break
        k = _simplex_closest(W, A, B, lam, k + 1, v)
        vv = v[0] * v[0] + v[1] * v[1] + v[2] * v[2]
        if k == 4 or vv <= 1e-24:
            return _overlap(ta, sa, Ra, ca, tb, sb, Rb, cb, p1, p2, n, geoms, ga, gb)
    for i in range(3):
        p1[i] = p2[i] = 0.0
        for j in range(k):
            p1[i] += lam[j] * A[j, i]
            p2[i] += lam[j] * B[j, i]
    d = np.sqrt(vv)
    for i in range(3):
        n[i] = (p2[i] - p1[i]) / d
    return d
