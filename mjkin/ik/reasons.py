"""Why a target failed, told apart: what is proven (out of reach, blocked by limits) from what was only not found.

Run after a failed solve only. Two cheap certificates:

* **out of reach** — a frame can be no farther from the anchor of the first joint
  that moves it than the sum of the fixed distances between the anchors of the
  rotating joints after it (and from the last one to the frame's point), plus the
  travel of its slides (:func:`reach_bound`). A position target beyond that bound
  by more than ``tol`` can never be met.
* **limits** — when a single hinge or slide moves the goal frames, the value that
  would meet the first position target is computed, the goals are checked there by
  FK with the limits ignored, and the target counts as blocked when every value
  inside the limits is farther from it than the tolerance allows.
* **balance** — a hard :class:`~mjkin.goals.Balance` keeps the centre of mass over its
  support, and every support point stays within its reach bound of an anchor, so the
  support lies inside the shadows of those balls on the floor (:func:`_balance`). A
  counted :class:`~mjkin.goals.ComTarget` whose shadow is farther outside them than
  ``tol`` can never be met.

Everything else is ``"not_found"``: the solver's starts ran out, nothing is proven.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from ..goals import Balance, ComTarget, Pose, Position, Program
from ..goals.com import floor_basis
from ..kinematics.qspace import BALL, FREE, HINGE, SLIDE
from ..kinematics.tree import Tree
from .evaluate import evaluate_program
from .kernel import HARD_TOL

if TYPE_CHECKING:
    from .method import ProblemView

Array = NDArray[np.float64]
OUT_OF_REACH, LIMITS, BALANCE, NOT_FOUND = "out_of_reach", "limits", "balance", "not_found"
PROVEN = (OUT_OF_REACH, LIMITS, BALANCE)
DIRECTIONS = 64  # floor directions the balance certificate tries


def _anchor(tree: Tree, body_pose: Array, joint: int) -> Array:
    """World anchor ``(B, 3)`` of ``joint`` from its body's world poses ``(B, 4, 4)`` (its joints at rest)."""
    return body_pose[:, :3, :3] @ tree.jnt_pos[joint] + body_pose[:, :3, 3]


def chain_joints(tree: Tree, body: int, active: NDArray[np.bool_]) -> list[int] | None:
    """The joints with an active dof that move ``body``, root first; None if a body mixes active and fixed joints."""
    joints = sorted({int(tree.plan.dof_jnt[d]) for d in tree.body_dofs[body] if active[d]})
    for b in {int(tree.jnt_body[j]) for j in joints}:
        own = np.flatnonzero(tree.jnt_body == b)
        if any(not active[tree.jnt_dofadr[j]] for j in own):
            return None  # its anchors would depend on the fixed joints' values: no cheap bound
    return joints


def reach_bound(tree: Tree, body: int, point: Array, active: NDArray[np.bool_], q: Array) -> tuple[Array, Array]:
    """The anchor ``(B, 3)`` of the first active joint moving ``body`` and a bound ``(B,)`` on the distance from it.

    ``point (3,)`` is in ``body``'s frame, ``q (B, nq)`` holds the joints that do not
    move. Rotating joints keep the distance between their anchor and every point
    after them, so the anchors of consecutive rotating joints stay as far apart as
    they are at rest (active joints at ``qpos0``); each slide adds its largest travel
    from ``qpos0``. A free joint, or an unlimited slide, gives an infinite bound.
    """
    joints = chain_joints(tree, body, active)
    B = len(q)
    if joints is None:
        return np.zeros((B, 3)), np.full(B, np.inf)
    rest = q.copy()
    for j in joints:
        a = tree.jnt_qadr[j]
        n = 7 if tree.jnt_type[j] == FREE else 4 if tree.jnt_type[j] == BALL else 1
        rest[:, a:a + n] = tree.qpos0[a:a + n]
    frames = tree.kinematics(rest)
    end = frames.pose("body", body)
    tip = end[:, :3, :3] @ point + end[:, :3, 3]
    if not joints:
        return tip, np.zeros(B)
    bound = np.zeros(B)
    anchor = _anchor(tree, frames.pose("body", int(tree.jnt_body[joints[0]])), joints[0])
    last = anchor
    for j in joints:
        kind = int(tree.jnt_type[j])
        if kind == FREE:
            return anchor, np.full(B, np.inf)
        if kind == SLIDE:
            a = tree.jnt_qadr[j]
            lo, hi = tree.layout.jnt_lo[j], tree.layout.jnt_hi[j]
            bound += max(abs(lo - tree.qpos0[a]), abs(hi - tree.qpos0[a]))
            continue
        here = _anchor(tree, frames.pose("body", int(tree.jnt_body[j])), j)
        bound += np.linalg.norm(here - last, axis=-1)
        last = here
    return anchor, bound + np.linalg.norm(tip - last, axis=-1)


