"""Every IK solution of one goal: many seeded starts solved as one batch, merged, polished, re-checked.

A numeric solver returns one answer; an analytic one (IKFast, IK-Geo) returns all
of them, but only for special 6-axis arms. :func:`solutions` gets them for any
chain from a batched :class:`mjkin.Problem`: ``starts`` quasi-random
configurations inside the limits (scrambled Sobol, so no basin of attraction is
left without a start by chance) each run to convergence, the converged ones are
merged by joint-space distance, polished to a tighter tolerance, and every
survivor is checked again by forward kinematics.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ..errors import GoalError, InputError
from ..goals import Goal
from ..goals.program import as_goals
from ..ik.evaluate import evaluate_program
from ..ik.kernel import summarise
from ..ik.method import Method
from ..ik.problem import Problem
from ..ik.reasons import NOT_FOUND
from ..ik.result import Result
from ..kinematics import qspace
from ..kinematics.qspace import HINGE
from ..kinematics.tree import Tree
from ..runtime.checks import check_count, check_number

Array = NDArray[np.float64]
STARTS = 128  # seeded starts per round
ROUNDS = 8  # rounds of starts at most: another while the last found a new solution
MAX_STARTS = 100_000  # starts over all rounds at most (starts x rounds; drawn ahead; ~2e7 iterations, under a minute)
SPREAD_POOL = 4  # with max_solutions = k, rounds stop once 4 k distinct solutions are there to spread from
MAX_ITERS = 200  # near a wrist singularity LM creeps: at 50 iterations 7 % of starts converged, at 200 most
MERGE = 1e-3  # solutions closer than this (largest joint difference, rad or m) are one
POLISH = 1e-3  # the polish run's tolerances, as a share of the caller's


def solutions(tree: Tree, goal: Goal | Sequence[Goal], *, max_solutions: int | None = None, starts: int = STARTS,
              rounds: int = ROUNDS, merge: float = MERGE, seed: int = 0, **options: Any) -> Result:
    """The distinct configurations that meet ``goal`` inside the joint limits.

    Rounds of ``starts`` seeded quasi-random starts (one scrambled Sobol sequence over
    the joints that move a goal frame, the others at ``qpos0``; after the first round,
    half of each round recombines the solutions found with fresh joint values) are
    solved, each round as one batch of :class:`mjkin.Problem`, until a round finds no
    new solution (at most ``rounds``). Converged answers are polished at a thousandth
    of the tolerances and merged when no joint differs by more than ``merge`` (unlimited
    hinges, and hinges whose range spans a full turn, compared modulo 2π: ``q`` and
    ``q + 2π`` are one solution); every survivor is checked again by FK against ``tol``
    and ``rot_tol`` and the joint limits, and only those that pass are returned.

    A 6-axis arm has finitely many solutions (a UR-type arm and one with a spherical
    wrist up to 8): on 1000 random poses of each, all were found except at poses
    within a hair of a wrist singularity (README, ``mjkin bench solutions``). A
    redundant chain (a 7-DoF arm under a pose goal) has continuous self-motion
    families instead: every round finds new members, so all ``rounds`` run (or until
    ``4 * max_solutions`` are there), and the answer is a spread of the families — the
    distinct converged starts, thinned by farthest-point sampling to ``max_solutions``
    — not every solution.

    Args:
        tree: the kinematic tree.
        goal: one goal or several with unbatched targets (see :mod:`mjkin.goals`).
        max_solutions: return at most this many, the most spread out (farthest-point
            sampling from the one nearest ``qpos0``); None: all found.
        starts: seeded starts per round.
        rounds: most rounds of starts (``starts * rounds`` at most :data:`MAX_STARTS`).
        merge: largest joint difference (rad or m) of two configurations counted as one.
        seed: seeds the starts (the same seed, the same answer).
        **options: :class:`mjkin.Problem` options (``method``, ``tol``, ``rot_tol``,
            ``base``, ``joints``, the method's own; ``restarts`` defaults to 0 (the starts are the
            restarts) and ``max_iters`` to 200).

    Returns:
        A :class:`mjkin.Result` with ``q (k, nq)`` sorted by distance from ``qpos0``, ``success``
        all True, ``status`` all ``"converged"``; ``k`` may be 0, and then ``reason`` (a 0-d string
        array, the whole goal's) says ``"out_of_reach"`` or ``"limits"`` when that is proven, else
        ``"not_found"``.

    Raises:
        GoalError: batched targets (give one goal; solve several goals in a loop).
        InputError: bad options.
    """
    n = check_count(starts, "starts", most=MAX_STARTS)
    if n * check_count(rounds, "rounds", most=MAX_STARTS) > MAX_STARTS:  # drawn ahead: (starts * rounds, nq) floats
        raise InputError(f"starts x rounds must be at most {MAX_STARTS:,}, got {n} x {rounds}")
    if max_solutions is not None:
        check_count(max_solutions, "max_solutions")
    merge = check_number(merge, "merge", 0, strict=True)
    given = as_goals(goal)
    if "root" in options:
        raise InputError("solutions takes no root= (a planted body's pose comes from one q0; solutions have many)")
    if any(g.batch() != () for g in given):
        raise GoalError("solutions takes one target per goal (no leading batch axis); call it once per target")
    if not isinstance(options.get("method"), Method):
        options.setdefault("restarts", 0)
        options.setdefault("max_iters", MAX_ITERS)
    many = tuple(_repeated(g, n) for g in given)
    problem = Problem(tree, many, seed=seed, **options)
    rng = np.random.default_rng(seed)
    pool = np.where(problem.restart_q, qspace.random(tree, rng, n * check_count(rounds, "rounds"), spread=True),
                    tree.qpos0)
    q = np.zeros((0, tree.nq))
    for r in range(rounds):
        starts_r = pool[r * n:(r + 1) * n]
        if len(q):
            starts_r = np.concatenate([starts_r[:n // 2], _recombined(problem, q, starts_r[n // 2:], rng)])
        found = problem.solve(starts_r)
        converged = found.q[found.success]
        if len(converged):  # polished before merging: near a singularity the 1e-6 band spans many merge widths
            converged = _polish(problem, given, _distinct(tree, converged, merge))
        more = _distinct(tree, np.concatenate([q, converged]), merge)
        grew, q = len(more) > len(q), more
        if (r and not grew) or (max_solutions is not None and len(q) >= SPREAD_POOL * max_solutions):
            break
    if len(q):
        q = _distinct(tree, q[_checked(problem, given, q)], merge)
    q = q[np.argsort(joint_distance(tree, q, tree.qpos0[None]), kind="stable")]
    if max_solutions is not None and len(q) > max_solutions:
        q = q[np.sort(_spread(tree, q, max_solutions))]
    return _result(problem, found, given, q)


def _recombined(problem: Problem, q: Array, fresh: Array, rng: np.random.Generator) -> Array:
    """Starts ``(m, nq)``: rows of the solutions ``q (k, nq)`` with half the moving joints from ``fresh (m, nq)``.

    Each start keeps the first or the second half of a random solution's moving joints and takes
    the rest from ``fresh``. Solutions of one pose often share half their joints (a spherical
    wrist's flip keeps the arm's three; the arm's configurations share one wrist pose), so such a
    start lands near a missing solution more often than a fully random one.
    """
    idx = np.flatnonzero(problem.restart_q)
    first = rng.random(len(fresh)) < 0.5
    mask = np.zeros(fresh.shape, dtype=bool)
    mask[:, idx[:len(idx) // 2]] = first[:, None]
    mask[:, idx[len(idx) // 2:]] = ~first[:, None]
    return np.where(mask, fresh, q[rng.integers(0, len(q), len(fresh))])


def _repeated(g: Goal, n: int) -> Goal:
    """Goal ``g`` with its targets repeated ``n`` times along a new leading batch axis."""
    changes: dict[str, Any] = {name: np.repeat(np.asarray(getattr(g, name))[None], n, axis=0) for name in g._batched}
    return replace(g, **changes)


def _periodic(tree: Tree) -> NDArray[np.int64]:
    """Dofs compared modulo 2π: hinges without limits or whose range spans a full turn."""
    wide = (tree.jnt_type == HINGE) & (~tree.jnt_limited | (np.diff(tree.jnt_range, axis=1)[:, 0] >= 2 * np.pi - 1e-9))
    return tree.jnt_dofadr[wide]


def joint_distance(tree: Tree, a: Array, b: Array) -> Array:
    """Largest joint difference ``(...)`` between ``a`` and ``b`` (broadcast ``(..., nq)``), wide hinges modulo 2π."""
    v = tree.difference(a, b)
    p = _periodic(tree)
    v[..., p] = np.arctan2(np.sin(v[..., p]), np.cos(v[..., p]))
    return np.abs(v).max(-1) if v.shape[-1] else np.zeros(v.shape[:-1])


def _distinct(tree: Tree, q: Array, merge: float) -> Array:
    """The rows of ``q (n, nq)`` that differ by more than ``merge`` from every earlier kept one."""
    kept: list[int] = []
    for i in range(len(q)):
        if not kept or joint_distance(tree, q[kept], q[i][None]).min() > merge:
            kept.append(i)
    return q[kept]


def _spread(tree: Tree, q: Array, k: int) -> NDArray[np.int64]:
    """Indices of ``k`` rows of ``q (n, nq)`` chosen by farthest-point sampling from row 0."""
    chosen = [0]
    near = joint_distance(tree, q, q[0][None])
    while len(chosen) < k:
        i = int(np.argmax(near))
        chosen.append(i)
        near = np.minimum(near, joint_distance(tree, q, q[i][None]))
    return np.array(chosen)


def _polish(problem: Problem, given: tuple[Goal, ...], q: Array) -> Array:
    """Each row of ``q (k, nq)`` solved again at tighter tolerances; a row that does not get there stays."""
    k = len(q)
    fine = Problem(problem.tree, tuple(_repeated(g, k) for g in given), method="lm", restarts=0,
                   tol=problem.tol * POLISH, rot_tol=problem.rot_tol * POLISH, base=problem.base,
                   joints=problem.joints, max_iters=20, seed=None)
    res = fine.solve(q)
    return np.where(res.success[:, None], res.q, q)


def _errors(problem: Problem, given: tuple[Goal, ...], q: Array) -> tuple[Array, Array, NDArray[np.bool_]]:
    """FK's check of ``q (k, nq)``: per-goal errors ``(k, G, 2)``, the worst ``(k, 2)``, and which rows succeed.

    A row succeeds when every counted goal is within ``tol`` and ``rot_tol`` and ``q`` is inside the limits.
    """
    tree, k = problem.tree, len(q)
    prog = problem.program(tuple(_repeated(g, k) for g in given))
    _, _, err = evaluate_program(tree, prog, np.ascontiguousarray(q))
    worst, met = np.empty((k, 2)), np.empty(k, dtype=bool)
    summarise(err, prog.counted, prog.hard, problem.tol, problem.rot_tol, worst, met)
    return err, worst, met & (joint_distance(tree, q, tree.clip(q)) <= 1e-12)


def _checked(problem: Problem, given: tuple[Goal, ...], q: Array) -> NDArray[np.bool_]:
    """Which rows of ``q (k, nq)`` FK finds converged and inside the joint limits."""
    return _errors(problem, given, q)[2] if len(q) else np.zeros(0, dtype=bool)


def _result(problem: Problem, found: Result, given: tuple[Goal, ...], q: Array) -> Result:
    """A :class:`Result` for the solutions ``q (k, nq)`` (each checked converged); ``found``: the batch solve."""
    tree, k = problem.tree, len(q)
    err, worst, _ = _errors(problem, given, q) if k else (np.zeros((0, len(given), 2)), np.zeros((0, 2)), None)
    reason = "" if k else (str(np.reshape(found.reason, -1)[0]) if found.reason is not None else "") or NOT_FOUND
    return Result(q=q, success=np.ones(k, bool), error=worst, iterations=np.zeros(k, np.int64),
                  status=np.full(k, "converged"), goal_errors=err,
                  goals=tuple(given[i] for i in problem.structure.order), method=found.method,
                  restarts=np.zeros(k, np.int64), reason=np.array(reason), tree=tree)
