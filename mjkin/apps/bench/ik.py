"""``mjkin bench ik``: 6-D pose IK, mjkin beside the baselines a user would write, re-checked by MuJoCo.

Every solver gets the same targets (FK of random in-limit configurations), the
same start and, for the single-start rows, the same iteration budget. Only the
solver's own work is inside a timed region; every answer is re-checked afterwards
with MuJoCo's ``mj_kinematics`` and success is counted from that re-check.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import mujoco
import numpy as np
from numpy.typing import NDArray

from ... import goals as G
from ...errors import InputError
from ...ik import Problem, solve
from ...ik.lm import AUTO_RESTARTS, TIMED_RESTARTS
from ...kinematics.qspace import HINGE, SLIDE
from ...kinematics.tree import Tree, load
from ...runtime.progress import track
from ...spatial import mat_to_rotvec
from . import REAL_ARMS, peers
from .report import GC_NOTE, Report, Row, gc_paused, shared_models_dir

Array = NDArray[np.float64]
Kind = Literal["site", "body"]

BUNDLED = ("arm7", "panda")
IK_ARMS: dict[str, tuple[str, str, Kind]] = {  # name: model (bundled name or path under shared models), frame, kind
    "arm7": ("arm7", "ee", "site"),
    "panda": ("panda", "flange", "site"),  # models/panda.xml, from its modified-DH table
    "ur5e": (REAL_ARMS["ur5e"], "wrist_3_link", "body"),
    "iiwa14": (REAL_ARMS["iiwa14"], "attachment_site", "site"),
    "gen3": (REAL_ARMS["gen3"], "pinch_site", "site"),
    "xarm7": (REAL_ARMS["xarm7"], "attachment_site", "site"),
}
TRAC_IK_ARMS = ("panda", "ur5e", "iiwa14", "gen3", "xarm7")
TRAC_IK_SOURCE = "TRAC-IK v1.4.6 README, Speed mode (published, not measured here)"
TRAC_IK_PUBLISHED: tuple[Row, ...] = (  # as printed in the source, 10 000 queries, 1e-5, 5 ms limit
    {"model": "panda", "solver": "TRAC-IK (published)", "success": 99.70, "mean_ms": 0.38, "source": TRAC_IK_SOURCE},
    {"model": "panda", "solver": "KDL (published)", "success": 61.77, "mean_ms": 2.14, "source": TRAC_IK_SOURCE},
    {"model": "iiwa14", "solver": "TRAC-IK (published)", "success": 99.84, "mean_ms": 0.31,
     "source": TRAC_IK_SOURCE},
    {"model": "iiwa14", "solver": "KDL (published)", "success": 37.64, "mean_ms": 3.38, "source": TRAC_IK_SOURCE},
)


@dataclass(frozen=True)
class Arm:
    """A model and the frame whose pose is solved for."""

    name: str
    tree: Tree
    frame: str
    kind: Kind

    @property
    def home(self) -> Array:
        """The first keyframe, else ``qpos0``: the start of ``bench ik``."""
        m = self.tree.model
        return m.key_qpos[0].copy() if m.nkey else self.tree.qpos0.copy()


@dataclass(frozen=True)
class Run:
    """One solver's answers: ``q (N, nq)``, seconds per target ``(N,)`` (None if only batched), counts ``(N,)``.

    ``cpu`` is the calling thread's CPU seconds per target, when measured: the solve's own
    work without the waits of a shared machine.
    """

    q: Array
    seconds: Array | None
    iterations: Array
    restarts: Array
    per_s: float | None = None
    cpu: Array | None = None
    status: NDArray[np.str_] | None = None


def arms(names: Sequence[str] | None, default: Sequence[str] = tuple(IK_ARMS)) -> list[Arm]:
    """Resolve ``--models``: names of :data:`IK_ARMS` or MJCF paths (frame: the last site, else the last body).

    Default arms whose shared model is missing are skipped; a named one that is missing is an error.
    """
    out = []
    for name in names or default:
        if name in IK_ARMS:
            src, frame, kind = IK_ARMS[name]
            if src not in BUNDLED:
                root = shared_models_dir()
                if root is None or not (root / src).is_file():
                    if names:
                        raise InputError(f"model {name!r} needs ../shared/models/{src} (or $MJKIN_SHARED_MODELS)")
                    continue
                src = str(root / src)
            out.append(Arm(name, load(src), frame, kind))
        elif Path(name).is_file():
            tree = load(name)
            m = tree.model
            kind = "site" if m.nsite else "body"
            frame = tree.names(kind)[-1] or ""
            if not frame:
                raise InputError(f"{name}: its last {kind} has no name; name it to benchmark it")
            out.append(Arm(Path(name).stem, tree, frame, kind))
        else:
            raise InputError(f"--models takes names ({', '.join(IK_ARMS)}) or MJCF files; {name!r} is neither")
    return out


def mid_range(tree: Tree) -> Array:
    """TRAC-IK's nominal start: every limited hinge/slide at the midpoint of its range, the rest at ``qpos0``."""
    q = tree.qpos0.copy()
    for j in range(tree.njnt):
        if tree.jnt_limited[j] and int(tree.jnt_type[j]) in (HINGE, SLIDE):
            q[tree.jnt_qadr[j]] = 0.5 * (tree.jnt_range[j, 0] + tree.jnt_range[j, 1])
    return q


