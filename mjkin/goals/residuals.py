"""What the kinds' compiled residuals share: the goal arrays, the scratch, the goal frame and rotation maps.

A kind's residual has one signature,
``residual(kin, ga, ws, rot, pos, irot, ipos, i, b, q, g, J, r0, err)``: goal ``i``
of target ``b`` at ``q (1, nq)`` writes its weighted rows ``g[r0:]`` and ``J[r0:, :nv]``
and its errors ``err[i] = [metres, radians]``. ``rot``/``pos``/``irot``/``ipos`` are
FK at ``q`` (:func:`mjkin.kinematics.fk.fk_kernel`'s outputs). For a frame goal the
evaluator has already put the goal frame's world rotation ``R``, point ``pt`` and
Jacobian ``J6`` there into the scratch ``ws`` (see :func:`scratch`). Arrays are
indexed element by element (see :mod:`mjkin.runtime.jit`).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numpy.typing import NDArray

from ..kinematics.fk import Kinematics
from ..kinematics.geoms import Geoms
from ..kinematics.jacobian import jacobian_kernel
from ..runtime.jit import njit, njit_inline

Array = NDArray[np.float64]
Index = NDArray[np.int64]


class GoalArrays(NamedTuple):
    """Goals as the compiled code reads them (see :class:`mjkin.goals.program.Program`)."""

    code: Index  # (G,) each goal's kind, by its registry code (mjkin.goals.registry)
    body: Index  # (G,) -1 for joint-space goals
    lrot: Array  # (G, 3, 3) goal frame in its body
    lpos: Array  # (G, 3)
    data: Array  # (B, G, DATA) targets
    aux: Index  # (G,) the kind's own integer
    column: Index  # (G,) error column that judges the goal: 0 tol (m), 1 rot_tol (rad)
    sqrt_w: Array  # (G,)
    row: Index  # (G + 1,) first residual row of each goal
    rest_q: Array  # (G, B, nq) a goal's joint-space target (rest pose), else unused
    joint_row: Array  # (G, nv) a goal's per-dof numbers (stiffness, coefficients), else unused
    level_rows: Index  # (L + 1,)
    counted: NDArray[np.bool_]  # (G,)
    hard: NDArray[np.bool_]  # (G,) a hard constraint (its rows, first of all, are values s >= 0 and ds/dv)
    # the rest is None in a problem of common kinds only (Program.arrays): the IK loop compiles no code for them
    geoms: Geoms | None  # the model's geoms, for distances
    bounded: Geoms | None  # the same, geoms mjkin cannot measure against a partner as bounding spheres
    pairs: Index | None  # (P, 4) geom pairs [geom1, geom2, goal, bounded] goals keep apart (each goal's contiguous)
    support: Index | None  # (S, 2) [goal, body] of the support points that goals balance over (each goal's contiguous)
    support_pos: Array | None  # (S, 3) those points in their bodies


@njit
def scratch(nv: int) -> tuple:
    """Work arrays of the residuals: ``J6 (1, 6, nv)``, ``pt (1, 3)``, ``R``, ``E``, ``Li (3, 3)``, ``v``, ``f (3,)``,
    ``dv (1, nv)``.
    """  # noqa: D205
    return (np.empty((1, 6, nv)), np.empty((1, 3)), np.empty((3, 3)), np.empty((3, 3)), np.empty((3, 3)),
            np.empty(3), np.empty(3), np.empty((1, nv)))


@njit_inline
def goal_frame(kin: Kinematics, ga: GoalArrays, i: int, rot: Array, pos: Array, irot: Array, ipos: Array,
               ws: tuple) -> None:
    """World rotation ``R``, point ``pt`` and Jacobian ``J6`` of goal ``i``'s frame into the scratch."""
    J6, pt, R = ws[0], ws[1], ws[2]
    bd = ga.body[i]
    for a in range(3):
        for c in range(3):
            R[a, c] = rot[0, bd, a, 0] * ga.lrot[i, 0, c] + rot[0, bd, a, 1] * ga.lrot[i, 1, c] + (
                rot[0, bd, a, 2] * ga.lrot[i, 2, c])
        pt[0, a] = pos[0, bd, a] + (rot[0, bd, a, 0] * ga.lpos[i, 0] + rot[0, bd, a, 1] * ga.lpos[i, 1]
                                    + rot[0, bd, a, 2] * ga.lpos[i, 2])
    J6[:] = 0.0
    jacobian_kernel(rot, pos, irot, ipos, kin.body_dof_idx[kin.body_dof_ptr[bd]:kin.body_dof_ptr[bd + 1]],
                    kin.dof_body, kin.dof_inner, kin.dof_axis, kin.dof_world, kin.dof_rot, kin.dof_anchor, pt, J6)


