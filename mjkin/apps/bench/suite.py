"""The benchmarks' shared parts (reports, timing, the shared models) and the FK, seeds, render and env benchmarks.

Same inputs, same work, the same process; ratios > 1 mean mjkin is faster. Nothing
here is asserted by tests (timings on shared machines are noisy): each benchmark
returns a :class:`Report` whose rows the CLI prints and, with ``--json``, writes.
"""

from __future__ import annotations

import argparse
import json
import os
import time
from collections.abc import Callable, Sequence
from pathlib import Path

import mujoco
import numpy as np

from ...errors import InputError
from ...kinematics.chain import ancestors, chain_of, pose_numba, pose_of
from ...kinematics.tree import Tree, load
from ...runtime.files import check_writable, write_text
from ...runtime.parallel import threads
from ...runtime.progress import track
from . import ALL, FK_MODELS, add_arguments
from .report import GC_NOTE, Report, Row, format_table, gc_paused, interleaved, seconds_per_call, shared_model

FK_BUNDLED = ("arm7", "primate", "panda")


def fk_models(names: Sequence[str] | None = None) -> list[tuple[str, Tree]]:
    """Models of the FK benchmark: bundled ones by name, shared real robots when present, or MJCF paths."""
    out = []
    for name in names or FK_MODELS:
        src = FK_MODELS.get(name, name)
        if src in FK_BUNDLED or Path(src).is_file():
            out.append((name if name in FK_MODELS else Path(name).stem, load(src)))
            continue
        tree = shared_model(src) if name in FK_MODELS else None
        if tree is not None:
            out.append((name, tree))
        elif names:
            raise InputError(f"--models takes {', '.join(FK_MODELS)} or MJCF files; {name!r} is not available")
    return out


def mujoco_user_loop(model: mujoco.MjModel, Q: np.ndarray) -> Callable[[], tuple[np.ndarray, np.ndarray]]:
    """The baseline: a user's Python loop of ``mj_kinematics`` reading every body pose as MuJoCo gives it.

    Each call allocates its outputs and returns ``xpos (N, nbody, 3)`` and ``xquat (N, nbody, 4)``:
    two contiguous row copies per configuration, the cheapest way to hold all the poses (what a user
    timing ``tree.fk`` against MuJoCo writes; :func:`mujoco_fk_loop` builds ``tree.fk``'s 4x4s instead).
    """
    data = mujoco.MjData(model)

    def run() -> tuple[np.ndarray, np.ndarray]:
        pos, quat = np.empty((len(Q), model.nbody, 3)), np.empty((len(Q), model.nbody, 4))
        for i, q in enumerate(Q):
            data.qpos[:] = q
            mujoco.mj_kinematics(model, data)
            pos[i] = data.xpos
            quat[i] = data.xquat
        return pos, quat

    return run


def mujoco_fk_loop(model: mujoco.MjModel, Q: np.ndarray) -> Callable[[], np.ndarray]:
    """A Python loop of ``mj_kinematics`` copying every body pose into ``tree.fk``'s ``(N, nbody, 4, 4)``.

    The output array is made once, outside the timed calls, and each pose goes in as two strided
    copies (rotation block, origin column): slower per configuration than :func:`mujoco_user_loop`.
    """
    data = mujoco.MjData(model)
    out = np.empty((len(Q), model.nbody, 4, 4))
    out[..., 3, :] = [0.0, 0.0, 0.0, 1.0]

    def run() -> np.ndarray:
        for i, q in enumerate(Q):
            data.qpos[:] = q
            mujoco.mj_kinematics(model, data)
            out[i, :, :3, :3] = data.xmat.reshape(-1, 3, 3)
            out[i, :, :3, 3] = data.xpos
        return out

    return run


def mujoco_site_pose(model: mujoco.MjModel, q: np.ndarray, site: int) -> Callable[[], np.ndarray]:
    """The baseline of one pose: ``mj_kinematics`` and the site's pose read into a 4x4 from Python."""
    data = mujoco.MjData(model)

    def run() -> np.ndarray:
        data.qpos[:] = q
        mujoco.mj_kinematics(model, data)
        T = np.eye(4)
        T[:3, :3] = data.site_xmat[site].reshape(3, 3)
        T[:3, 3] = data.site_xpos[site]
        return T

    return run


