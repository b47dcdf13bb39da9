"""``mjkin bench constraints``: hard constraints kept inside the solver, judged afterwards by MuJoCo alone.

Clearance: arm7 and the Panda among three spheres and a table, 6-D targets made from
random configurations that keep the margin (so an answer exists). Beside the solve with
:class:`~mjkin.goals.Clearance`: the same solve without it, the reject-and-retry a user
writes (solve, then re-solve from random starts until MuJoCo finds no pair inside the
margin) and mink's ``CollisionAvoidanceLimit`` (when installed). Every answer is judged
by MuJoCo: ``mj_collision`` with the margin on every geom proposes the pairs (its own
filters), ``mj_geomDistance`` measures them. Then two-hand targets near the body of the
primate (and the G1) with self-clearance and balance (:class:`~mjkin.goals.CenterOfMass`), and a
followed path with ``max_joint_speed``.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Literal

import mujoco
import numpy as np
from numpy.typing import NDArray

from ... import goals as G
from ...errors import InputError
from ...ik import Problem
from ...kinematics.qspace import FREE
from ...kinematics.tree import Tree, bundled_models, load
from ...motion import follow, sole_points
from ...runtime.progress import track
from ...spatial import mat_to_rotvec
from . import peers
from .report import GC_NOTE, Report, Row, gc_paused, shared_models_dir

Array = NDArray[np.float64]

MARGIN = 0.005  # m: the clearance every answer must keep (the Panda's link0 and link1 stand 8 mm apart)
TOL, ROT_TOL = 1e-4, 1e-3  # m, rad: the pose tolerance (bench ik's)
JUDGE_TOL = 1e-6  # m: MuJoCo's distance may fall this far below the margin (the solver's hard tolerance)
RETRIES = 20  # reject-and-retry: re-solves from random starts after the first
MINK_ITERS = 200
ARMS = {"arm7": "ee", "panda": "flange"}
OBSTACLES = (  # name, type, size, pos: three spheres about the workspace and a table in front
    ("ball_a", mujoco.mjtGeom.mjGEOM_SPHERE, (0.08, 0, 0), (0.45, 0.25, 0.55)),
    ("ball_b", mujoco.mjtGeom.mjGEOM_SPHERE, (0.08, 0, 0), (0.35, -0.3, 0.75)),
    ("ball_c", mujoco.mjtGeom.mjGEOM_SPHERE, (0.06, 0, 0), (-0.3, 0.35, 0.6)),
    ("table", mujoco.mjtGeom.mjGEOM_BOX, (0.25, 0.4, 0.02), (0.6, 0.0, 0.2)),
)


def obstacle_scene(model: str) -> Tree:
    """The bundled ``model`` with :data:`OBSTACLES` added to its world body (colliding with everything)."""
    spec = mujoco.MjSpec.from_file(str(bundled_models()[model]))
    for name, kind, size, pos in OBSTACLES:
        spec.worldbody.add_geom(name=name, type=kind, size=size, pos=pos, contype=1, conaffinity=1,
                                rgba=(0.8, 0.3, 0.3, 0.6))
    return load(spec)


class Judge:
    """MuJoCo's own verdict on clearance: the least ``mj_geomDistance`` over the pairs ``mj_collision`` proposes.

    A copy of the model whose every geom has ``margin`` (+ a little) as its collision margin:
    MuJoCo's filters (contype/conaffinity, parent–child, ``<exclude>``) and broad phase pick
    the pairs within reach, ``mj_geomDistance`` measures each.
    """

    def __init__(self, tree: Tree, margin: float) -> None:
        m = tree.model.__copy__()
        m.geom_margin[:] = margin + 0.01
        m.geom_gap[:] = 0.0
        # no mid-phase: its bounding volumes were built when the model compiled, without this margin, and dropped
        # pairs apart by less than it (the Panda's link0-link1, 8 mm, among three spheres in the world body)
        m.opt.disableflags |= int(mujoco.mjtDisableBit.mjDSBL_MIDPHASE)
        self.model, self.data, self.margin = m, mujoco.MjData(m), margin
        self.fromto = np.zeros(6)

    def clearance(self, q: Array) -> float:
        """The least distance (m) of any MuJoCo contact pair at ``q``, capped at ``margin + 0.01``."""
        m, d = self.model, self.data
        d.qpos[:] = q
        mujoco.mj_kinematics(m, d)
        mujoco.mj_collision(m, d)
        least = self.margin + 0.01
        seen = set()
        for c in d.contact[:d.ncon]:
            pair = (int(c.geom1), int(c.geom2))
            if pair not in seen:
                seen.add(pair)
                least = min(least, mujoco.mj_geomDistance(m, d, pair[0], pair[1], least + 1.0, self.fromto))
        return float(least)

    def clear(self, q: Array) -> bool:
        """Every pair at least the margin apart (to :data:`JUDGE_TOL`)."""
        return self.clearance(q) >= self.margin - JUDGE_TOL


@dataclass(frozen=True)
class ClearanceCase:
    """A clearance benchmark case: one arm among the obstacles, its frame, start, targets ``(N, 4, 4)`` and judge."""

    name: str
    tree: Tree
    frame: str
    q0: Array
    targets: Array
    judge: Judge


def clearance_case(name: str, n: int, rng: np.random.Generator, margin: float = MARGIN) -> ClearanceCase:
    """``n`` targets from random configurations MuJoCo finds clear by ``margin`` (an answer exists for each)."""
    tree = obstacle_scene(name)
    judge = Judge(tree, margin)
    frame = ARMS[name]
    qs: list[Array] = []
    for _ in range(100):
        qs += [q for q in tree.random_q(rng, 4 * n) if judge.clearance(q) >= margin + 1e-3][:n - len(qs)]
        if len(qs) == n:
            break
    else:
        raise InputError(f"{name}: too few random configurations keep {margin} m of clearance; give a smaller margin")
    q0 = tree.model.key_qpos[0].copy() if tree.model.nkey else tree.qpos0.copy()
    return ClearanceCase(name, tree, frame, q0, tree.pose(np.array(qs), frame), judge)


def pose_ok(tree: Tree, frame: str, q: Array, T: Array) -> bool:
    """``frame``'s pose at ``q`` within :data:`TOL` / :data:`ROT_TOL` of ``T``, by MuJoCo's ``mj_kinematics``."""
    m, d = tree.model, mujoco.MjData(tree.model)
    d.qpos[:] = q
    mujoco.mj_kinematics(m, d)
    i = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_SITE, frame)
    R = d.site_xmat[i].reshape(3, 3)
    return bool(np.linalg.norm(d.site_xpos[i] - T[:3, 3]) <= TOL
                and np.linalg.norm(mat_to_rotvec(T[:3, :3] @ R.T)) <= ROT_TOL)


@dataclass(frozen=True)
class Answers:
    """One solver's answers ``q (N, nq)``, seconds per target ``(N,)`` and its own success flags ``(N,)``."""

    q: Array
    seconds: Array
    said: NDArray[np.bool_]