def mujoco_poses(model: mujoco.MjModel, frame: str, kind: Kind, qs: Array) -> Array:
    """World poses ``(N, 4, 4)`` of ``frame`` at ``qs (N, nq)`` from MuJoCo's ``mj_kinematics`` (the re-check)."""
    data = mujoco.MjData(model)
    obj = mujoco.mjtObj.mjOBJ_SITE if kind == "site" else mujoco.mjtObj.mjOBJ_BODY
    i = mujoco.mj_name2id(model, obj, frame)
    T = np.broadcast_to(np.eye(4), (len(qs), 4, 4)).copy()
    for n, q in enumerate(qs):
        data.qpos[:] = q
        mujoco.mj_kinematics(model, data)
        T[n, :3, 3] = data.site_xpos[i] if kind == "site" else data.xpos[i]
        T[n, :3, :3] = (data.site_xmat[i] if kind == "site" else data.xmat[i]).reshape(3, 3)
    return T


def frame_errors(model: mujoco.MjModel, frame: str, kind: Kind, qs: Array, targets: Array) -> tuple[Array, Array]:
    """Re-check answers with MuJoCo: position (m) and rotation (rad) error of ``frame`` at ``qs (N, nq)``.

    The pose comes from ``mj_kinematics``, not from the solver; rotation error is the
    angle of ``R_reachedᵀ R_target`` (atan2 form, accurate near zero).
    """
    T = mujoco_poses(model, frame, kind, qs)
    ep = np.linalg.norm(T[:, :3, 3] - targets[:, :3, 3], axis=-1)
    D = np.swapaxes(T[:, :3, :3], -1, -2) @ targets[:, :3, :3]
    s = 0.5 * np.linalg.norm(np.stack([D[:, 2, 1] - D[:, 1, 2], D[:, 0, 2] - D[:, 2, 0],
                                       D[:, 1, 0] - D[:, 0, 1]], -1), axis=-1)
    c = 0.5 * (np.trace(D, axis1=-2, axis2=-1) - 1.0)
    return ep, np.arctan2(s, c)


def error_components(model: mujoco.MjModel, frame: str, kind: Kind, qs: Array, targets: Array) -> Array:
    """The error twist ``(N, 6)`` as TRAC-IK judges it, from MuJoCo's poses at ``qs``.

    KDL's ``diffRelative(target, reached)``: the position error and the rotation vector of
    ``R_targetᵀ R_reached``, both in the target's axes (m, rad). TRAC-IK succeeds when
    every component is within its ``eps``.
    """
    T = mujoco_poses(model, frame, kind, qs)
    R_t = targets[:, :3, :3]
    dp = np.einsum("nji,nj->ni", R_t, T[:, :3, 3] - targets[:, :3, 3])
    return np.concatenate([dp, mat_to_rotvec(np.swapaxes(R_t, -1, -2) @ T[:, :3, :3])], axis=-1)


