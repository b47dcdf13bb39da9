"""Goals encoded as arrays for the compiled evaluator: the structure once, the targets at each solve."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from functools import cached_property
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from ..errors import GoalError
from ..kinematics.geoms import Geoms, native_pairs
from . import registry
from .base import DATA, Array, Goal, broadcast
from .clearance import bounded_geoms
from .residuals import GoalArrays

if TYPE_CHECKING:
    from ..kinematics.tree import Tree


@dataclass(frozen=True, eq=False)
class Structure:
    """What a set of goals compiles to besides its targets: hard constraints first, then by priority level.

    The rows of the hard goals (``hard``, see :attr:`mjkin.goals.Goal.hard`) come
    first, before ``level_rows[0]``, outside every priority level. ``order[k]`` is
    the index, among the goals as given, of the ``k``-th goal as solved.
    ``key`` tells goals of the same structure (same kinds, frames, weights, priorities).
    """

    key: tuple
    order: tuple[int, ...]
    code: NDArray[np.int64]  # (G,) each goal's kind, by its registry code
    body: NDArray[np.int64]
    lrot: Array
    lpos: Array
    aux: NDArray[np.int64]
    column: NDArray[np.int64]
    sqrt_w: Array
    row: NDArray[np.int64]
    joint_row: Array
    level_rows: NDArray[np.int64]
    counted: NDArray[np.bool_]
    hard: NDArray[np.bool_]
    pairs: NDArray[np.int64]  # (P, 4) geom pairs [geom1, geom2, goal, bounded] of the goals that keep geoms apart
    bounded: Geoms  # the geoms for the bounded pairs (see mjkin.goals.clearance.bounded_geoms)
    support: NDArray[np.int64]  # (S, 2) [goal, body] of the support points of the goals that balance
    support_pos: Array  # (S, 3) those points in their bodies
    joint_targets: bool  # some goal has a joint-space target (a rest pose)

    @cached_property
    def codes(self) -> tuple[int, ...]:
        """The registry codes of the goal kinds present, ascending."""
        return tuple(sorted(set(self.code.tolist())))

    @cached_property
    def common(self) -> bool:
        """Whether every goal is of a :attr:`~mjkin.goals.Goal.common` kind: the goal arrays then carry no geoms,
        pairs or support points, and the IK loop compiles no code for them (:func:`mjkin.ik.loop.other_goal`).
        """  # noqa: D205
        return all(registry.KINDS[c].common for c in self.codes)


@dataclass(frozen=True, eq=False, init=False)
class Program:
    """A :class:`Structure` with targets: ``G`` goals, ``B`` targets, ``m`` residual rows.

    The targets are ``data (B, G, DATA)`` and ``rest_q (G, B or 1, nq)``; :attr:`arrays` holds
    them with everything else the compiled evaluator reads.
    """

    structure: Structure
    goals: tuple[Goal, ...]  # sorted by priority, as solved
    batch: tuple[int, ...]  # () or (B,)
    data: Array
    rest_q: Array
    geoms: Geoms  # the tree's

    def __init__(self, structure: Structure, goals: tuple[Goal, ...], batch: tuple[int, ...], data: Array,
                 rest_q: Array, geoms: Geoms) -> None:
        # at once, as Result does: a frozen dataclass's own __init__ costs ~0.5 µs more, on every solve
        self.__dict__.update(structure=structure, goals=goals, batch=batch, data=data, rest_q=rest_q, geoms=geoms)

    @cached_property
    def arrays(self) -> GoalArrays:
        """The compiled evaluator's arrays (made when first asked for: a single solve copies only the targets)."""
        st = self.structure
        if st.common:
            return GoalArrays(st.code, st.body, st.lrot, st.lpos, self.data, st.aux, st.column, st.sqrt_w, st.row,
                              self.rest_q, st.joint_row, st.level_rows, st.counted, st.hard, None, None, None, None,
                              None)
        return GoalArrays(st.code, st.body, st.lrot, st.lpos, self.data, st.aux, st.column, st.sqrt_w, st.row,
                          self.rest_q, st.joint_row, st.level_rows, st.counted, st.hard, self.geoms, st.bounded,
                          st.pairs, st.support, st.support_pos)

    @property
    def B(self) -> int:
        """Number of targets (1 when unbatched)."""
        return int(self.data.shape[0])

    def target(self, b: int) -> Program:
        """The program of target ``b`` alone (unbatched)."""
        rest = self.rest_q[:, b:b + 1] if self.structure.joint_targets else self.rest_q
        return Program(self.structure, self.goals, (), self.data[b:b + 1], rest, self.geoms)

    def __getattr__(self, name: str) -> Any:
        """The goal arrays by name (``prog.body``, ``prog.level_rows``...)."""
        if name in GoalArrays._fields:
            return getattr(self.arrays, name)
        raise AttributeError(name)