HARD_TOL = 1e-6  # a hard constraint holds when every row s >= -HARD_TOL (in its kind's units: m or rad)


@njit_inline
def hard_error(ga: GoalArrays, i: int, g: Array, err: Array) -> None:
    """A hard goal's error: how far its lowest row ``s`` is below zero (0 when it holds), in its column."""
    v = 0.0
    for r in range(ga.row[i], ga.row[i + 1]):
        if not -g[r] <= v:  # NaN is infinitely violated
            v = -g[r] if g[r] == g[r] else np.inf
    err[i, 0] = 0.0
    err[i, 1] = 0.0
    err[i, ga.column[i]] = v


@njit
def owned(owner: Index, i: int) -> tuple[int, int]:
    """The rows ``lo:hi`` of a table that belong to goal ``i``, given each row's goal ``owner (R,)`` (each goal's
    rows contiguous, goals ascending): Clearance's pairs, CenterOfMass's support points.
    """  # noqa: D205
    lo, hi = 0, 0
    for p in range(owner.shape[0]):
        if owner[p] < i:
            lo = p + 1
        if owner[p] <= i:
            hi = p + 1
    return lo, hi


@njit
def skew_times(v: Array, M: Array, out: Array, r0: int) -> None:
    """``out[r0:r0+3] = -[v]x M`` for ``M (3, n)``: the rate of a frame-fixed vector ``v`` is ``ω × v``."""
    for k in range(M.shape[1]):
        out[r0, k] = -(v[1] * M[2, k] - v[2] * M[1, k])
        out[r0 + 1, k] = -(v[2] * M[0, k] - v[0] * M[2, k])
        out[r0 + 2, k] = -(v[0] * M[1, k] - v[1] * M[0, k])


@njit_inline
def log_rotation(E: Array, out: Array) -> tuple[float, float]:
    """Rotation vector of ``E (3, 3)`` into ``out (3,)``; returns its angle ``θ`` in ``[0, π]`` and ``cot(θ/2)``.

    ``cot(θ/2)`` is ``w / |xyz|`` of the quaternion found on the way (inf at ``θ = 0``): what
    :func:`left_jacobian_inverse` needs, without a sine or cosine.
    """
    tr = E[0, 0] + E[1, 1] + E[2, 2]
    # Shepperd: pick the largest quaternion component for accuracy
    if tr >= E[0, 0] and tr >= E[1, 1] and tr >= E[2, 2]:
        w = 0.5 * np.sqrt(max(1.0 + tr, 0.0))
        x, y, z = (E[2, 1] - E[1, 2]) / (4 * w), (E[0, 2] - E[2, 0]) / (4 * w), (E[1, 0] - E[0, 1]) / (4 * w)
    elif E[0, 0] >= E[1, 1] and E[0, 0] >= E[2, 2]:
        x = 0.5 * np.sqrt(max(1.0 + E[0, 0] - E[1, 1] - E[2, 2], 0.0))
        w, y, z = (E[2, 1] - E[1, 2]) / (4 * x), (E[0, 1] + E[1, 0]) / (4 * x), (E[0, 2] + E[2, 0]) / (4 * x)
    elif E[1, 1] >= E[2, 2]:
        y = 0.5 * np.sqrt(max(1.0 - E[0, 0] + E[1, 1] - E[2, 2], 0.0))
        w, x, z = (E[0, 2] - E[2, 0]) / (4 * y), (E[0, 1] + E[1, 0]) / (4 * y), (E[1, 2] + E[2, 1]) / (4 * y)
    else:
        z = 0.5 * np.sqrt(max(1.0 - E[0, 0] - E[1, 1] + E[2, 2], 0.0))
        w, x, y = (E[1, 0] - E[0, 1]) / (4 * z), (E[0, 2] + E[2, 0]) / (4 * z), (E[1, 2] + E[2, 1]) / (4 * z)
    if w < 0.0:
        w, x, y, z = -w, -x, -y, -z
    s = np.sqrt(x * x + y * y + z * z)
    angle = 2.0 * np.arctan2(s, w)
    k = 2.0 / w if s < 1e-12 else angle / s
    out[0], out[1], out[2] = k * x, k * y, k * z
    return angle, (w / s if s > 0.0 else np.inf)