def pinocchio_frame_pose(tree: Tree, frame: str, q: np.ndarray) -> Callable[[], object]:
    """Pinocchio's one pose, as its users call it: ``forwardKinematics`` then ``updateFramePlacement``.

    The model comes from the URDF of the chain to the site (:func:`mjkin.peers.pinocchio_model`,
    checked equal to ``tree.pose``); the call returns pinocchio's own ``SE3`` of the frame.
    Raises :class:`mjkin.peers.Unavailable` when pinocchio is missing or cannot take the chain.
    """
    from . import peers

    pin = peers.require("pinocchio", "pin")
    model, data, fid = peers.pinocchio_model(tree, frame, "site")

    def run() -> object:
        pin.forwardKinematics(model, data, q)
        return pin.updateFramePlacement(model, data, fid)

    return run


def pose_without_c(tree: Tree, frame: str, q: np.ndarray) -> Callable[[], object]:
    """``tree.pose(q, frame, "site")``'s compiled call as it runs without the C module ``_posecall``.

    :func:`mjkin.kinematics.chain.pose_numba` on the frame's chain: numba's compiled entry
    called from Python, what a package installed without a C compiler runs. Against the
    ``tree.pose`` row it shows what the C call path saves.
    """
    body, local = tree.frame_body(frame, "site")
    chain = chain_of(tree, ancestors(tree, body), local)
    return lambda: pose_numba(chain, q)


def single_pose_rows(name: str, tree: Tree, q: np.ndarray, min_time: float, skipped: list[Row]) -> list[Row]:
    """One site pose for one q: mjkin's ``tree.pose``, MuJoCo and pinocchio, each a loop of single calls.

    ``ratio``: the library's time over mjkin's (> 1: mjkin faster). A peer that cannot run adds
    its reason to ``skipped``.
    """
    from .peers import Unavailable

    site = tree.model.nsite - 1
    frame = tree.names("site")[site]
    calls: list[tuple[str, str, Callable[[], object]]] = [
        ("mjkin", "tree.pose(q, site)", lambda: tree.pose(q, frame, "site")),
        ("mjkin without its C call", "pose_numba(chain, q): numba's entry from Python", pose_without_c(tree, frame, q)),
        ("mujoco", "mj_kinematics + site_xpos/site_xmat into a 4x4", mujoco_site_pose(tree.model, q, site))]
    try:
        calls.append(("pinocchio", "forwardKinematics + updateFramePlacement", pinocchio_frame_pose(tree, frame, q)))
    except Unavailable as e:
        skipped.append({"model": name, "library": "pinocchio", "reason": str(e)})
    rows: list[Row] = []
    for library, call, fn in calls:
        us = 1e6 * seconds_per_call(fn, min_time)
        rows.append({"model": name, "site": frame, "library": library, "call": call, "us": us,
                     "ratio": us / float(rows[0]["us"]) if rows else 1.0})  # type: ignore[arg-type]
    return rows