def past_limits(tree: Tree, qs: Array) -> Array:
    """How far each answer ``qs (N, nq)`` lies beyond its limited hinge/slide joints' ranges, ``(N,)`` (0 = inside)."""
    j = np.flatnonzero(tree.jnt_limited & np.isin(tree.jnt_type, (HINGE, SLIDE)))
    q, lo, hi = qs[:, tree.jnt_qadr[j]], tree.jnt_range[j, 0], tree.jnt_range[j, 1]
    return np.maximum(np.maximum(lo - q, q - hi), 0.0).max(axis=-1, initial=0.0)


def mjkin_single(arm: Arm, targets: Array, q0: Array, tol: float, rot_tol: float, functional: bool = False,
                 **options: Any) -> Run:
    """One ``problem.solve`` per target, each timed on its own (the goal built inside the timed call, as a user does).

    The :class:`mjkin.Problem` is made once beforehand, as a peer's solver object is (TRAC-IK's, rtb's robot);
    ``functional``: one :func:`mjkin.solve` per target instead (the README's first example), nothing made beforehand.
    """
    tree, frame, kind = arm.tree, arm.frame, arm.kind
    problem = Problem(tree, G.Pose(frame, T=targets[0], kind=kind), tol=tol, rot_tol=rot_tol, **options)
    problem.solve(q0)  # compile
    call = ((lambda goal: solve(tree, goal, q0=q0, tol=tol, rot_tol=rot_tol, **options)) if functional else
        (lambda goal: problem.solve(q0, [goal])))
    N = len(targets)
    q, seconds, cpu = np.empty((N, tree.nq)), np.empty(N), np.empty(N)
    iters, used, status = np.empty(N), np.empty(N), np.empty(N, dtype="<U16")
    with gc_paused():
        for k in range(N):
            start, start_cpu = time.perf_counter(), time.thread_time()
            res = call(G.Pose(frame, T=targets[k], kind=kind))
            seconds[k], cpu[k] = time.perf_counter() - start, time.thread_time() - start_cpu
            q[k], iters[k], used[k], status[k] = res.q, res.iterations, res.restarts, res.status
    return Run(q, seconds, iters, used, N / seconds.sum(), cpu, status)


def mjkin_batched(arm: Arm, targets: Array, q0: Array, tol: float, rot_tol: float, repeat: int = 3,
                  **options: Any) -> Run:
    """All targets in one :func:`mjkin.solve` call (all cores); solves/s from the best of ``repeat`` calls."""
    tree, frame, kind = arm.tree, arm.frame, arm.kind
    solve(tree, G.Pose(frame, T=targets[:2], kind=kind), q0=q0, tol=tol, rot_tol=rot_tol, **options)  # compile
    best = np.inf
    with gc_paused():
        for _ in range(repeat):
            start = time.perf_counter()
            res = solve(tree, G.Pose(frame, T=targets, kind=kind), q0=q0, tol=tol, rot_tol=rot_tol, **options)
            best = min(best, time.perf_counter() - start)
    return Run(res.q, None, res.iterations.astype(float), res.restarts.astype(float), len(targets) / best,
               status=np.asarray(res.status))


