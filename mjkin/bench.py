"""Benchmarks: mjkin and its baseline side by side in one process, reported as ratios.

Nothing here is asserted by tests: timings on shared machines are noisy. Each
benchmark returns rows (dicts) and the CLI prints them as a table.
"""

from __future__ import annotations

import importlib.util
import os
import time
from collections.abc import Callable
from pathlib import Path
from typing import Literal

import mujoco
import numpy as np

from .progress import track
from .tree import Tree, load

Row = dict[str, object]
Tables = dict[str, list[Row]]


def seconds_per_call(fn: Callable[[], object], min_time: float = 0.2, repeat: int = 3) -> float:
    """Best of ``repeat`` runs of the mean time per call over at least ``min_time`` seconds."""
    fn()  # warm caches
    best = np.inf
    for _ in range(repeat):
        n, start = 0, time.perf_counter()
        while True:
            fn()
            n += 1
            elapsed = time.perf_counter() - start
            if elapsed >= min_time:
                break
        best = min(best, elapsed / n)
    return float(best)


def shared_models_dir() -> Path | None:
    """The mesh-free real robots: ``$MJKIN_SHARED_MODELS``, else ``../shared/models`` from here up."""
    env = os.environ.get("MJKIN_SHARED_MODELS")
    if env:
        return Path(env) if Path(env).is_dir() else None
    for base in (Path.cwd(), *Path.cwd().parents, Path(__file__).resolve().parent.parent):
        cand = base.parent / "shared" / "models"
        if cand.is_dir():
            return cand
    return None


def shared_model(relpath: str) -> Tree | None:
    """Load ``relpath`` from :func:`shared_models_dir`, or ``None`` when it is not there."""
    root = shared_models_dir()
    if root is None or not (root / relpath).is_file():
        return None
    return load(root / relpath)


def mujoco_fk_loop(model: mujoco.MjModel, Q: np.ndarray) -> Callable[[], np.ndarray]:
    """The baseline: a Python loop of ``mj_kinematics`` copying out every body pose."""
    data = mujoco.MjData(model)
    out = np.empty((len(Q), model.nbody, 12))

    def run() -> np.ndarray:
        for i, q in enumerate(Q):
            data.qpos[:] = q
            mujoco.mj_kinematics(model, data)
            out[i, :, :3] = data.xpos
            out[i, :, 3:] = data.xmat
        return out

    return run


def fk_models() -> list[tuple[str, Tree]]:
    """Models of the FK benchmark: the bundled 7-DoF arm and primate, and real robots when present."""
    models = [("arm7", load("arm7")), ("primate", load("primate"))]
    for name, rel in (("panda", "franka_emika_panda/panda_nohand.xml"), ("g1", "unitree_g1/g1.xml")):
        tree = shared_model(rel)
        if tree is not None:
            models.append((name, tree))
    return models


def bench_fk(sizes: tuple[int, ...] = (1, 100, 10_000), seed: int = 0, min_time: float = 0.2) -> Tables:
    """Batched FK throughput of mjkin vs a Python loop of ``mj_kinematics``."""
    rows: list[Row] = []
    rng = np.random.default_rng(seed)
    cases = [(n, t, B) for n, t in fk_models() for B in sizes]
    for name, tree, B in track(cases, "bench fk"):
        Q = tree.random_q(rng, B)
        t_mjkin = seconds_per_call(lambda: tree.fk(Q), min_time)  # noqa: B023
        t_mj = seconds_per_call(mujoco_fk_loop(tree.model, Q), min_time)
        rows.append({"model": name, "nbody": tree.nbody, "batch": B,
                     "mjkin q/s": B / t_mjkin, "mujoco-loop q/s": B / t_mj,
                     "mjkin us/q": 1e6 * t_mjkin / B, "mujoco us/q": 1e6 * t_mj / B,
                     "ratio": t_mj / t_mjkin})
    return {"batched FK: mjkin vs a Python loop of mj_kinematics (ratio > 1: mjkin faster)": rows}