def timed(solve_one: Callable[[int], tuple[Array, bool]], n: int) -> Answers:
    """Time ``solve_one(k)`` for each target (after one untimed call), the collector paused."""
    solve_one(0)
    qs, seconds, said = [], np.empty(n), np.empty(n, bool)
    with gc_paused():
        for k in range(n):
            start = time.perf_counter()
            q, ok = solve_one(k)
            seconds[k] = time.perf_counter() - start
            qs.append(q)
            said[k] = ok
    return Answers(np.array(qs), seconds, said)


def mjkin_answers(s: ClearanceCase, clearance: bool, margin: float) -> Answers:
    """One ``problem.solve`` per target from the home pose, with or without a hard Clearance of ``margin``."""
    extra = [G.Clearance(margin)] if clearance else []
    problem = Problem(s.tree, [G.Pose(s.frame, T=s.targets[0]), *extra], tol=TOL, rot_tol=ROT_TOL)

    def one(k: int) -> tuple[Array, bool]:
        res = problem.solve(s.q0, [G.Pose(s.frame, T=s.targets[k]), *extra])
        return res.q, bool(res.success)

    return timed(one, len(s.targets))


def reject_and_retry(s: ClearanceCase, rng: np.random.Generator) -> Answers:
    """The baseline a user writes: solve without clearance; while MuJoCo finds a pair inside the margin,
    solve again from a random start (up to :data:`RETRIES` times). MuJoCo's checks are inside the timed call.
    """  # noqa: D205
    problem = Problem(s.tree, G.Pose(s.frame, T=s.targets[0]), tol=TOL, rot_tol=ROT_TOL)
    starts = s.tree.random_q(rng, RETRIES)

    def one(k: int) -> tuple[Array, bool]:
        goal = G.Pose(s.frame, T=s.targets[k])
        for q0 in (s.q0, *starts):
            res = problem.solve(q0, [goal])
            if res.success and s.judge.clear(res.q):
                return res.q, True
        return res.q, False

    return timed(one, len(s.targets))


