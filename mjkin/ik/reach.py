"""Recursive reach (the Finnish thesis): its author's own greedy method, on points.

The chain is seen as points — the joint anchors from the root to the tool — a
fixed distance apart. One pass puts the tool on the goal and walks back toward
the root: where the link before can meet the moved one (the intersection of a
sphere around its base and a sphere around the moved point, a circle) the
joint goes to the nearest point of that circle and the pass ends; where they
cannot meet, the link is turned toward its target and moved onto it (or, when
the target is too close for the link before to reach, away from that link's
joint, the nearest it can come), and the same question is asked one link
nearer the root. When the pass arrives at the
root's own link, that link is turned toward what is left: if the root would
have to move for the chain to follow (the goal is outside the ring
``max(0, 2·max L − ΣL) ≤ |goal − root| ≤ ΣL``) the solve ends with status
``"root_would_move"``, stretched toward the goal. The joint values that realise
the new points are found base to tip, each joint turning its next point onto
the wanted one (hinges about their axis, ball joints by the shortest arc, both
clamped into their limits); on planar chains one pass is exact, on chains of
ball joints the passes repeat until the tool is within ``tol``. Passes that stand
still (a chain folded on the goal's line is a fixed point of them) get one more
run, started stretched toward the goal. Like the thesis
says, it behaves badly with joint limits (a clamped joint leaves the points
where the pass did not put them; the next pass starts from there). A hinge in a
3-D chain cannot put its next point where the pass wants it (it turns in one
plane only), and such chains did not converge (0 of 50 targets on the 7-DoF arm
and on 3-, 6- and 12-hinge chains), so they are refused.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, replace
from typing import Any, ClassVar

import numpy as np
from numpy.typing import NDArray

from .. import spatial
from ..errors import GoalError
from ..goals import Position, Program
from ..kinematics.fk import fk_scratch
from ..kinematics.qspace import BALL, FREE, HINGE, quat_angle_clip, quat_turn
from ..kinematics.tree import Tree
from ..runtime.checks import check_count
from .kernel import CONVERGED, LIMITS, MAX_ITERATIONS, TIMEOUT, UNREACHABLE, fk_into
from .method import MAX_ITERS, Method, ProblemView
from .result import History, Result, package

Array = NDArray[np.float64]
ROOT_WOULD_MOVE = "root_would_move"
PATIENCE = 10  # passes without progress before a solve counts as stalled


def circle_point(c1: Array, r1: float, c2: Array, r2: float, near: Array,
                 normal: Array | None = None) -> Array | None:
    """The point of the circle where spheres ``(c1, r1)`` and ``(c2, r2)`` meet nearest to ``near``; None if apart.

    When ``near`` is on the line of centres every point of the circle is as near; then
    the one in the plane with ``normal`` (a planar chain's) is taken, if given.
    """
    axis = c2 - c1
    d = float(np.linalg.norm(axis))
    scale = max(r1, r2, d, 1e-300)
    if d < 1e-12 * scale:  # concentric: they meet everywhere or nowhere
        if abs(r1 - r2) > 1e-12 * scale:
            return None
        w = near - c1
        n = float(np.linalg.norm(w))
        return c1 + r1 * (w / n if n > 1e-12 * scale else np.array([1.0, 0.0, 0.0]))
    if d > r1 + r2 + 1e-12 * scale or d < abs(r1 - r2) - 1e-12 * scale:
        return None
    e = axis / d
    a = (d * d + r1 * r1 - r2 * r2) / (2 * d)
    # the circle's radius by Heron's product, not sqrt(r1² - a²): near tangency that difference is all rounding
    # and its root amplifies it to ~1e-8 (found by hypothesis: a zero-length link moved a point by 4e-8)
    dr = r1 - r2  # grouped so that each factor is one rounding from exact, also for nearly concentric spheres
    h = np.sqrt(max((d + r1 + r2) * (d + dr) * (d - dr) * (r1 + r2 - d), 0.0)) / (2 * d)
    m = c1 + a * e
    w = near - m
    w -= (w @ e) * e
    n = float(np.linalg.norm(w))
    if n < 1e-12 * scale:  # ``near`` on the axis: any point of the circle (in the chain's plane if known)
        w = np.cross(normal if normal is not None else ([1.0, 0.0, 0.0] if abs(e[0]) < 0.9 else [0.0, 1.0, 0.0]), e)
        n = float(np.linalg.norm(w))
    return m + h * w / n


def reach_points(points: Array, goal: Array, normal: Array | None = None) -> tuple[Array, bool]:
    """One recursive-reach pass over ``points (m+1, 3)`` (root first, tool last) toward ``goal (3,)``.

    Returns the new points (link lengths kept, the root where it was) and whether
    the pass ended at a circle of two spheres (True) or had to turn the root's
    link toward a target it cannot meet (False). ``normal``: the plane of a planar
    chain, kept when a circle offers no nearest point.
    """
    lengths = np.linalg.norm(np.diff(points, axis=0), axis=1)
    new = points.copy()
    target = np.asarray(goal, dtype=np.float64).copy()
    for k in range(len(points) - 1, 1, -1):  # the link from point k-1 to point k, tool end first
        new[k] = target
        met = circle_point(new[k - 2], lengths[k - 2], target, lengths[k - 1], new[k - 1], normal)
        if met is not None:
            new[k - 1] = met
            return new, True
        reach_back = target - new[k - 2]
        if float(np.linalg.norm(reach_back)) < lengths[k - 2] - lengths[k - 1]:
            # too close for the link before to reach: the nearest the link can come is pointing away from
            # that joint (turning it toward the target would keep a folded, straight chain where it is)
            new[k - 1] = target + lengths[k - 1] * _toward(reach_back, points[k] - points[k - 1])
        else:
            new[k - 1] = target - lengths[k - 1] * _toward(target - new[k - 1], points[k] - points[k - 1])
        target = new[k - 1]  # the link turned (toward its target, or away as above) and moved there
    n = float(np.linalg.norm(target - new[0]))
    met = abs(n - lengths[0]) <= 1e-12 * max(n, lengths[0], 1e-300)
    for k in range(1, len(points)):  # the root's link turned toward what is left; the rest follows it
        new[k] = new[k - 1] + lengths[k - 1] * _toward(new[k] - new[k - 1] if k > 1 else target - new[0],
                                                       points[k] - points[k - 1])
    return new, met


def _toward(d: Array, before: Array) -> Array:
    """The unit direction of ``d``; the link's direction ``before`` when ``d`` is zero."""
    for v in (d, before):
        n = float(np.linalg.norm(v))
        if not 1e-150 < n < 1e150:  # squares that lose their bits (subnormal) or overflow: the scaled norm
            n = float(spatial.norm(v))  # (numpy's norm of (0, 0, 4e-160) was 1e-6 off)
        if n > 0:
            return v / n
    return np.zeros(3)


class _Chain:
    """The joints between the root and the tool, grouped by anchor, with FK scratch space."""

    def __init__(self, tree: Tree, body: int, lpos: Array, joints: list[int]) -> None:
        self.kin = tree.kin
        self.scratch = fk_scratch(self.kin.parent, self.kin.jnt_inner)
        self.body, self.lpos, self.joints = body, lpos, joints
        self.tree = tree
        axes = self.frames(tree.qpos0)[1]
        planar = (all(tree.jnt_type[j] == HINGE for j in joints) and len(joints) > 0 and
            bool(np.all(np.linalg.norm(np.cross(axes, axes[0]), axis=-1) < 1e-9)))
        self.normal = axes[0] / np.linalg.norm(axes[0]) if planar else None  # the plane of a planar chain

    def frames(self, q: Array) -> tuple[Array, Array, Array, list[Array]]:
        """World anchors ``(nj, 3)``, axes ``(nj, 3)`` of the chain's joints, the tool ``(3,)``, joint frames."""
        rot, pos, irot, ipos = self.scratch
        kin = self.kin
        fk_into(kin, q[None], rot, pos, irot, ipos)
        inner, jbody, axis, anchor = kin.jnt_inner, kin.jnt_body, kin.jnt_axis, kin.jnt_pos
        anchors, axes, Rs = [], [], []
        for j in self.joints:
            R, x = (irot[0, inner[j]], ipos[0, inner[j]]) if inner[j] >= 0 else (rot[0, jbody[j]], pos[0, jbody[j]])
            anchors.append(R @ anchor[j] + x)
            axes.append(R @ axis[j])
            Rs.append(R)
        tool = rot[0, self.body] @ self.lpos + pos[0, self.body]
        return np.array(anchors).reshape(-1, 3), np.array(axes).reshape(-1, 3), tool, Rs

    def points(self, q: Array) -> tuple[Array, list[list[int]]]:
        """The chain as points ``(m+1, 3)`` (distinct anchors, then the tool) and the joints at each anchor."""
        anchors, _, tool, _ = self.frames(q)
        pts: list[Array] = []
        groups: list[list[int]] = []
        scale = max(float(np.abs(anchors).max(initial=0.0)), float(np.abs(tool).max()), 1.0)
        for k, a in enumerate(anchors):
            if pts and np.linalg.norm(a - pts[-1]) <= 1e-9 * scale:
                groups[-1].append(k)
            else:
                pts.append(a)
                groups.append([k])
        return np.array(pts + [tool]), groups

    def align(self, q: Array, want: Array, groups: list[list[int]]) -> bool:
        """Turn the joints base to tip so each brings its next point onto ``want``; True if one hit a limit."""
        kin = self.kin
        jtype, qadr, lo, hi = kin.jnt_type, kin.jnt_qadr, kin.jnt_lo, kin.jnt_hi
        pinned = False
        for g, members in enumerate(groups):
            for k in members:
                anchors, axes, tool, Rs = self.frames(q)
                now = self.points_from(anchors, tool, groups)
                v1, v2 = now[g + 1] - anchors[k], want[g + 1] - anchors[k]
                j, c = self.joints[k], int(qadr[self.joints[k]])
                if jtype[j] == HINGE:
                    u = axes[k]
                    if np.linalg.norm(np.cross(u, v1)) < 1e-6 * np.linalg.norm(v1):
                        # the next point is on the axis (a twist joint): turn the rest of the chain
                        # toward where it is wanted instead (least squares over the points beyond)
                        v1, v2 = now[g + 2:] - anchors[k], want[g + 2:] - anchors[k]
                    v1, v2 = np.reshape(v1, (-1, 3)), np.reshape(v2, (-1, 3))
                    sin = float(np.sum(np.cross(v1, v2) @ u))
                    cos = float(np.sum(v1 * v2) - np.sum((v1 @ u) * (v2 @ u)))
                    turned = q[c] + np.arctan2(sin, cos)
                    q[c] = min(max(turned, lo[j]), hi[j])
                    pinned = pinned or abs(turned - q[c]) > 1e-12  # the limit cut the turn
                else:  # ball: the shortest arc from v1 to v2, as a rotation vector in the joint frame
                    w = np.cross(v1, v2)
                    s = float(np.linalg.norm(w))
                    if s < 1e-15 * max(float(np.linalg.norm(v1) * np.linalg.norm(v2)), 1e-300):
                        continue
                    u = Rs[k].T @ (w * np.arctan2(s, v1 @ v2) / s)
                    quat_turn(q, c, u[0], u[1], u[2])
                    before = q[c:c + 4].copy()
                    quat_angle_clip(q, c, hi[j])
                    pinned = pinned or not np.allclose(before, q[c:c + 4], atol=1e-12)
        return pinned

    @staticmethod
    def points_from(anchors: Array, tool: Array, groups: list[list[int]]) -> Array:
        """The chain's points from joint anchors: the first anchor of each group, then the tool."""
        return np.array([anchors[m[0]] for m in groups] + [tool])


def reach_one(chain: _Chain, q: Array, goal: Array, tol: float, max_iters: int, deadline: float,
              hist_q: Array, hist_err: Array) -> tuple[int, int | str, float]:
    """Recursive reach for one target; ``q (nq,)`` is updated in place. Returns (passes, status, error).

    Pass ``k``'s configuration and error go into ``hist_q[k]``, ``hist_err[k, 0]`` while there is room.
    The run stops with ``TIMEOUT`` once ``time.monotonic()`` passes ``deadline`` (read after each pass).
    """
    pts, groups = chain.points(q)
    if len(hist_q):
        hist_q[0], hist_err[0, 0] = q, np.linalg.norm(goal - pts[-1])
    lengths = np.linalg.norm(np.diff(pts, axis=0), axis=1)
    dist = float(np.linalg.norm(goal - pts[0]))
    total, inner = float(lengths.sum()), max(0.0, 2 * float(lengths.max(initial=0.0)) - float(lengths.sum()))
    if len(lengths) == 0 or dist > total * (1 + 1e-12) or dist < inner * (1 - 1e-12):
        if len(lengths) and dist > total:
            _stretch(chain, q, pts, goal, lengths, groups)
        elif len(lengths):  # folded toward it as far as one pass goes
            chain.align(q, reach_points(pts, goal, chain.normal)[0], groups)
        e = float(np.linalg.norm(goal - chain.points(q)[0][-1]))
        if len(lengths) and len(hist_q) > 1:
            hist_q[1], hist_err[1, 0] = q, e
        return int(len(lengths) > 0), ROOT_WOULD_MOVE, e
    best, best_q, since, pinned, kicked = np.inf, q.copy(), 0, False, False
    for it in range(max_iters + 1):
        pts, _ = chain.points(q)
        e = float(np.linalg.norm(goal - pts[-1]))
        if it < len(hist_q):
            hist_q[it], hist_err[it, 0] = q, e
        if e < best * (1 - 1e-9):
            best, best_q, since = e, q.copy(), 0
        else:
            since += 1
        if e <= tol:
            return it, CONVERGED, e
        if since >= PATIENCE and not kicked:
            # stalled: a chain folded on the line through the goal is a fixed point of the passes (each link's
            # nearest move keeps it on the line); one more run starts stretched toward the goal, off that fold
            kicked, since = True, 0
            _stretch(chain, q, pts, goal, lengths, groups)
            continue
        if since >= PATIENCE:
            q[:] = best_q
            return it, LIMITS if pinned else UNREACHABLE, best
        if it == max_iters:
            break
        if time.monotonic() > deadline:
            q[:] = best_q
            return it, TIMEOUT, best
        pinned = chain.align(q, reach_points(pts, goal, chain.normal)[0], groups)
    q[:] = best_q
    return max_iters, MAX_ITERATIONS, best


def _stretch(chain: _Chain, q: Array, pts: Array, goal: Array, lengths: Array, groups: list[list[int]]) -> None:
    """Turn ``q (nq,)`` in place so the chain's points lie on the ray from the root toward ``goal``."""
    way = _toward(goal - pts[0], pts[1] - pts[0])
    chain.align(q, pts[0] + np.concatenate([[0.0], np.cumsum(lengths)])[:, None] * way, groups)


def solve_reach(tree: Tree, prog: Program, q: Array, tol: float, rot_tol: float, max_iters: int,
                active: NDArray[np.bool_], history: bool, restarts: Array, restart_q: NDArray[np.bool_],
                timeout: float | None = None) -> Result:
    """Recursive reach on one position goal (see :func:`mjkin.solve`); ``q (B, nq)`` holds the starts.

    One iteration is one pass; with ``history`` every pass's configuration is kept (of the first run).
    A target that is not met (a clamped joint stalled the passes) starts again from ``restarts (K, nq)``,
    taken where ``restart_q`` is True and from its own start elsewhere; the best run is kept.
    ``timeout``: seconds per target, restarts included (None: none).
    """
    if len(prog.goals) != 1 or prog.code[0] != Position.code:
        raise GoalError("method 'reach' handles one Position goal; use 'lm' (auto) for other or several goals")
    body = int(prog.body[0])
    dof_jnt = tree.plan.dof_jnt
    in_chain = [int(j) for j in np.unique(dof_jnt[tree.body_dofs[body]]) if active[tree.jnt_dofadr[j]]]
    movable = [j for j in in_chain if tree.jnt_type[j] != FREE]  # a free root joint is the root: it stays
    if any(tree.jnt_type[j] not in (HINGE, BALL) for j in movable):
        names = [tree.names("joint")[j] for j in movable if tree.jnt_type[j] not in (HINGE, BALL)]
        raise GoalError(f"method 'reach' moves hinge and ball joints only; the chain has slide joints {names}")
    chain = _Chain(tree, body, np.asarray(prog.lpos[0], dtype=np.float64), movable)
    hinges = [j for j in movable if tree.jnt_type[j] == HINGE]
    if hinges and chain.normal is None:
        names = [tree.names("joint")[j] for j in hinges]
        raise GoalError(f"method 'reach' solves planar chains (parallel hinges) and chains of ball joints; this "
                        f"chain turns hinges {names} about different axes or beside ball joints: use 'auto' or 'ccd'")
    B = prog.B
    iters, codes, err = np.zeros(B, np.int64), np.zeros(B, np.int64), np.zeros(B)
    root_moves = np.zeros(B, bool)
    goals = prog.data[:, 0, :3]
    H = max_iters + 1 if history else 0
    hist_q, hist_err = np.full((B, H, tree.nq), np.nan), np.full((B, H, 2), np.nan)
    hist_err[..., 1] = 0.0
    used = np.zeros(B, np.int64)
    for b in range(B):
        deadline = np.inf if timeout is None else time.monotonic() + timeout
        goal, start = np.asarray(goals[b], dtype=np.float64), q[b].copy()
        it, code, e = reach_one(chain, q[b], goal, tol, max_iters, deadline, hist_q[b], hist_err[b])
        iters[b], err[b], best_code, last = it, e, code, code
        for k in range(len(restarts)):
            if last in (CONVERGED, TIMEOUT, ROOT_WOULD_MOVE):  # met, out of time, or no start can help
                break
            qk = np.where(restart_q, restarts[k], start)
            it, last, e = reach_one(chain, qk, goal, tol, max_iters, deadline, hist_q[b, :0], hist_err[b, :0])
            iters[b] += it
            used[b] = k + 1
            if e < err[b]:
                q[b], err[b], best_code = qk, e, last
        if last == TIMEOUT and best_code != CONVERGED:
            best_code = TIMEOUT
        root_moves[b] = best_code == ROOT_WOULD_MOVE
        codes[b] = UNREACHABLE if root_moves[b] else int(best_code)
    errors = np.zeros((B, 1, 2))
    errors[:, 0, 0] = err
    hist_err[np.arange(H)[None, :] > iters[:, None]] = np.nan
    res = package(prog, q, errors, iters, codes, used, tol, rot_tol, "reach",
                  History(hist_q, hist_err) if history else None, tree)
    if root_moves.any():
        labels: NDArray[Any] = np.where(root_moves, ROOT_WOULD_MOVE, np.asarray(res.status).reshape(-1))
        res = replace(res, status=labels.reshape(np.shape(res.status)) if np.ndim(res.status) else labels[0])
    return res


@dataclass(frozen=True)
class Reach(Method):
    """Recursive reach on one position goal, for planar chains and chains of ball joints.

    ``max_iters`` passes per run. Status ``"root_would_move"`` when the goal is
    outside the ring the chain can reach without moving its root.
    """

    name: ClassVar[str] = "reach"
    max_iters: int = 100

    def __post_init__(self) -> None:
        super().__post_init__()
        check_count(self.max_iters, "max_iters", 0, whole_floats=True, most=MAX_ITERS)

    def prepare(self, problem: ProblemView) -> None:  # noqa: D102
        prog = problem.structure
        if len(prog.code) != 1 or prog.code[0] != Position.code:
            raise GoalError("method 'reach' handles one Position goal; use 'lm' (auto) for other or several goals")

    def run(self, problem: ProblemView, prog: Program, q: Array) -> Result:  # noqa: D102
        return solve_reach(problem.tree, prog, q, problem.tol, problem.rot_tol, int(self.max_iters), problem.active,
                           problem.history, problem.starts, problem.restart_q, problem.time_limit)
