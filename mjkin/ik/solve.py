"""``mjkin.solve``: one front door to every IK method, batched over targets."""

from __future__ import annotations

import os
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field, replace

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .. import goals as G
from ..errors import InputError
from ..qspace import NQ, NV
from ..tree import Tree
from . import kernel
from .kernel import STATUS_NAMES

Array = NDArray[np.float64]

METHODS = ("auto", "lm", "dls", "pinv", "transpose", "ccd", "analytic2", "optimize", "reach")
CORES = os.cpu_count() or 1
AUTO_RESTARTS = 24  # many short runs beat few long ones on hard targets (see mjkin bench ik)
_CODES = {"lm": kernel.LM, "dls": kernel.DLS, "pinv": kernel.PINV, "transpose": kernel.TRANSPOSE}
_MAX_ITERS = {"lm": 50, "dls": 1000, "pinv": 100, "transpose": 2000, "ccd": 200, "optimize": 500}


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
        status: ``"converged"``, ``"unreachable"`` (stalled away from the goal), ``"limits"``
            (stalled with a joint held at its limit) or ``"max_iterations"``.
        goal_errors: ``(..., G, 2)`` per goal, in :attr:`goals` order (sorted by priority).
        goals: the goals as solved.
        method: the method that ran.
        restarts: ``(...)`` random restarts used.
        history: per-iteration record when asked for (``history=True``).
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

    def singular_values(self) -> NDArray:
        """Singular values ``(..., k)`` of the top-priority goals' Jacobian at :attr:`q`.

        The smallest tends to zero at a singularity (a stretched arm); their
        product is Yoshikawa's manipulability.
        """
        if self.tree is None:
            raise InputError("this result was built without its tree; use mjkin.singular_values(tree, goals, q)")
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


def _start(tree: Tree, q0: ArrayLike | None, B: int, batch: tuple[int, ...]) -> Array:
    if q0 is None:
        q0 = tree.qpos0
    q = tree.check_q(q0, "q0")
    if q.ndim == 2 and q.shape[0] != B or q.ndim > 2 or (q.ndim == 2 and not batch):
        raise InputError(f"q0 has shape {q.shape}; expected ({tree.nq},) or ({B}, {tree.nq}) for these targets")
    return tree.clip(np.ascontiguousarray(np.broadcast_to(q, (B, tree.nq)), dtype=np.float64))


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


def _frozen_q(tree: Tree, active: NDArray[np.bool_]) -> NDArray[np.bool_]:
    """Mask over q of the joints none of whose dofs are active."""
    frozen = np.zeros(tree.nq, dtype=bool)
    for j in range(tree.njnt):
        kind = int(tree.jnt_type[j])
        if not active[tree.jnt_dofadr[j]:tree.jnt_dofadr[j] + NV[kind]].any():
            frozen[tree.jnt_qadr[j]:tree.jnt_qadr[j] + NQ[kind]] = True
    return frozen


def solve(tree: Tree, goals: G.Goal | Sequence[G.Goal], q0: ArrayLike | None = None, method: str = "auto",
          tol: float = 1e-6, rot_tol: float = 1e-5, max_iters: int | None = None, *,
          damping: float | None = None, alpha: float | None = None, max_step: float | None = None,
          halving: bool = False, goal_step: float | None = None, restarts: int | None = None,
          seed: int | None = 0, patience: int | None = None,
          base: str | None = None, joints: Sequence[str] | None = None, root: str | None = None,
          history: bool = False, sweep: str = "backward", avoid_collisions: bool = False) -> Result:
    """Find ``q`` that meets the goals, from ``q0`` (default ``qpos0``), inside the joint limits.

    Args:
        tree: the kinematic tree.
        goals: one goal or several (see :mod:`mjkin.goals`); targets may carry one
            leading batch axis ``B``, solved together.
        q0: start ``(nq,)`` or one per target ``(B, nq)``; clipped into the limits.
        method: ``"auto"`` (= ``"lm"``: damped least squares with an adaptive,
            error-dependent λ, step acceptance and 24 seeded random restarts when it
            stalls — the most robust), ``"dls"`` (fixed λ), ``"pinv"``,
            ``"transpose"``, ``"ccd"``, ``"analytic2"`` (two-link planar),
            ``"optimize"`` (SciPy, box and coupling constraints), or ``"reach"``
            (recursive reach; status ``"root_would_move"`` when the goal is out of the chain's ring).
        tol: position tolerance in metres.
        rot_tol: rotation tolerance in radians.
        max_iters: iteration (CCD: sweep) limit of each run (the start and every
            restart); a per-method default when None.
        damping: λ of ``dls`` (default 5 % of the model's size, ``MjModel.stat.extent``),
            the floor of ``lm``'s λ (default 1e-5 of it).
        alpha: step size of ``transpose``; default Buss's ``<e, JJᵀe> / |JJᵀe|²``.
        max_step: largest joint change per iteration (rad or m); default unlimited
            for the seeds' methods, 0.5 for ``lm``.
        halving: iterative goal halving (seed 002 §4.6.3): when a step does not
            lower the error, retract and aim halfway, repeatedly.
        goal_step: the most residual (m, or rad for orientation rows) a step aims to
            remove, so the effector walks toward a far goal (error clamping); default
            unlimited.
        restarts: random restarts (within limits) when a solve stalls; default 24
            for ``auto``, 0 otherwise.
        seed: seeds the restarts, so solves are reproducible.
        patience: iterations without progress before a run counts as stalled; default
            6 for ``lm``/``auto`` (then it restarts), 10 for the others.
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

    Raises:
        GoalError, UnknownNameError, InputError: malformed goals, names or options.
    """
    options = {"method": method, "tol": tol, "rot_tol": rot_tol, "max_iters": max_iters, "damping": damping,
               "alpha": alpha, "max_step": max_step, "halving": halving, "goal_step": goal_step,
               "restarts": restarts, "seed": seed, "patience": patience, "base": base, "joints": joints,
               "root": root, "history": history, "sweep": sweep}
    result = replace(_solve(tree, goals, q0, **options), tree=tree)  # type: ignore[arg-type]
    return _collision_free(tree, goals, result, options) if avoid_collisions else result