def mujoco_dls(arm: Arm, targets: Array, q0: Array, tol: float, rot_tol: float, max_iters: int,
               damping: float = 0.05) -> Run:
    """Damped least squares on MuJoCo's own ``mj_kinematics`` + ``mj_jacSite``/``mj_jacBody``, as a user writes it.

    Joint limits by clipping after each step; stops when both errors are within tolerance.
    """
    model, frame, kind = arm.tree.model, arm.frame, arm.kind
    data = mujoco.MjData(model)
    site = kind == "site"
    i = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SITE if site else mujoco.mjtObj.mjOBJ_BODY, frame)
    limited = model.jnt_limited.astype(bool) & (model.jnt_type > 1)
    qa, lo, hi = model.jnt_qposadr[limited], model.jnt_range[limited, 0], model.jnt_range[limited, 1]
    jacp, jacr = np.zeros((3, model.nv)), np.zeros((3, model.nv))
    cur, neg, diff, err, goal = np.zeros(4), np.zeros(4), np.zeros(4), np.zeros(6), np.zeros(4)
    lam2 = damping ** 2 * np.eye(6)
    N = len(targets)
    out, seconds, cpu, iters = np.empty((N, model.nq)), np.empty(N), np.empty(N), np.zeros(N)
    with gc_paused():
        for n, T in enumerate(targets):
            start, start_cpu = time.perf_counter(), time.thread_time()
            mujoco.mju_mat2Quat(goal, T[:3, :3].ravel())
            q = q0.copy()
            for it in range(max_iters + 1):
                data.qpos[:] = q
                mujoco.mj_kinematics(model, data)
                mujoco.mj_comPos(model, data)
                err[:3] = T[:3, 3] - (data.site_xpos[i] if site else data.xpos[i])
                mujoco.mju_mat2Quat(cur, data.site_xmat[i] if site else data.xmat[i])
                mujoco.mju_negQuat(neg, cur)
                mujoco.mju_mulQuat(diff, goal, neg)
                mujoco.mju_quat2Vel(err[3:], diff, 1.0)
                if it == max_iters or (np.linalg.norm(err[:3]) <= tol and np.linalg.norm(err[3:]) <= rot_tol):
                    break
                (mujoco.mj_jacSite if site else mujoco.mj_jacBody)(model, data, jacp, jacr, i)
                J = np.vstack([jacp, jacr])
                dq = J.T @ np.linalg.solve(J @ J.T + lam2, err)
                mujoco.mj_integratePos(model, q, dq, 1.0)
                q[qa] = np.clip(q[qa], lo, hi)
            seconds[n], cpu[n] = time.perf_counter() - start, time.thread_time() - start_cpu
            out[n], iters[n] = q, it
    return Run(out, seconds, iters, np.zeros(N), N / seconds.sum(), cpu)


def mink_ik(arm: Arm, targets: Array, q0: Array, tol: float, rot_tol: float, max_iters: int) -> Run:
    """The same targets through mink, run as its examples run it.

    FrameTask + ConfigurationLimit, ``solve_ik`` (daqp), integrate, and convergence by
    ``FrameTask.compute_error`` (translation and rotation norms) after each step.
    Raises :class:`mjkin.peers.Unavailable` when mink is not installed.
    """
    mink = peers.require("mink", "mink")

    config = mink.Configuration(arm.tree.model)
    task = mink.FrameTask(arm.frame, arm.kind, position_cost=1.0, orientation_cost=1.0, lm_damping=1.0)
    limits = [mink.ConfigurationLimit(config.model)]
    N = len(targets)
    out, seconds, cpu, iters = np.empty((N, arm.tree.nq)), np.empty(N), np.empty(N), np.zeros(N)
    with gc_paused():
        for n in range(-1, N):  # n = -1: one untimed solve first (imports, first QP)
            T = targets[max(n, 0)]
            start, start_cpu = time.perf_counter(), time.thread_time()
            config.update(q0)
            task.set_target(mink.SE3.from_matrix(T))
            it = 0
            while it < max_iters:
                vel = mink.solve_ik(config, [task], 1.0, "daqp", damping=1e-3, limits=limits)
                config.integrate_inplace(vel, 1.0)
                it += 1
                e = task.compute_error(config)
                if np.linalg.norm(e[:3]) <= tol and np.linalg.norm(e[3:]) <= rot_tol:
                    break
            elapsed, elapsed_cpu = time.perf_counter() - start, time.thread_time() - start_cpu
            if n >= 0:
                seconds[n], cpu[n], out[n], iters[n] = elapsed, elapsed_cpu, config.q, it
    return Run(out, seconds, iters, np.zeros(N), N / seconds.sum(), cpu)


RTB_ILIMIT = 50  # iterations per search: as many as each of mjkin's lm runs


