"""``mjkin.solve``: one solve through a :class:`~mjkin.Problem` made for it, or kept from a call of its structure.

Making a problem (validating the options, encoding the goals' structure, choosing
the restart joints, packing the compiled loop's arrays) costs several times an easy
solve, and a loop of ``mjkin.solve`` calls used to pay it on every call. So each tree
keeps the last :data:`KEPT` problems ``mjkin.solve`` made on it (:attr:`mjkin.Tree.problems`),
keyed by everything a problem is made from except the targets: the goals' kinds,
frames, weights and priorities (:func:`mjkin.goals.program.key_of`), the method and
every option, each with its type (``tol=True`` is refused, not taken for ``1.0``), the
model's extent (the methods' damping scales with it) and ``$MJKIN_COMPILE``. A kept
problem only reads the new targets and ``q0``, so the answer is the one a new
problem gives, bit for bit: a problem keeps nothing from one solve to the next but
buffers it overwrites (its restart starts are only read; with ``seed=None`` they are
drawn again each solve).

Not kept, made for each call as before: problems with ``root=`` (its pose goal and
shifted priorities are made from the goals) or ``avoid_collisions``, goals that read
the model's geoms (clearance, balance: the model's collision flags may change between
calls), and options whose values are not plain numbers, strings or lists of them.
"""

from __future__ import annotations

import os
import threading
from collections.abc import Sequence
from dataclasses import fields
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from ..errors import MjkinError
from ..goals import Goal
from ..goals.program import as_goals, key_of
from ..kinematics.tree import Tree, check_tree
from .method import Method
from .problem import Problem
from .result import Result

KEPT = 16  # problems kept per tree, the least recently used dropped first
_PLAIN = (str, int, float, bool, type(None), np.integer, np.floating, np.bool_)
_lock = threading.Lock()


class _Unkept(Exception):
    """An option whose value cannot be part of a key: the call makes its own problem."""


def _typed(value: Any) -> Any:
    """``value`` with its type, as a hashable key part; :class:`_Unkept` for what is not plain."""
    if isinstance(value, _PLAIN):
        return type(value), value
    if isinstance(value, (list, tuple)):
        return type(value), tuple([_typed(v) for v in value])
    if isinstance(value, Method):
        return type(value), tuple([_typed(getattr(value, f.name)) for f in fields(value)])
    raise _Unkept


def _keeps(problem: Problem) -> bool:
    """Whether ``problem`` may serve later calls: nothing in it was made from targets or the model's geoms."""
    st = problem.structure
    return problem.root is None and not problem.avoid_collisions and not len(st.pairs) and not len(st.support)


def solve(tree: Tree, goals: Goal | Sequence[Goal], q0: ArrayLike | None = None, method: str | Method = "auto",
          tol: float = 1e-6, rot_tol: float = 1e-5, **options: Any) -> Result:
    """Find ``q`` that meets the goals, from ``q0`` (default ``qpos0``), inside the joint limits.

    ``Problem(tree, goals, method=method, tol=tol, rot_tol=rot_tol, **options).solve(q0)``, equal
    to it bit for bit; see :class:`~mjkin.Problem` for every option. The problem is kept on the tree
    for later calls of the same goal structure and options (see :mod:`mjkin.ik.solve`), so a loop of
    calls with new targets runs about as fast as one Problem's :meth:`~mjkin.Problem.solve`.

    Args:
        tree: the kinematic tree.
        goals: one goal or several; targets may carry one leading batch axis ``B``.
        q0: start ``(nq,)`` or one per target ``(B, nq)``; clipped into the limits.
        method: a name (``"auto"``, ``"lm"``, ``"dls"``, ...) or a method object.
        tol: position tolerance in metres.
        rot_tol: rotation tolerance in radians.
        **options: the problem's options, by keyword: ``timeout`` (seconds per target), ``base``,
            ``joints`` and ``root`` (which joints move), ``history``, ``seed``, ``avoid_collisions``;
            and the named method's (``max_iters``, ``restarts``, ``damping``, ...).

    Raises:
        GoalError, UnknownNameError, InputError: malformed goals, names or options.
    """
    try:
        kept: dict = check_tree(tree).problems
        given = as_goals(goals)
        key = (key_of(given), _typed(method), _typed(tol), _typed(rot_tol),
               tuple([(name, _typed(options[name])) for name in sorted(options)]),
               float(tree.model.stat.extent), os.environ.get("MJKIN_COMPILE"))
        with _lock:
            problem = kept.get(key)
    except (MjkinError, _Unkept, TypeError):  # a new problem raises the error it would raise first, or takes them
        return Problem(tree, goals, method=method, tol=tol, rot_tol=rot_tol, **options).solve(q0)
    if problem is None:
        problem = Problem(tree, given, method=method, tol=tol, rot_tol=rot_tol, **options)
        if not _keeps(problem):
            return problem.solve(q0)
        with _lock:
            kept[key] = problem
            while len(kept) > KEPT:
                del kept[next(iter(kept))]
    return problem._solve(q0, given)
