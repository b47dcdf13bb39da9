"""What a solve returns: :class:`Result`, its per-iteration :class:`History`, and :func:`package`."""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from ..errors import InputError
from ..goals import Goal
from ..kinematics.tree import Tree, fingerprint
from .kernel import STATUS_NAMES, summarise

if TYPE_CHECKING:
    from ..goals import Program

Array = NDArray[np.float64]
STATUS = np.array(STATUS_NAMES)
NO_REASON = np.full(1, "", dtype="<U12")[0]  # an unbatched success's reason


@dataclass(frozen=True)
class History:
    """Per-iteration record of a solve (iteration 0 is the start).

    ``q (..., H, nq)`` and ``error (..., H, 2)`` (worst position and rotation
    error over the counted goals); rows after a solve's last iteration repeat nothing
    and are NaN.
    """

    q: Array
    error: Array


@dataclass(frozen=True, init=False)
class Result:
    """What :func:`solve` found. Shapes carry the batch shape ``...`` of the targets (none if unbatched).

    Attributes:
        q: ``(..., nq)`` best configuration found, inside the joint limits, a valid ``qpos``.
        success: ``(...)`` every counted goal within ``tol`` (metres) and ``rot_tol`` (radians),
            and every hard constraint holding (each row ``>= -1e-6``, :data:`~mjkin.ik.kernel.HARD_TOL`).
        error: ``(..., 2)`` worst ``[position (m), rotation (rad)]`` error over the counted goals.
        iterations: ``(...)`` steps taken (CCD: sweeps).
        status: ``"converged"``, ``"unreachable"`` (stalled away from the goal, or nothing may
            move), ``"limits"`` (stalled with a joint limit blocking the way), ``"max_iterations"``,
            ``"timeout"`` (the ``timeout`` ran out first), ``"constraint"`` (stalled with a hard
            constraint holding the answer back, or no pose found that keeps every hard constraint:
            :attr:`binding` names it; with ``avoid_collisions``, the contact that could not be avoided).
        goal_errors: ``(..., G, 2)`` per goal, in :attr:`goals` order (hard constraints first, then by
            priority); a hard constraint's is its violation (how far its lowest row is below zero).
        goals: the goals as solved.
        method: the method that ran.
        restarts: ``(...)`` random restarts used.
        history: per-iteration record when asked for (``history=True``).
        reason: ``(...)`` why a target failed, beside ``status``: ``"out_of_reach"`` (proven: the
            target lies beyond the chain's reach bound, :func:`mjkin.ik.reasons.reach_bound`),
            ``"limits"`` (proven: reachable only outside the joint limits; checked where it is cheap,
            a single moving joint), ``"balance"`` (proven: a centre-of-mass target outside every support a
            hard balance can reach), ``"not_found"`` (no proof either way); ``""`` for a success.
        binding: ``(...)`` index in :attr:`goals` of the hard constraint at (or below) its bound at
            :attr:`q` when the solve did not converge, else -1.
        tree: the tree solved on; not pickled (a result sent to another process travels
            without its ``MjModel``): re-attach it with :meth:`with_tree`.
    """

    q: Array
    success: Array
    error: Array
    iterations: Array
    status: Array
    goal_errors: Array
    goals: tuple[Goal, ...]
    method: str
    restarts: Array
    history: History | None = None
    reason: NDArray[np.str_] | None = None
    binding: Array | None = None
    tree: Tree | None = field(default=None, repr=False, compare=False)

    def __init__(self, q: Array, success: Array, error: Array, iterations: Array, status: Array, goal_errors: Array,
                 goals: tuple[Goal, ...], method: str, restarts: Array, history: History | None = None,
                 reason: NDArray[np.str_] | None = None, binding: Array | None = None,
                 tree: Tree | None = None) -> None:
        # the fields at once: a frozen dataclass's own __init__ sets them one by one (~2 µs of a ~40 µs solve)
        self.__dict__.update(q=q, success=success, error=error, iterations=iterations, status=status,
                             goal_errors=goal_errors, goals=goals, method=method, restarts=restarts, history=history,
                             reason=reason, binding=binding, tree=tree)

    def __getstate__(self) -> dict:
        """Pickle everything but the tree (its ``MjModel`` is large and the receiver usually has it).

        The tree's :func:`~mjkin.kinematics.tree.fingerprint` travels instead, for :meth:`with_tree` to check.
        """
        made_on = fingerprint(self.tree) if self.tree is not None else self.__dict__.get("_fingerprint")
        return {**self.__dict__, "tree": None, "_fingerprint": made_on}

    def with_tree(self, tree: Tree) -> Result:
        """This result with its tree attached again (after unpickling).

        Raises:
            InputError: ``tree`` is not the model the result was solved on.
        """
        made_on = fingerprint(self.tree) if self.tree is not None else self.__dict__.get("_fingerprint")
        if made_on is not None and fingerprint(tree) != made_on:
            raise InputError(f"this result was solved on another model (fingerprint {made_on}), not on "
                             f"{tree.name!r} ({fingerprint(tree)})")
        return replace(self, tree=tree)

    def singular_values(self) -> NDArray:
        """Singular values ``(..., k)`` of the top-priority goals' Jacobian at :attr:`q`.

        The smallest tends to zero at a singularity (a stretched arm); their
        product is Yoshikawa's manipulability.
        """
        if self.tree is None:
            raise InputError("this result has no tree (results are pickled without it); "
                             "use result.with_tree(tree) or mjkin.singular_values(tree, goals, q)")
        from .evaluate import singular_values

        return singular_values(self.tree, self.goals, self.q)