def bench_seeds(out: Path | None = None) -> Tables:
    """The seeds' examples (SEEDS.md §4): tables, and PNG figures in ``out`` when matplotlib is there."""
    from . import seeds

    one = []
    for label, goal in (("(-20, 5)", seeds.REACHABLE), ("(-35, 5)", seeds.UNREACHABLE)):
        for method in seeds.METHODS:
            res = seeds.three_link(method, goal)
            e = res.history.error[:, 0] if res.history is not None else np.zeros(1)
            one.append({"goal": label, "method": method, "status": str(res.status),
                        "frames": int(res.iterations), **{f"err@{f}": float(e[min(f, int(res.iterations))])
                                                          for f in (0, 5, 10, 15, 20)},
                        "max joint step": float(seeds.joint_steps(res).max())})
    two = []
    runs = {n: seeds.ccd_convergence(n) for n in (3, 20)}
    for i in range(7):
        row: Row = {"sweep": i}
        for n, err in runs.items():
            row[f"n={n} error"] = f"{err[i]:.2e}"
            row[f"n={n} ratio"] = f"{err[i] / err[i - 1]:.2g}" if i else ""
        two.append(row)
    three = []
    for xyz in ([0.9, 0.8, 0.0], [2.0, 0.0, 0.0], [0.1, 0.1, 0.0]):
        goal = np.array(xyz)
        q, ok = seeds.two_link(goal)
        tip = load("planar_2link").pose(q, "tip")[:, :3, 3] if ok else None
        three.append({"goal": str(xyz[:2]), "reachable": ok,
                      "elbow + (q)": np.round(q[0], 4).tolist() if ok else "-",
                      "elbow - (q)": np.round(q[1], 4).tolist() if ok else "-",
                      "FK error": float(np.abs(tip - goal).max()) if tip is not None else "-"})
    files = seeds.figures(out or Path("mjkin-seeds"))
    tables = {"seed 1: three-link arm 15/10/5 from [pi/8, pi/4, pi/4], one step per frame": one,
              "seed 2: CCD on n unit links toward (0.9, 0.75), error after each sweep": two,
              "seed 3: two-link analytic IK (links 1.0, 0.7)": three}
    tables["figures"] = [{"file": str(f)} for f in files] or [{"file": "(matplotlib not installed: pip install "
                                                                      "'mjkin[plot]')"}]
    return tables


def format_table(rows: list[Row]) -> str:
    """Rows as an aligned text table (floats with 3 significant digits)."""
    if not rows:
        return "(no rows)"
    cols = list(rows[0])

    def cell(v: object) -> str:
        if isinstance(v, float):
            return f"{v:.3g}" if abs(v) < 1e5 else f"{v:,.0f}"
        return str(v)

    cells = [[cell(r.get(c, "")) for c in cols] for r in rows]
    widths = [max(len(c), *(len(r[i]) for r in cells)) for i, c in enumerate(cols)]
    line = "  ".join(c.rjust(w) for c, w in zip(cols, widths, strict=True))
    body = ["  ".join(v.rjust(w) for v, w in zip(r, widths, strict=True)) for r in cells]
    return "\n".join([line, "-" * len(line), *body])


IK_ARMS: tuple[tuple[str, str, str, Literal["site", "body"]], ...] = (  # name, model, frame, frame kind
    ("arm7", "arm7", "ee", "site"),
    ("panda", "franka_emika_panda/panda_nohand.xml", "attachment_site", "site"),
    ("ur5e", "universal_robots_ur5e/ur5e.xml", "wrist_3_link", "body"),
    ("iiwa14", "kuka_iiwa_14/iiwa14.xml", "attachment_site", "site"),
    ("gen3", "kinova_gen3/gen3.xml", "pinch_site", "site"),
    ("xarm7", "ufactory_xarm7/xarm7_nohand.xml", "attachment_site", "site"),
)