def rtb_ik_lm(arm: Arm, targets: Array, q0: Array, tol: float, rot_tol: float, slimit: int) -> tuple[Run, Array]:
    """Robotics Toolbox's C++ ``ik_LM`` (Chan's damping), one call per target; also its own success flags ``(N,)``.

    Built once: a ``DHRobot`` from the model's modified-DH table (:func:`mjkin.peers.rtb_ets`)
    and its ``ets()``, whose ``ik_LM`` is the C++ call (``Robot.ik_LM`` builds the ETS again on
    every call). Its one tolerance bounds ``E = ½ |e|²`` over the 6-D error: ``E < ½ min(tol,
    rot_tol)²`` is the loosest bound that keeps both errors within theirs. ``slimit`` searches of
    :data:`RTB_ILIMIT` iterations, the first from ``q0``, the others from random in-limit starts.
    """
    ets = peers.rtb_ets(arm.tree, arm.frame, arm.kind)
    budget = {"q0": q0, "ilimit": RTB_ILIMIT, "slimit": slimit, "tol": 0.5 * min(tol, rot_tol) ** 2}
    ets.ik_LM(targets[0], **budget)  # untimed first call
    N = len(targets)
    q, seconds, cpu, iters, searches, said = (np.empty((N, arm.tree.nq)), np.empty(N), np.empty(N), np.empty(N),
                                              np.empty(N), np.empty(N, dtype=bool))
    with gc_paused():
        for k in range(N):
            start, start_cpu = time.perf_counter(), time.thread_time()
            sol = ets.ik_LM(targets[k], **budget)
            seconds[k], cpu[k] = time.perf_counter() - start, time.thread_time() - start_cpu
            q[k], iters[k], searches[k], said[k] = sol.q, sol.iterations, sol.searches, sol.success
    return Run(q, seconds, iters, searches, N / seconds.sum(), cpu), said


def trac_ik(arm: Arm, targets: Array, q0: Array, eps: float, time_limit: float) -> tuple[Run, Array]:
    """TRAC-IK (Speed mode, pytracik) one call per target, as its README calls it; also its own success flags.

    Built once from the chain's URDF (:func:`mjkin.peers.trac_ik_solver`); each call is
    ``TracIK.ik(position, rotation, seed)`` (its matrix-to-quaternion step included) with
    TRAC-IK's own time limit and ``eps``. A call that finds nothing returns ``None``: its
    answer is counted as the seed. TRAC-IK reports no iteration counts, and its CPU time is not
    measured: Speed mode solves in two threads of its own, not in the calling one.
    """
    solver = peers.trac_ik_solver(arm.tree, arm.frame, arm.kind, time_limit, eps)
    pos, rot = targets[:, :3, 3].copy(), targets[:, :3, :3].copy()
    solver.ik(pos[0], rot[0], q0)  # untimed first call
    N = len(targets)
    q, seconds, said = np.empty((N, arm.tree.nq)), np.empty(N), np.empty(N, dtype=bool)
    with gc_paused():
        for k in range(N):
            start = time.perf_counter()
            answer = solver.ik(pos[k], rot[k], q0)
            seconds[k] = time.perf_counter() - start
            said[k] = answer is not None
            q[k] = q0 if answer is None else answer
    none = np.full(N, np.nan)
    return Run(q, seconds, none, none, N / seconds.sum()), said


def peer_row(arm: Arm, name: str, run: Run, said: Array, targets: Array, tol: float, rot_tol: float,
              within: NDArray[np.bool_] | None = None, eps: float | None = None) -> Row:
    """A peer's row: :func:`row`, and how often the peer itself claimed success (``said (N,)``).

    Also how many answers went past a joint limit and how far; with ``eps`` (TRAC-IK) the
    success by TRAC-IK's own per-component test (:func:`error_components`).
    """
    r = row(arm, name, run, targets, tol, rot_tol, within=within)
    r["solver_says"] = 100.0 * float(said.mean())
    if eps is not None:
        e = np.abs(error_components(arm.tree.model, arm.frame, arm.kind, run.q, targets))
        ok = (e <= eps).all(axis=-1) & (True if within is None else within)
        r["success_per_component"] = 100.0 * float(ok.mean())
    past = past_limits(arm.tree, run.q)
    r["past_limits"] = int(np.sum(past > 0))
    r["past_limit_max"] = float(past.max())
    return r


