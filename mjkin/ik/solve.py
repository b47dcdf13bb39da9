"""``mjkin.solve``: one front door to every IK method, batched over targets."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field, replace

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .. import goals as G
from ..checks import check_count, check_flag, check_number
from ..errors import GoalError, InputError
from ..kinematics import qspace
from ..kinematics.qspace import FREE, NQ, NV, clip_kernel
from ..kinematics.tree import Tree, fingerprint
from ..parallel import parallel_chunks
from . import kernel
from .kernel import STATUS_NAMES

Array = NDArray[np.float64]

METHODS = ("auto", "lm", "dls", "pinv", "transpose", "ccd", "analytic2", "optimize", "reach")
AUTO_RESTARTS = 24  # many short runs beat few long ones on hard targets (see mjkin bench ik)
# lm's initial μ (λ² = λ_min² + μ·cost) and largest joint step per iteration: on the TRAC-IK protocol
# (3000 targets, mid-range start, 1e-5) 0.1 / 1.0 cut mean iterations against 0.01 / 0.5 on every real arm
# (Panda 26.5 -> 21.4, UR5e 27.5 -> 19.0, iiwa14 10.8 -> 8.8, Gen3 11.1 -> 8.9, xArm7 15.4 -> 14.8), success 100 %
LM_MU, LM_MAX_STEP = 0.1, 1.0
# lm's stall test: a run in which no unmet goal's error has fallen by LM_PROGRESS (10 %) within LM_PATIENCE
# iterations restarts. A converging run falls fast; one creeping along a joint limit was kept alive by any gain
# of the merit at all (patience 6, 1e-9). The last run (no restart left) goes on while any error falls.
# Same protocol: mean iterations Panda 20.1 -> 13.4, UR5e 21.0 -> 15.3, xArm7 14.4 -> 10.9, batched solves/s
# x1.4-1.5, success 100 %; from `home` at 1e-4 likewise.
LM_PATIENCE, LM_PROGRESS = 4, 0.1
TIMED_RESTARTS = 1000  # with a timeout, auto restarts until the time runs out (as TRAC-IK does)
_CODES = {"lm": kernel.LM, "dls": kernel.DLS, "pinv": kernel.PINV, "transpose": kernel.TRANSPOSE}
_MAX_ITERS = {"lm": 50, "dls": 1000, "pinv": 100, "transpose": 2000, "ccd": 200, "optimize": 500}
_STATUS = np.array(STATUS_NAMES)
# optimize's time limit per target when none is given: SciPy's SLSQP has no other bound on its wall time (on the
# primate with a half-space and a plane goal and a planted root it ran for minutes), while its usual solves take
# milliseconds (the test suite's slowest target, on ball_chain's cones, 500 SLSQP iterations in about 1 s)
OPTIMIZE_TIMEOUT = 5.0


@dataclass(frozen=True)
class History:
    """Per-iteration record of a solve (iteration 0 is the start).

    ``q (..., H, nq)`` and ``error (..., H, 2)`` (worst position and rotation
    error over the counted goals); rows after a solve's last iteration repeat nothing
    and are NaN.
    """

    q: Array
    error: Array


@dataclass(frozen=True)
class Result:
    """What :func:`solve` found. Shapes carry the batch shape ``...`` of the targets (none if unbatched).

    Attributes:
        q: ``(..., nq)`` best configuration found, inside the joint limits, a valid ``qpos``.
        success: ``(...)`` every counted goal within ``tol`` (metres) and ``rot_tol`` (radians).
        error: ``(..., 2)`` worst ``[position (m), rotation (rad)]`` error over the counted goals.
        iterations: ``(...)`` steps taken (CCD: sweeps).
        status: ``"converged"``, ``"unreachable"`` (stalled away from the goal, or nothing may
            move), ``"limits"`` (stalled with a joint limit blocking the way), ``"max_iterations"``,
            ``"timeout"`` (the ``timeout`` ran out first) or ``"collision"`` (``avoid_collisions``:
            every pose found was in contact).
        goal_errors: ``(..., G, 2)`` per goal, in :attr:`goals` order (sorted by priority).
        goals: the goals as solved.
        method: the method that ran.
        restarts: ``(...)`` random restarts used.
        history: per-iteration record when asked for (``history=True``).
        tree: the tree solved on; not pickled (a result sent to another process travels
            without its ``MjModel``): re-attach it with :meth:`with_tree`.
    """

    q: Array
    success: Array
    error: Array
    iterations: Array
    status: Array
    goal_errors: Array
    goals: tuple[G.Goal, ...]
    method: str
    restarts: Array
    history: History | None = None
    tree: Tree | None = field(default=None, repr=False, compare=False)

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
        return singular_values(self.tree, self.goals, self.q)

    @property
    def position_error(self) -> Array:
        """Worst position error (m), ``(...)``."""
        return self.error[..., 0]

    @property
    def rotation_error(self) -> Array:
        """Worst rotation error (rad), ``(...)``."""
        return self.error[..., 1]


def _shaped(batch: tuple[int, ...], a: Array) -> Array:
    return a.reshape(batch + a.shape[1:]) if batch else a[0]


def singular_values(tree: Tree, goals: G.Goal | Sequence[G.Goal], q: ArrayLike) -> NDArray:
    """Singular values ``(..., k)`` (descending) of the highest-priority goals' Jacobian at ``q``.

    The smallest tends to zero at a singularity (a stretched arm);
    ``prod(s)`` is Yoshikawa's manipulability.
    """
    prog = G.compile_goals(tree, goals)
    q = tree.check_q(q)
    qs = np.ascontiguousarray(np.broadcast_to(q, (prog.B, tree.nq)) if q.ndim == 1 else q.reshape(-1, tree.nq))
    _, J, _ = kernel.evaluate_program(tree, prog, qs)
    rows = J[:, prog.level_rows[0]:prog.level_rows[1]]
    s = np.linalg.svd(rows, compute_uv=False)
    return s.reshape(q.shape[:-1] + s.shape[-1:]) if q.ndim > 1 else (s[0] if prog.batch == () else s)


def _start(tree: Tree, q0: ArrayLike | None, B: int, batch: tuple[int, ...], wrap: NDArray[np.int64]) -> Array:
    """The starts ``(B, nq)``: ``q0`` clipped into the limits, quaternions normalised, ``wrap`` hinges wrapped."""
    if q0 is None:
        q0 = tree.qpos0
    q = tree.check_q(q0, "q0")
    if q.ndim == 2 and q.shape[0] != B or q.ndim > 2 or (q.ndim == 2 and not batch):
        raise InputError(f"q0 has shape {q.shape}; expected ({tree.nq},) or ({B}, {tree.nq}) for these targets")
    out = np.empty((B, tree.nq))
    out[:] = q
    clip_kernel(out, tree.jnt_type, tree.jnt_qadr, tree.layout.jnt_lo, tree.layout.jnt_hi)
    qspace.wrap(tree, out, wrap)
    return out


def _active_dofs(tree: Tree, prog: G.Program, base: str | None,
                 joints: Sequence[str] | None) -> NDArray[np.bool_]:
    """Dofs allowed to move: those of ``joints``, or of the chains between ``base`` and the goal bodies."""
    active = np.ones(tree.nv, dtype=bool)
    if joints is None and base is None:
        return active
    if joints is not None:
        active[:] = False
        for name in joints:
            j = tree.id(name, "joint")
            active[tree.jnt_dofadr[j]:tree.jnt_dofadr[j] + NV[int(tree.jnt_type[j])]] = True
    if base is not None:
        b = tree.id(base, "body")
        below = np.zeros(tree.nv, dtype=bool)
        for body in {int(x) for x in prog.body if x >= 0}:
            chain = set(tree.body_dofs[body].tolist()) - set(tree.body_dofs[b].tolist())
            below[list(chain)] = True
        active &= below
    return active


def _masks(tree: Tree, prog: G.Program, base: str | None, joints: Sequence[str] | None,
           rooted: bool) -> tuple[NDArray[np.bool_], NDArray[np.bool_]]:
    """:func:`_active_dofs` and :func:`_restart_q`, kept on the tree for repeated calls."""
    key = (prog.body.tobytes(), base, None if joints is None else tuple(joints), rooted)
    cache: dict = tree.__dict__.setdefault("_solve_masks", {})
    if key not in cache:
        if len(cache) > 64:
            cache.clear()
        active = _active_dofs(tree, prog, base, joints)
        cache[key] = active, _restart_q(tree, prog, active, rooted)
    return cache[key]


def _restart_q(tree: Tree, prog: G.Program, active: NDArray[np.bool_], rooted: bool) -> NDArray[np.bool_]:
    """Entries of q a restart may randomise: joints with an active dof that moves a goal frame.

    Every other joint keeps its start value (an object's slide joints do not
    help an arm reach), and with a planted ``root`` so does the free joint.
    """
    moving = np.zeros(tree.nv, dtype=bool)
    bodies = {int(x) for x in prog.body if x >= 0}
    for body in bodies:
        moving[tree.body_dofs[body]] = True
    if not bodies:  # joint-space goals only
        moving[:] = True
    moving &= active
    mask = np.zeros(tree.nq, dtype=bool)
    for j in range(tree.njnt):
        kind = int(tree.jnt_type[j])
        if moving[tree.jnt_dofadr[j]:tree.jnt_dofadr[j] + NV[kind]].any() and not (rooted and kind == FREE):
            mask[tree.jnt_qadr[j]:tree.jnt_qadr[j] + NQ[kind]] = True
    return mask


def _random_starts(tree: Tree, seed: int | None, n: int) -> Array:
    """``n`` restart configurations ``(n, nq)``, the same for the same seed (kept on the tree).

    Quasi-random (:func:`mjkin.kinematics.qspace.random` with ``spread``): on the TRAC-IK
    protocol it cut the Panda's mean iterations by about 15 %.
    """
    if seed is None:
        return np.ascontiguousarray(qspace.random(tree, np.random.default_rng(), n, spread=True))
    cache: dict = tree.__dict__.setdefault("_random_starts", {})
    key = (int(seed), n)
    if key not in cache:
        if len(cache) > 32:
            cache.clear()
        cache[key] = np.ascontiguousarray(qspace.random(tree, np.random.default_rng(seed), n, spread=True))
    return cache[key]


def solve(tree: Tree, goals: G.Goal | Sequence[G.Goal], q0: ArrayLike | None = None, method: str = "auto",
          tol: float = 1e-6, rot_tol: float = 1e-5, max_iters: int | None = None, *,
          damping: float | None = None, alpha: float | None = None, max_step: float | None = None,
          halving: bool = False, goal_step: float | None = None, restarts: int | None = None,
          seed: int | None = 0, patience: int | None = None,
          base: str | None = None, joints: Sequence[str] | None = None, root: str | None = None,
          history: bool = False, sweep: str = "backward", avoid_collisions: bool = False,
          timeout: float | None = None) -> Result:
    """Find ``q`` that meets the goals, from ``q0`` (default ``qpos0``), inside the joint limits.

    Args:
        tree: the kinematic tree.
        goals: one goal or several (see :mod:`mjkin.goals`); targets may carry one
            leading batch axis ``B``, solved together.
        q0: start ``(nq,)`` or one per target ``(B, nq)``; clipped into the limits (quaternions
            normalised, unlimited hinges wrapped as in the result).
        method: ``"auto"`` (= ``"lm"``: damped least squares with an adaptive,
            error-dependent λ, step acceptance and 24 seeded random restarts when it
            stalls — the most robust), ``"dls"`` (fixed λ), ``"pinv"``,
            ``"transpose"``, ``"ccd"``, ``"analytic2"`` (two-link planar),
            ``"optimize"`` (SciPy, box and coupling constraints), or ``"reach"``
            (recursive reach, for planar chains and chains of ball joints; status
            ``"root_would_move"`` when the goal is out of the chain's ring).
        tol: position tolerance in metres.
        rot_tol: rotation tolerance in radians.
        max_iters: iteration (CCD: sweep) limit of each run (the start and every
            restart); a per-method default when None.
        damping: λ of ``dls`` (default 5 % of the model's size, ``MjModel.stat.extent``),
            the floor of ``lm``'s λ (default 1e-5 of it).
        alpha: step size of ``transpose``; default Buss's ``<e, JJᵀe> / |JJᵀe|²``.
        max_step: largest joint change per iteration (rad or m); default unlimited
            for the seeds' methods, 1.0 for ``lm``.
        halving: iterative goal halving (seed 002 §4.6.3): when a step does not
            lower the error, retract and aim halfway, repeatedly.
        goal_step: the most residual (m, or rad for orientation rows) a step aims to
            remove, so the effector walks toward a far goal (error clamping); default
            unlimited.
        restarts: random restarts (within limits) when a solve stalls (every iterative
            method); default 24 for ``auto`` (1000 with a ``timeout``: restart until the
            time runs out), 0 otherwise.
        seed: seeds the restarts, so solves are reproducible.
        patience: iterations without progress before a run counts as stalled; default
            4 for ``lm``/``auto`` (progress there: an unmet goal's error fell by 10 %;
            then it restarts; in the last run any fall counts), 10 for the others (any
            fall counts).
        base: only joints between this body and the goal frames move.
        joints: only these joints move.
        root: a body that stays where it is (e.g. a planted foot): a top-priority
            pose goal holds it while the free root joint moves the rest.
        history: keep every iterate (``Result.history``).
        sweep: CCD joint order, ``"backward"`` (tip to base) or ``"forward"``.
        avoid_collisions: reject solutions where MuJoCo finds contacts (between
            non-adjacent bodies, or with the world): re-solve from seeded random
            starts (``restarts`` of them, at least 8); if none is free of contact,
            ``success`` is False and ``status`` is ``"collision"``.
        timeout: seconds each target may take, restarts included, with every method
            (checked inside the compiled loops per iteration, by ``reach`` per pass, by
            ``optimize`` at every evaluation SciPy asks for; ``analytic2`` takes no time);
            a target that runs out returns its best pose so far with
            ``status="timeout"``. Default none, except ``optimize``:
            :data:`OPTIMIZE_TIMEOUT` (5 s) per target; ``inf`` means no limit.

    Restarts (and collision retries) randomise only the joints that move a goal
    frame and may move (``joints``/``base``); every other joint keeps its ``q0``
    value, and with ``root`` the free joint keeps its pose. When nothing may move
    (a model without joints, ``joints=[]``, ``base=`` the goals' own body) every
    method returns the start after 0 iterations: ``"converged"`` if the goals
    already hold there, else ``"unreachable"``.

    Unlimited hinges come back in ``(-π, π]`` about ``qpos0`` (the angle MuJoCo turns
    them by), except those a :class:`~mjkin.goals.Coupling` goal names (its equation
    is in the joint values themselves); limited hinges are never wrapped.

    Repeated calls with the same goal structure (kinds, frames, weights,
    priorities) and new targets reuse the encoded goals and the restart starts,
    so a loop of single solves costs little more than the solves themselves.

    Raises:
        GoalError, UnknownNameError, InputError: malformed goals, names or options (every
            numeric option is checked: a NaN, a string or a value out of range is one line
            naming it).
    """
    if method not in METHODS:
        raise InputError(f"unknown IK method {method!r}; choose one of: {', '.join(METHODS)}")
    tol, rot_tol = check_number(tol, "tol", 0, strict=True), check_number(rot_tol, "rot_tol", 0, strict=True)
    if timeout is not None:
        timeout = check_number(timeout, "timeout (seconds)", 0, strict=True, infinite=True)
    time_limit = (OPTIMIZE_TIMEOUT if method == "optimize" else None) if timeout is None else (
        None if timeout == np.inf else timeout)
    for value, label, inf in ((damping, "damping", False), (alpha, "alpha", False), (max_step, "max_step", True),
                              (goal_step, "goal_step", True)):
        if value is not None:
            check_number(value, label, 0, strict=True, infinite=inf)
    check_flag(halving, "halving")
    seed = None if seed is None else check_count(seed, "seed", 0, whole_floats=True)
    if not isinstance(goals, (G.Goal, list, tuple)):
        raise GoalError(f"goals must be a mjkin.goals goal or a list of them, got {type(goals).__name__}")
    goal_list = [goals] if isinstance(goals, G.Goal) else list(goals)
    if method == "analytic2":
        given = {"max_iters": max_iters, "damping": damping, "alpha": alpha, "max_step": max_step,
                 "goal_step": goal_step, "restarts": restarts, "patience": patience, "base": base, "joints": joints,
                 "root": root, "halving": halving or None, "history": history or None,
                 "avoid_collisions": avoid_collisions or None}
        bad = [k for k, v in given.items() if v is not None]
        if bad:
            raise InputError(f"method 'analytic2' is closed-form and cannot honour {', '.join(bad)}; "
                             "use an iterative method (auto, dls, ...) for those")
    if root is not None:  # a planted body: a top-priority pose goal at its pose in q0
        body = tree.id(root, "body")
        pose = tree.kinematics(tree.check_q(tree.qpos0 if q0 is None else q0, "q0")).pose("body", body)
        if pose.ndim > 2:
            raise InputError("root= needs one q0 (nq,): the planted body has one pose")
        low = min(g.priority for g in goal_list if isinstance(g, G.Goal)) if goal_list else 0
        goal_list = [G.Pose(root, kind="body", T=pose)] + [replace(g, priority=g.priority + 1 - low)
                                                          if isinstance(g, G.Goal) else g for g in goal_list]
    prog = G.compile_goals(tree, goal_list)
    wrap = _wrapped_hinges(tree, prog)
    q = _start(tree, q0, prog.B, prog.batch, wrap)
    name = "lm" if method == "auto" else method
    patience = (LM_PATIENCE if name == "lm" else 10) if patience is None else check_count(patience, "patience",
                                                                                          whole_floats=True)
    iters = _MAX_ITERS.get(name, 100) if max_iters is None else check_count(max_iters, "max_iters", 0,
                                                                             whole_floats=True)
    n_restarts = (0 if method != "auto" else AUTO_RESTARTS if time_limit is None else TIMED_RESTARTS) \
        if restarts is None else check_count(restarts, "restarts", 0, whole_floats=True)
    active, restart_q = _masks(tree, prog, base, joints, root is not None)
    starts = _random_starts(tree, seed, n_restarts)
    if not active.any():  # nothing may move: the start is the answer, whatever the method
        result = _immobile(tree, prog, q, tol, rot_tol, method, history)
    elif name == "analytic2":
        from .analytic import solve_analytic2

        result = replace(solve_analytic2(tree, prog, q, tol), tree=tree)
    elif name == "optimize":
        from .optimize import solve_optimize

        result = solve_optimize(tree, prog, q, tol, rot_tol, iters, active, starts, restart_q, time_limit)
    elif name == "ccd":
        from .ccd import solve_ccd

        result = solve_ccd(tree, prog, q, tol, rot_tol, iters, sweep, active, history, starts, restart_q, patience,
                           time_limit)
    elif name == "reach":
        from .reach import solve_reach

        result = solve_reach(tree, prog, q, tol, rot_tol, iters, active, history, starts, restart_q, time_limit)
    else:
        extent = float(tree.model.stat.extent) or 1.0
        st = kernel.settings(tol, rot_tol, ((1e-5 if name == "lm" else 0.05) * extent) if damping is None else damping,
                             LM_MU if name == "lm" else 0.0, 0.0 if alpha is None else alpha,
                             (LM_MAX_STEP if name == "lm" else np.inf) if max_step is None else max_step, halving,
                             patience, np.inf if goal_step is None else goal_step, time_limit,
                             LM_PROGRESS if name == "lm" else 1e-9)
        result = run_kernel(tree, prog, q, _CODES[name], st, iters, starts, restart_q, active, history, method)
    if avoid_collisions:
        retries = _random_starts(tree, seed, max(8, n_restarts))
        result = _collision_free(tree, prog, result, q, retries, restart_q, method,
                                 dict(tol=tol, rot_tol=rot_tol, max_iters=max_iters, damping=damping, alpha=alpha,
                                      max_step=max_step, halving=halving, goal_step=goal_step, patience=patience,
                                      base=base, joints=joints, sweep=sweep, timeout=timeout))
    if len(wrap):
        q_out = np.array(result.q)
        qspace.wrap(tree, q_out, wrap)
        result = replace(result, q=q_out)
    return result


def _wrapped_hinges(tree: Tree, prog: G.Program) -> NDArray[np.int64]:
    """The q entries :func:`solve` wraps into (-π, π]: unlimited hinges that no Coupling goal names."""
    hinges = tree.layout.unlimited_hinge_q
    if not len(hinges) or not len(prog.coupling):
        return hinges
    coupled = tree.jnt_qadr[tree.plan.dof_jnt[np.flatnonzero(np.any(prog.coupling != 0, axis=0))]]
    return hinges[~np.isin(hinges, coupled)]


def _immobile(tree: Tree, prog: G.Program, q: Array, tol: float, rot_tol: float, method: str,
              history: bool) -> Result:
    """The result when no dof may move: the starts ``q (B, nq)`` as they are, met or not, after 0 iterations."""
    _, _, err = kernel.evaluate_program(tree, prog, q)
    worst, met = np.empty((prog.B, 2)), np.empty(prog.B, dtype=bool)
    kernel.summarise(err, prog.counted, tol, rot_tol, worst, met)
    zeros = np.zeros(prog.B, np.int64)
    status = np.where(met, kernel.CONVERGED, kernel.UNREACHABLE)
    return package(prog, q, err, zeros, status, zeros, tol, rot_tol, method,
                   History(q[:, None].copy(), worst[:, None].copy()) if history else None, tree)


def _collision_free(tree: Tree, prog: G.Program, result: Result, q0: Array, retries: Array,
                    restart_q: NDArray[np.bool_], method: str, options: dict) -> Result:
    """Re-solve the targets whose solution is in contact, from the retry starts, until one is free.

    A retry start takes ``retries[k]`` where ``restart_q`` is True and the target's
    ``q0`` elsewhere, as restarts do.
    """
    from ..scene import Scene

    scene = Scene(tree)
    q = np.array(result.q).reshape(-1, tree.nq)
    error = np.array(result.error).reshape(-1, 2)
    goal_errors = np.array(result.goal_errors).reshape(len(q), -1, 2)
    success = np.array(result.success).reshape(-1).copy()
    status = np.array(result.status).reshape(-1).astype("<U14")
    for b in range(len(q)):
        if not scene.in_collision(q[b]):
            continue
        one = [g.take(b, b + 1) for g in prog.goals]
        for start in np.where(restart_q, retries, q0[b]):
            retry = solve(tree, one, start, method, restarts=0, **options)
            found = np.reshape(retry.q, (tree.nq,))
            if retry.success.all() and not scene.in_collision(found):
                q[b], error[b], goal_errors[b] = found, np.reshape(retry.error, 2), retry.goal_errors.reshape(-1, 2)
                success[b], status[b] = True, "converged"
                break
        else:
            success[b], status[b] = False, "collision"
    shape = np.shape(result.success)
    return replace(result, q=q.reshape(np.shape(result.q)), error=error.reshape(np.shape(result.error)),
                   goal_errors=goal_errors.reshape(np.shape(result.goal_errors)), success=success.reshape(shape),
                   status=status.reshape(shape) if shape else status[0])


def run_kernel(tree: Tree, prog: G.Program, q: Array, code: int, st: kernel.Settings, max_iters: int,
               starts: Array, restart_q: NDArray[np.bool_], active: NDArray[np.bool_], history: bool,
               method: str) -> Result:
    """Run the compiled solver on every target and package the result.

    ``starts (K, nq)`` are shared by all targets (C-contiguous, as every other
    array here, so one compiled specialisation serves every batch size).
    """
    B = prog.B
    H = max_iters + 1 if history else 0
    hist_q = np.full((B, H, tree.nq), np.nan)
    hist_err = np.zeros((B, H, 2))
    iters, status, used = np.zeros(B, np.int64), np.zeros(B, np.int64), np.zeros(B, np.int64)
    err = np.zeros((B, len(prog.goals), 2))
    kin, ga = kernel.kinematic_arrays(tree), kernel.program_arrays(prog)

    def run(lo: int, hi: int) -> None:  # targets lo..hi-1; the compiled code releases the GIL
        kernel.solve_batch(kin, ga, q, code, st, max_iters, starts, restart_q, active, iters, status, used, err,
                           hist_q, hist_err, lo, hi)

    parallel_chunks(run, B)
    if history:
        valid = np.arange(H)[None, :] <= iters[:, None]
        hist_err[~valid] = np.nan
    return package(prog, q, err, iters, status, used, st.tol, st.rot_tol, method,
                   History(hist_q, hist_err) if history else None, tree)


def package(prog: G.Program, q: Array, err: Array, iters: NDArray, status: NDArray, used: NDArray, tol: float,
            rot_tol: float, method: str, history: History | None = None, tree: Tree | None = None) -> Result:
    """Build a :class:`Result` from flat per-target arrays."""
    worst, success = np.empty((len(q), 2)), np.empty(len(q), dtype=bool)
    kernel.summarise(err, prog.counted, float(tol), float(rot_tol), worst, success)
    names = _STATUS[status]
    b = prog.batch
    hist = None if history is None else History(_shaped(b, history.q), _shaped(b, history.error))
    return Result(q=_shaped(b, q), success=_shaped(b, success), error=_shaped(b, worst),
                  iterations=_shaped(b, iters), status=_shaped(b, names), goal_errors=_shaped(b, err),
                  goals=prog.goals, method=method, restarts=_shaped(b, used), history=hist, tree=tree)
