"""The IK loop, compiled with the registered goal kinds: whole solves of targets, and goal evaluation.

This file is a template: :mod:`mjkin.ik.compiled` writes a copy with
:func:`evaluate_goals` dispatching to every kind of the registry
(:mod:`mjkin.goals.registry`) and imports that copy. A solve of one target runs
entirely inside :func:`solve_one`; :func:`solve_batch` runs a range of targets
(the caller splits large batches across threads: the compiled code releases the GIL).
Python calls :func:`solve_packed`, which takes all the arrays as one packed argument
(:mod:`mjkin.ik.packed`); the other two are inlined into it.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from mjkin.goals.compiled import GoalArrays, goal_frame, scratch
from mjkin.ik.kernel import (
    CONVERGED,
    LIMITS,
    LM,
    MAX_ITERATIONS,
    TIMEOUT,
    UNREACHABLE,
    Settings,
    _converged,
    _costs,
    _finite_row,
    _fk,
    _levels_met,
    _max_abs,
    _merit,
    _progressed,
    _scaled_errors,
    _step,
    step_scratch,
    summarise,
)
from mjkin.ik.packed import Packed
from mjkin.jit import monotonic_ns, njit, njit_inline
from mjkin.kinematics.fk import Kinematics, fk_scratch
from mjkin.kinematics.qspace import HINGE, SLIDE, clip_kernel, integrate_kernel

if TYPE_CHECKING:
    from mjkin.goals.program import Program
    from mjkin.kinematics.tree import Tree

Array = NDArray[np.float64]
Index = NDArray[np.int64]


# BEGIN evaluate_goals (generated: one branch per registered kind)
@njit_inline
def evaluate_goals(kin: Kinematics, ga: GoalArrays, ws: tuple, b: int, q: Array, rot: Array, pos: Array,
                   irot: Array, ipos: Array, g: Array, J: Array, err: Array) -> None:
    """Weighted residuals ``g (m,)``, Jacobians ``J (m, nv)``, errors ``err (G, 2)`` at ``q (1, nq)``.

    ``rot``/``pos``/``irot``/``ipos`` hold FK at ``q``; ``b`` selects the target; ``ws``
    comes from :func:`mjkin.goals.compiled.scratch`.
    """
    for i in range(ga.kind.shape[0]):
        err[i, 0] = 0.0
        err[i, 1] = 0.0
        if ga.body[i] >= 0:
            goal_frame(kin, ga, i, rot, pos, irot, ipos, ws)
        pass  # DISPATCH: mjkin.ik.compiled puts one branch per registered kind here
# END evaluate_goals


@njit_inline
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
    ws, sws = scratch(nv), step_scratch(m, nv)
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


@njit_inline
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
def solve_packed(pk: Packed, lo: int, hi: int) -> None:
    """Solve targets ``lo <= b < hi`` of a packed problem (:mod:`mjkin.ik.packed`) and summarise their errors."""
    solve_batch(pk.kin, pk.ga, pk.q, pk.method, pk.settings, pk.max_iters, pk.starts, pk.restart_q, pk.active, pk.iters,
                pk.status, pk.used, pk.err, pk.hist_q, pk.hist_err, lo, hi)
    summarise(pk.err[lo:hi], pk.ga.counted, pk.settings.tol, pk.settings.rot_tol, pk.worst[lo:hi], pk.success[lo:hi])




@njit
def evaluate_batch(kin: Kinematics, ga: GoalArrays, q: Array, g: Array, J: Array, err: Array) -> None:
    """Residuals ``g (B, m)``, Jacobians ``J (B, m, nv)`` and errors ``err (B, G, 2)`` at ``q (B, nq)``."""
    rot, pos, irot, ipos = fk_scratch(kin.parent, kin.jnt_inner)
    ws = scratch(J.shape[2])
    for b in range(q.shape[0]):
        _fk(kin, q[b:b + 1], rot, pos, irot, ipos)
        evaluate_goals(kin, ga, ws, b, q[b:b + 1], rot, pos, irot, ipos, g[b], J[b], err[b])


def evaluate_program(tree: Tree, prog: Program, q: Array) -> tuple[Array, Array, Array]:
    """Residuals ``(B, m)``, Jacobians ``(B, m, nv)`` and errors ``(B, G, 2)`` at ``q (B, nq)``."""
    B, m = q.shape[0], int(prog.row[-1])
    g, J, err = np.zeros((B, m)), np.zeros((B, m, tree.nv)), np.zeros((B, len(prog.goals), 2))
    evaluate_batch(tree.kin, prog.arrays, q, g, J, err)
    return g, J, err
