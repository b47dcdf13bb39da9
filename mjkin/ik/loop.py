"""The IK loop: whole solves of targets, and goal evaluation, for every built-in goal kind.

:func:`evaluate_goals` has a branch for each built-in kind (:mod:`mjkin.goals`).
The ten :attr:`~mjkin.goals.Goal.common` ones are compiled into every problem's loop;
the others (Clearance, the centre of mass's two) sit in :func:`other_goal`, which
numba compiles to nothing for goal arrays that do not carry their arrays (a problem
of common kinds only: :attr:`mjkin.goals.Program.arrays`). So a Pose problem compiles
no distance or balance code, and the two loops are two specialisations of the same
compiled, cached functions. A kind the user registers runs in a copy of this file
with a branch for it (:mod:`mjkin.ik.generated`).

A solve of one target runs entirely inside :func:`solve_one`; :func:`solve_batch`
runs a range of targets (the caller splits large batches across threads: the
compiled code releases the GIL). Python calls :func:`solve_packed`, which takes all
the arrays as one packed argument (:mod:`mjkin.ik.packed`); the other two are
inlined into it by numba (one call site each), the kernels they call by LLVM
(:data:`mjkin.runtime.jit.njit_inline`).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from mjkin.goals import (
    Aim,
    Balance,
    Clearance,
    ComTarget,
    Coupling,
    HalfSpace,
    Line,
    Orientation,
    Plane,
    Pose,
    Position,
    Rest,
    StepLimit,
)
from mjkin.goals.aim import residual as aim_residual
from mjkin.goals.clearance import residual as clearance_residual
from mjkin.goals.com import balance_residual
from mjkin.goals.com import residual as com_residual
from mjkin.goals.coupling import residual as coupling_residual
from mjkin.goals.halfspace import residual as halfspace_residual
from mjkin.goals.line import residual as line_residual
from mjkin.goals.orientation import residual as orientation_residual
from mjkin.goals.plane import residual as plane_residual
from mjkin.goals.pose import residual as pose_residual
from mjkin.goals.position import residual as position_residual
from mjkin.goals.residuals import GoalArrays, goal_frame, hard_error, scratch
from mjkin.goals.rest import residual as rest_residual
from mjkin.goals.steplimit import residual as steplimit_residual
from mjkin.ik.kernel import (
    BINDING,
    CONSTRAINT,
    CONVERGED,
    DLS,
    HARD_TOL,
    LIMITS,
    LM,
    MAX_ITERATIONS,
    TIMEOUT,
    UNREACHABLE,
    Settings,
    aim_scale,
    finite_row,
    fk_into,
    fk_into_scratch,
    hard_violation,
    is_converged,
    level_costs,
    levels_met,
    max_abs,
    merit_of,
    priority_step,
    progressed,
    scaled_errors,
    summarise,
)
from mjkin.ik.loop_shared import correct_hard, inward, loop_scratch, stack_active, to_first_limit
from mjkin.ik.packed import Packed
from mjkin.kinematics.fk import Kinematics, fk_scratch
from mjkin.kinematics.geoms import Geoms
from mjkin.kinematics.qspace import HINGE, SLIDE, clip_kernel, integrate_kernel
from mjkin.runtime.jit import njit, njit_inline, njit_ir_inline
from mjkin.runtime.numba_ext import borrowed, borrowed_fields, keep_alive, monotonic_ns

if TYPE_CHECKING:
    from mjkin.goals.program import Program
    from mjkin.kinematics.tree import Tree

Array = NDArray[np.float64]
Index = NDArray[np.int64]


# the built-in kinds' registry codes (mjkin.goals registers them first, in this order): constants to numba
POSITION, ORIENTATION, POSE, AIM, LINE, PLANE, HALF_SPACE, REST, COUPLING, STEP_LIMIT = (
    Position.code, Orientation.code, Pose.code, Aim.code, Line.code, Plane.code, HalfSpace.code, Rest.code,
    Coupling.code, StepLimit.code)
CLEARANCE, COM_TARGET, BALANCE = Clearance.code, ComTarget.code, Balance.code
BUILT_IN = BALANCE + 1  # kinds registered later (codes from here on) run in a copy of this file (mjkin.ik.generated)


@njit_inline
def evaluate_goals(kin: Kinematics, ga: GoalArrays, ws: tuple, b: int, q: Array, rot: Array, pos: Array,
                   irot: Array, ipos: Array, g: Array, J: Array, err: Array) -> None:
    """Weighted residuals ``g (m,)``, Jacobians ``J (m, nv)``, errors ``err (G, 2)`` at ``q (1, nq)``.

    ``rot``/``pos``/``irot``/``ipos`` hold FK at ``q``; ``b`` selects the target; ``ws``
    comes from :func:`mjkin.goals.residuals.scratch`. A hard goal's error is its violation.
    Each kind's residual is inlined here by numba (one call site each).
    """
    for i in range(ga.code.shape[0]):
        err[i, 0] = 0.0
        err[i, 1] = 0.0
        if ga.body[i] >= 0:
            goal_frame(kin, ga, i, rot, pos, irot, ipos, ws)
        code, r0 = ga.code[i], ga.row[i]
        if code == POSITION:
            position_residual(kin, ga, ws, rot, pos, irot, ipos, i, b, q, g, J, r0, err)
        elif code == ORIENTATION:
            orientation_residual(kin, ga, ws, rot, pos, irot, ipos, i, b, q, g, J, r0, err)
        elif code == POSE:
            pose_residual(kin, ga, ws, rot, pos, irot, ipos, i, b, q, g, J, r0, err)
        elif code == AIM:
            aim_residual(kin, ga, ws, rot, pos, irot, ipos, i, b, q, g, J, r0, err)
        elif code == LINE:
            line_residual(kin, ga, ws, rot, pos, irot, ipos, i, b, q, g, J, r0, err)
        elif code == PLANE:
            plane_residual(kin, ga, ws, rot, pos, irot, ipos, i, b, q, g, J, r0, err)
        elif code == HALF_SPACE:
            halfspace_residual(kin, ga, ws, rot, pos, irot, ipos, i, b, q, g, J, r0, err)
        elif code == REST:
            rest_residual(kin, ga, ws, rot, pos, irot, ipos, i, b, q, g, J, r0, err)
        elif code == COUPLING:
            coupling_residual(kin, ga, ws, rot, pos, irot, ipos, i, b, q, g, J, r0, err)
        elif code == STEP_LIMIT:
            steplimit_residual(kin, ga, ws, rot, pos, irot, ipos, i, b, q, g, J, r0, err)
        # REGISTERED KINDS: mjkin.ik.generated adds a branch here for each kind registered after these
        else:
            other_goal(kin, ga, ga.geoms, ws, rot, pos, irot, ipos, code, i, b, q, g, J, r0, err)
        if ga.hard[i]:
            hard_error(ga, i, g, err)


@njit_inline
def other_goal(kin: Kinematics, ga: GoalArrays, geoms: Geoms | None, ws: tuple, rot: Array, pos: Array, irot: Array,
               ipos: Array, code: int, i: int, b: int, q: Array, g: Array, J: Array, r0: int, err: Array) -> None:
    """Goal ``i``'s rows when its kind is a built-in one that is not common: Clearance, the centre of mass's two.

    ``geoms`` is ``ga.geoms``: None in a problem of common kinds only, whose goal arrays carry no
    geoms, pairs or support points (:attr:`mjkin.goals.Program.arrays`). numba prunes a branch on an
    argument that is None by its type, so for such a problem this compiles to nothing.
    """
    if geoms is None:
        return
    if code == CLEARANCE:
        clearance_residual(kin, ga, ws, rot, pos, irot, ipos, i, b, q, g, J, r0, err)
    elif code == COM_TARGET:
        com_residual(kin, ga, ws, rot, pos, irot, ipos, i, b, q, g, J, r0, err)
    elif code == BALANCE:
        balance_residual(kin, ga, ws, rot, pos, irot, ipos, i, b, q, g, J, r0, err)


@njit_ir_inline
def solve_one(kin: Kinematics, ga: GoalArrays, b: int, q: Array, method: int, st: Settings, max_iters: int,
              restarts: Array, restart_q: NDArray[np.bool_], active: NDArray[np.bool_], err_out: Array,
              hist_q: Array, hist_err: Array, work: tuple) -> tuple:
    """Solve target ``b`` from ``q (1, nq)`` (overwritten with the best configuration found).

    ``restarts (K, nq)``: starts tried in turn when a run stalls or uses up
    ``max_iters``; only the entries where ``restart_q (nq,)`` is True are taken
    from them, the others keep this target's start values. ``active (nv,)``:
    dofs allowed to move. ``work``: :func:`loop_scratch`, borrowed. Returns
    (iterations, status, restarts used, binding goal); the status is ``TIMEOUT``
    when ``st.timeout_ns`` ran out first, and the binding goal the hard goal whose
    constraint holds the answer back (-1: none).

    The loop evaluates one configuration per pass (a start, or a trial step
    from the current one) at a single place, so the inlined kinematics and
    goal code are compiled once. Hard goals' rows (``g[:h]``, ``h = level_rows[0]``)
    are constraints ``s >= 0`` (see :mod:`mjkin.ik.kernel`); without any, none of
    their work is done.
    """
    deadline = monotonic_ns() + st.timeout_ns if st.timeout_ns > 0 else 0
    tol, rot_tol, lam, lm_c, alpha, max_step = st.tol, st.rot_tol, st.damping, st.lm_factor, st.alpha, st.max_step
    halving, patience, goal_step = st.halving, st.patience, st.goal_step
    nv = kin.dof_body.shape[0]
    level_rows, counted, hard = ga.level_rows, ga.counted, ga.hard
    m, G, L = ga.row[-1], ga.code.shape[0], level_rows.shape[0] - 1
    lo, hi, dof_q, dof_j = kin.jnt_lo, kin.jnt_hi, kin.dof_qadr, kin.dof_jnt
    # from here on, arrays without reference counts (mjkin.runtime.numba_ext.borrowed): the caller owns them all
    kin, ga, q, restarts, restart_q, active, err_out, hist_q, hist_err = borrowed(
        (kin, ga, q, restarts, restart_q, active, err_out, hist_q, hist_err))
    level_rows, counted, hard, lo, hi, dof_q, dof_j = borrowed((level_rows, counted, hard, lo, hi, dof_q, dof_j))
    (rot, pos, irot, ipos, fA, ft, fR, ws, sws, g, gt, J, Jt, err, errt, cost, costt, lam2, dq, qt, best_q, q_start,
     locked, held, warm, res, hard_row, s_h, J_h, best_s, on, levels, lam2h, run_ref) = work
    # qt: the configuration evaluated next (a start, or a trial step from q); held: the dofs the last step
    # locked at a limit, warm: those the next step starts with locked (see below); res: the step's residual,
    # for the locks' multipliers; run_ref: each goal's error (in tolerances) at this run's last progress
    qt[:] = q
    best_q[:] = q
    q_start[:] = q
    held[:] = False
    # hard constraints: rows [0, h); the live ones (hard_row), their values and Jacobian at q (s_h, J_h; set
    # by the first pass), the active set of a step (on)
    h = level_rows[0]
    any_hard = hard_row.any()
    best_s[:] = 0.0
    viol, violt, infeasible, best_inf, inf_ref = 0.0, 0.0, 0.0, np.inf, 0.0
    best, best_met = np.inf, -1  # merit and levels met of the best configuration (returned)
    status, it, run_it, used, since_best, attempts = MAX_ITERATIONS, 0, 0, 0, 0, 0
    mu = lm_c  # LM: λ² = λ_min² + μ · cost, μ shrinks after a good step and grows after a bad one:
    # gently (÷2, ×4) where a rejection only damps; with hard rows a rejection also halves the step, and
    # the gentle pair then used up its iterations against a blocking constraint (test_render's blocked
    # target) instead of settling there: ÷3, ×10 with them
    mu_down, mu_up = (3.0, 10.0) if any_hard else (2.0, 4.0)
    scale, fresh, any_locked, corrected = 1.0, True, False, False
    while True:
        fk_into_scratch(kin, qt, rot, pos, irot, ipos, fA, ft, fR)
        evaluate_goals(kin, ga, ws, b, qt, rot, pos, irot, ipos, gt, Jt, errt)
        level_costs(gt, level_rows, costt)
        accept = (fresh or not (method == LM or halving) or merit_of(costt) <= merit_of(cost)
                  or max_abs(dq) < 1e-15)
        if any_hard:  # feasibility first: less violation wins, a new violation loses
            violt = hard_violation(gt, hard_row)
            pt, pc = max(violt - HARD_TOL, 0.0), max(viol - HARD_TOL, 0.0)
            if accept and not fresh and pt > pc and not corrected:
                # a good step bent off a curved constraint: pull the trial's violated rows back to zero
                # from where it landed (a second-order correction), and judge that instead
                for r in range(h):
                    on[r] = hard_row[r] and gt[r] < 0.0
                correct_hard(gt[:h], Jt[:h], on, locked, qt, kin)
                clip_kernel(qt, kin.jnt_type, kin.jnt_qadr, lo, hi)
                corrected = True
                continue
            accept = fresh or pt < pc or (pt <= pc and accept)
        corrected = False
        if accept:
            q[:] = qt
            g, gt = gt, g
            J, Jt = Jt, J
            err, errt = errt, err
            cost[:] = costt
            merit = merit_of(cost)
            if any_hard:
                viol = violt
                infeasible = max(viol - HARD_TOL, 0.0)
                s_h[:] = g[:h]
                J_h[:] = J[:h]
            if not fresh:
                mu = max(mu / mu_down, 1e-9)
            keep = 1.0 - (st.progress if used < restarts.shape[0] else 1e-9)
            if fresh:
                since_best = 0
                scaled_errors(err, tol, rot_tol, run_ref)
                inf_ref = infeasible
            elif progressed(err, counted, tol, rot_tol, run_ref, keep):  # the last run goes on while any error falls
                since_best = 0
            elif infeasible < keep * inf_ref:  # or while the violation falls
                since_best = 0
                inf_ref = infeasible
            else:
                since_best += 1
            fresh, attempts, scale = False, 0, 1.0
            met = levels_met(err, counted, ga.row, level_rows, tol, rot_tol)
            if infeasible < best_inf or (infeasible == best_inf and (  # feasible first, then higher levels met,
                    met > best_met or (met == best_met and merit < best))):  # then merit
                best, best_met, best_inf = merit, met, infeasible
                best_q[:] = q
                err_out[:] = err
                if any_hard:
                    best_s[:] = s_h
            if it < hist_q.shape[0]:
                hist_q[it] = q[0]
                for i in range(G):
                    if counted[i]:
                        hist_err[it, 0] = max(hist_err[it, 0], err[i, 0])
                        hist_err[it, 1] = max(hist_err[it, 1], err[i, 1])
            if is_converged(err, counted, hard, tol, rot_tol):
                status = CONVERGED
                break
        else:  # rejected: damp harder (LM) or halve the step
            attempts += 1
            if method == LM:
                mu *= mu_up
                for lv in range(L):
                    lam2[lv] = lam * lam + mu * cost[lv]
            if method != LM or any_hard:
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
                held[:] = False
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
        one = L == 1 and not any_hard  # one level: start from the dofs the last step locked, see inward
        for d in range(nv):
            warm[d] = one and active[d] and held[d] and inward(d, q, lo, hi, dof_q, dof_j, J, g) > 0.0
            locked[d] = warm[d] or not active[d]
        for r in range(h):
            on[r] = hard_row[r] and s_h[r] < 0.0
        for _ in range(3 + h):  # lock joints the step would push through a limit, activate hard rows it would
            if any_hard:        # push below zero, then re-solve
                levels[0] = stack_active(s_h, J_h, on, g, J)
                lam2h[1:] = lam2
            # one call site: the step is inlined (and compiled on its own) once, not once per branch
            priority_step(J, g, levels if any_hard else level_rows, locked, method, lam2h if any_hard else lam2,
                          alpha, scale, goal_step, sws, dq[0], any_hard)
            if not finite_row(dq):  # beyond floating point (a target ~1e300 m away): no step, the run ends
                dq[:] = 0.0
                since_best = patience
                break
            changed = False
            if one and (method == LM or method == DLS) and warm.any():  # free a warm lock whose limit's multiplier
                # says "in": with λ > 0 the step is strictly convex, so the freed joint then moves in (see inward)
                aim = aim_scale(g, scale, goal_step)
                for r in range(m):  # the step's residual: it solved J dq ≈ -aim g (damped)
                    res[r] = -aim * g[r]
                    for c in range(nv):
                        res[r] -= J[r, c] * dq[0, c]
                for d in range(nv):
                    if warm[d] and inward(d, q, lo, hi, dof_q, dof_j, J, res) > 0.0:
                        warm[d] = locked[d] = False
                        changed = True
            big = max_abs(dq)
            if big > max_step:
                dq[0] *= max_step / big
            for d in range(nv):
                jj, qd = dof_j[d], q[0, dof_q[d]]
                if locked[d] or not (kin.jnt_type[jj] == HINGE or kin.jnt_type[jj] == SLIDE):
                    continue
                if (dq[0, d] < 0 and qd <= lo[jj] + 1e-12) or (dq[0, d] > 0 and qd >= hi[jj] - 1e-12):
                    locked[d] = True  # at the limit and pushing outwards
                    changed = True
            for r in range(h):
                if hard_row[r] and not on[r] and s_h[r] + J_h[r] @ dq[0] < 0.0:
                    on[r] = True  # the linearised constraint would be crossed
                    changed = True
            if not changed:
                break
        if attempts > 0:  # after a rejection, go only as far as the first limit the step crosses: clipped there,
            to_first_limit(q, dq, locked, kin, lo, hi)  # the step bent and was rejected again and again (a run
        any_locked = False                              # stalled 4e-4 from a limit); the next step locks it
        for d in range(nv):
            held[d] = locked[d] and active[d]
            any_locked = any_locked or held[d]
        qt[:] = q
        integrate_kernel(qt, dq, kin.jnt_type, kin.jnt_qadr, kin.jnt_dofadr)
        clip_kernel(qt, kin.jnt_type, kin.jnt_qadr, lo, hi)
    q[:] = best_q
    binding = -1
    if any_hard and status != CONVERGED:  # the hard goal whose lowest row is at (or below) its bound
        low = np.inf
        for i in range(G):
            if hard[i]:
                for r in range(ga.row[i], ga.row[i + 1]):
                    if best_s[r] < BINDING and best_s[r] < low:
                        low, binding = best_s[r], i
        if binding >= 0 and status != TIMEOUT and (best_inf > 0.0 or status == UNREACHABLE or status == LIMITS):
            status = CONSTRAINT
    return it, status, used, binding


@njit_ir_inline
def solve_batch(kin: Kinematics, ga: GoalArrays, q: Array, method: int, st: Settings, max_iters: int,
                restarts: Array, restart_q: NDArray[np.bool_], active: NDArray[np.bool_], iters: Index,
                status: Index, used: Index, binding: Index, err: Array, hist_q: Array, hist_err: Array, lo: int,
                hi: int) -> None:
    """Solve targets ``lo <= b < hi`` of ``q (B, nq)`` in place; see :func:`solve_one`."""
    own = loop_scratch(kin, ga, q.shape[1])
    work = borrowed(own)
    for b in range(lo, hi):
        it, code, u, bind = solve_one(kin, ga, b, q[b:b + 1], method, st, max_iters, restarts, restart_q, active,
                                      err[b], hist_q[b], hist_err[b], work)
        iters[b] = it
        status[b] = code
        used[b] = u
        binding[b] = bind
    keep_alive(own)


@njit
def solve_packed(pk: Packed, lo: int, hi: int) -> None:
    """Solve targets ``lo <= b < hi`` of a packed problem (:mod:`mjkin.ik.packed`) and summarise their errors."""
    (kin, ga, settings, method, max_iters, starts, restart_q, active, q, iters, status, used, binding, err, hist_q,
     hist_err, worst, success) = borrowed_fields(pk)  # the caller holds pk, and so its arrays, for the call
    solve_batch(kin, ga, q, method, settings, max_iters, starts, restart_q, active, iters, status, used, binding, err,
                hist_q, hist_err, lo, hi)
    summarise(err[lo:hi], ga.counted, ga.hard, settings.tol, settings.rot_tol, worst[lo:hi], success[lo:hi])


@njit
def evaluate_batch(kin: Kinematics, ga: GoalArrays, q: Array, g: Array, J: Array, err: Array) -> None:
    """Residuals ``g (B, m)``, Jacobians ``J (B, m, nv)`` and errors ``err (B, G, 2)`` at ``q (B, nq)``."""
    rot, pos, irot, ipos = fk_scratch(kin.parent, kin.jnt_inner)
    ws = scratch(J.shape[2])
    for b in range(q.shape[0]):
        fk_into(kin, q[b:b + 1], rot, pos, irot, ipos)
        evaluate_goals(kin, ga, ws, b, q[b:b + 1], rot, pos, irot, ipos, g[b], J[b], err[b])


def evaluate_program(tree: Tree, prog: Program, q: Array) -> tuple[Array, Array, Array]:
    """Residuals ``(B, m)``, Jacobians ``(B, m, nv)`` and errors ``(B, G, 2)`` at ``q (B, nq)``."""
    B, m = q.shape[0], int(prog.row[-1])
    g, J, err = np.zeros((B, m)), np.zeros((B, m, tree.nv)), np.zeros((B, len(prog.goals), 2))
    evaluate_batch(tree.kin, prog.arrays, q, g, J, err)
    return g, J, err