def mink_answers(s: ClearanceCase, margin: float) -> Answers:
    """Mink as its collision example runs it: FrameTask, ConfigurationLimit and ``CollisionAvoidanceLimit`` over
    every moving geom against every other geom, ``solve_ik`` (daqp) and integrate until ``compute_error`` is
    within tolerance (at most :data:`MINK_ITERS` steps). Only mink's calls are timed.

    Raises :class:`mjkin.peers.Unavailable` when mink is not installed.
    """  # noqa: D205
    mink = peers.require("mink", "mink")
    model = s.tree.model
    moving = [g for g in range(model.ngeom) if model.geom_bodyid[g] > 0 and model.geom_contype[g]]
    fixed = [g for g in range(model.ngeom) if model.geom_bodyid[g] == 0 and model.geom_contype[g]]
    config = mink.Configuration(model)
    task = mink.FrameTask(s.frame, "site", position_cost=1.0, orientation_cost=1.0, lm_damping=1.0)
    limits = [mink.ConfigurationLimit(model),
              mink.CollisionAvoidanceLimit(model, [(moving, moving + fixed)], minimum_distance_from_collisions=margin,
                                           collision_detection_distance=margin + 0.1)]

    def one(k: int) -> tuple[Array, bool]:
        config.update(s.q0)
        task.set_target(mink.SE3.from_matrix(s.targets[k]))
        for _ in range(MINK_ITERS):
            vel = mink.solve_ik(config, [task], 1.0, "daqp", damping=1e-3, limits=limits)
            config.integrate_inplace(vel, 1.0)
            e = task.compute_error(config)
            if np.linalg.norm(e[:3]) <= TOL and np.linalg.norm(e[3:]) <= ROT_TOL:
                return config.q.copy(), True
        return config.q.copy(), False

    return timed(one, len(s.targets))


def judged_row(s: ClearanceCase, solver: str, a: Answers, baseline_ms: float | None) -> Row:
    """Success judged by MuJoCo (pose within tolerance and clearance kept), violations among the solver's own
    successes, median time and its ratio to the solve without clearance.
    """  # noqa: D205
    pose = np.array([pose_ok(s.tree, s.frame, q, T) for q, T in zip(a.q, s.targets, strict=True)])
    clear = np.array([s.judge.clear(q) for q in a.q])
    ms = 1e3 * float(np.median(a.seconds))
    return {"model": s.name, "solver": solver, "targets": len(a.q), "success_%": 100.0 * float(np.mean(pose & clear)),
            "said_success_%": 100.0 * float(np.mean(a.said)),
            "violations_in_successes": int(np.count_nonzero(a.said & ~clear)),
            "deepest_below_margin_mm": round(1e3 * max(0.0, s.judge.margin - min(map(s.judge.clearance, a.q))), 3),
            "median_ms": ms, "x_without": ms / baseline_ms if baseline_ms else 1.0}


def bench_clearance(n: int, seed: int, margin: float, skipped: list[Row]) -> list[Row]:
    """The arms among obstacles: mjkin with and without Clearance, reject-and-retry, mink."""
    rows: list[Row] = []
    rng = np.random.default_rng(seed)
    for name in track(tuple(ARMS), "bench constraints: arms"):
        s = clearance_case(name, n, rng, margin)
        plain = mjkin_answers(s, False, margin)
        base = 1e3 * float(np.median(plain.seconds))
        rows.append(judged_row(s, "mjkin Clearance", mjkin_answers(s, True, margin), base))
        rows.append(judged_row(s, "mjkin without (no clearance)", plain, base))
        rows.append(judged_row(s, "reject-and-retry", reject_and_retry(s, np.random.default_rng(seed)), base))
        try:
            rows.append(judged_row(s, "mink CollisionAvoidanceLimit", mink_answers(s, margin), base))
        except peers.Unavailable as e:
            skipped.append({"model": name, "solver": "mink CollisionAvoidanceLimit", "reason": str(e)})
    return rows


# ------------------------------------------------------------------------------------------ figures

HANDS = {"primate": ("left_hand", "right_hand", ("left_foot", "right_foot")),
         "g1": ("left_zero_link", "right_zero_link", ("left_foot", "right_foot"))}


def figures() -> list[tuple[str, Tree]]:
    """The primate, and the G1 when the shared models are here."""
    out = [("primate", load("primate"))]
    root = shared_models_dir()
    if root is not None and (root / "unitree_g1/g1.xml").is_file():
        out.append(("g1", load(root / "unitree_g1/g1.xml")))
    return out


