"""``mjkin.Problem``: goals of one structure compiled once against a tree, then solved again and again.

A problem holds what does not change between solves — the goals' frames,
weights and priorities, the method and its settings, which joints may move and
which a restart may randomise, the restart starts — so that ``problem.solve(q0,
goals)`` only encodes new targets and runs the compiled loop.
"""

from __future__ import annotations

import hashlib
import weakref
from collections.abc import Sequence
from dataclasses import replace
from typing import Any

import numpy as np
import scipy
from numpy.typing import ArrayLike, NDArray

from ..errors import GoalError, InputError
from ..goals import Clearance, Coupling, Goal, Pose, Program
from ..goals.program import as_goals, encode, key_of, structure
from ..kinematics import qspace
from ..kinematics.qspace import FREE, NQ, NV, clip_kernel
from ..kinematics.tree import Tree, check_tree
from ..runtime import tier
from ..runtime.cache import stamp, stored_array
from ..runtime.checks import check_count, check_flag, check_number
from .by_name import METHODS
from .evaluate import evaluate_program
from .kernel import CONVERGED, UNREACHABLE, summarise
from .method import MAX_UNTIMED, Method
from .reasons import certify
from .result import History, Result, package

Array = NDArray[np.float64]
# avoid_collisions' clearance (m): past the hard constraints' tolerance (1e-6), so MuJoCo finds no contact
AVOID_MARGIN = 1e-5
# restart starts drawn per tree, seed and count (Problem._random_starts); gone with the tree
SEEDED_STARTS: weakref.WeakKeyDictionary[Tree, dict[tuple[int, int], Array]] = weakref.WeakKeyDictionary()


def seeded_starts(tree: Tree, seed: int, n: int) -> Array:
    """``qspace.random(tree, default_rng(seed), n, spread=True)`` ``(n, nq)``, read from the disk cache when kept there.

    Keyed by all it depends on: the limits and ``qpos0`` it reads, the seed, ``n``, numpy's and scipy's versions and
    the source of :mod:`mjkin.kinematics.qspace` (:func:`mjkin.runtime.cache.stamp`).
    """
    lay = tree.layout
    inputs = hashlib.sha256()
    for a in (tree.qpos0, lay.scalar_q, lay.scalar_hinge, lay.scalar_lo, lay.scalar_hi, lay.ball_q, lay.ball_max,
              lay.free_q):
        inputs.update(np.ascontiguousarray(a).tobytes() + b"|")
    key = (f"starts {seed} {n} {tree.nq} {inputs.hexdigest()} {np.__version__} {scipy.__version__} "
           f"{stamp(qspace.__file__)}")
    return stored_array("starts", key, lambda: np.ascontiguousarray(
        qspace.random(tree, np.random.default_rng(seed), n, spread=True)))


def method_of(method: str | Method, options: dict) -> Method:
    """A method object from a name and its options, or the object itself (then without options)."""
    if isinstance(method, Method):
        if options:
            raise InputError(f"options {', '.join(map(repr, options))} belong in the method object "
                             f"({type(method).__name__}(...)) when one is given")
        return method
    if not isinstance(method, str) or method not in METHODS:
        raise InputError(f"unknown IK method {method!r}; choose one of: {', '.join(METHODS)}, or a mjkin.ik method "
                         "object")
    return METHODS[method].with_options(options)


