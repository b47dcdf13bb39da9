"""``mjkin.solve``: one solve through a :class:`~mjkin.Problem` made for it."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from numpy.typing import ArrayLike

from ..goals import Goal
from ..kinematics.tree import Tree
from .method import Method
from .problem import Problem
from .result import Result


def solve(tree: Tree, goals: Goal | Sequence[Goal], q0: ArrayLike | None = None, method: str | Method = "auto",
          tol: float = 1e-6, rot_tol: float = 1e-5, **options: Any) -> Result:
    """Find ``q`` that meets the goals, from ``q0`` (default ``qpos0``), inside the joint limits.

    ``Problem(tree, goals, method=method, tol=tol, rot_tol=rot_tol, **options).solve(q0)``, equal
    to it bit for bit; see :class:`~mjkin.Problem` for every option. A loop of solves with new
    targets is faster through one Problem.

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
    return Problem(tree, goals, method=method, tol=tol, rot_tol=rot_tol, **options).solve(q0)