def row(arm: Arm, solver: str, run: Run, targets: Array, tol: float, rot_tol: float,
        batched: Run | None = None, extra: Row | None = None, within: NDArray[np.bool_] | None = None) -> Row:
    """A table row; success is re-checked by MuJoCo (:func:`frame_errors`), never taken from the solver.

    ``within (N,)``, when given, marks the answers that count at all (e.g. those inside a time limit).
    """
    ok = success(arm, run.q, targets, tol, rot_tol)
    if within is not None:
        ok &= within
    ms = None if run.seconds is None else 1e3 * run.seconds
    r: Row = {"model": arm.name, "solver": solver, "success": 100.0 * float(ok.mean()),
              "mean_ms": None if ms is None else float(ms.mean()),
              "median_ms": None if ms is None else float(np.median(ms)),
              "p95_ms": None if ms is None else float(np.percentile(ms, 95)),
              "single_per_s": None if ms is None else run.per_s,
              "batched_per_s": None if batched is None else batched.per_s,
              "cpu_mean_ms": None if run.cpu is None else 1e3 * float(run.cpu.mean()),
              "cpu_median_ms": None if run.cpu is None else 1e3 * float(np.median(run.cpu)),
              "iterations_mean": float(run.iterations.mean()), "restarts_mean": float(run.restarts.mean())}
    if batched is not None:
        r["batched_success"] = 100.0 * float(success(arm, batched.q, targets, tol, rot_tol).mean())
    r.update(extra or {})
    return r


def success(arm: Arm, q: Array, targets: Array, tol: float, rot_tol: float) -> NDArray[np.bool_]:
    """Per target: both errors, as MuJoCo computes them at ``q``, within tolerance."""
    ep, er = frame_errors(arm.tree.model, arm.frame, arm.kind, q, targets)
    return (ep <= tol) & (er <= rot_tol)


def targets_for(arm: Arm, n: int, seed: int) -> Array:
    """``n`` reachable poses ``(n, 4, 4)``: FK of random in-limit configurations (seeded per model name)."""
    rng = np.random.default_rng([seed, *arm.name.encode()])
    return arm.tree.pose(arm.tree.random_q(rng, n), arm.frame, arm.kind)


def check_settings(n: int, tol: float, rot_tol: float, iters: int, time_limit: float = 1.0) -> None:
    """Raise :class:`InputError` for settings no benchmark can run with."""
    if n < 1:
        raise InputError(f"--targets must be at least 1, got {n}")
    if not (tol > 0 and rot_tol > 0 and np.isfinite(tol) and np.isfinite(rot_tol)):
        raise InputError(f"--tol and --rot-tol must be positive, got {tol}, {rot_tol}")
    if iters < 1:
        raise InputError(f"--iters must be at least 1, got {iters}")
    if not time_limit > 0:
        raise InputError(f"the time limit must be positive, got {time_limit}")


IK_PEERS = ("mink", "rtb-ik_LM", "trac-ik")  # bench ik
TRAC_IK_PEERS = ("rtb-ik_LM", "trac-ik")  # bench ik --protocol trac-ik
PEER_NOTES = {
    "peers": "each peer's FK checked equal to tree.pose to 1e-12 on random in-limit configurations before any "
             "timing; a peer that differs, cannot take the chain or is not installed gets no row, only the reason",
    "rtb-ik_LM": "Robotics Toolbox's C++ ETS.ik_LM on a DHRobot of RevoluteMDH links read from the model's own "
                 "modified-DH table; tol: E < 0.5 min(tol, rot_tol)^2 (E = 0.5 |6-D error|^2); searches after the "
                 "first from random in-limit starts",
    "trac-ik": "TRAC-IK Speed mode (pytracik TracIK.ik) on a URDF of the model's chain, eps = min(tol, rot_tol); "
               "success_per_component: TRAC-IK's own test (every error component, in the target's axes, within "
               "eps; re-checked by mj_kinematics)",
    "solver_says": "% of answers the peer itself called solved",
    "past_limits": "answers beyond a joint limit, and past_limit_max by how much (rad; pytracik keeps the limits "
                   "in float32)",
}


def peer(name: str, arm: Arm, targets: Array, q0: Array, tol: float, rot_tol: float, time_limit: float,
         iters: int | None) -> Row:
    """The row of one peer, or :class:`mjkin.peers.Unavailable` with the reason it has none.

    ``iters`` is ``bench ik``'s single-start budget (mink's; ``ik_LM`` gets mjkin's 1 + 24 starts);
    ``None`` is TRAC-IK's protocol: ``ik_LM`` searches up to 1 + 1000 times, and as it has no
    time limit of its own, a solve that took longer than ``time_limit`` counts as failed.
    TRAC-IK keeps its own ``time_limit`` in both.
    """
    if name == "mink" and iters is not None:
        return row(arm, name, mink_ik(arm, targets, q0, tol, rot_tol, iters), targets, tol, rot_tol)
    if name == "rtb-ik_LM":
        run, said = rtb_ik_lm(arm, targets, q0, tol, rot_tol, 1 + (AUTO_RESTARTS if iters else TIMED_RESTARTS))
        if iters is not None:
            return peer_row(arm, name, run, said, targets, tol, rot_tol)
        assert run.seconds is not None
        late = run.seconds > time_limit
        return {**peer_row(arm, name, run, said, targets, tol, rot_tol, within=~late), "timeouts": int(late.sum())}
    if name == "trac-ik":
        eps = min(tol, rot_tol)
        return peer_row(arm, name, *trac_ik(arm, targets, q0, eps, time_limit), targets, tol, rot_tol, eps=eps)
    known = IK_PEERS if iters is not None else TRAC_IK_PEERS
    raise InputError(f"peers are {', '.join(known)}; not {name!r}")