def pose_errors(T: np.ndarray, target: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Position (m) and rotation (rad) distances between poses ``(..., 4, 4)``."""
    from .spatial import mat_to_quat, quat_distance

    return (np.linalg.norm(T[..., :3, 3] - target[..., :3, 3], axis=-1),
            quat_distance(mat_to_quat(T[..., :3, :3]), mat_to_quat(target[..., :3, :3])))


def mujoco_dls(model: mujoco.MjModel, frame: str, kind: str, targets: np.ndarray, q0: np.ndarray, tol: float,
               rot_tol: float, max_iters: int = 200, damping: float = 0.05) -> tuple[np.ndarray, np.ndarray]:
    """The baseline: damped least squares on MuJoCo's own ``mj_kinematics`` + ``mj_jacSite``/``mj_jacBody``.

    Returns reached poses ``(N, 4, 4)`` and seconds per solve ``(N,)``.
    """
    data = mujoco.MjData(model)
    obj = mujoco.mjtObj.mjOBJ_SITE if kind == "site" else mujoco.mjtObj.mjOBJ_BODY
    i = mujoco.mj_name2id(model, obj, frame)
    limited = model.jnt_limited.astype(bool) & (model.jnt_type > 1)
    qa = model.jnt_qposadr[limited]
    lo, hi = model.jnt_range[limited, 0], model.jnt_range[limited, 1]
    jacp, jacr = np.zeros((3, model.nv)), np.zeros((3, model.nv))
    cur, neg, diff, err = np.zeros(4), np.zeros(4), np.zeros(4), np.zeros(6)
    lam2 = damping ** 2 * np.eye(6)
    reached, times = np.empty((len(targets), 4, 4)), np.empty(len(targets))
    for n, T in enumerate(targets):
        goal_q = np.zeros(4)
        mujoco.mju_mat2Quat(goal_q, T[:3, :3].ravel())
        start = time.perf_counter()
        q = q0.copy()
        for _ in range(max_iters + 1):
            data.qpos[:] = q
            mujoco.mj_kinematics(model, data)
            mujoco.mj_comPos(model, data)
            x = data.site_xpos[i] if kind == "site" else data.xpos[i]
            R = data.site_xmat[i] if kind == "site" else data.xmat[i]
            err[:3] = T[:3, 3] - x
            mujoco.mju_mat2Quat(cur, R)
            mujoco.mju_negQuat(neg, cur)
            mujoco.mju_mulQuat(diff, goal_q, neg)
            mujoco.mju_quat2Vel(err[3:], diff, 1.0)
            if np.linalg.norm(err[:3]) <= tol and np.linalg.norm(err[3:]) <= rot_tol:
                break
            (mujoco.mj_jacSite if kind == "site" else mujoco.mj_jacBody)(model, data, jacp, jacr, i)
            J = np.vstack([jacp, jacr])
            dq = J.T @ np.linalg.solve(J @ J.T + lam2, err)
            mujoco.mj_integratePos(model, q, dq, 1.0)
            q[qa] = np.clip(q[qa], lo, hi)
        times[n] = time.perf_counter() - start
        reached[n, :3, :3] = R.reshape(3, 3)
        reached[n, :3, 3] = x
        reached[n, 3] = [0, 0, 0, 1]
    return reached, times


def mink_loop(model: mujoco.MjModel, frame: str, kind: str, targets: np.ndarray, q0: np.ndarray, tol: float,
              rot_tol: float, max_iters: int = 200) -> tuple[np.ndarray, np.ndarray]:
    """The same targets through mink (a QP per step, joint limits as constraints), as its examples set it up.

    Returns reached poses ``(N, 4, 4)`` and seconds per solve ``(N,)``.
    """
    import mink

    config = mink.Configuration(model)
    task = mink.FrameTask(frame, kind, position_cost=1.0, orientation_cost=1.0, lm_damping=1.0)
    limits = [mink.ConfigurationLimit(model)]
    reached, times = np.empty((len(targets), 4, 4)), np.empty(len(targets))
    for n, T in enumerate(targets):
        start = time.perf_counter()
        config.update(q0)
        task.set_target(mink.SE3.from_matrix(T))
        for _ in range(max_iters + 1):
            reached[n] = config.get_transform_frame_to_world(frame, kind).as_matrix()
            ep, er = pose_errors(reached[n], T)
            if ep <= tol and er <= rot_tol:
                break
            config.integrate_inplace(mink.solve_ik(config, [task], 1.0, "daqp", limits=limits), 1.0)
        times[n] = time.perf_counter() - start
    return reached, times


def bench_ik(n: int = 1000, seed: int = 0, tol: float = 1e-4, rot_tol: float = 1e-3) -> Tables:
    """6-D pose IK on random reachable targets: mjkin (single and batched) vs a MuJoCo DLS loop (and mink)."""
    from . import goals as G
    from .ik import solve

    rows: list[Row] = []
    root = shared_models_dir()
    has_mink = importlib.util.find_spec("mink") is not None
    for name, src, frame, kind in track(IK_ARMS, "bench ik"):
        path = src if src == "arm7" else (root / src if root else None)
        if path is None or (src != "arm7" and not Path(path).is_file()):
            continue
        tree = load(path)
        rng = np.random.default_rng(seed)
        targets = tree.pose(tree.random_q(rng, n), frame, kind)
        home = tree.model.key_qpos[0].copy() if tree.model.nkey else tree.qpos0.copy()
        for warm in (targets[:2], targets[0]):  # compile both the batched and the single-target signatures
            solve(tree, G.Pose(frame, T=warm, kind=kind), q0=home, tol=tol, rot_tol=rot_tol)
        single = np.empty(n)
        q_single = np.empty((n, tree.nq))
        for k in range(n):
            start = time.perf_counter()
            q_single[k] = solve(tree, G.Pose(frame, T=targets[k], kind=kind), q0=home, tol=tol, rot_tol=rot_tol).q
            single[k] = time.perf_counter() - start
        batched = np.inf
        for _ in range(3):  # best of three, as seconds_per_call: the machine is shared
            start = time.perf_counter()
            res = solve(tree, G.Pose(frame, T=targets, kind=kind), q0=home, tol=tol, rot_tol=rot_tol)
            batched = min(batched, time.perf_counter() - start)
        reached, base = mujoco_dls(tree.model, frame, kind, targets, home, tol, rot_tol)
        runs = [("mjkin", tree.pose(q_single, frame, kind), single, n / single.sum()),
                ("mjkin batched", tree.pose(res.q, frame, kind), None, n / batched),
                ("mujoco DLS loop", reached, base, n / base.sum())]
        if has_mink:
            by_mink, t_mink = mink_loop(tree.model, frame, kind, targets, home, tol, rot_tol)
            runs.append(("mink", by_mink, t_mink, n / t_mink.sum()))
        for label, T, times, rate in runs:
            ep, er = pose_errors(T, targets)
            rows.append({"arm": name, "solver": label, "success %": 100 * ((ep <= tol) & (er <= rot_tol)).mean(),
                         "median ms": "-" if times is None else 1e3 * float(np.median(times)),
                         "p95 ms": "-" if times is None else 1e3 * float(np.percentile(times, 95)),
                         "solves/s": rate,
                         "median vs baseline": "-" if times is None else float(np.median(base) / np.median(times)),
                         "solves/s vs baseline": rate / (n / base.sum())})
    if not has_mink:
        rows.append({"arm": "-", "solver": "mink: not installed (pip install 'mjkin[bench]')"})
    return {f"{n} random reachable 6-D poses from the home keyframe, success at {tol:g} m / {rot_tol:g} rad "
            "(speed vs baseline > 1: mjkin faster)": rows}


def bench_render(n: int = 60, width: int = 640, height: int = 480, seed: int = 0) -> Tables:
    """Frames/s of mjkin's render pipeline (markers, trail) beside a bare ``mujoco.Renderer`` loop."""
    from .render import Overlay, default_camera, frames

    rows: list[Row] = []
    for name in ("arm7", "primate"):
        tree = load(name)
        qs = tree.random_q(np.random.default_rng(seed), n)
        site = tree.names("site")[0]
        cam = default_camera(tree, qs)

        def pipeline(overlay: Overlay | None) -> float:
            start = time.perf_counter()
            frames(tree, qs, width, height, camera=cam, overlay=overlay)  # noqa: B023
            return n / (time.perf_counter() - start)

        plain = pipeline(None)
        marked = pipeline(Overlay(points=np.full((3, 3), 0.2), trail=site))
        model, data = tree.model, mujoco.MjData(tree.model)
        start = time.perf_counter()
        with mujoco.Renderer(model, height, width) as r:
            for q in qs:
                data.qpos[:] = q
                mujoco.mj_forward(model, data)
                r.update_scene(data, cam)
                r.render()
        bare = n / (time.perf_counter() - start)
        rows.append({"model": name, "size": f"{width}x{height}", "bare Renderer frames/s": bare,
                     "mjkin frames/s": plain, "overhead %": 100 * (bare / plain - 1),
                     "with markers + trail frames/s": marked})
    return {"offscreen rendering: mjkin's pipeline vs a bare mujoco.Renderer loop (same frames and camera; "
            "markers and trail add drawing work of their own)": rows}


def bench_env(steps: int = 2000, seed: int = 0) -> Tables:
    """Environment steps per second (random actions) beside gymnasium's MuJoCo ``Reacher-v5``."""
    import gymnasium as gym

    import mjkin.envs  # noqa: F401  (registers the ids)

    def rate(env: gym.Env) -> float:
        env.reset(seed=seed)
        env.action_space.seed(seed)
        start = time.perf_counter()
        for _ in range(steps):
            _, _, term, trunc, _ = env.step(env.action_space.sample())
            if term or trunc:
                env.reset()
        elapsed = time.perf_counter() - start
        env.close()
        return steps / elapsed

    try:
        reacher = rate(gym.make("Reacher-v5"))
    except Exception as e:  # gymnasium's MuJoCo envs missing: report, do not fail
        reacher = float("nan")
        print(f"Reacher-v5 unavailable: {e}")
    rows: list[Row] = [{"env": "Reacher-v5 (gymnasium)", "action": "torque", "steps/s": reacher, "ratio": 1.0}]
    for env_id in ("mjkin/Reach-v0", "mjkin/PlanarReach-v0"):
        for action in ("joint", "cartesian"):
            r = rate(gym.make(env_id, action_type=action))
            rows.append({"env": env_id, "action": action, "steps/s": r, "ratio": r / reacher})
    return {f"environment steps per second, {steps} random steps (ratio vs Reacher-v5)": rows}


BENCHMARKS: dict[str, Callable[[], Tables]] = {"fk": bench_fk, "ik": bench_ik, "seeds": bench_seeds,
                                               "render": bench_render, "env": bench_env}


def bench_play() -> Tables:
    """Frame rate and drag-to-new-frame latency of ``mjkin play`` (see :mod:`mjkin.play.bench`)."""
    from .play.bench import measure

    return measure()


BENCHMARKS["play"] = bench_play