class Problem:
    """Goals of one structure on a tree, compiled once; :meth:`solve` takes new targets.

    Args:
        tree: the kinematic tree.
        goals: one goal or several (see :mod:`mjkin.goals`); targets may carry one
            leading batch axis ``B``, solved together.
        method: a name (``"auto"``, ``"lm"``, ``"dls"``, ``"pinv"``, ``"transpose"``, ``"ccd"``,
            ``"analytic2"``, ``"optimize"``, ``"reach"``) or a method object
            (:class:`mjkin.ik.LM` ``(restarts=8)``, ...). ``auto`` is :class:`~mjkin.ik.Auto`: damped
            least squares with an adaptive, error-dependent λ, step acceptance and 24 seeded
            random restarts when it stalls — the most robust.
        tol: position tolerance in metres; rot_tol: rotation tolerance in radians.
        timeout: seconds each target may take, restarts included, with every method; a target
            that runs out returns its best pose so far with ``status="timeout"``. Default none,
            except ``optimize``: 5 s per target; ``inf`` means no limit. Without one a target may take
            at most :data:`~mjkin.ik.method.MAX_UNTIMED` iterations (``max_iters x (restarts + 1)``).
        base: only joints between this body and the goal frames move.
        joints: only these joints move.
        root: a body that stays where it is (e.g. a planted foot): a top-priority pose goal
            holds it at its pose in each solve's ``q0`` while the free root joint moves the rest.
        history: keep every iterate (``Result.history``).
        seed: seeds the restarts, so solves are reproducible (None: new ones each solve).
        avoid_collisions: keep every geom pair MuJoCo would collide apart: a hard
            :class:`~mjkin.goals.Clearance` of 10 µm (:data:`AVOID_MARGIN`) is added (first in
            ``Result.goals``, as hard goals are); a solve that cannot keep it ends with ``status``
            ``"constraint"``. Only the joints that move the goal frames move.
        **options: the named method's options (``max_iters``, ``damping``, ``restarts``, ...).

    Restarts randomise only the joints that move a goal frame
    and may move; every other joint keeps its ``q0`` value, and with ``root`` so does the
    free joint. When nothing may move (no joints, ``joints=[]``, ``base=`` the goals' own
    body) every method returns the start after 0 iterations: ``"converged"`` if the goals
    already hold there, else ``"unreachable"``. Unlimited hinges come back in ``(-π, π]``
    about ``qpos0``, except those a :class:`~mjkin.goals.Coupling` names.

    Raises:
        GoalError, UnknownNameError, InputError: malformed goals, names or options.
    """

    @tier.first_use
    def __init__(self, tree: Tree, goals: Goal | Sequence[Goal], *, method: str | Method = "auto",
                 tol: float = 1e-6, rot_tol: float = 1e-5, timeout: float | None = None, base: str | None = None,
                 joints: Sequence[str] | None = None, root: str | None = None, history: bool = False,
                 seed: int | None = 0, avoid_collisions: bool = False, **options: Any) -> None:
        self.tree = check_tree(tree)
        self.method = method_of(method, options)
        self.method_name = self.method.name
        self.tol = check_number(tol, "tol", 0, strict=True)
        self.rot_tol = check_number(rot_tol, "rot_tol", 0, strict=True)
        if timeout is not None:
            timeout = check_number(timeout, "timeout (seconds)", 0, strict=True, infinite=True)
        self.time_limit = self.method.default_timeout() if timeout is None else (
            None if timeout == np.inf else timeout)
        if timeout is None and self.time_limit is None and (work := self.method.untimed_iterations()) > MAX_UNTIMED:
            raise InputError(f"max_iters x (restarts + 1) is {work:,} iterations a target, more than {MAX_UNTIMED:,} "
                             "without a time limit: give a timeout (seconds per target; inf: none) to search longer")
        self.history = check_flag(history, "history")
        self.avoid_collisions = check_flag(avoid_collisions, "avoid_collisions")
        self.seed = None if seed is None else check_count(seed, "seed", 0, whole_floats=True)
        self.base, self.joints, self.root = base, None if joints is None else _names(joints, "joints"), root
        user = as_goals(goals)
        self.user_key = key_of(user)
        if root is not None:  # a planted body: a top-priority pose goal, its target set from each q0
            self.root_body = tree.id(root, "body")
            low = min(g.priority for g in user)
            user = (Pose(root, kind="body"),) + tuple(replace(g, priority=g.priority + 1 - low) for g in user)
        if self.avoid_collisions:  # clearance from every pair MuJoCo would collide, as a hard constraint
            user = user + (Clearance(AVOID_MARGIN),)
        self.structure = structure(tree, user)
        self.wrap = self._wrapped_hinges()
        self.active = self._active_dofs()
        self.mobile = bool(self.active.any())  # some dof may move
        self.restart_q = self._restart_q()
        self.n_restarts = self.method.restart_count(self.time_limit is not None)
        self.starts = self._random_starts(self.n_restarts) if self.seed is not None else np.zeros((0, tree.nq))
        self.goals = user  # as given (with the root's pose goal first); a solve's goals replace their targets
        self.prepared = self.method.prepare(self)  # what the method keeps for this problem (Jacobian ones: a Loop)

    def __getstate__(self) -> dict:
        """Pickle the problem without what its method prepared (made again on arrival)."""
        return {k: v for k, v in self.__dict__.items() if k != "prepared"}

    def __setstate__(self, state: dict) -> None:
        self.__dict__.update(state)
        self.prepared = self.method.prepare(self)

    # ------------------------------------------------------------------ solve
    def solve(self, q0: ArrayLike | None = None, goals: Goal | Sequence[Goal] | None = None) -> Result:
        """Solve from ``q0`` (default ``qpos0``; ``(nq,)`` or one per target ``(B, nq)``) for ``goals``.

        ``goals`` must have the structure given at construction (same kinds, frames,
        weights and priorities, in the same order); only their targets are read.
        None solves the construction's goals.

        Raises:
            GoalError: goals of another structure, or malformed targets.
            InputError: a malformed ``q0``.
        """
        if goals is None:
            given = self.goals
        else:
            given = as_goals(goals)
            if key_of(given) != self.user_key:
                raise GoalError("these goals differ from the problem's in kind, frame, weight or priority; "
                                "make a new mjkin.Problem for them")
            if self.root is not None:
                given = (self.goals[0],) + given
            if self.avoid_collisions:
                given = given + (self.goals[-1],)
        return self._solve(q0, given)

    @tier.first_use
    def _solve(self, q0: ArrayLike | None, given: tuple[Goal, ...]) -> Result:
        """Solve from ``q0`` for ``given``: the goals as :attr:`goals` holds them (the root's pose goal first, the
        collision clearance last), of the problem's structure, unchecked (:func:`mjkin.solve` checked them).
        """  # noqa: D205
        tree = self.tree
        q_start = tree.qpos0 if q0 is None else q0
        if self.root is not None:
            pose = tree.kinematics(tree.check_q(q_start, "q0")).pose("body", self.root_body)
            if pose.ndim > 2:
                raise InputError("root= needs one q0 (nq,): the planted body has one pose")
            given = (Pose(self.root, kind="body", T=pose),) + given[1:]
        prog = self.program(given)
        q = self._start(q_start, prog)
        if self.seed is None and self.n_restarts:
            self.starts = self._random_starts(self.n_restarts)
        if not self.mobile:  # nothing may move: the start is the answer, whatever the method
            result = self._immobile(prog, q)
        else:
            result = self.method.run(self, prog, q)  # the run overwrites its starts
        ok = result.success  # np.all of one target's np.bool_ costs ~1 µs, a tenth of a solve's Python
        if not (ok if isinstance(ok, np.bool_) else np.all(ok)):  # only a failure pays for telling a proof from a miss
            reason = certify(self, prog, q, np.reshape(result.success, -1))
            result = replace(result, reason=reason.reshape(np.shape(result.success)))
        if len(self.wrap):
            q_out = np.array(result.q)
            qspace.wrap(tree, q_out, self.wrap)
            result = replace(result, q=q_out)
        return result

    def program(self, given: tuple[Goal, ...]) -> Program:
        """The targets of ``given`` (goals of the problem's structure, ordered as :attr:`goals`) encoded on it."""
        return encode(self.tree, self.structure, given)

    # ------------------------------------------------------------ once per problem
    def _wrapped_hinges(self) -> NDArray[np.int64]:
        """The q entries a solve wraps into (-π, π]: unlimited hinges that no Coupling goal names."""
        tree, st = self.tree, self.structure
        hinges = tree.layout.unlimited_hinge_q
        couplings = [i for i in range(len(st.code)) if st.code[i] == Coupling.code]
        if not len(hinges) or not couplings:
            return hinges
        named = np.flatnonzero(np.any(st.joint_row[couplings] != 0, axis=0))
        coupled = tree.jnt_qadr[tree.plan.dof_jnt[named]]
        return hinges[~np.isin(hinges, coupled)]

    def _active_dofs(self) -> NDArray[np.bool_]:
        """Dofs allowed to move: those of ``joints``, or of the chains between ``base`` and the goal bodies.

        With ``avoid_collisions``, only dofs that move a goal frame (an object's joints are not
        pushed aside to make room).
        """
        tree = self.tree
        active = np.ones(tree.nv, dtype=bool)
        if self.joints is not None:
            active[:] = False
            for name in self.joints:
                j = tree.id(name, "joint")
                active[tree.jnt_dofadr[j]:tree.jnt_dofadr[j] + NV[int(tree.jnt_type[j])]] = True
        if self.base is not None:
            b = tree.id(self.base, "body")
            below = np.zeros(tree.nv, dtype=bool)
            for body in {int(x) for x in self.structure.body if x >= 0}:
                chain = set(tree.body_dofs[body].tolist()) - set(tree.body_dofs[b].tolist())
                below[list(chain)] = True
            active &= below
        bodies = {int(x) for x in self.structure.body if x >= 0}
        if self.avoid_collisions and bodies:  # keeping clear moves only the joints that move the goal frames
            moving = np.zeros(tree.nv, dtype=bool)
            for body in bodies:
                moving[tree.body_dofs[body]] = True
            active &= moving
        return active

    def _restart_q(self) -> NDArray[np.bool_]:
        """Entries of q a restart may randomise: joints with an active dof that moves a goal frame.

        Every other joint keeps its start value (an object's slide joints do not
        help an arm reach), and with a planted ``root`` so does the free joint.
        """
        tree = self.tree
        moving = np.zeros(tree.nv, dtype=bool)
        bodies = {int(x) for x in self.structure.body if x >= 0}
        for body in bodies:
            moving[tree.body_dofs[body]] = True
        if not bodies:  # joint-space goals only
            moving[:] = True
        moving &= self.active
        mask = np.zeros(tree.nq, dtype=bool)
        for j in range(tree.njnt):
            kind = int(tree.jnt_type[j])
            if moving[tree.jnt_dofadr[j]:tree.jnt_dofadr[j] + NV[kind]].any() and not (
                    self.root is not None and kind == FREE):
                mask[tree.jnt_qadr[j]:tree.jnt_qadr[j] + NQ[kind]] = True
        return mask

    def _random_starts(self, n: int) -> Array:
        """``n`` restart configurations ``(n, nq)``, the same for the same seed.

        Quasi-random (:func:`mjkin.kinematics.qspace.random` with ``spread``): on the
        TRAC-IK protocol it cut the Panda's mean iterations by about 15 %. Setting up
        scipy's Sobol sequence costs ~0.5 ms, ten easy solves, so a seed's starts are
        drawn once per tree (:data:`SEEDED_STARTS`) and each problem gets a copy; and
        importing it (``scipy.stats``) ~0.4 s, most of a warm process's first solve, so
        they are kept on disk too (:func:`seeded_starts`).
        """
        if self.seed is None:  # fresh entropy
            return np.ascontiguousarray(qspace.random(self.tree, np.random.default_rng(), n, spread=True))
        drawn = SEEDED_STARTS.setdefault(self.tree, {})
        if (self.seed, n) not in drawn:
            drawn[self.seed, n] = seeded_starts(self.tree, self.seed, n)
        return drawn[self.seed, n].copy()

    # ------------------------------------------------------------ once per solve
    def _start(self, q0: ArrayLike, prog: Program) -> Array:
        """The starts ``(B, nq)``: ``q0`` clipped into the limits, quaternions normalised, hinges wrapped."""
        tree = self.tree
        q = tree.check_q(q0, "q0")
        B = prog.B
        if q.ndim == 2 and q.shape[0] != B or q.ndim > 2 or (q.ndim == 2 and not prog.batch):
            raise InputError(f"q0 has shape {q.shape}; expected ({tree.nq},) or ({B}, {tree.nq}) for these targets")
        out = np.empty((B, tree.nq))
        out[:] = q
        clip_kernel(out, tree.jnt_type, tree.jnt_qadr, tree.layout.jnt_lo, tree.layout.jnt_hi)
        qspace.wrap(tree, out, self.wrap)
        return out

    def _immobile(self, prog: Program, q: Array) -> Result:
        """The result when no dof may move: the starts ``q (B, nq)`` as they are, met or not, after 0 iterations."""
        _, _, err = evaluate_program(self.tree, prog, q)
        worst, met = np.empty((prog.B, 2)), np.empty(prog.B, dtype=bool)
        summarise(err, prog.counted, prog.hard, self.tol, self.rot_tol, worst, met)
        zeros = np.zeros(prog.B, np.int64)
        status = np.where(met, CONVERGED, UNREACHABLE)
        history = History(q[:, None].copy(), worst[:, None].copy()) if self.history else None
        return package(prog, q, err, zeros, status, zeros, self.tol, self.rot_tol, self.method_name, history,
                       self.tree)


def _names(value: Any, what: str) -> list:
    """``value`` as a list of names; :class:`InputError` for text (one name is ``[name]``) or what does not iterate."""
    try:
        if isinstance(value, (str, bytes)):
            raise TypeError
        return list(value)
    except TypeError:  # a number, an object, a 0-d array
        raise InputError(f"{what} must be a list of names or None, got {value!r:.40}") from None