def bench_fk(models: Sequence[str] | None = None, sizes: Sequence[int] = (1, 100, 10_000), seed: int = 0,
             min_time: float = 0.2) -> Report:
    """All body poses for a batch (``tree.fk``) vs MuJoCo; one site pose for one q vs MuJoCo and pinocchio."""
    if not sizes or min(sizes) < 1:
        raise InputError(f"--batch sizes must be at least 1, got {list(sizes)}")
    batched: list[Row] = []
    single: list[Row] = []
    skipped: list[Row] = []
    rng = np.random.default_rng(seed)
    cases = [(n, t, B) for n, t in fk_models(models) for B in sizes]
    for name, tree, B in track(cases, "bench fk"):
        Q = tree.random_q(rng, B)
        t_mjkin, t_mj, t_4x4 = interleaved([lambda: tree.fk(Q), mujoco_user_loop(tree.model, Q),  # noqa: B023
                                            mujoco_fk_loop(tree.model, Q)], min_time)
        batched.append({"model": name, "nbody": tree.nbody, "batch": B, "mjkin_us_per_q": 1e6 * t_mjkin / B,
                        "mujoco_us_per_q": 1e6 * t_mj / B, "mjkin_q_per_s": B / t_mjkin,
                        "mujoco_q_per_s": B / t_mj, "ratio": t_mj / t_mjkin, "ratio_4x4_loop": t_4x4 / t_mjkin})
    for name, tree in fk_models(models):
        if tree.model.nsite:
            single += single_pose_rows(name, tree, tree.random_q(rng), min_time, skipped)
    tables = {"batched FK, every body pose: tree.fk(Q) (4x4s) vs a Python loop of mj_kinematics reading xpos and "
              "xquat into arrays (ratio > 1: mjkin faster; ratio_4x4_loop: vs the loop copying into tree.fk's "
              "4x4s)": batched,
              "one site pose for one q, each library's call in a loop (ratio: its time / mjkin's; > 1: mjkin "
              "faster)": single}
    if skipped:
        tables["pinocchio without a row (the reason)"] = skipped
    return Report(tables, {"sizes": list(sizes), "seed": seed,
                           "timing": f"median of 5 runs of >= {min_time} s of calls each (batched FK: mjkin's "
                                     "and the loops' runs taking turns)", "gc": GC_NOTE,
                           "threads": f"tree.fk of a batch: {threads()} (MJKIN_NUM_THREADS)",
                           "tree.pose": "through the C module _posecall" if pose_of is not pose_numba
                                        else "through numba's entry (the C module _posecall was not built)",
                           "pinocchio": "the chain to the site as a URDF, its FK checked equal to tree.pose to 1e-12 "
                                        "before timing; returns its SE3 (not copied into a 4x4)"},
                  {"skipped": skipped})


# -------------------------------------------------------------------------------------------- seeds


def bench_seeds(out: Path | None = None) -> Report:
    """The seeds' examples (three-link arm, CCD, two-link closed form): tables; PNG figures in ``out``."""
    from ..demo import seeds

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
            row[f"n={n} ratio"] = f"{err[i] / err[i - 1]:.2g}" if i and err[i - 1] > 0 else ""  # none once exact
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
    return Report(tables)


# ------------------------------------------------------------------------------------------- render


def bench_render(frames_n: int = 60, width: int = 640, height: int = 480, seed: int = 0,
                 repeat: int = 3) -> Report:
    """Frames/s of mjkin's render pipeline beside a bare ``mujoco.Renderer`` loop doing the same MuJoCo work.

    Both make a renderer, set each q, run ``mj_kinematics`` + ``mj_comPos`` + ``mj_camlight``
    (what drawing needs), update the scene with the same camera and keep every frame.
    """
    from ...render import Overlay, default_camera, frames, headless_gl

    if frames_n < 1 or width < 1 or height < 1:
        raise InputError(f"--frames, --width and --height must be positive, got {frames_n}, {width}, {height}")
    rows: list[Row] = []
    for name in track(("arm7", "primate"), "bench render"):
        tree = load(name)
        qs = tree.random_q(np.random.default_rng(seed), frames_n)
        site = tree.names("site")[0]
        cam = default_camera(tree, qs)

        def pipeline(overlay: Overlay | None, qs: np.ndarray = qs) -> float:
            start = time.perf_counter()
            list(frames(tree, qs, width, height, camera=cam, overlay=overlay))  # noqa: B023 (frames are lazy)
            return len(qs) / (time.perf_counter() - start)

        def bare_loop(qs: np.ndarray = qs) -> float:
            model, data = tree.model, mujoco.MjData(tree.model)  # noqa: B023
            model.vis.global_.offwidth = max(width, model.vis.global_.offwidth)
            model.vis.global_.offheight = max(height, model.vis.global_.offheight)
            headless_gl()
            start = time.perf_counter()
            out = np.empty((len(qs), height, width, 3), dtype=np.uint8)
            with mujoco.Renderer(model, height, width) as r:
                for t, q in enumerate(qs):
                    data.qpos[:] = q
                    mujoco.mj_kinematics(model, data)
                    mujoco.mj_comPos(model, data)
                    mujoco.mj_camlight(model, data)
                    r.update_scene(data, cam)  # noqa: B023
                    out[t] = r.render()
            return len(qs) / (time.perf_counter() - start)

        pipeline(None, qs[:1])  # first contexts and shaders, untimed
        bare_loop(qs[:1])
        bare = plain = 0.0
        for _ in range(repeat):  # interleaved, best of each: software GL on a shared machine is noisy
            bare, plain = max(bare, bare_loop()), max(plain, pipeline(None))
        marked = pipeline(Overlay(points=np.full((3, 3), 0.2), trail=site))
        rows.append({"model": name, "size": f"{width}x{height}", "mujoco_frames_per_s": bare,
                     "mjkin_frames_per_s": plain, "ratio": plain / bare, "with_markers_trail_frames_per_s": marked})
    return Report({"offscreen rendering: mjkin.render.frames vs a bare mujoco.Renderer loop (same frames, camera "
                   "and MuJoCo calls; ratio > 1: mjkin faster; markers and trail add drawing of their own)": rows},
                  {"frames": frames_n, "width": width, "height": height, "seed": seed,
                   "timing": f"best of {repeat} interleaved runs each", "MUJOCO_GL": os.environ.get("MUJOCO_GL")})


