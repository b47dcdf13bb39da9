"""The compiled IK core's parts: one step, the costs and tests a solve loop makes, and the settings.

The loop itself is :mod:`mjkin.ik.loop`, with a branch for each goal kind. Each iteration (the damped least-squares and
pseudoinverse updates of the lecture notes, with the Finnish thesis's priorities):

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
   (the Finnish thesis's iterative goal halving).

Hard constraints (goals with ``hard``, rows ``s >= 0`` before every level) are an
active set: the rows that are violated, or that the step would push below zero,
are solved as equalities ``s + J dq = 0`` at a level above every goal (joints are
locked and rows activated, then the step is recomputed, until neither changes). A
step that leaves a hard row below ``-HARD_TOL`` when its start did not (or that
does not reduce the violation of an infeasible start) is rejected and halved; the
best configuration is the feasible one first, then by levels met and merit.

A solve ends converged (every counted goal within ``tol``/``rot_tol``, every hard row
``>= -HARD_TOL``), or
stalled (no progress — an unmet counted goal's error falling by the fraction
``progress``, or at all in the last run, which has no restart to go to — for
``patience`` iterations: ``unreachable``, or
``limits`` when a joint limit blocks the way, ``constraint`` when a hard one
does), or at ``max_iters``. A stalled
solve restarts from the given random configurations, if any; the best
configuration seen is returned.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numpy.typing import NDArray

from ..goals.residuals import HARD_TOL
from ..kinematics.fk import Kinematics, fk_kernel_in
from ..runtime.jit import njit, njit_inline

Array = NDArray[np.float64]
Index = NDArray[np.int64]

DLS, PINV, TRANSPOSE, LM = 0, 1, 2, 3
CONVERGED, UNREACHABLE, MAX_ITERATIONS, LIMITS, TIMEOUT, CONSTRAINT = 0, 1, 2, 3, 4, 5
STATUS_NAMES = ("converged", "unreachable", "max_iterations", "limits", "timeout", "constraint")
BINDING = 1e-5  # a hard row with s below this at the answer binds it (names it in Result.binding)
HARD_DAMPING2 = 1e-12  # λ² of the active hard rows' level: solved (almost) exactly, whatever the method


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
    progress: float  # relative fall of a goal's error that counts as progress (see progressed)


def settings(tol: float, rot_tol: float, damping: float, lm_factor: float = 0.0, alpha: float = 0.0,
             max_step: float = np.inf, halving: bool = False, patience: int = 10, goal_step: float = np.inf,
             timeout: float | None = None, progress: float = 1e-9) -> Settings:
    """:class:`Settings` with Python types fixed, so every call shares one compiled specialisation."""
    return Settings(float(tol), float(rot_tol), float(damping), float(lm_factor), float(alpha), float(max_step),
                    bool(halving), int(patience), float(goal_step), timeout_ns(timeout), float(progress))


def timeout_ns(timeout: float | None) -> int:
    """A time limit in seconds as the compiled loops take it: nanoseconds, 0 for none (so is one past ~146 years)."""
    if timeout is None or not timeout * 1e9 < 2**62:  # int64 nanoseconds; 1e300 s overflowed
        return 0
    return max(1, int(round(timeout * 1e9)))


# ------------------------------------------------------------------ kinematics
@njit_inline
def fk_into(kin: Kinematics, q: Array, rot: Array, pos: Array, irot: Array, ipos: Array) -> None:
    """Forward kinematics of ``q (1, nq)``: world ``rot (1, nbody, 3, 3)``, ``pos (1, nbody, 3)`` and inner frames."""
    fk_into_scratch(kin, q, rot, pos, irot, ipos, np.empty((3, 3)), np.empty(3), np.empty((3, 3)))


@njit_inline
def fk_into_scratch(kin: Kinematics, q: Array, rot: Array, pos: Array, irot: Array, ipos: Array, A: Array, t: Array,
           R: Array) -> None:
    """:func:`fk_into` with its scratch given (:func:`mjkin.kinematics.fk.fk_kernel_in`): the IK loop's."""
    fk_kernel_in(q, kin.parent, kin.fixed_rot, kin.fixed_pos, kin.jnt_start, kin.jnt_count, kin.jnt_inner,
                 kin.fixed_plain, kin.hinge_coord, kin.anchor_zero, kin.jnt_type, kin.jnt_qadr, kin.jnt_axis,
                 kin.jnt_pos, kin.qpos0, rot, pos, irot, ipos, A, t, R)