def peers_beside(mine: list[Row], arm: Arm, names: Sequence[str], skipped: list[Row], *args: Any) -> list[Row]:
    """``mine`` (mjkin's rows of ``arm``, the first the reference) and the peers' rows, with the time ratios.

    ``args`` are :func:`peer`'s after the arm; a peer without a row adds its reason to ``skipped``.
    """
    rows = list(mine)
    for name in names:
        try:
            rows.append(peer(name, arm, *args))
        except peers.Unavailable as e:
            skipped.append({"model": arm.name, "solver": name, "reason": str(e)})
    for r in rows:  # > 1: mjkin faster
        for stat in ("median", "mean", "cpu_median"):
            theirs, ours = r.get(f"{stat}_ms"), mine[0].get(f"{stat}_ms")
            r[f"{stat}_ratio"] = None if theirs is None or not ours else float(theirs) / float(ours)  # type: ignore
    return rows


def peer_tables(skipped: list[Row]) -> dict[str, list[Row]]:
    """The table of peers that got no row, with the reason (none when every peer ran)."""
    return {"peers without a row (the reason)": skipped} if skipped else {}


def bench_ik(models: Sequence[str] | None = None, targets: int = 1000, tol: float = 1e-4, rot_tol: float = 1e-3,
             iters: int = 200, seed: int = 0, peers: Sequence[str] = IK_PEERS, time_limit: float = 0.005) -> Report:
    """Run mjkin (auto; single start) beside MuJoCo DLS and the peers on the same targets, start and budget.

    ``peers``: which of :data:`IK_PEERS` to run; one that is not installed, or whose chain
    cannot be given to it or differs from the model's, gets no row but a line in the table of
    reasons. ``time_limit``: TRAC-IK's own per solve (it has no iteration budget).
    """
    check_settings(targets, tol, rot_tol, iters, time_limit)
    rows: list[Row] = []
    skipped: list[Row] = []
    for arm in track(arms(models), "bench ik"):
        T, q0 = targets_for(arm, targets, seed), arm.home
        auto = mjkin_single(arm, T, q0, tol, rot_tol)
        mine = [row(arm, "mjkin", auto, T, tol, rot_tol, mjkin_batched(arm, T, q0, tol, rot_tol)),
                row(arm, "mjkin.solve", mjkin_single(arm, T, q0, tol, rot_tol, functional=True), T, tol, rot_tol)]
        one: dict[str, Any] = {"restarts": 0, "max_iters": iters}
        mine.append(row(arm, "mjkin-single-start", mjkin_single(arm, T, q0, tol, rot_tol, **one), T, tol, rot_tol,
                        mjkin_batched(arm, T, q0, tol, rot_tol, **one)))
        mine.append(row(arm, "mujoco-dls", mujoco_dls(arm, T, q0, tol, rot_tol, iters), T, tol, rot_tol))
        rows += peers_beside(mine, arm, peers, skipped, T, q0, tol, rot_tol, time_limit, iters)
    settings = {"targets": targets, "tol_m": tol, "rot_tol_rad": rot_tol, "iters": iters, "seed": seed,
                "start": "home keyframe (else qpos0)", "success": "% of targets within both tolerances, "
                "re-checked by mujoco.mj_kinematics", "mjkin": "method auto: up to 50 iterations x (1 + 24 restarts)",
                "mjkin.solve": "mjkin's row through the functional entry, one mjkin.solve(tree, goal, ...) per target",
                "single-start budget": f"{iters} iterations, no restart (mjkin-single-start, mujoco-dls, mink)",
                "rtb-ik_LM budget": f"{RTB_ILIMIT} iterations x {1 + AUTO_RESTARTS} searches, as mjkin's",
                "trac-ik budget": f"its own time limit, {time_limit:g} s", **PEER_NOTES,
                "times": "wall clock per target, one call each; cpu_mean_ms: the calling thread's CPU time "
                         "(the solve's own work, without waits for a shared machine's cores)",
                "ratios": "median_ratio / mean_ratio / cpu_median_ratio: the row's time over mjkin's in the same run "
                          "(> 1: mjkin faster)",
                "gc": GC_NOTE}
    title = (f"{targets} random reachable 6-D poses per model from the home keyframe; success at {tol:g} m / "
             f"{rot_tol:g} rad re-checked by mj_kinematics; times per target, one call each")
    return Report({title: rows, **peer_tables(skipped)}, settings, {"skipped": skipped})