# ---------------------------------------------------------------------------------------------- env


def env_steps_per_s(env: object, steps: int, seed: int) -> float:
    """Steps/s of ``env`` (single or vector) under random actions, resetting a single env when it ends.

    The actions are drawn before the clock starts, and a few untimed steps first
    load (or compile) whatever the env's first step needs.
    """
    import gymnasium as gym

    space = env.action_space  # type: ignore[attr-defined]
    space.seed(seed)
    actions = [space.sample() for _ in range(steps)]
    vector = isinstance(env, gym.vector.VectorEnv)
    env.reset(seed=seed)  # type: ignore[attr-defined]
    for a in actions[:3]:
        env.step(a)  # type: ignore[attr-defined]
    env.reset(seed=seed)  # type: ignore[attr-defined]
    with gc_paused():
        start = time.perf_counter()
        for a in actions:
            _, _, term, trunc, _ = env.step(a)  # type: ignore[attr-defined]
            if not vector and (term or trunc):
                env.reset()  # type: ignore[attr-defined]
        elapsed = time.perf_counter() - start
    env.close()  # type: ignore[attr-defined]
    return steps * (env.num_envs if vector else 1) / elapsed  # type: ignore[attr-defined]


def bench_env(steps: int = 2000, num_envs: int = 256, seed: int = 0) -> Report:
    """Env steps/s (random actions, no rendering) of mjkin's envs beside gymnasium's ``Reacher-v5``, one process.

    With the native vector env (``vectorization_mode="vector_entry_point"``), also the
    total steps/s of ``num_envs`` mjkin envs (joint and cartesian actions) against one ``Reacher-v5``.
    """
    import gymnasium as gym

    import mjkin.envs  # noqa: F401  (registers the ids)

    if steps < 1 or num_envs < 1:
        raise InputError(f"--steps and --num-envs must be at least 1, got {steps}, {num_envs}")
    try:
        reacher = env_steps_per_s(gym.make("Reacher-v5"), steps, seed)
    except Exception as e:  # gymnasium's MuJoCo envs missing: report, do not fail
        reacher, note = float("nan"), f"Reacher-v5 unavailable: {' '.join(str(e).split())}"
    else:
        note = "measured in this process"
    rows: list[Row] = [{"env": "Reacher-v5 (gymnasium)", "action": "torque", "envs": 1, "steps_per_s": reacher,
                        "ratio": 1.0}]
    for env_id in ("mjkin/Reach-v0", "mjkin/PlanarReach-v0"):
        for action in ("joint", "cartesian"):
            r = env_steps_per_s(gym.make(env_id, action_type=action), steps, seed)
            rows.append({"env": env_id, "action": action, "envs": 1, "steps_per_s": r, "ratio": r / reacher})
    for action in ("joint", "cartesian"):  # cartesian: one batched IK call for all envs per step
        vec = gym.make_vec("mjkin/Reach-v0", num_envs=num_envs, vectorization_mode="vector_entry_point",
                           action_type=action)
        r = env_steps_per_s(vec, max(1, steps // 10), seed)
        rows.append({"env": "mjkin/Reach-v0 (make_vec, vector_entry_point)", "action": action,
                     "envs": num_envs, "steps_per_s": r, "ratio": r / reacher})
    vec_note = f"{max(1, steps // 10)} vector steps of {num_envs} envs, total env steps/s"
    return Report({f"environment steps per second, {steps} random steps, no rendering (ratio vs one Reacher-v5 "
                   "in this process)": rows},
                  {"steps": steps, "num_envs": num_envs, "seed": seed, "Reacher-v5": note, "vector": vec_note,
                   "gc": GC_NOTE})


def check_paths(args: argparse.Namespace) -> None:
    """Check the files and folders the benchmark ``args.which`` writes (``--plot``, ``--out``), before any work.

    ``--out`` may be an existing folder or a new one inside an existing folder (created by the run), never a file.
    """
    if getattr(args, "plot", None):
        check_writable(args.plot, (".png",), "--plot")
    if args.which == "seeds":
        out = Path(args.out)
        if out.exists() and not out.is_dir():
            raise InputError(f"--out {args.out!r} is a file; give a folder (existing, or new inside an existing one)")
        check_writable(out / "seed1_reach_frames.png" if out.is_dir() else out, what="--out")


def run(args: argparse.Namespace) -> Report:
    """Run the benchmark ``args.which`` with its options (:func:`main` checks their paths first)."""
    if args.which == "fk":
        return bench_fk(args.models, args.batch, args.seed)
    if args.which == "ik":
        from .ik import bench_ik, bench_trac_ik

        if args.protocol == "trac-ik":
            return bench_trac_ik(args.models, args.targets or 10_000, args.tol or 1e-5, args.rot_tol or 1e-5,
                                 args.time_limit, args.seed)
        return bench_ik(args.models, args.targets or 1000, args.tol or 1e-4, args.rot_tol or 1e-3, args.iters,
                        args.seed, time_limit=args.time_limit)
    if args.which == "realtime":
        from .realtime import bench_realtime

        return bench_realtime(args.dofs, args.frames, args.seed, args.plot)
    if args.which == "constraints":
        from .constraints import bench_constraints

        return bench_constraints(args.targets, args.margin, args.seed)
    if args.which == "retarget":
        from .retarget import bench_retarget

        return bench_retarget(args.repeat, args.clips, args.models)
    if args.which == "solutions":
        from .solutions import bench_solutions

        return bench_solutions(args.poses, args.checks, args.seed)
    if args.which == "render":
        return bench_render(args.frames, args.width, args.height, args.seed)
    if args.which == "env":
        return bench_env(args.steps, args.num_envs, args.seed)
    if args.which == "play":
        from .play import measure

        return Report(measure())
    if args.which == "startup":
        from .retarget import CLIPS, mocap_dir
        from .startup import bench_startup

        folder = mocap_dir()
        return bench_startup(tuple(args.entries), None if folder is None else folder / CLIPS[0])
    return bench_seeds(Path(args.out))


def main(args: argparse.Namespace) -> int:
    """``mjkin bench ...``: run, print every table, write ``--json`` atomically (checked before any work)."""
    if args.json:
        check_writable(args.json, (".json",), "--json")
    if args.which == "all":
        defaults = argparse.ArgumentParser()
        add_arguments(defaults)
        runs = [defaults.parse_args([name, "--seed", str(args.seed)]) for name in ALL]
    else:
        runs = [args]
    for one in runs:
        check_paths(one)  # all of them before the first benchmark starts
    out = {}
    for one in runs:
        report = run(one)
        for title, rows in report.tables.items():
            print(f"== mjkin bench {one.which}: {title}")
            print(format_table(rows))
            print()
        if report.settings:
            print("settings: " + "; ".join(f"{k}: {v}" for k, v in report.settings.items()))
        for note in report.notes:
            print(note)
        out[one.which] = report.as_json()
    if args.json:
        data = out if args.which == "all" else out[args.which]
        write_text(args.json, json.dumps(data, indent=1, default=_plain) + "\n")
        print(f"wrote {args.json}")
    return 0


def _plain(v: object) -> object:
    """Return numpy scalars and arrays as plain JSON values."""
    if isinstance(v, np.generic):
        return v.item()
    if isinstance(v, np.ndarray):
        return v.tolist()
    raise TypeError(f"not JSON serialisable: {type(v).__name__}")