@njit_inline
def left_jacobian_inverse(phi: Array, theta: float, cot_half: float, out: Array) -> None:
    """``J_l⁻¹(φ) = I - ½[φ]x + c [φ]x²``, the map from world angular velocity to ``dφ/dt``.

    ``θ = |φ|`` and ``cot_half = cot(θ/2)``; ``c = 1/θ² - (1 + cos θ) / (2θ sin θ) = 1/θ² - cot(θ/2) / (2θ)``.
    """
    if theta < 1e-4:
        c = 1.0 / 12.0 + theta * theta / 720.0
    else:
        c = 1.0 / (theta * theta) - cot_half / (2.0 * theta)
    x, y, z = phi[0], phi[1], phi[2]
    t2 = x * x + y * y + z * z
    for i in range(3):  # [φ]x² = φφᵀ - |φ|² I
        for k in range(3):
            out[i, k] = (1.0 - c * t2 if i == k else 0.0) + c * phi[i] * phi[k]
    out[0, 1] += 0.5 * z
    out[0, 2] -= 0.5 * y
    out[1, 0] -= 0.5 * z
    out[1, 2] += 0.5 * x
    out[2, 0] += 0.5 * y
    out[2, 1] -= 0.5 * x


@njit_inline
def position_rows(ga: GoalArrays, ws: tuple, i: int, b: int, g: Array, J: Array, r0: int, err: Array) -> None:
    """Rows ``r0:r0+3`` of a point goal: ``w (p - target)``; the error is the distance (m)."""
    J6, pt = ws[0], ws[1]
    w = ga.sqrt_w[i]
    for a in range(3):
        g[r0 + a] = w * (pt[0, a] - ga.data[b, i, a])
        for j in range(J.shape[1]):
            J[r0 + a, j] = w * J6[0, a, j]
    err[i, 0] = np.sqrt((pt[0, 0] - ga.data[b, i, 0]) ** 2 + (pt[0, 1] - ga.data[b, i, 1]) ** 2
                        + (pt[0, 2] - ga.data[b, i, 2]) ** 2)


@njit_inline
def orientation_rows(ga: GoalArrays, ws: tuple, i: int, b: int, g: Array, J: Array, r0: int, err: Array) -> None:
    """Rows ``r0:r0+3`` of a full orientation goal: ``w log(R Rtᵀ)`` (world axes); the error is the angle."""
    J6, R, E, Li, v = ws[0], ws[2], ws[3], ws[4], ws[5]
    w = ga.sqrt_w[i]
    for a in range(3):  # E = R Rtᵀ: the rotation from the target Rt to the frame, world axes
        for c in range(3):
            E[a, c] = (R[a, 0] * ga.data[b, i, 3 + 3 * c] + R[a, 1] * ga.data[b, i, 4 + 3 * c]
                       + R[a, 2] * ga.data[b, i, 5 + 3 * c])
    theta, cot_half = log_rotation(E, v)
    left_jacobian_inverse(v, theta, cot_half, Li)
    for a in range(3):
        g[r0 + a] = w * v[a]
        for j in range(J.shape[1]):
            J[r0 + a, j] = w * (Li[a, 0] * J6[0, 3, j] + Li[a, 1] * J6[0, 4, j] + Li[a, 2] * J6[0, 5, j])
    err[i, 1] = theta