def _shaped(batch: tuple[int, ...], a: NDArray) -> NDArray:
    return a.reshape(batch + a.shape[1:])


def package(prog: Program, q: Array, err: Array, iters: NDArray, status: NDArray, used: NDArray, tol: float,
            rot_tol: float, method: str, history: History | None = None, tree: Tree | None = None,
            binding: NDArray | None = None) -> Result:
    """Build a :class:`Result` from flat per-target arrays (``binding`` None: no binding constraint)."""
    worst, success = np.empty((len(q), 2)), np.empty(len(q), dtype=bool)
    summarise(err, prog.counted, prog.hard, float(tol), float(rot_tol), worst, success)
    return result_of(prog, q, worst, success, err, iters, status, used, method, history, tree,
                     np.full(len(q), -1, np.int64) if binding is None else binding)


def result_of(prog: Program, q: Array, worst: Array, success: NDArray, err: Array, iters: NDArray, status: NDArray,
              used: NDArray, method: str, history: History | None, tree: Tree | None, binding: NDArray) -> Result:
    """A :class:`Result` from flat per-target arrays, already summarised (``worst (B, 2)``, ``success (B,)``).

    The result keeps the arrays (views of them), so they must be the caller's no more.
    """
    b = prog.batch
    if not b:  # one target: its row of each (a single solve's path, so without the reshapes)
        hist = None if history is None else History(history.q[0], history.error[0])
        return Result(q=q[0], success=success[0], error=worst[0], iterations=iters[0], status=STATUS[status[0]],
                      goal_errors=err[0], goals=prog.goals, method=method, restarts=used[0], history=hist,
                      reason=NO_REASON, binding=binding[0], tree=tree)
    hist = None if history is None else History(_shaped(b, history.q), _shaped(b, history.error))
    return Result(q=_shaped(b, q), success=_shaped(b, success), error=_shaped(b, worst),
                  iterations=_shaped(b, iters), status=_shaped(b, STATUS[status]), goal_errors=_shaped(b, err),
                  goals=prog.goals, method=method, restarts=_shaped(b, used), history=hist,
                  reason=_shaped(b, np.full(len(q), "", dtype="<U12")), binding=_shaped(b, binding), tree=tree)