def frame_kind(tree: Tree, frame: str) -> Literal["site", "body"]:
    """``site`` when the model has a site of that name, else ``body``."""
    return "site" if frame in tree.names("site") else "body"


def sole_support(tree: Tree, feet: Sequence[str]) -> list[tuple[str, tuple[float, ...]]]:
    """The feet's toe and heel points (:func:`mjkin.motion.sole_points`) as ``(frame, offset)`` support points.

    A foot whose body has no geom to stand on gives its frame's origin alone.
    """
    out: list[tuple[str, tuple[float, ...]]] = []
    for f in feet:
        body, T = tree.frame_body(f)
        try:
            soles = sole_points(tree, tree.model.body(body).name)
        except InputError:
            out.append((f, (0.0, 0.0, 0.0)))
            continue
        out += [(f, tuple(T[:3, :3].T @ (p - T[:3, 3]))) for p in soles]  # body frame -> the foot frame's
    return out


def com_inside(tree: Tree, q: Array, support: Sequence[tuple[str, tuple[float, ...]]]) -> bool:
    """The CoM's ground projection inside the convex hull of the support points' (MuJoCo's CoM and frames)."""
    d = mujoco.MjData(tree.model)
    d.qpos[:] = q
    mujoco.mj_kinematics(tree.model, d)
    mujoco.mj_comPos(tree.model, d)
    com = d.subtree_com[0, :2]
    pts = []
    for f, offset in support:
        site = frame_kind(tree, f) == "site"
        i = mujoco.mj_name2id(tree.model, mujoco.mjtObj.mjOBJ_SITE if site else mujoco.mjtObj.mjOBJ_BODY, f)
        x, R = (d.site_xpos[i], d.site_xmat[i]) if site else (d.xpos[i], d.xmat[i])
        pts.append((x + R.reshape(3, 3) @ np.asarray(offset))[:2])
    return inside_hull(np.array(pts), com)


def inside_hull(points: Array, p: Array) -> bool:
    """``p (2,)`` inside the convex hull of ``points (K, 2)`` (on a segment when K = 2, to 1e-6 m)."""
    from scipy.spatial import ConvexHull

    if len(points) < 3:
        a, b = points[0], points[-1]
        t = np.clip((p - a) @ (b - a) / max((b - a) @ (b - a), 1e-300), 0.0, 1.0)
        return bool(np.linalg.norm(a + t * (b - a) - p) <= 1e-6)
    hull = ConvexHull(points)
    return bool(np.all(hull.equations[:, :2] @ p + hull.equations[:, 2] <= 1e-6))


def near_body(tree: Tree, q0: Array, qs: Array) -> Array:
    """``qs (N, nq)`` with a free root joint put back where ``q0`` has it: the hands' targets stay near the body."""
    out = qs.copy()
    if tree.njnt and tree.jnt_type[0] == FREE:
        out[:, :7] = q0[:7]
    return out


@dataclass(frozen=True)
class Figure:
    """A figure's two-hand targets ``(N, 3)`` each, its start, feet and MuJoCo's judge of self-contact."""

    name: str
    tree: Tree
    q0: Array
    hands: tuple[tuple[str, Array], tuple[str, Array]]
    feet: tuple[str, ...]
    judge: Judge

    def goals(self, k: int, extra: Sequence[G.Goal]) -> list[G.Goal]:
        """Both hands on their ``k``-th targets, then ``extra``."""
        return [*(G.Position(f, p[k], kind=frame_kind(self.tree, f)) for f, p in self.hands), *extra]

    def row(self, label: str, extra: Sequence[G.Goal]) -> Row:
        """One solve per target from the keyframe; self-penetration (and CoM) among the successes, by MuJoCo."""
        n = len(self.hands[0][1])
        limbs = [j for j, t in zip(self.tree.names("joint"), self.tree.jnt_type, strict=True) if t != FREE]
        problem = Problem(self.tree, self.goals(0, extra), tol=1e-3, joints=limbs)  # the root stays where it stands

        def one(k: int) -> tuple[Array, bool]:
            res = problem.solve(self.q0, self.goals(k, extra))
            return res.q, bool(res.success)

        a = timed(one, n)
        pen = np.array([self.judge.clearance(q) < -JUDGE_TOL for q in a.q])
        row: Row = {"model": self.name, "goals": label, "targets": n, "success_%": 100.0 * float(np.mean(a.said)),
                    "self_penetration_in_successes": int(np.count_nonzero(a.said & pen)),
                    "median_ms": 1e3 * float(np.median(a.seconds))}
        if any(isinstance(g, G.Balance) for g in extra):
            support = sole_support(self.tree, self.feet)
            row["com_outside_in_successes"] = int(sum(not com_inside(self.tree, q, support) for q in a.q[a.said]))
        return row