def bench_trac_ik(models: Sequence[str] | None = None, targets: int = 10_000, tol: float = 1e-5,
                  rot_tol: float = 1e-5, time_limit: float = 0.005, seed: int = 0,
                  peers: Sequence[str] = TRAC_IK_PEERS) -> Report:
    """TRAC-IK's protocol: random in-limit configurations, FK poses, mid-range start, 1e-5, 5 ms per solve.

    Means and medians are over all queries, failures included; the limit is ``mjkin.solve(timeout=...)``
    for mjkin, TRAC-IK's own for TRAC-IK, and for ``ik_LM`` (which has none) a slower solve fails.
    """
    check_settings(targets, tol, rot_tol, 1, time_limit)
    rows: list[Row] = []
    skipped: list[Row] = []
    for arm in track(arms(models, TRAC_IK_ARMS), "bench ik --protocol trac-ik"):
        T, q0 = targets_for(arm, targets, seed), mid_range(arm.tree)
        single = mjkin_single(arm, T, q0, tol, rot_tol, timeout=time_limit)
        r = row(arm, "mjkin single", single, T, tol, rot_tol)
        batched = mjkin_batched(arm, T, q0, tol, rot_tol, timeout=time_limit)
        b = row(arm, "mjkin batched", batched, T, tol, rot_tol)
        assert batched.per_s is not None
        b["mean_ms"], b["batched_per_s"] = 1e3 / batched.per_s, batched.per_s
        for out, run in ((r, single), (b, batched)):
            out["timeouts"] = int(np.sum(run.status == "timeout"))
        rows += peers_beside([r, b], arm, peers, skipped, T, q0, tol, rot_tol, time_limit, None)
    published = [p for p in TRAC_IK_PUBLISHED if p["model"] in {r["model"] for r in rows}]
    settings = {"protocol": "trac-ik", "targets": targets, "tol_m": tol, "rot_tol_rad": rot_tol,
                "time_limit_s": time_limit, "seed": seed, "start": "mid-range of every limited joint",
                "time limit": "mjkin.solve(timeout=...)", "gc": GC_NOTE,
                "success": "% within both tolerances (norms), re-checked by mujoco.mj_kinematics",
                "mean_ms": "over all queries including failures; batched: wall time of the best of 3 calls / targets",
                "cpu_mean_ms": "the calling thread's CPU time per single call (no waits for a shared machine)",
                "rtb-ik_LM budget": f"{RTB_ILIMIT} iterations x {1 + TIMED_RESTARTS} searches; it has no time limit "
                                    "of its own: a solve over the limit counts as failed (column timeouts)",
                "trac-ik budget": f"its own time limit, {time_limit:g} s", **PEER_NOTES,
                "ratios": "median_ratio / mean_ratio / cpu_median_ratio: the row's time over mjkin single's (> 1: "
                          "mjkin faster)",
                "published": TRAC_IK_SOURCE}
    tables = {f"TRAC-IK protocol: {targets} random in-limit configurations -> FK poses, start mid-range, "
              f"{tol:g} m / {rot_tol:g} rad, {1e3 * time_limit:g} ms per solve": rows, **peer_tables(skipped)}
    if published:
        tables[TRAC_IK_SOURCE] = published
    return Report(tables, settings, {"published": published, "skipped": skipped})
