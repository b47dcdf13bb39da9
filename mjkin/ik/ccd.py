"""Cyclic coordinate descent (lecture notes; a Spanish answer on CCD): one joint at a time, either way along.

Each joint turns (or slides) to bring the tool point as close to the goal as
that joint alone can: a hinge by the angle between (tool - joint) and
(goal - joint) about its axis (the seed's ``atan2`` difference, in 3D), a slide
by the tool-to-goal offset along its axis, a ball joint by the shortest arc.
One iteration is one full sweep. Limits are respected by clamping each move.
A hinge whose axis passes through the tool (or the goal) cannot bring them
closer, whatever its angle, so it stays where it is (turning by the ``atan2``
of rounding errors would spin it to a limit). A stalled run is ``limits`` when
a limit cut a joint's move in the last sweep (the limit blocks the way), else
``unreachable``.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass
from typing import ClassVar

import numpy as np
from numpy.typing import NDArray

from ..errors import GoalError
from ..goals import Position, Program
from ..kinematics.fk import fk_scratch
from ..kinematics.mat3 import matvec3
from ..kinematics.qspace import BALL, HINGE, SLIDE, quat_angle_clip, quat_turn
from ..kinematics.tree import Tree
from ..runtime.checks import check_count
from ..runtime.jit import njit
from ..runtime.numba_ext import monotonic_ns
from ..runtime.parallel import parallel_chunks
from . import kernel
from .kernel import CONVERGED, LIMITS, MAX_ITERATIONS, TIMEOUT, UNREACHABLE, Kinematics, fk_into
from .method import MAX_ITERS, Method, ProblemView
from .result import History, Result, package

Array = NDArray[np.float64]
Index = NDArray[np.int64]


@njit
def _tool(rot: Array, pos: Array, body: int, lpos: Array, out: Array) -> None:
    matvec3(rot[0, body], lpos, out)
    for a in range(3):
        out[a] += pos[0, body, a]


ON_AXIS = 1e-9  # a point this close to a hinge's axis (relative to the distances involved) is on it


@njit
def ccd_one(kin: Kinematics, q: Array, body: int, lpos: Array, goal: Array, order: Index, tol: float, sweeps: int,
            patience: int, deadline: int, hist_q: Array, hist_err: Array) -> tuple:
    """CCD for one target; ``q (1, nq)`` is updated in place. Returns (sweeps, status, error).

    ``deadline``: ``monotonic_ns`` time at which the run stops with ``TIMEOUT`` (0 = none), read after each sweep.
    """
    rot, pos, irot, ipos = fk_scratch(kin.parent, kin.jnt_inner)
    jtype, qadr, axis, anchor = kin.jnt_type, kin.jnt_qadr, kin.jnt_axis, kin.jnt_pos
    inner, jbody, lo, hi = kin.jnt_inner, kin.jnt_body, kin.jnt_lo, kin.jnt_hi
    p, u, a, v1, v2, w = np.empty(3), np.empty(3), np.empty(3), np.empty(3), np.empty(3), np.empty(3)
    w4 = np.empty(4)
    best, since, status, it = np.inf, 0, MAX_ITERATIONS, 0
    pinned = False
    while True:
        fk_into(kin, q, rot, pos, irot, ipos)
        _tool(rot, pos, body, lpos, p)
        e = np.sqrt((p[0] - goal[0]) ** 2 + (p[1] - goal[1]) ** 2 + (p[2] - goal[2]) ** 2)
        if it < hist_q.shape[0]:
            hist_q[it] = q[0]
            hist_err[it, 0] = e
        if e <= tol:
            status = CONVERGED
            break
        if e < best * (1 - 1e-9):
            best, since = e, 0
        else:
            since += 1
        if since >= patience:
            status = LIMITS if pinned else UNREACHABLE
            break
        if it >= sweeps:
            break
        if deadline and monotonic_ns() > deadline:
            status = TIMEOUT
            break
        it += 1
        pinned = False
        for j in order:
            fk_into(kin, q, rot, pos, irot, ipos)
            _tool(rot, pos, body, lpos, p)
            R, x = (irot[0, inner[j]], ipos[0, inner[j]]) if inner[j] >= 0 else (rot[0, jbody[j]], pos[0, jbody[j]])
            matvec3(R, axis[j], u)
            matvec3(R, anchor[j], a)
            for k in range(3):
                a[k] += x[k]
                v1[k] = p[k] - a[k]
                v2[k] = goal[k] - a[k]
            c = qadr[j]
            if jtype[j] == SLIDE:
                want = q[0, c] + u[0] * (goal[0] - p[0]) + u[1] * (goal[1] - p[1]) + u[2] * (goal[2] - p[2])
                q[0, c] = min(max(want, lo[j]), hi[j])
                pinned = pinned or abs(want - q[0, c]) > 1e-12 * (1.0 + abs(want))
            elif jtype[j] == HINGE:  # angle between the projections of v1 and v2 on the plane normal to u
                d1, d2 = v1 @ u, v2 @ u
                off1, off2 = 0.0, 0.0  # squared distances of the tool and the goal from the axis
                for k in range(3):  # from the components (|v|² - d² would be all rounding near the axis)
                    off1 += (v1[k] - d1 * u[k]) ** 2
                    off2 += (v2[k] - d2 * u[k]) ** 2
                if min(off1, off2) <= (ON_AXIS * ON_AXIS) * max(v1 @ v1, v2 @ v2):
                    continue  # on the axis: turning moves neither closer
                cx, cy, cz = v1[1] * v2[2] - v1[2] * v2[1], v1[2] * v2[0] - v1[0] * v2[2], v1[0] * v2[1] - v1[1] * v2[0]
                sin = u[0] * cx + u[1] * cy + u[2] * cz
                cos = v1 @ v2 - d1 * d2
                want = q[0, c] + np.arctan2(sin, cos)
                q[0, c] = min(max(want, lo[j]), hi[j])
                pinned = pinned or abs(want - q[0, c]) > 1e-12
            elif jtype[j] == BALL:  # shortest arc from v1 to v2, as a local rotation vector
                n1, n2 = np.sqrt(v1 @ v1), np.sqrt(v2 @ v2)
                if n1 < 1e-12 or n2 < 1e-12:
                    continue
                w[0] = v1[1] * v2[2] - v1[2] * v2[1]
                w[1] = v1[2] * v2[0] - v1[0] * v2[2]
                w[2] = v1[0] * v2[1] - v1[1] * v2[0]
                s = np.sqrt(w @ w)
                if s < 1e-15:
                    continue
                angle = np.arctan2(s, v1 @ v2)
                for k in range(3):  # R^T (axis * angle): angular velocity in the joint frame
                    u[k] = (R[0, k] * w[0] + R[1, k] * w[1] + R[2, k] * w[2]) * angle / s
                quat_turn(q[0], c, u[0], u[1], u[2])
                for k in range(4):
                    w4[k] = q[0, c + k]
                quat_angle_clip(q[0], c, hi[j])
                for k in range(4):
                    pinned = pinned or abs(w4[k] - q[0, c + k]) > 1e-12  # the cone cut the turn
    return it, status, e


@njit
def _ccd_batch(kin: Kinematics, q: Array, body: int, lpos: Array, goals: Array, order: Index, tol: float, sweeps: int,
               patience: int, timeout: int, starts: Array, restart_q: NDArray[np.bool_], iters: Index, status: Index,
               err: Array, used: Index, hist_q: Array, hist_err: Array, lo: int, hi: int) -> None:
    """CCD for targets ``lo <= b < hi``, restarting from ``starts`` when a run stalls; keeps the best.

    A restart takes the entries of ``starts[k]`` where ``restart_q`` is True and keeps the target's own start
    values elsewhere. ``timeout``: nanoseconds per target, restarts included (0 = none).
    """
    for b in range(lo, hi):
        deadline = monotonic_ns() + timeout if timeout > 0 else 0
        best = q[b].copy()
        q_start = q[b].copy()
        it, st, e = ccd_one(kin, q[b:b + 1], body, lpos, goals[b], order, tol, sweeps, patience, deadline,
                            hist_q[b], hist_err[b])
        iters[b], status[b], err[b] = it, st, e
        best[:] = q[b]
        for k in range(starts.shape[0]):
            if st == CONVERGED or st == TIMEOUT:
                break
            for c in range(q.shape[1]):
                q[b, c] = starts[k, c] if restart_q[c] else q_start[c]
            it, st, e = ccd_one(kin, q[b:b + 1], body, lpos, goals[b], order, tol, sweeps, patience, deadline,
                                hist_q[b, :0], hist_err[b, :0])
            iters[b] += it
            used[b] = k + 1
            if e < err[b]:
                err[b], status[b] = e, st
                best[:] = q[b]
        if st == TIMEOUT and status[b] != CONVERGED:
            status[b] = TIMEOUT
        q[b] = best


def solve_ccd(tree: Tree, prog: Program, q: Array, tol: float, rot_tol: float, sweeps: int, sweep: str,
              active: NDArray[np.bool_], history: bool, starts: Array, restart_q: NDArray[np.bool_],
              patience: int = 10, timeout: float | None = None) -> Result:
    """CCD on one position goal (see :func:`mjkin.solve`); ``timeout`` in seconds per target (None: none)."""
    if len(prog.goals) != 1 or prog.code[0] != Position.code:
        raise GoalError("method 'ccd' handles one Position goal; use 'lm' (auto) for other or several goals")
    body = int(prog.body[0])
    dof_jnt = tree.plan.dof_jnt
    chain = [int(j) for j in np.unique(dof_jnt[tree.body_dofs[body]])
             if active[tree.jnt_dofadr[j]] and tree.jnt_type[j] in (HINGE, SLIDE, BALL)]
    order = np.array(chain if sweep == "base_to_tip" else chain[::-1], dtype=np.int64)
    B = prog.B
    H = sweeps + 1 if history else 0
    hist_q, hist_err = np.full((B, H, tree.nq), np.nan), np.full((B, H, 2), np.nan)
    hist_err[..., 1] = 0.0
    iters, status, err, used = np.zeros(B, np.int64), np.zeros(B, np.int64), np.zeros(B), np.zeros(B, np.int64)
    kin = tree.kin
    goals = np.ascontiguousarray(prog.data[:, 0, :3])

    def run(lo: int, hi: int) -> None:
        _ccd_batch(kin, q, body, prog.lpos[0], goals, order, tol, sweeps, patience, kernel.timeout_ns(timeout), starts,
                   restart_q, iters, status, err, used, hist_q, hist_err, lo, hi)

    parallel_chunks(run, B)
    hist_err[np.arange(H)[None, :] > iters[:, None]] = np.nan
    errors = np.zeros((B, 1, 2))
    errors[:, 0, 0] = err
    return package(prog, q, errors, iters, status, used, tol, rot_tol, "ccd",
                   History(hist_q, hist_err) if history else None, tree)


SWEEPS = {"tip_to_base": "tip_to_base", "base_to_tip": "base_to_tip", "backward": "tip_to_base",
          "forward": "base_to_tip"}  # the last two: the names before 0.2, deprecated


@dataclass(frozen=True)
class CCD(Method):
    """Cyclic coordinate descent on one position goal: each joint in turn turns (or slides) the tool at the target.

    ``sweep``: the joint order of a sweep, ``"tip_to_base"`` or ``"base_to_tip"``;
    ``max_iters`` sweeps per run; ``patience`` sweeps without progress end a run.
    """

    name: ClassVar[str] = "ccd"
    max_iters: int = 200
    sweep: str = "tip_to_base"
    patience: int = 10

    def __post_init__(self) -> None:
        super().__post_init__()
        check_count(self.max_iters, "max_iters", 0, whole_floats=True, most=MAX_ITERS)
        check_count(self.patience, "patience", whole_floats=True, most=MAX_ITERS)
        if self.sweep not in SWEEPS:
            raise GoalError(f"sweep must be 'tip_to_base' or 'base_to_tip', not {self.sweep!r}")
        if SWEEPS[self.sweep] != self.sweep:
            warnings.warn(f"sweep={self.sweep!r} is now sweep={SWEEPS[self.sweep]!r}", DeprecationWarning,
                          stacklevel=3)

    def prepare(self, problem: ProblemView) -> None:  # noqa: D102
        prog = problem.structure
        if len(prog.code) != 1 or prog.code[0] != Position.code:
            raise GoalError("method 'ccd' handles one Position goal; use 'lm' (auto) for other or several goals")

    def run(self, problem: ProblemView, prog: Program, q: Array) -> Result:  # noqa: D102
        return solve_ccd(problem.tree, prog, q, problem.tol, problem.rot_tol, int(self.max_iters),
                         SWEEPS[self.sweep], problem.active, problem.history, problem.starts, problem.restart_q,
                         int(self.patience), problem.time_limit)