def _collision_free(tree: Tree, goals: G.Goal | Sequence[G.Goal], result: Result, options: dict) -> Result:
    """Re-solve the targets whose solution is in contact, from random starts, until one is free."""
    from ..scene import Scene

    scene = Scene(tree)
    q = np.array(result.q).reshape(-1, tree.nq)
    error = np.array(result.error).reshape(-1, 2)
    goal_errors = np.array(result.goal_errors).reshape(len(q), -1, 2)
    success = np.array(result.success).reshape(-1).copy()
    status = np.array(result.status).reshape(-1).astype("<U14")
    rng = np.random.default_rng(options["seed"])
    goal_list = [goals] if isinstance(goals, G.Goal) else list(goals)
    tries = max(8, options["restarts"] or 0)
    for b in range(len(q)):
        if not scene.in_collision(q[b]):
            continue
        one = [_target(g, b, len(q)) for g in goal_list]
        for start in tree.random_q(rng, tries):
            retry = _solve(tree, one, start, **{**options, "restarts": 0})  # type: ignore[arg-type]
            if retry.success and not scene.in_collision(retry.q):
                q[b], error[b], goal_errors[b] = retry.q, retry.error, retry.goal_errors
                success[b], status[b] = True, "converged"
                break
        else:
            success[b], status[b] = False, "collision"
    shape = np.shape(result.success)
    return replace(result, q=q.reshape(np.shape(result.q)), error=error.reshape(np.shape(result.error)),
                   goal_errors=goal_errors.reshape(np.shape(result.goal_errors)), success=success.reshape(shape),
                   status=status.reshape(shape) if shape else status[0])


def _target(goal: G.Goal, b: int, B: int) -> G.Goal:
    """The ``b``-th target of a batched goal (unbatched goals as they are)."""
    if goal.batch() == ():
        return goal
    fields = {name: np.asarray(getattr(goal, name))[b]
              for name in ("xyz", "quat", "T", "point", "direction", "normal", "q_rest")
              if hasattr(goal, name) and np.ndim(getattr(goal, name)) > {"T": 2, "quat": 1}.get(name, 1)}
    return replace(goal, **fields)


