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
          tol: float = 1e-6, rot_tol: float = 1e-5, *, timeout: float | None = None, base: str | None = None,
          joints: Sequence[str] | None = None, root: str | None = None, **options: Any) -> Result:
    """Find ``q`` that meets the goals, from ``q0`` (default ``qpos0``), inside the joint limits.

    ``Problem(tree, goals, method=method, tol=tol, ...).solve(q0)``, equal to it bit for
    bit; see :class:`~mjkin.Problem` for every argument and option (``history``,
    ``seed``, ``avoid_collisions``, and the method's own: ``max_iters``, ``restarts``,
    ``damping``, ...). A loop of solves with new targets is faster through one Problem.

    Args:
        tree: the kinematic tree.
        goals: one goal or several; targets may carry one leading batch axis ``B``.
        q0: start ``(nq,)`` or one per target ``(B, nq)``; clipped into the limits.
        method: a name (``"auto"``, ``"lm"``, ``"dls"``, ...) or a method object.
        tol: position tolerance in metres.
        rot_tol: rotation tolerance in radians.
        timeout: seconds each target may take, restarts included.
        base: only joints between this body and the goal frames move.
        joints: only these joints move.
        root: a body that stays where it is in ``q0`` (a planted foot).
        **options: problem options and the method's options.

    Raises:
        GoalError, UnknownNameError, InputError: malformed goals, names or options.
    """
    return Problem(tree, goals, method=method, tol=tol, rot_tol=rot_tol, timeout=timeout, base=base, joints=joints,
                   root=root, **options).solve(q0)
