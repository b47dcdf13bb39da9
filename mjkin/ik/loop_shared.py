"""The parts of the IK loop that do not depend on the goal kinds, compiled once for the loop and any copy of it.

A kind the user registers runs in a copy of :mod:`mjkin.ik.loop` (:mod:`mjkin.ik.generated`);
what the loop calls from here is compiled and cached once, not again in each copy, and
LLVM inlines or links it as before.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from mjkin.goals.residuals import GoalArrays, scratch
from mjkin.ik.kernel import HARD_DAMPING2, damped_solve, step_scratch
from mjkin.kinematics.fk import Kinematics, fk_scratch
from mjkin.kinematics.qspace import HINGE, SLIDE, integrate_kernel
from mjkin.runtime.jit import njit, njit_inline

Array = NDArray[np.float64]
Index = NDArray[np.int64]


@njit_inline
def loop_scratch(kin: Kinematics, ga: GoalArrays, nq: int) -> tuple:
    """The work arrays of :func:`mjkin.ik.loop.solve_one` for a problem's sizes (``nq``: the tree's).

    Made once for a range of targets, not per target: for a short solve (a 6-D
    pose on a 7-DoF arm) their allocation was a measurable part of it.
    ``solve_one`` takes them :func:`~mjkin.runtime.numba_ext.borrowed`, so the caller keeps this tuple
    alive past its last solve.
    """
    nv, m, G, L = kin.dof_body.shape[0], ga.row[-1], ga.code.shape[0], ga.level_rows.shape[0] - 1
    h = ga.level_rows[0]  # hard constraints: rows [0, h)
    rot, pos, irot, ipos = fk_scratch(kin.parent, kin.jnt_inner)
    hard_row = np.zeros(h, dtype=np.bool_)  # the rows of hard goals (the others in [0, h) are unused)
    for i in range(G):
        if ga.hard[i]:
            hard_row[ga.row[i]:ga.row[i + 1]] = True
    levels = np.empty(L + 2, dtype=np.int64)  # [active hard rows | the goal levels]
    levels[1:] = ga.level_rows
    lam2h = np.empty(L + 1)
    lam2h[0] = HARD_DAMPING2
    return (rot, pos, irot, ipos, np.empty((3, 3)), np.empty(3), np.empty((3, 3)), scratch(nv), step_scratch(m, nv),
            np.empty(m), np.empty(m), np.empty((m, nv)), np.empty((m, nv)), np.empty((G, 2)), np.empty((G, 2)),
            np.empty(L), np.empty(L), np.empty(L), np.empty((1, nv)), np.empty((1, nq)), np.empty((1, nq)),
            np.empty((1, nq)), np.empty(nv, dtype=np.bool_), np.empty(nv, dtype=np.bool_),
            np.empty(nv, dtype=np.bool_), np.empty(m), hard_row, np.empty(h), np.empty((h, nv)), np.empty(h),
            np.empty(h, dtype=np.bool_), levels, lam2h, np.empty(G))


@njit_inline
def inward(d: int, q: Array, lo: Array, hi: Array, dof_q: Index, dof_j: Index, J: Array, v: Array) -> float:
    """``J[:, d]ᵀ v``, signed to point into dof ``d``'s range from the limit it sits at in ``q (1, nq)`` (0 at none).

    Both uses read a limit's multiplier from its sign. With ``v = g``, > 0 means the cost ``½|g|²`` falls
    past the limit: a dof the last step locked there starts the next step locked, so the step is solved
    once, not twice (found free, then locked). The sign is the multiplier at the cost's least along the
    limit, so a joint that would help from inside is freed as the run nears it. With ``v = res = e - J dq``
    after a damped step that kept ``d`` fixed (it minimised ``|J dq - e|² + λ²|dq|²``), > 0 means that
    objective falls as ``d`` moves inward; its least over the other dofs is convex in ``d``'s value, so the
    step solved again with ``d`` free moves it inward. (Without damping, pinv's minimum-norm choice among
    equal residuals may push it straight back out: not used there.)
    """
    jj, qd = dof_j[d], q[0, dof_q[d]]
    side = 1.0 if qd <= lo[jj] + 1e-12 else (-1.0 if qd >= hi[jj] - 1e-12 else 0.0)
    dot = 0.0
    if side != 0.0:
        for r in range(v.shape[0]):
            dot += J[r, d] * v[r]
    return side * dot


@njit
def to_first_limit(q: Array, dq: Array, locked: NDArray[np.bool_], kin: Kinematics, lo: Array, hi: Array) -> None:
    """Shorten ``dq (1, nv)`` so that no free hinge or slide of ``q (1, nq)`` goes past its limit (it may reach it)."""
    t = 1.0
    for d in range(dq.shape[1]):
        jj = kin.dof_jnt[d]
        if locked[d] or not (kin.jnt_type[jj] == HINGE or kin.jnt_type[jj] == SLIDE):
            continue
        qd, v = q[0, kin.dof_qadr[d]], dq[0, d]
        if v < 0.0 and qd + v < lo[jj]:
            t = min(t, (lo[jj] - qd) / v)
        elif v > 0.0 and qd + v > hi[jj]:
            t = min(t, (hi[jj] - qd) / v)
    if t < 1.0:
        for d in range(dq.shape[1]):
            dq[0, d] *= t


@njit
def correct_hard(s: Array, Js: Array, on: NDArray[np.bool_], locked: NDArray[np.bool_], q: Array,
             kin: Kinematics) -> None:
    """Move ``q (1, nq)`` by the least-norm ``dq`` (free dofs) with ``s + Js dq = 0`` on the rows ``on``.

    ``s``/``Js`` are overwritten.
    """
    k = stack_active(s, Js, on, s, Js)
    A = Js[k:].copy()
    for d in range(A.shape[1]):
        if locked[d]:
            A[:, d] = 0.0
    x = np.zeros(A.shape[1])
    if k < s.shape[0]:
        n = min(A.shape)
        damped_solve(A, -s[k:], HARD_DAMPING2, x, np.empty((n, n)), np.empty(n))
    integrate_kernel(q, x.reshape(1, -1), kin.jnt_type, kin.jnt_qadr, kin.jnt_dofadr)


@njit
def stack_active(s: Array, Js: Array, on: NDArray[np.bool_], g: Array, J: Array) -> int:
    """Write the active hard rows (``on``) of ``s (h,)``/``Js (h, nv)`` to the end of ``g[:h]``/``J[:h]``.

    Returns where they start: the first row of the step's top level.
    """
    h = s.shape[0]
    k = h
    for r in range(h - 1, -1, -1):
        if on[r]:
            k -= 1
            g[k] = s[r]
            J[k] = Js[r]
    return k
