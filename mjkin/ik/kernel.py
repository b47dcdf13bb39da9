"""The compiled IK core: goal residuals and Jacobians, one step, and whole solves.

A solve of one target runs entirely inside :func:`solve_one`; :func:`solve_batch`
runs a range of targets (the caller splits large batches across threads: the
compiled code releases the GIL). Each iteration (seed 000/002):

1. forward kinematics at ``q`` and every goal's weighted residual ``g`` and
   Jacobian ``J`` (rows grouped by priority level);
2. a step ``dq`` by task-priority resolution: level by level, solve the
   level's rows restricted to the null space ``P`` of the levels above,
   ``dq += (J_l P)^# (-g_l - J_l dq)``, then shrink ``P``. ``^#`` is the
   damped least-squares inverse ``Aᵀ(AAᵀ + λ²I)⁻¹`` (``dls``, and ``lm`` with
   an adaptive λ), the SVD pseudoinverse (``pinv``), or the scaled transpose
   ``αAᵀ`` with Buss's step size (``transpose``);
   With ``goal_step`` each level aims only that far per step (the seeds'
   animation: ``V = G - E`` walked frame by frame, Buss's error clamping);
3. joints that the step would push through a limit are locked (their column
   removed) and the step recomputed; the step is integrated (quaternions for
   ball/free joints) and clamped into the limits;
4. ``lm`` accepts a step only if it lowers the cost (level by level), else it
   raises λ (Levenberg–Marquardt, ``λ² = λ_min² + μ·cost``); ``halving`` instead retracts and halves the way to the goal
   (seed 002 §4.6.3).

A solve ends converged (every counted goal within ``tol``/``rot_tol``), or
stalled (no progress — an unmet counted goal's error falling by the fraction
``progress``, or at all in the last run, which has no restart to go to — for
``patience`` iterations: ``unreachable``, or
``limits`` when a joint limit blocks the way), or at ``max_iters``. A stalled
solve restarts from the given random configurations, if any; the best
configuration seen is returned.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, NamedTuple

import numpy as np
from numpy.typing import NDArray

from ..goals import AIM, AXIS, COUPLING, HALFSPACE, LINE, ORIENTATION, PLANE, POSE, POSITION, REST
from ..jit import matvec3, monotonic_ns, njit, njit_inline
from ..kinematics.fk import Kinematics, fk_kernel, fk_scratch, kinematic_arrays
from ..kinematics.jacobian import jacobian_kernel
from ..kinematics.qspace import BALL, FREE, HINGE, SLIDE, clip_kernel, difference_kernel, integrate_kernel

if TYPE_CHECKING:
    from ..goals import Program
    from ..kinematics.tree import Tree

Array = NDArray[np.float64]
Index = NDArray[np.int64]

DLS, PINV, TRANSPOSE, LM = 0, 1, 2, 3
CONVERGED, UNREACHABLE, MAX_ITERATIONS, LIMITS, TIMEOUT = 0, 1, 2, 3, 4
STATUS_NAMES = ("converged", "unreachable", "max_iterations", "limits", "timeout")


class GoalArrays(NamedTuple):
    """A :class:`mjkin.goals.Program` as the compiled code reads it (same fields, same shapes)."""

    kind: Index
    body: Index
    lrot: Array
    lpos: Array
    data: Array
    aux: Index
    sqrt_w: Array
    row: Index
    rest_q: Array
    rest_k: Array
    coupling: Array
    level_rows: Index
    counted: NDArray[np.bool_]


class Settings(NamedTuple):
    """Solver parameters (build with :func:`settings`, which fixes every field's type)."""

    tol: float  # position tolerance (m)
    rot_tol: float  # rotation tolerance (rad)
    damping: float  # λ of dls, λ_min of lm
    lm_factor: float  # lm: initial μ of λ² = λ_min² + μ·cost (0 for fixed λ)
    alpha: float  # transpose step size (0 = Buss's)
    max_step: float  # largest joint change per iteration
    halving: bool  # iterative goal halving
    patience: int  # iterations without progress before a run counts as stalled
    goal_step: float  # largest residual norm one step aims to remove
    timeout_ns: int  # per-target time limit (0 = none)
    progress: float  # relative fall of a goal's error that counts as progress (see _progressed)


def settings(tol: float, rot_tol: float, damping: float, lm_factor: float = 0.0, alpha: float = 0.0,
             max_step: float = np.inf, halving: bool = False, patience: int = 10, goal_step: float = np.inf,
             timeout: float | None = None, progress: float = 1e-9) -> Settings:
    """:class:`Settings` with Python types fixed, so every call shares one compiled specialisation."""
    return Settings(float(tol), float(rot_tol), float(damping), float(lm_factor), float(alpha), float(max_step),
                    bool(halving), int(patience), float(goal_step), timeout_ns(timeout), float(progress))


def timeout_ns(timeout: float | None) -> int:
    """A time limit in seconds as the compiled loops take it: nanoseconds, 0 for none."""
    return 0 if timeout is None else max(1, int(round(timeout * 1e9)))


def program_arrays(prog: Program) -> GoalArrays:
    """The goals as the compiled code reads them."""
    return GoalArrays(prog.kind, prog.body, prog.lrot, prog.lpos, prog.data, prog.aux, prog.sqrt_w, prog.row,
                      prog.rest_q, prog.rest_k, prog.coupling, prog.level_rows, prog.counted)


# ------------------------------------------------------------------ kinematics
@njit_inline
def _fk(kin: Kinematics, q: Array, rot: Array, pos: Array, irot: Array, ipos: Array) -> None:
    fk_kernel(q, kin.parent, kin.fixed_rot, kin.fixed_pos, kin.jnt_start, kin.jnt_count, kin.jnt_inner,
              kin.fixed_plain, kin.hinge_coord, kin.anchor_zero, kin.jnt_type, kin.jnt_qadr, kin.jnt_axis,
              kin.jnt_pos, kin.qpos0, rot, pos, irot, ipos)


@njit_inline
def _jac(kin: Kinematics, rot: Array, pos: Array, irot: Array, ipos: Array, body: int, point: Array, J6: Array) -> None:
    J6[:] = 0.0
    jacobian_kernel(rot, pos, irot, ipos, kin.body_dof_idx[kin.body_dof_ptr[body]:kin.body_dof_ptr[body + 1]],
                    kin.dof_body, kin.dof_inner, kin.dof_axis, kin.dof_world, kin.dof_rot, kin.dof_anchor, point, J6)


@njit
def _skew_times(v: Array, M: Array, out: Array) -> None:
    """``out = -[v]x M`` for ``M (3, n)``: the rate of a frame-fixed vector ``v`` is ``ω × v = -[v]x ω``."""
    for k in range(M.shape[1]):
        out[0, k] = -(v[1] * M[2, k] - v[2] * M[1, k])
        out[1, k] = -(v[2] * M[0, k] - v[0] * M[2, k])
        out[2, k] = -(v[0] * M[1, k] - v[1] * M[0, k])


@njit
def _log_rotation(E: Array, out: Array) -> float:
    """Rotation vector of ``E (3, 3)`` into ``out (3,)``; returns its angle in ``[0, π]``."""
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
    return angle


@njit
def _left_jacobian_inverse(phi: Array, theta: float, out: Array) -> None:
    """``J_l⁻¹(φ) = I - ½[φ]x + c [φ]x²``, the map from world angular velocity to ``dφ/dt``."""
    if theta < 1e-4:
        c = 1.0 / 12.0 + theta * theta / 720.0
    else:
        c = 1.0 / (theta * theta) - (1.0 + np.cos(theta)) / (2.0 * theta * np.sin(max(theta, 1e-9)))
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


@njit
def goal_scratch(nv: int) -> tuple:
    """Work arrays for :func:`evaluate_goals`, made once per solve."""
    return (np.empty((1, 6, nv)), np.empty((1, 3)), np.empty((3, 3)), np.empty((3, 3)), np.empty((3, 3)),
            np.empty(3), np.empty(3), np.empty((1, nv)))


@njit_inline
def evaluate_goals(kin: Kinematics, ga: GoalArrays, ws: tuple, b: int, q: Array, rot: Array, pos: Array, irot: Array,
                   ipos: Array, g: Array, J: Array, err: Array) -> None:
    """Weighted residuals ``g (m,)``, Jacobians ``J (m, nv)``, errors ``err (G, 2)`` at ``q (1, nq)``.

    ``rot``/``pos``/``irot``/``ipos`` must hold FK at ``q``. ``b`` selects the target;
    ``ws`` comes from :func:`goal_scratch`.
    """
    kind, body, lrot, lpos, data, aux, sqrt_w, row = (ga.kind, ga.body, ga.lrot, ga.lpos, ga.data, ga.aux, ga.sqrt_w,
                                                      ga.row)
    rest_q, rest_k, coupling = ga.rest_q, ga.rest_k, ga.coupling
    J6, pt, R, E, Li, v, f, dv = ws
    nv = J.shape[1]
    for i in range(kind.shape[0]):
        r0, k = row[i], kind[i]
        w = sqrt_w[i]
        err[i, 0] = 0.0
        err[i, 1] = 0.0
        if k == REST:
            difference_kernel(q, rest_q[aux[i], b:b + 1], kin.jnt_type, kin.jnt_qadr, kin.jnt_dofadr, dv)
            for j in range(nv):
                g[r0 + j] = w * rest_k[aux[i], j] * dv[0, j]
                for c in range(nv):
                    J[r0 + j, c] = 1.0 if c == j else 0.0
            for jt in range(kin.jnt_type.shape[0]):  # rotations: d log(q_rest⁻¹ q) = J_r⁻¹(φ) ω (local ω)
                if kin.jnt_type[jt] == BALL or kin.jnt_type[jt] == FREE:
                    d0 = kin.jnt_dofadr[jt] + (3 if kin.jnt_type[jt] == FREE else 0)
                    for a in range(3):
                        v[a] = -dv[0, d0 + a]
                    _left_jacobian_inverse(v, float(np.sqrt(v @ v)), Li)  # J_l⁻¹(-φ) = J_r⁻¹(φ)
                    for a in range(3):
                        for c in range(3):
                            J[r0 + d0 + a, d0 + c] = Li[a, c]
            for j in range(nv):
                for c in range(nv):
                    J[r0 + j, c] *= w * rest_k[aux[i], j]
            continue
        if k == COUPLING:
            s = -data[b, i, 0]
            for j in range(nv):
                s += coupling[aux[i], j] * q[0, kin.dof_qadr[j]]
                J[r0, j] = w * coupling[aux[i], j]
            g[r0] = w * s
            err[i, 0] = abs(s)
            continue
        # a frame goal: world frame (R, p) of the goal point and its Jacobian
        bd = body[i]
        for a in range(3):  # the common goals below index arrays element-wise (see mjkin.jit)
            for c in range(3):
                R[a, c] = rot[0, bd, a, 0] * lrot[i, 0, c] + rot[0, bd, a, 1] * lrot[i, 1, c] + (
                    rot[0, bd, a, 2] * lrot[i, 2, c])
            pt[0, a] = pos[0, bd, a] + (rot[0, bd, a, 0] * lpos[i, 0] + rot[0, bd, a, 1] * lpos[i, 1]
                                        + rot[0, bd, a, 2] * lpos[i, 2])
        _jac(kin, rot, pos, irot, ipos, bd, pt, J6)
        if k == POSITION or k == POSE:
            for a in range(3):
                g[r0 + a] = w * (pt[0, a] - data[b, i, a])
                for j in range(nv):
                    J[r0 + a, j] = w * J6[0, a, j]
            err[i, 0] = np.sqrt((pt[0, 0] - data[b, i, 0]) ** 2 + (pt[0, 1] - data[b, i, 1]) ** 2
                                + (pt[0, 2] - data[b, i, 2]) ** 2)
        if k == ORIENTATION or k == POSE:
            o = r0 + (3 if k == POSE else 0)
            for a in range(3):  # E = R Rtᵀ: the rotation from the target Rt to the frame, world axes
                for c in range(3):
                    E[a, c] = (R[a, 0] * data[b, i, 3 + 3 * c] + R[a, 1] * data[b, i, 4 + 3 * c]
                               + R[a, 2] * data[b, i, 5 + 3 * c])
            theta = _log_rotation(E, v)
            _left_jacobian_inverse(v, theta, Li)
            for a in range(3):
                g[o + a] = w * v[a]
                for j in range(nv):
                    J[o + a, j] = w * (Li[a, 0] * J6[0, 3, j] + Li[a, 1] * J6[0, 4, j] + Li[a, 2] * J6[0, 5, j])
            err[i, 1] = theta
        if k == POSITION or k == ORIENTATION or k == POSE:
            continue
        Jp, Jr, p, d = J6[0, :3], J6[0, 3:], pt[0], data[b, i]
        if k == AXIS or k == AIM:
            if k == AXIS:  # frame axis e_aux must match the target's
                for a in range(3):
                    f[a] = R[a, aux[i]]
                    v[a] = d[3 + 3 * a + aux[i]]
            else:  # frame axis (local d[3:6]) must point from p at the point d[0:3]
                matvec3(R, d[3:6], f)
                L = np.sqrt((d[0] - p[0]) ** 2 + (d[1] - p[1]) ** 2 + (d[2] - p[2]) ** 2)
                for a in range(3):
                    v[a] = (d[a] - p[a]) / L if L > 1e-12 else f[a]
            _skew_times(f, Jr, J[r0:r0 + 3])
            if k == AIM and L > 1e-12:  # the direction to the point moves with p
                for a in range(3):
                    for c in range(3):
                        P = ((1.0 if a == c else 0.0) - v[a] * v[c]) / L
                        for j in range(nv):
                            J[r0 + a, j] += P * Jp[c, j]
            n2 = 0.0
            for a in range(3):
                g[r0 + a] = w * (f[a] - v[a])
                n2 += (f[a] - v[a]) ** 2
                for j in range(nv):
                    J[r0 + a, j] *= w
            err[i, 1] = 2.0 * np.arcsin(min(0.5 * np.sqrt(n2), 1.0))
        elif k == LINE:
            u = d[3:6]
            s = (p[0] - d[0]) * u[0] + (p[1] - d[1]) * u[1] + (p[2] - d[2]) * u[2]
            n2 = 0.0
            for a in range(3):
                e = p[a] - d[a] - s * u[a]
                g[r0 + a] = w * e
                n2 += e * e
                for j in range(nv):
                    J[r0 + a, j] = w * (Jp[a, j] - u[a] * (u[0] * Jp[0, j] + u[1] * Jp[1, j] + u[2] * Jp[2, j]))
            err[i, 0] = np.sqrt(n2)
        elif k == PLANE or k == HALFSPACE:
            n = d[3:6]
            s = (p[0] - d[0]) * n[0] + (p[1] - d[1]) * n[1] + (p[2] - d[2]) * n[2]
            active = k == PLANE or s < 0.0
            g[r0] = w * s if active else 0.0
            for j in range(nv):
                J[r0, j] = w * (n[0] * Jp[0, j] + n[1] * Jp[1, j] + n[2] * Jp[2, j]) if active else 0.0
            err[i, 0] = abs(s) if active else 0.0


# ------------------------------------------------------------------------ step
@njit_inline
def _damped_solve(A: Array, e: Array, lam2: float, x: Array) -> None:
    """``x = Aᵀ (AAᵀ + λ²I)⁻¹ e`` (or the equal ``(AᵀA + λ²I)⁻¹ Aᵀ e`` when A is tall), by Cholesky."""
    m, n = A.shape
    tall = m > n
    k = n if tall else m
    M = np.empty((k, k))
    b = np.empty(k)
    for i in range(k):
        if tall:
            acc = 0.0
            for r in range(m):
                acc += A[r, i] * e[r]
            b[i] = acc
        else:
            b[i] = e[i]
    for i in range(k):
        for j in range(i + 1):
            acc = 0.0
            if tall:
                for r in range(m):
                    acc += A[r, i] * A[r, j]
            else:
                for c in range(n):
                    acc += A[i, c] * A[j, c]
            M[i, j] = acc
        M[i, i] += lam2
    for i in range(k):  # in-place Cholesky, lower triangle: M = L Lᵀ
        for j in range(i + 1):
            acc = M[i, j]
            for r in range(j):
                acc -= M[i, r] * M[j, r]
            if i == j:
                M[i, i] = np.sqrt(max(acc, 1e-300))
            else:
                M[i, j] = acc / M[j, j]
    for i in range(k):  # L y = b
        acc = b[i]
        for r in range(i):
            acc -= M[i, r] * b[r]
        b[i] = acc / M[i, i]
    for i in range(k - 1, -1, -1):  # Lᵀ z = y
        acc = b[i]
        for r in range(i + 1, k):
            acc -= M[r, i] * b[r]
        b[i] = acc / M[i, i]
    if tall:
        x[:] = b
    else:
        for c in range(n):
            acc = 0.0
            for r in range(m):
                acc += A[r, c] * b[r]
            x[c] = acc


@njit_inline
def _solve_level(A: Array, e: Array, method: int, lam2: float, alpha: float, x: Array, basis: Array,
                 need_basis: bool) -> int:
    """``x = A^# e`` for the method.

    When ``need_basis`` (levels below this one), also writes an orthonormal
    basis of A's row space into the rows of ``basis`` and returns its rank, for
    the null-space projector. Without it, damped steps take one small linear
    solve instead of an SVD.
    """
    m, n = A.shape
    x[:] = 0.0
    if m == 0:
        return 0
    if not need_basis and lam2 > 0.0 and (method == DLS or method == LM):
        _damped_solve(A, e, lam2, x)
        return 0
    if not need_basis and method == TRANSPOSE:
        Ae = A.T @ e
        AAe = A @ Ae
        den = AAe @ AAe
        x[:] = (alpha if alpha > 0 else ((e @ AAe) / den if den > 1e-300 else 0.0)) * Ae
        return 0
    U, s, Vt = np.linalg.svd(A, full_matrices=False)
    cutoff = max(1e-10, 1e-12 * s[0]) if s.shape[0] else 1e-10
    rank = 0
    for i in range(s.shape[0]):
        if s[i] > cutoff:
            basis[rank] = Vt[i]
            rank += 1
    if method == TRANSPOSE:
        Ae = A.T @ e
        AAe = A @ Ae
        den = AAe @ AAe
        x[:] = (alpha if alpha > 0 else ((e @ AAe) / den if den > 1e-300 else 0.0)) * Ae
        return rank
    for i in range(s.shape[0]):
        if method == PINV:
            if s[i] <= cutoff:
                continue
            k = 1.0 / s[i]
        else:
            k = s[i] / (s[i] * s[i] + lam2)
        x += (k * (U[:, i] @ e)) * Vt[i]
    return rank


@njit
def step_scratch(m: int, nv: int) -> tuple:
    """Work arrays for :func:`_step`: projector, level step, row-space basis, level residual."""
    return np.empty((nv, nv)), np.empty(nv), np.empty((nv, nv)), np.empty(m)


@njit_inline
def _step(J: Array, g: Array, level_rows: Index, locked: NDArray[np.bool_], method: int, lam2: Array, alpha: float,
          scale: float, clamp: float, ws: tuple, dq: Array) -> None:
    """Task-priority step ``dq`` for weighted residuals ``g``, Jacobian ``J``; locked dofs stay put.

    Each level aims to remove ``scale`` times its residual, at most ``clamp`` of it in norm.
    ``ws`` comes from :func:`step_scratch`.
    """
    nv = J.shape[1]
    P, x, basis, e_all = ws
    free = True
    for j in range(nv):
        for c in range(nv):
            P[j, c] = 0.0 if (c != j or locked[j]) else 1.0
        free = free and not locked[j]
    dq[:] = 0.0
    for lv in range(level_rows.shape[0] - 1):
        Jl = J[level_rows[lv]:level_rows[lv + 1]]
        gl = g[level_rows[lv]:level_rows[lv + 1]]
        n = np.sqrt(gl @ gl)
        k = scale * (clamp / n if n > clamp else 1.0)
        e = e_all[:gl.shape[0]]
        for r in range(gl.shape[0]):
            acc = -k * gl[r]
            for c in range(nv):
                acc -= Jl[r, c] * dq[c]
            e[r] = acc
        plain = free and lv == 0  # P is still the identity
        A = Jl if plain else Jl @ P
        last = lv == level_rows.shape[0] - 2
        rank = _solve_level(A, e, method, lam2[lv], alpha, x, basis, not last)
        if plain:
            dq += x
        else:
            dq += P @ x
        for r in range(rank):
            P -= np.outer(basis[r], basis[r])


# ----------------------------------------------------------------------- solve
@njit
def _costs(g: Array, level_rows: Index, out: Array) -> None:
    for lv in range(level_rows.shape[0] - 1):
        out[lv] = 0.0
        for r in range(level_rows[lv], level_rows[lv + 1]):
            out[lv] += g[r] * g[r]


PRIORITY_WEIGHT = 1e4  # merit weight of a level relative to the next one down


@njit
def _merit(cost: Array) -> float:
    """One number to compare configurations: level costs weighted ``PRIORITY_WEIGHT`` apart.

    Steps are strictly prioritised; acceptance is by merit, so a met higher
    level drifting by a second-order amount does not veto progress below it,
    while a real loss at a higher level outweighs gains below.
    """
    m, w = 0.0, 1.0
    for lv in range(cost.shape[0] - 1, -1, -1):
        m += w * cost[lv]
        w *= PRIORITY_WEIGHT
    return m


@njit
def _max_abs(x: Array) -> float:
    """``max |x|`` over a ``(1, n)`` row, without the temporary ``np.abs`` would allocate."""
    m = 0.0
    for j in range(x.shape[1]):
        m = max(m, abs(x[0, j]))
    return m


@njit
def _finite_row(x: Array) -> bool:
    """Whether every entry of a ``(1, n)`` row is finite (no NaN, no inf)."""
    for j in range(x.shape[1]):
        if not abs(x[0, j]) < np.inf:
            return False
    return True


@njit
def _levels_met(err: Array, counted: NDArray[np.bool_], row: Index, level_rows: Index, tol: float,
                rot_tol: float) -> int:
    """How many levels, from the top, have every counted goal within tolerance."""
    met = level_rows.shape[0] - 1
    for i in range(err.shape[0]):
        if counted[i] and not (err[i, 0] <= tol and err[i, 1] <= rot_tol):  # NaN is never met
            lv = 0
            while level_rows[lv + 1] <= row[i]:
                lv += 1
            met = min(met, lv)
    return met


@njit
def _progressed(err: Array, counted: NDArray[np.bool_], tol: float, rot_tol: float, ref: Array,
                keep: float) -> bool:
    """Whether a counted goal outside tolerance has fallen below ``keep`` times its error in ``ref (G,)``.

    Errors are in tolerances (``max(e_pos/tol, e_rot/rot_tol)``). Stalls are judged
    goal by goal rather than by the merit: a goal that cannot be met (a rest pose, a
    conflicting lower level) keeps the merit from falling while the goals that decide
    success still converge. When True, ``ref`` takes the current errors.
    """
    hit = False
    for i in range(err.shape[0]):
        if counted[i] and ref[i] > 1.0 and max(err[i, 0] / tol, err[i, 1] / rot_tol) < keep * ref[i]:
            hit = True
    if hit:
        _scaled_errors(err, tol, rot_tol, ref)
    return hit


@njit
def _scaled_errors(err: Array, tol: float, rot_tol: float, out: Array) -> None:
    for i in range(err.shape[0]):
        out[i] = max(err[i, 0] / tol, err[i, 1] / rot_tol)


@njit
def _converged(err: Array, counted: NDArray[np.bool_], tol: float, rot_tol: float) -> bool:
    for i in range(err.shape[0]):
        if counted[i] and not (err[i, 0] <= tol and err[i, 1] <= rot_tol):  # NaN is never converged
            return False
    return True


@njit
def solve_one(kin: Kinematics, ga: GoalArrays, b: int, q: Array, method: int, st: Settings, max_iters: int,
              restarts: Array, restart_q: NDArray[np.bool_], active: NDArray[np.bool_], err_out: Array,
              hist_q: Array, hist_err: Array) -> tuple:
    """Solve target ``b`` from ``q (1, nq)`` (overwritten with the best configuration found).

    ``restarts (K, nq)``: starts tried in turn when a run stalls or uses up
    ``max_iters``; only the entries where ``restart_q (nq,)`` is True are taken
    from them, the others keep this target's start values. ``active (nv,)``:
    dofs allowed to move. Returns (iterations, status, restarts used); the
    status is ``TIMEOUT`` when ``st.timeout_ns`` ran out first.

    The loop evaluates one configuration per pass (a start, or a trial step
    from the current one) at a single place, so the inlined kinematics and
    goal code are compiled once.
    """
    deadline = monotonic_ns() + st.timeout_ns if st.timeout_ns > 0 else 0
    tol, rot_tol, lam, lm_c, alpha, max_step = st.tol, st.rot_tol, st.damping, st.lm_factor, st.alpha, st.max_step
    halving, patience, goal_step = st.halving, st.patience, st.goal_step
    nv = kin.dof_body.shape[0]
    level_rows, counted = ga.level_rows, ga.counted
    m, G, L = ga.row[-1], ga.kind.shape[0], level_rows.shape[0] - 1
    rot, pos, irot, ipos = fk_scratch(kin.parent, kin.jnt_inner)
    ws, sws = goal_scratch(nv), step_scratch(m, nv)
    g, gt = np.empty(m), np.empty(m)
    J, Jt = np.empty((m, nv)), np.empty((m, nv))
    err, errt = np.empty((G, 2)), np.empty((G, 2))
    cost, costt = np.empty(L), np.empty(L)
    lam2 = np.empty(L)
    dq = np.empty((1, nv))
    qt = q.copy()  # the configuration evaluated next: a start, or a trial step from q
    best_q = q.copy()
    q_start = q.copy()
    locked = np.zeros(nv, dtype=np.bool_)
    lo, hi, dof_q, dof_j = kin.jnt_lo, kin.jnt_hi, kin.dof_qadr, kin.dof_jnt
    best, best_met = np.inf, -1  # merit and levels met of the best configuration (returned)
    run_ref = np.empty(G)  # each goal's error (in tolerances) at this run's last progress
    status, it, run_it, used, since_best, attempts = MAX_ITERATIONS, 0, 0, 0, 0, 0
    mu = lm_c  # LM: λ² = λ_min² + μ · cost, μ shrinks after a good step and grows after a bad one
    scale, fresh, any_locked = 1.0, True, False
    while True:
        _fk(kin, qt, rot, pos, irot, ipos)
        evaluate_goals(kin, ga, ws, b, qt, rot, pos, irot, ipos, gt, Jt, errt)
        _costs(gt, level_rows, costt)
        if (fresh or not (method == LM or halving) or _merit(costt) <= _merit(cost)
                or _max_abs(dq) < 1e-15):  # accept qt
            q[:] = qt
            g, gt = gt, g
            J, Jt = Jt, J
            err, errt = errt, err
            cost[:] = costt
            merit = _merit(cost)
            if not fresh:
                mu = max(mu / 3.0, 1e-9)
            if fresh:
                since_best = 0
                _scaled_errors(err, tol, rot_tol, run_ref)
            elif _progressed(err, counted, tol, rot_tol, run_ref,  # the last run goes on while any error falls
                             1.0 - (st.progress if used < restarts.shape[0] else 1e-9)):
                since_best = 0
            else:
                since_best += 1
            fresh, attempts, scale = False, 0, 1.0
            met = _levels_met(err, counted, ga.row, level_rows, tol, rot_tol)
            if met > best_met or (met == best_met and merit < best):  # met higher levels first, then merit
                best, best_met = merit, met
                best_q[:] = q
                err_out[:] = err
            if it < hist_q.shape[0]:
                hist_q[it] = q[0]
                for i in range(G):
                    if counted[i]:
                        hist_err[it, 0] = max(hist_err[it, 0], err[i, 0])
                        hist_err[it, 1] = max(hist_err[it, 1], err[i, 1])
            if _converged(err, counted, tol, rot_tol):
                status = CONVERGED
                break
        else:  # rejected: damp harder (LM) or halve the step
            attempts += 1
            if method == LM:
                mu *= 10.0
                for lv in range(L):
                    lam2[lv] = lam * lam + mu * cost[lv]
            else:
                scale *= 0.5
            if attempts >= 12:  # no attempt helped: count as a stall
                since_best = patience
        if deadline and monotonic_ns() > deadline:
            status = TIMEOUT
            break
        if since_best >= patience or run_it >= max_iters:  # this run ended: restart, or stop
            if used < restarts.shape[0]:
                for k in range(qt.shape[1]):
                    qt[0, k] = restarts[used, k] if restart_q[k] else q_start[0, k]
                used += 1
                run_it, mu, fresh = 0, lm_c, True
                dq[:] = 0.0
                continue
            if since_best >= patience:
                status = LIMITS if any_locked else UNREACHABLE
            break
        if attempts == 0:  # a new iteration from the accepted q
            it += 1
            run_it += 1
            for lv in range(L):
                lam2[lv] = lam * lam + (mu * cost[lv] if method == LM else 0.0)
        for d in range(nv):
            locked[d] = not active[d]
        for _ in range(3):  # lock joints the step would push through a limit, then re-solve
            _step(J, g, level_rows, locked, method, lam2, alpha, scale, goal_step, sws, dq[0])
            if not _finite_row(dq):  # beyond floating point (a target ~1e300 m away): no step, the run ends
                dq[:] = 0.0
                since_best = patience
                break
            big = _max_abs(dq)
            if big > max_step:
                dq[0] *= max_step / big
            changed = False
            for d in range(nv):
                jj, qd = dof_j[d], q[0, dof_q[d]]
                if locked[d] or not (kin.jnt_type[jj] == HINGE or kin.jnt_type[jj] == SLIDE):
                    continue
                if (dq[0, d] < 0 and qd <= lo[jj] + 1e-12) or (dq[0, d] > 0 and qd >= hi[jj] - 1e-12):
                    locked[d] = True  # at the limit and pushing outwards
                    changed = True
            if not changed:
                break
        any_locked = False
        for d in range(nv):
            any_locked = any_locked or (locked[d] and active[d])
        qt[:] = q
        integrate_kernel(qt, dq, kin.jnt_type, kin.jnt_qadr, kin.jnt_dofadr)
        clip_kernel(qt, kin.jnt_type, kin.jnt_qadr, lo, hi)
    q[:] = best_q
    return it, status, used


@njit
def solve_batch(kin: Kinematics, ga: GoalArrays, q: Array, method: int, st: Settings, max_iters: int,
                restarts: Array, restart_q: NDArray[np.bool_], active: NDArray[np.bool_], iters: Index,
                status: Index, used: Index, err: Array, hist_q: Array, hist_err: Array, lo: int, hi: int) -> None:
    """Solve targets ``lo <= b < hi`` of ``q (B, nq)`` in place; see :func:`solve_one`."""
    for b in range(lo, hi):
        it, code, u = solve_one(kin, ga, b, q[b:b + 1], method, st, max_iters, restarts, restart_q, active, err[b],
                                hist_q[b], hist_err[b])
        iters[b] = it
        status[b] = code
        used[b] = u


@njit
def summarise(err: Array, counted: NDArray[np.bool_], tol: float, rot_tol: float, worst: Array,
              success: NDArray[np.bool_]) -> None:
    """Worst counted ``[position, rotation]`` error ``worst (B, 2)`` and ``success (B,)`` from ``err (B, G, 2)``.

    A NaN error stays NaN (and is no success); with no counted goal the worst is 0.
    """
    for b in range(err.shape[0]):
        for c in range(2):
            w = 0.0
            for i in range(err.shape[1]):
                e = err[b, i, c]
                if counted[i] and (e > w or e != e) and w == w:
                    w = e
            worst[b, c] = w
        success[b] = worst[b, 0] <= tol and worst[b, 1] <= rot_tol


@njit
def _evaluate_batch(kin: Kinematics, ga: GoalArrays, q: Array, g: Array, J: Array, err: Array) -> None:
    rot, pos, irot, ipos = fk_scratch(kin.parent, kin.jnt_inner)
    ws = goal_scratch(J.shape[2])
    for b in range(q.shape[0]):
        _fk(kin, q[b:b + 1], rot, pos, irot, ipos)
        evaluate_goals(kin, ga, ws, b, q[b:b + 1], rot, pos, irot, ipos, g[b], J[b], err[b])


def evaluate_program(tree: Tree, prog: Program, q: Array) -> tuple[Array, Array, Array]:
    """Residuals ``(B, m)``, Jacobians ``(B, m, nv)`` and errors ``(B, G, 2)`` at ``q (B, nq)``."""
    B, m = q.shape[0], int(prog.row[-1])
    g, J, err = np.zeros((B, m)), np.zeros((B, m, tree.nv)), np.zeros((B, len(prog.goals), 2))
    _evaluate_batch(kinematic_arrays(tree), program_arrays(prog), q, g, J, err)
    return g, J, err