# ------------------------------------------------------------------------ step
@njit_inline
def damped_solve(A: Array, e: Array, lam2: float, x: Array, M: Array, b: Array) -> None:
    """``x = Aᵀ (AAᵀ + λ²I)⁻¹ e`` (or the equal ``(AᵀA + λ²I)⁻¹ Aᵀ e`` when A is tall), by Cholesky.

    ``M (k, k)`` and ``b (k,)``, ``k = min(A.shape)``, are its scratch. The factor's
    diagonal is kept inverted, so a solve divides ``k`` times, not ``k²`` (a 6x7
    step is the IK loop's largest single cost).
    """
    m, n = A.shape
    tall = m > n
    k = n if tall else m
    if tall:  # M = AᵀA, b = Aᵀe (lower triangle)
        for i in range(k):
            acc = 0.0
            for r in range(m):
                acc += A[r, i] * e[r]
            b[i] = acc
            for j in range(i + 1):
                acc = 0.0
                for r in range(m):
                    acc += A[r, i] * A[r, j]
                M[i, j] = acc
    else:  # M = AAᵀ, b = e
        for i in range(k):
            b[i] = e[i]
            for j in range(i + 1):
                acc = 0.0
                for c in range(n):
                    acc += A[i, c] * A[j, c]
                M[i, j] = acc
    for i in range(k):  # in place, lower triangle: M + λ²I = L Lᵀ, with 1 / L[i, i] on the diagonal
        for j in range(i):
            acc = M[i, j]
            for r in range(j):
                acc -= M[i, r] * M[j, r]
            M[i, j] = acc * M[j, j]
        acc = M[i, i] + lam2
        for r in range(i):
            acc -= M[i, r] * M[i, r]
        M[i, i] = 1.0 / np.sqrt(max(acc, 1e-300))
    for i in range(k):  # L y = b
        acc = b[i]
        for r in range(i):
            acc -= M[i, r] * b[r]
        b[i] = acc * M[i, i]
    for i in range(k - 1, -1, -1):  # Lᵀ z = y
        acc = b[i]
        for r in range(i + 1, k):
            acc -= M[r, i] * b[r]
        b[i] = acc * M[i, i]
    if tall:
        for c in range(n):
            x[c] = b[c]
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
        k = min(m, n)
        damped_solve(A, e, lam2, x, basis[:k, :k], basis[k, :k])  # no basis needed: its rows are scratch
        return 0
    if not need_basis and method == TRANSPOSE:
        Ae = A.T @ e
        AAe = A @ Ae
        den = AAe @ AAe
        x[:] = (alpha if alpha > 0 else ((e @ AAe) / den if den > 1e-300 else 0.0)) * Ae
        return 0
    if not np.all(np.isfinite(A)):  # rows overflowed by a target ~1e308 m off: no step (the SVD would raise)
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
        else:  # λ² can underflow to 0 (λ below ~1e-154): a zero singular value then adds nothing, as with λ > 0
            den = s[i] * s[i] + lam2
            k = s[i] / den if den > 0.0 else 0.0
        x += (k * (U[:, i] @ e)) * Vt[i]
    return rank


@njit
def step_scratch(m: int, nv: int) -> tuple:
    """Work arrays for :func:`priority_step`: projector, level step, row-space basis, level residual, level Jacobian."""
    return np.empty((nv, nv)), np.empty(nv), np.empty((nv + 1, nv)), np.empty(m), np.empty((m, nv))


@njit_inline
def aim_scale(g: Array, scale: float, clamp: float) -> float:
    """The factor ``k`` of a level's residual ``g`` its step aims to remove: ``scale``, at most ``clamp`` in norm."""
    n = 0.0
    for r in range(g.shape[0]):
        n += g[r] * g[r]
    n = np.sqrt(n)
    return scale * (clamp / n if n > clamp else 1.0)