def as_goals(goals: Goal | Sequence[Goal]) -> tuple[Goal, ...]:
    """One goal or several as a tuple, checked to be goals; lists inside the list are flattened into it."""
    if isinstance(goals, Goal):
        out: tuple = (goals,)
    elif isinstance(goals, (list, tuple)):
        out = tuple(goals)
        if not all(isinstance(g, Goal) for g in out):
            out = tuple(h for g in goals for h in (g if isinstance(g, (list, tuple)) else (g,)))
    else:
        raise GoalError(f"goals must be a mjkin.goals goal or a list of them, got {type(goals).__name__}")
    if not out:
        raise GoalError("give at least one goal")
    for g in out:
        if not isinstance(g, Goal):
            raise GoalError(f"goals must be mjkin.goals objects, got {type(g).__name__}")
        if g.code < 0:
            raise GoalError(f"goal kind {type(g).__name__} is not registered (mjkin.goals.register)")
    return out


def key_of(goals: tuple[Goal, ...]) -> tuple:
    """The structure key of ``goals`` (in the order given)."""
    return tuple([g.key() for g in goals])


def structure(tree: Tree, goals: Goal | Sequence[Goal]) -> Structure:
    """Validate the goals' frames, weights and priorities against ``tree`` and encode them.

    Raises:
        GoalError: a goal is malformed.
        UnknownNameError: a frame or joint name the model does not have.
    """
    given = as_goals(goals)
    # hard constraints first, then by priority (stable within a level)
    order = tuple(sorted(range(len(given)), key=lambda i: (not given[i].hard, given[i].priority)))
    gs = [given[i] for i in order]
    G = len(gs)
    body = np.full(G, -1, dtype=np.int64)
    lrot = np.tile(np.eye(3), (G, 1, 1))
    lpos = np.zeros((G, 3))
    aux = np.zeros(G, dtype=np.int64)
    joint_row = np.zeros((G, tree.nv))
    for i, g in enumerate(gs):
        body[i], lrot[i], lpos[i], aux[i], jr = g.static(tree)
        if jr is not None:
            joint_row[i] = jr
    row = np.concatenate([[0], np.cumsum([g.nrows(tree) for g in gs])]).astype(np.int64)
    pairs = [np.column_stack([p, np.full(len(p), i), ~native_pairs(tree.geoms, p)]) for i, g in enumerate(gs)
             if (p := getattr(g, "geom_pairs", lambda _: None)(tree)) is not None and len(p)]
    all_pairs = np.ascontiguousarray(np.concatenate(pairs) if pairs else np.zeros((0, 4)), dtype=np.int64)
    points = [np.column_stack([np.full(len(p), i), p]) for i, g in enumerate(gs)
              if (p := getattr(g, "support_points", lambda _: None)(tree)) is not None]
    support = np.concatenate(points) if points else np.zeros((0, 5))
    soft = [i for i in range(G) if not gs[i].hard]  # sorted: each level's rows are contiguous
    level_rows = np.array([row[i] for k, i in enumerate(soft) if k == 0 or gs[i].priority != gs[soft[k - 1]].priority]
                          + [row[-1]], dtype=np.int64)
    return Structure(
        key=key_of(given), order=order, code=np.array([g.code for g in gs], dtype=np.int64), body=body, lrot=lrot,
        lpos=lpos, aux=aux, column=np.array([g.column(tree) for g in gs], dtype=np.int64),
        sqrt_w=np.sqrt([float(g.weight) for g in gs]), row=row, joint_row=joint_row, level_rows=level_rows,
        counted=np.array([g.weight > 0 and g.counted and not g.hard for g in gs]),
        hard=np.array([g.weight > 0 and g.hard for g in gs], dtype=np.bool_),
        pairs=all_pairs, bounded=bounded_geoms(tree.geoms, all_pairs[:, :2]),
        support=np.ascontiguousarray(support[:, :2], dtype=np.int64), support_pos=np.ascontiguousarray(support[:, 2:]),
        joint_targets=any(g.joint_target for g in gs))


def encode(tree: Tree, st: Structure, given: tuple[Goal, ...]) -> Program:
    """The targets of the goals ``given`` (structure ``st``, in the order given; see :func:`as_goals`) on top of ``st``.

    Raises:
        GoalError: malformed targets, batches that disagree, or goals of another structure.
    """
    G = len(st.order)
    if len(given) != G:
        raise GoalError(f"expected {G} goals of the problem's structure, got {len(given)}")
    gs = given if G == 1 else tuple(given[i] for i in st.order)
    try:
        batch = broadcast([g.batch() for g in gs])
    except ValueError:
        raise GoalError(f"goal targets have different batch sizes: {[g.batch() for g in gs]}") from None
    if len(batch) > 1:
        raise GoalError(f"targets may have one leading batch axis, got batch shape {batch}")
    B = batch[0] if batch else 1
    data = np.zeros((B, G, DATA))
    rest = np.zeros((G, B if st.joint_targets else 1, tree.nq))
    for i, g in enumerate(gs):
        g.encode(tree, data[:, i], rest[i])
    return Program(st, gs, batch, data, rest, tree.geoms)


def compile_goals(tree: Tree, goals: Goal | Sequence[Goal]) -> Program:
    """Validate and encode goals at once (a :class:`~mjkin.Problem` keeps the structure between solves)."""
    given = as_goals(goals)
    return encode(tree, structure(tree, given), given)