def figure(name: str, tree: Tree, n: int, seed: int) -> Figure:
    """``n`` two-hand targets from random configurations (root kept at the keyframe's) free of self-contact."""
    left, right, feet = HANDS[name]
    judge = Judge(tree, 0.0)
    q0 = tree.model.key_qpos[0].copy() if tree.model.nkey else tree.qpos0.copy()
    qs = np.array([q for q in near_body(tree, q0, tree.random_q(np.random.default_rng(seed), 20 * n))
                   if judge.clearance(q) > 1e-3][:n])
    hands = tuple((f, tree.pose(qs, f, frame_kind(tree, f))[:, :3, 3]) for f in (left, right))
    return Figure(name, tree, q0, hands, feet, judge)  # type: ignore[arg-type]


def bench_figures(n: int, seed: int) -> list[Row]:
    """Two-hand targets near the body without and with self-clearance, then with balance too."""
    rows: list[Row] = []
    for name, tree in track(figures(), "bench constraints: figures"):
        fig = figure(name, tree, n, seed)
        rows.append(fig.row("no clearance", []))
        rows.append(fig.row("Clearance(0)", [G.Clearance(0.0)]))
        rows.append(fig.row("Clearance(0) + CenterOfMass(support=feet)",
                            [G.Clearance(0.0), G.Balance(sole_support(tree, fig.feet))]))
    return rows


# ------------------------------------------------------------------------------------------ speed


def bench_speed(frames: int = 120, fps: float = 30.0, speed: float = 1.0) -> list[Row]:
    """arm7's ee around a fast circle, followed with and without ``max_joint_speed``: frame-to-frame joint
    speed beyond the limit, tracking error.
    """  # noqa: D205
    tree = load("arm7")
    q0 = tree.model.key_qpos[0]
    c = tree.pose(q0, "ee")[:3, 3]
    t = np.linspace(0.0, 2.0 * np.pi, frames)
    path = c + 0.25 * np.stack([np.zeros_like(t), np.sin(t), np.cos(t) - 1.0], axis=1)
    rows: list[Row] = []
    for label, limit in (("without", None), (f"max_joint_speed={speed} rad/s", speed)):
        traj = follow(tree, "ee", path, q0=q0, fps=fps, max_joint_speed=limit)
        qs = np.vstack([q0, traj.q])
        rate = np.abs(np.diff(qs, axis=0)).max(axis=1) * fps
        err = np.linalg.norm(tree.pose(traj.q, "ee")[:, :3, 3] - path, axis=1)
        rows.append({"path": f"circle r=0.25 m, {frames} frames at {fps:g} fps", "follow": label,
                     "peak_joint_speed_rad_s": float(rate.max()),
                     "frames_over_limit": int(np.count_nonzero(rate > speed + 1e-6)) if limit else None,
                     "track_err_mean_mm": 1e3 * float(err.mean()), "track_err_max_mm": 1e3 * float(err.max())})
    return rows


def bench_constraints(targets: int = 100, margin: float = MARGIN, seed: int = 0) -> Report:
    """Clearance among obstacles (with its baselines), self-clearance and balance of figures, a speed-limited path."""
    if targets < 1 or not margin >= 0:
        raise InputError(f"--targets must be >= 1 and the margin >= 0, got {targets}, {margin}")
    skipped: list[Row] = []
    tables = {
        f"arms among 3 spheres and a table, 6-D targets from clear random configurations, clearance >= {margin * 1e3:g}"
        f" mm: success judged by MuJoCo (pose within {TOL:g} m / {ROT_TOL:g} rad by mj_kinematics, clearance by "
        "mj_geomDistance over mj_collision's pairs); x_without: median time / the same solve without Clearance":
            bench_clearance(targets, seed, margin, skipped),
        "two hands at targets near the body (tol 1 mm) from the keyframe, the root fixed: self-penetration and CoM "
        "judged by MuJoCo":
            bench_figures(max(1, targets // 2), seed),
        "a path followed with and without max_joint_speed (motion.follow): frame-to-frame speed and tracking":
            bench_speed(),
    }
    if skipped:
        tables["peers without a row (the reason)"] = skipped
    return Report(tables, {"targets": targets, "seed": seed, "margin_m": margin,
                           "timing": "median of one timed solve per target after an untimed one, one thread, a "
                                     "shared machine: compare ratios within the run", "gc": GC_NOTE,
                           "retries": f"reject-and-retry: up to {RETRIES} random restarts"})