@njit_inline
def priority_step(J: Array, g: Array, level_rows: Index, locked: NDArray[np.bool_], method: int, lam2: Array,
                  alpha: float, scale: float, clamp: float, ws: tuple, dq: Array, hard_level: bool) -> None:
    """Task-priority step ``dq`` for weighted residuals ``g``, Jacobian ``J``; locked dofs stay put.

    Each level aims to remove ``scale`` times its residual, at most ``clamp`` of it in norm.
    ``hard_level``: the first level holds active hard constraints, solved by damped least
    squares (with ``lam2[0]``) whatever the method. ``ws`` comes from :func:`step_scratch`.
    """
    nv = J.shape[1]
    P, x, basis, e_all, A_all = ws
    levels = level_rows.shape[0] - 1
    free = True
    for j in range(nv):
        free = free and not locked[j]
    if levels > 1:  # the projector onto what the levels above leave free: the unlocked dofs to start with
        P[:] = 0.0  # whole rows and columns at once, here and below: as fast compiled, and numpy's when interpreted
        for j in range(nv):
            if not locked[j]:
                P[j, j] = 1.0
    dq[:] = 0.0
    for lv in range(levels):
        r0, r1 = level_rows[lv], level_rows[lv + 1]
        Jl, gl = J[r0:r1], g[r0:r1]
        k = aim_scale(gl, scale, clamp)
        e = e_all[:r1 - r0]
        for r in range(r1 - r0):
            acc = -k * gl[r]
            if lv > 0:  # what the levels above already move (nothing yet at the first)
                for c in range(nv):
                    acc -= Jl[r, c] * dq[c]
            e[r] = acc
        if lv == 0:  # P is diagonal here (the unlocked dofs): no products
            A = Jl
            if not free:
                A = A_all[:r1 - r0]
                A[:] = Jl
                for c in range(nv):
                    if locked[c]:
                        A[:, c] = 0.0
        else:
            A = Jl @ P
        rank = _solve_level(A, e, LM if hard_level and lv == 0 else method, lam2[lv], alpha, x, basis,
                            lv < levels - 1)
        if lv == 0:
            for c in range(nv):
                if not locked[c]:
                    dq[c] += x[c]
        else:
            dq += P @ x
        for r in range(rank):
            P -= np.outer(basis[r], basis[r])


# ----------------------------------------------------------------------- solve
@njit_inline
def level_costs(g: Array, level_rows: Index, out: Array) -> None:
    """``out[l]``: the squared norm of level ``l``'s weighted residual rows."""
    for lv in range(level_rows.shape[0] - 1):
        out[lv] = 0.0
        for r in range(level_rows[lv], level_rows[lv + 1]):
            out[lv] += g[r] * g[r]


PRIORITY_WEIGHT = 1e4  # merit weight of a level relative to the next one down


@njit_inline
def merit_of(cost: Array) -> float:
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


@njit_inline
def max_abs(x: Array) -> float:
    """``max |x|`` over a ``(1, n)`` row, without the temporary ``np.abs`` would allocate."""
    m = 0.0
    for j in range(x.shape[1]):
        m = max(m, abs(x[0, j]))
    return m


@njit_inline
def finite_row(x: Array) -> bool:
    """Whether every entry of a ``(1, n)`` row is finite (no NaN, no inf)."""
    for j in range(x.shape[1]):
        if not abs(x[0, j]) < np.inf:
            return False
    return True


@njit_inline
def levels_met(err: Array, counted: NDArray[np.bool_], row: Index, level_rows: Index, tol: float,
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


@njit_inline
def progressed(err: Array, counted: NDArray[np.bool_], tol: float, rot_tol: float, ref: Array,
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
        scaled_errors(err, tol, rot_tol, ref)
    return hit


@njit_inline
def scaled_errors(err: Array, tol: float, rot_tol: float, out: Array) -> None:
    """``out[i]``: goal ``i``'s (position, rotation) error (n, 2) in units of its tolerance, the larger."""
    for i in range(err.shape[0]):
        out[i] = max(err[i, 0] / tol, err[i, 1] / rot_tol)


@njit_inline
def is_converged(err: Array, counted: NDArray[np.bool_], hard: NDArray[np.bool_], tol: float, rot_tol: float) -> bool:
    """Every counted goal within ``tol``/``rot_tol`` and every hard goal's violation within ``HARD_TOL``."""
    for i in range(err.shape[0]):
        if counted[i] and not (err[i, 0] <= tol and err[i, 1] <= rot_tol):  # NaN is never converged
            return False
        if hard[i] and not (err[i, 0] <= HARD_TOL and err[i, 1] <= HARD_TOL):
            return False
    return True


@njit_inline
def hard_violation(g: Array, hard_row: NDArray[np.bool_]) -> float:
    """How far the hard rows ``g[:h]`` (``hard_row (h,)`` the live ones) fall below zero (0 when all hold)."""
    v = 0.0
    for r in range(hard_row.shape[0]):
        if hard_row[r] and not -g[r] <= v:  # NaN counts as infinitely violated
            v = -g[r] if g[r] == g[r] else np.inf
    return v


@njit
def summarise(err: Array, counted: NDArray[np.bool_], hard: NDArray[np.bool_], tol: float, rot_tol: float,
              worst: Array, success: NDArray[np.bool_]) -> None:
    """Worst counted ``[position, rotation]`` error ``worst (B, 2)`` and ``success (B,)`` from ``err (B, G, 2)``.

    A NaN error stays NaN (and is no success); with no counted goal the worst is 0.
    Success also needs every hard goal (``hard (G,)``) within ``HARD_TOL`` of holding
    (their errors are their violations, not part of ``worst``).
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
        for i in range(err.shape[1]):
            if hard[i] and not (err[b, i, 0] <= HARD_TOL and err[b, i, 1] <= HARD_TOL):
                success[b] = False