def _positions(tree: Tree, prog: Program, skip: set[int]) -> list[tuple[int, int, Array, Array]]:
    """The counted position targets on bodies not in ``skip``.

    Each as ``(goal index, body, point in the body (3,), targets (B, 3))``.
    """
    out = []
    st = prog.structure
    for i, g in enumerate(prog.goals):
        if st.counted[i] and isinstance(g, (Position, Pose)) and float(g.weight) > 0 and int(st.body[i]) not in skip:
            target = g.targets()[0] if isinstance(g, Position) else g.targets()[1]
            out.append((i, int(st.body[i]), st.lpos[i], np.broadcast_to(target, (prog.B, 3))))
    return out


def certify(problem: ProblemView, prog: Program, q0: Array, success: NDArray[np.bool_]) -> NDArray[np.str_]:
    """The reason ``(B,)`` of each target: ``""`` where ``success``, else proven or ``"not_found"``.

    ``q0 (B, nq)`` are the solve's starts (the joints that do not move keep them).
    """
    tree, active = problem.tree, problem.active
    reason = np.where(success, "", NOT_FOUND).astype("<U12")
    failed = ~success
    st = prog.structure
    free = active & (tree.jnt_type[tree.plan.dof_jnt] == FREE)  # dofs of free joints that may move
    # goal frames a free joint carries: their reach bound is infinite (no FK for it) and more than one joint moves
    carried = ({b for b in {int(b) for b in st.body[st.counted]} if b >= 0 and free[tree.body_dofs[b]].any()}
        if free.any() else set())
    goals = _positions(tree, prog, carried)
    for _, body, point, target in goals:
        anchor, bound = reach_bound(tree, body, point, active, q0)
        with np.errstate(over="ignore"):  # a distance past the float range is inf, and out of reach all the same
            far = np.linalg.norm(target - anchor, axis=-1) > bound + problem.tol
        reason[failed & far] = OUT_OF_REACH
    if goals and not carried:
        blocked = _limits(problem, prog, q0, goals[0])
        reason[failed & (reason == NOT_FOUND) & blocked] = LIMITS
    reason[failed & (reason == NOT_FOUND) & _balance(problem, prog, q0)] = BALANCE
    return reason


