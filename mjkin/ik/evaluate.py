"""Goal residuals, Jacobians and errors at given configurations, and the singular values of the goals' Jacobian."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..goals import Goal, Program, compile_goals
from ..kinematics.tree import Tree, check_tree
from .generated import loop_for

Array = NDArray[np.float64]


def evaluate_program(tree: Tree, prog: Program, q: Array) -> tuple[Array, Array, Array]:
    """Residuals ``(B, m)``, Jacobians ``(B, m, nv)`` and errors ``(B, G, 2)`` at ``q (B, nq)``."""
    q = np.require(q, np.float64, ["C", "W"])  # one signature: a read-only q compiled the kernel again (a minute)
    return loop_for(prog.structure.codes).evaluate_program(tree, prog, q)


def evaluate(tree: Tree, goals: Goal | Sequence[Goal], q: ArrayLike) -> tuple[Array, Array, Array]:
    """Weighted residuals ``(B, m)``, Jacobians ``(B, m, nv)`` and per-goal errors ``(B, G, 2)``.

    Errors are ``[metres, radians]`` of each goal in natural units (unweighted).
    Goals come back sorted by priority, as the solvers see them.
    """
    prog = compile_goals(tree, goals)
    qs = np.broadcast_to(tree.check_q(q), (prog.B, tree.nq))
    return evaluate_program(tree, prog, np.ascontiguousarray(qs))


def singular_values(tree: Tree, goals: Goal | Sequence[Goal], q: ArrayLike) -> NDArray:
    """Singular values ``(..., k)`` (descending) of the highest-priority goals' Jacobian at ``q``.

    The smallest tends to zero at a singularity (a stretched arm);
    ``prod(s)`` is Yoshikawa's manipulability.
    """
    prog = compile_goals(check_tree(tree), goals)
    q = tree.check_q(q)
    qs = np.ascontiguousarray(np.broadcast_to(q, (prog.B, tree.nq)) if q.ndim == 1 else q.reshape(-1, tree.nq))
    _, J, _ = evaluate_program(tree, prog, qs)
    rows = J[:, prog.level_rows[0]:prog.level_rows[1]]
    s = np.linalg.svd(rows, compute_uv=False)
    return s.reshape(q.shape[:-1] + s.shape[-1:]) if q.ndim > 1 else (s[0] if prog.batch == () else s)