def _solve(tree: Tree, goals: G.Goal | Sequence[G.Goal], q0: ArrayLike | None, method: str, tol: float,
           rot_tol: float, max_iters: int | None, damping: float | None, alpha: float | None,
           max_step: float | None, halving: bool, goal_step: float | None, restarts: int | None, seed: int | None,
           patience: int | None, base: str | None, joints: Sequence[str] | None, root: str | None, history: bool,
           sweep: str) -> Result:
    if method not in METHODS:
        raise InputError(f"unknown IK method {method!r}; choose one of: {', '.join(METHODS)}")
    if not (np.isfinite(tol) and tol > 0 and np.isfinite(rot_tol) and rot_tol > 0):
        raise InputError(f"tol and rot_tol must be positive numbers, got {tol!r}, {rot_tol!r}")
    goal_list = [goals] if isinstance(goals, G.Goal) else list(goals)
    if root is not None:
        body = tree.id(root, "body")
        start = tree.check_q(tree.qpos0 if q0 is None else q0, "q0")
        pose = tree.kinematics(start).pose("body", body)
        low = min((g.priority for g in goal_list if isinstance(g, G.Goal)), default=0)
        goal_list = [G.Pose(root, kind="body", T=pose)] + [replace(g, priority=g.priority + 1 - low)
                                                         if isinstance(g, G.Goal) else g for g in goal_list]
    prog = G.compile_goals(tree, goal_list)
    name = "lm" if method == "auto" else method
    patience = (6 if name == "lm" else 10) if patience is None else int(patience)
    iters = _MAX_ITERS.get(name, 100) if max_iters is None else int(max_iters)
    if iters < 0:
        raise InputError(f"max_iters must be >= 0, got {max_iters}")
    q = _start(tree, q0, prog.B, prog.batch)
    active = _active_dofs(tree, prog, base, joints)
    if name == "analytic2":
        from .analytic import solve_analytic2

        return solve_analytic2(tree, prog, q, tol)
    n_restarts = (AUTO_RESTARTS if method == "auto" else 0) if restarts is None else int(restarts)
    if n_restarts < 0:
        raise InputError(f"restarts must be >= 0, got {restarts}")
    if name == "reach":
        from .reach import solve_reach

        return solve_reach(tree, prog, q, tol, rot_tol, iters, active, history)
    if name == "optimize":
        from .optimize import solve_optimize

        return solve_optimize(tree, prog, q, tol, rot_tol, iters, active, n_restarts, seed)
    # one seeded set of restarts shared by every target (a batch solves exactly as a loop of single
    # solves); joints that may not move keep their start values
    starts = np.broadcast_to(tree.random_q(np.random.default_rng(seed), n_restarts) if n_restarts
                             else np.zeros((0, tree.nq)), (prog.B, n_restarts, tree.nq))
    frozen = np.zeros(tree.nq, dtype=bool) if active.all() else _frozen_q(tree, active)
    if n_restarts and frozen.any():
        starts = starts.copy()
        starts[:, :, frozen] = q[:, None, frozen]
    if name == "ccd":
        from .ccd import solve_ccd

        return solve_ccd(tree, prog, q, tol, rot_tol, iters, sweep, active, history, starts, patience)
    extent = float(tree.model.stat.extent) or 1.0
    default_damping = (1e-5 if name == "lm" else 0.05) * extent
    params = np.array([tol, rot_tol, default_damping if damping is None else damping,
                       0.01 if name == "lm" else 0.0, 0.0 if alpha is None else alpha,
                       (0.5 if name == "lm" else np.inf) if max_step is None else max_step,
                       float(halving), float(patience), np.inf if goal_step is None else goal_step])
    if not params[8] > 0:
        raise InputError(f"goal_step must be a positive number, got {goal_step!r}")
    return run_kernel(tree, prog, q, _CODES[name], params, iters, starts, active, history, method)


def run_kernel(tree: Tree, prog: G.Program, q: Array, code: int, params: Array, max_iters: int, starts: Array,
               active: NDArray[np.bool_], history: bool, method: str) -> Result:
    """Run the compiled solver on every target and package the result."""
    B = prog.B
    H = max_iters + 1 if history else 0
    hist_q = np.full((B, H, tree.nq), np.nan)
    hist_err = np.zeros((B, H, 2))
    iters, status, used = np.zeros(B, np.int64), np.zeros(B, np.int64), np.zeros(B, np.int64)
    err = np.zeros((B, len(prog.goals), 2))
    tk, pa = kernel.kinematic_arrays(tree), kernel.program_arrays(prog)
    starts = np.array(starts)  # writable and contiguous: numba's dispatcher types it on its fast path

    def run(lo: int, hi: int) -> None:  # targets lo..hi-1; the compiled code releases the GIL
        kernel.solve_batch(tk, pa, q, code, params, max_iters, starts, active, iters, status, used, err,
                           hist_q, hist_err, lo, hi)

    parallel_chunks(run, B)
    if history:
        valid = np.arange(H)[None, :] <= iters[:, None]
        hist_err[~valid] = np.nan
    return package(prog, q, err, iters, status, used, params[0], params[1], method,
                   History(hist_q, hist_err) if history else None)


def parallel_chunks(run: Callable[[int, int], None], n: int, min_chunk: int = 32, per_worker: int = 8) -> None:
    """Call ``run(lo, hi)`` over ``range(n)`` split across the machine's cores (threads).

    Each thread takes the next chunk when it is done with one: hard targets (restarts)
    come in clusters, and equal halves would leave one core idle while the other works.
    """
    workers = min(CORES, max(1, n // min_chunk))
    if workers <= 1:
        run(0, n)
        return
    chunks = min(workers * per_worker, max(workers, n // min_chunk))
    edges = np.linspace(0, n, chunks + 1).astype(int)
    with ThreadPoolExecutor(workers) as pool:
        for f in [pool.submit(run, int(a), int(b)) for a, b in zip(edges[:-1], edges[1:], strict=True)]:
            f.result()


def package(prog: G.Program, q: Array, err: Array, iters: NDArray, status: NDArray, used: NDArray, tol: float,
            rot_tol: float, method: str, history: History | None = None) -> Result:
    """Build a :class:`Result` from flat per-target arrays."""
    counted = err[:, prog.counted] if prog.counted.any() else np.zeros((len(q), 1, 2))
    worst = counted.max(axis=1)
    success = (worst[:, 0] <= tol) & (worst[:, 1] <= rot_tol)
    names = np.array(STATUS_NAMES)[status]
    b = prog.batch
    hist = None if history is None else History(_shaped(b, history.q), _shaped(b, history.error))
    return Result(q=_shaped(b, q), success=_shaped(b, success), error=_shaped(b, worst),
                  iterations=_shaped(b, iters), status=_shaped(b, names), goal_errors=_shaped(b, err),
                  goals=prog.goals, method=method, restarts=_shaped(b, used), history=hist)