def _balance(problem: ProblemView, prog: Program, q0: Array) -> NDArray[np.bool_]:
    """Targets ``(B,)`` whose centre-of-mass target lies outside every support a hard Balance can reach.

    Each support point stays within its :func:`reach_bound` of an anchor (``q0 (B, nq)``
    holds the joints that do not move), so on every floor direction ``u`` the support
    keeps ``u·x <= max_k (u·a_k + r_k)``. A counted ComTarget beyond that on one of
    :data:`DIRECTIONS` directions by more than ``tol`` (plus what a ``margin < 0`` allows
    outside) is proven out of balance.
    """
    tree, st, B = problem.tree, prog.structure, prog.B
    proven = np.zeros(B, dtype=bool)
    targets = [np.broadcast_to(g.targets()[0], (B, 3)) for i, g in enumerate(prog.goals)
               if st.counted[i] and isinstance(g, ComTarget)]
    if not targets:
        return proven
    angle = np.linspace(0.0, 2 * np.pi, DIRECTIONS, endpoint=False)
    along = np.column_stack([np.cos(angle), np.sin(angle)]) @ floor_basis(tree)[1:]  # (D, 3) floor directions
    for i, g in enumerate(prog.goals):
        if not (st.hard[i] and isinstance(g, Balance)):
            continue
        reach = np.full((B, DIRECTIONS), -np.inf)
        own = st.support[:, 0] == i
        for body, point in zip(st.support[own, 1], st.support_pos[own], strict=True):
            anchor, bound = reach_bound(tree, int(body), point, problem.active, q0)
            reach = np.maximum(reach, anchor @ along.T + bound[:, None])
        allowed = problem.tol + max(0.0, -float(g.margin)) + HARD_TOL
        for xyz in targets:
            proven |= np.max(xyz @ along.T - reach, axis=1) > allowed
    return proven


def _limits(problem: ProblemView, prog: Program, q0: Array, goal: tuple[int, int, Array, Array]) -> NDArray[np.bool_]:
    """Targets ``(B,)`` proven blocked by the limits when one limited hinge or slide moves every goal frame.

    The value that puts ``goal``'s point nearest its target is computed with the
    limits ignored; there FK must meet every counted goal (so the target is
    reachable without limits), and every value inside the limits must leave that
    point farther than ``tol`` from its target.
    """
    tree, active = problem.tree, problem.active
    B = prog.B
    no = np.zeros(B, dtype=bool)
    st = prog.structure
    bodies = {int(b) for b, c in zip(st.body, st.counted, strict=True) if c and b >= 0}
    if len(bodies) != len({int(b) for b in st.body if b >= 0}):
        return no  # a goal on joints only: not this simple case
    moving = {int(tree.plan.dof_jnt[d]) for b in bodies for d in tree.body_dofs[b] if active[d]}
    if len(moving) != 1:
        return no
    j = moving.pop()
    kind = int(tree.jnt_type[j])
    if kind not in (HINGE, SLIDE) or not tree.jnt_limited[j]:
        return no
    i, body, point, target = goal
    a = int(tree.jnt_qadr[j])
    rest = q0.copy()
    rest[:, a] = tree.qpos0[a]
    frames = tree.kinematics(rest)
    jb = frames.pose("body", int(tree.jnt_body[j]))
    axis = jb[:, :3, :3] @ tree.jnt_axis[j]
    anchor = _anchor(tree, jb, j)
    end = frames.pose("body", body)
    tip = end[:, :3, :3] @ point + end[:, :3, 3]
    lo, hi = tree.jnt_range[j] - tree.qpos0[a]
    if kind == SLIDE:
        need = np.einsum("bi,bi->b", target - tip, axis)
        gap = np.maximum(lo - need, need - hi)
    else:
        u = tip - anchor
        u -= np.einsum("bi,bi->b", u, axis)[:, None] * axis
        v = target - anchor
        v -= np.einsum("bi,bi->b", v, axis)[:, None] * axis
        need = np.arctan2(np.einsum("bi,bi->b", axis, np.cross(u, v)), np.einsum("bi,bi->b", u, v))
        turns = need[:, None] + 2 * np.pi * np.arange(-2, 3)
        gap = np.minimum(np.maximum(lo - turns, turns - hi).min(-1), np.pi)
        radius = np.linalg.norm(u, axis=-1)
    there = rest.copy()
    there[:, a] += need
    _, _, err = evaluate_program(tree, prog, np.ascontiguousarray(there))
    met = np.all(((err[:, :, 0] <= problem.tol) & (err[:, :, 1] <= problem.rot_tol)) | ~st.counted, axis=1)
    # how far the point stays from where it must be: the slide's gap, or the chord to the nearest allowed angle
    nearest = gap if kind == SLIDE else 2 * radius * np.sin(np.maximum(gap, 0) / 2)
    return met & (gap > 0) & (nearest - err[:, i, 0] > problem.tol)
