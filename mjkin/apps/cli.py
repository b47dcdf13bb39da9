"""The ``mjkin`` command: inspect models, compute FK and IK, render, benchmark.

Every argument and output path is checked before any IK or rendering starts,
and every user mistake ends as one line on stderr and exit status 2, never a
traceback.
"""

from __future__ import annotations

import argparse
import itertools
import os
import re
import sys
from collections.abc import Callable, Iterable, Sequence
from importlib import metadata
from typing import TYPE_CHECKING, Any

import numpy as np

from .. import motion, spatial
from ..errors import InputError, MjkinError, MjkinIOError
from ..goals import Goal, Orientation, Position
from ..ik import METHODS, solve
from ..ik.method import MAX_RESTARTS
from ..ik.problem import method_of
from ..kinematics.qspace import BALL, FREE, HINGE, JOINT_NAMES
from ..kinematics.tree import Tree, bundled_models, load, source_of
from ..runtime import progress, tier
from ..runtime.files import check_writable, strict_json
from . import bench, placement_cli, retarget_cli
from .argtypes import Once, nonnegative_int, positive_float, positive_int, time_limit

if TYPE_CHECKING:
    from numpy.typing import NDArray

    from ..render import Overlay

Command = Callable[[argparse.Namespace], int]

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg")
MAX_SIDE = 8192  # largest --width/--height: MuJoCo's offscreen buffer is raised to it, GL allows 16384 at least
SIGPIPE_EXIT = 128 + 13  # what a shell reports for a tool that SIGPIPE ended (``set -o pipefail`` sees it)
UNIT_TOL = 1e-3  # a command-line quaternion whose norm is further from 1 (not rounding: a mistake) gets a warning
VECTOR_OPTIONS = ("--pos", "--quat", "--q", "--q0", "--center", "--normal", "--start", "--end", "--points", "--region")
NEGATIVE_NUMBER = re.compile(r"-\.?\d")  # how a value such as "-20,5,0" starts (argparse takes it for an option)
TIMEOUT = 10.0  # seconds per IK target of ``mjkin ik`` and ``mjkin trajectory`` unless --timeout says otherwise


class Parser(argparse.ArgumentParser):
    """An argument parser whose errors are one line (no usage dump) with exit status 2.

    A single-valued option given twice is an error (:class:`~mjkin.argtypes.Once`), not the last one silently.
    """

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self.register("action", None, Once)
        self.register("action", "store", Once)

    def parse_known_args(self, args: Sequence[str] | None = None,  # type: ignore[override]
                         namespace: argparse.Namespace | None = None) -> tuple[argparse.Namespace, list[str]]:
        """argparse's, without the bookkeeping of :class:`~mjkin.argtypes.Once` in the result."""
        parsed, rest = super().parse_known_args(args, namespace)
        parsed.__dict__.pop("_given_once", None)
        return parsed, rest

    def error(self, message: str) -> None:  # type: ignore[override]
        """Print ``mjkin <command>: error: message`` and exit 2."""
        self.exit(2, f"{self.prog}: error: {message}\n")


def keyframes(tree: Tree) -> dict[str, np.ndarray]:
    """The model's named keyframes (``<key name=...>``): name → qpos."""
    m = tree.model
    return {m.key(i).name: m.key_qpos[i].copy() for i in range(m.nkey) if m.key(i).name}


def warn(text: str) -> None:
    """Print ``mjkin: warning: text`` on stderr (one line)."""
    print(f"mjkin: warning: {text}", file=sys.stderr)


def parse_q(text: str, tree: Tree, degrees: bool = False, seed: int | None = None, what: str = "--q") -> np.ndarray:
    """A configuration from numbers (``"0.1 0.2 ..."`` or ``"0.1,0.2,..."``), a keyframe name, or ``random``.

    ``random`` draws inside the joint limits (seeded by ``seed``) and keeps a free
    root joint at its ``qpos0`` pose (a random world pose would sink the figure
    into the floor or fly it off); ``degrees`` converts the hinge values of
    numbers. Quaternions that are not unit are normalised, with a warning.
    """
    word = text.strip()
    keys = keyframes(tree)
    if word in keys:
        return keys[word]
    if word == "random":
        q = tree.random_q(np.random.default_rng(seed))
        free = tree.layout.free_q.ravel()
        q[free] = tree.qpos0[free]
        return q
    try:
        q = np.array([float(v) for v in text.replace(",", " ").split()])
    except ValueError:
        names = f", or a keyframe name ({', '.join(keys)})" if keys else " (the model has no named keyframes)"
        raise InputError(f"{what} must be {tree.nq} numbers separated by spaces or commas, 'random'{names}; "
                         f"got {text!r}") from None
    q = tree.check_q(q, what).copy()
    if degrees:
        hinge = tree.jnt_qadr[tree.jnt_type == HINGE]
        q[hinge] = np.radians(q[hinge])
    return unit_quaternions(tree, q, what)


def unit_quaternions(tree: Tree, q: np.ndarray, what: str) -> np.ndarray:
    """``q (nq,)`` with its ball and free-joint quaternions made unit, in place; one warning names those changed."""
    said = []
    names = tree.names("joint")
    for j in np.flatnonzero(np.isin(tree.jnt_type, (BALL, FREE))):
        a = int(tree.jnt_qadr[j]) + (3 if tree.jnt_type[j] == FREE else 0)
        norm = _normalise(q[a:a + 4])
        if norm is not None:
            said.append(f"joint {names[j] or j} (norm {norm:.6g})")
    if said:
        warn(f"{what}: normalised the quaternion{'s' * (len(said) > 1)} of {', '.join(said)} to unit length")
    return q


def _normalise(quat: np.ndarray) -> float | None:
    """Make ``quat (4,)`` unit in place when its norm is off by more than :data:`UNIT_TOL`; returns that norm, or None.

    A zero quaternion is left for the caller's check to refuse.
    """
    norm = float(np.linalg.norm(quat))
    if norm == 0.0 or abs(norm - 1.0) <= UNIT_TOL:
        return None
    quat /= norm
    return norm


def display_q(tree: Tree, q: np.ndarray) -> np.ndarray:
    """``q (nq,)`` for printing: unlimited hinges wrapped into (-pi, pi] (the same pose)."""
    out = np.array(q, dtype=np.float64)
    hinge = tree.jnt_qadr[(tree.jnt_type == HINGE) & ~tree.jnt_limited.astype(bool)]
    out[hinge] -= 2 * np.pi * np.ceil((out[hinge] - np.pi) / (2 * np.pi))
    return out


def fixed(values: Iterable[float], sign: bool = False) -> str:
    """Numbers with 6 decimals, space-separated; one that rounds to zero prints as 0.000000, never -0.000000.

    ``sign`` leaves a space where a minus would go, so columns line up.
    """
    return " ".join(f"{round(float(v), 6) + 0.0:{' ' if sign else ''}.6f}" for v in values)


def within_limits(args: argparse.Namespace, tree: Tree, q: np.ndarray, what: str) -> np.ndarray:
    """``q (nq,)`` or ``(T, nq)`` clipped into the joint limits with ``--clip``, else as given (warning if outside)."""
    problem = motion.outside_limits(tree, q)
    if problem and args.clip:
        return tree.clip(q)
    if problem:
        warn(f"{problem}; {what} (--clip clips into the limits)")
    return q


def cmd_info(args: argparse.Namespace) -> int:
    """Print the tree: bodies with their joints, and sites."""
    tree = load(args.model)
    print(describe(tree))
    return 0


def describe(tree: Tree) -> str:
    """Human-readable outline of a tree."""
    m = tree.model
    bodies, joints, sites = tree.names("body"), tree.names("joint"), tree.names("site")
    lines = [f"model {tree.name or '(unnamed)'}: nq={tree.nq} nv={tree.nv} "
             f"bodies={tree.nbody - 1} (+ world) joints={tree.njnt} sites={m.nsite}"]
    depth = np.zeros(tree.nbody, dtype=int)
    for b in range(1, tree.nbody):
        depth[b] = depth[tree.body_parent[b]] + 1
        lines.append(f"{'  ' * depth[b]}body {bodies[b] or b}")
        for j in np.flatnonzero(tree.jnt_body == b):
            kind = JOINT_NAMES[int(tree.jnt_type[j])]
            text = f"{'  ' * depth[b]}  joint {joints[j] or j}: {kind}"
            if kind in ("hinge", "slide"):
                text += f" axis={np.round(tree.jnt_axis[j], 4).tolist()}"
            if tree.jnt_limited[j]:
                lo, hi = tree.jnt_range[j]
                text += f" range=[{lo:.4g}, {hi:.4g}]" if kind != "ball" else f" cone={hi:.4g} rad"
            lines.append(text)
        for s in np.flatnonzero(tree.site_body == b):
            lines.append(f"{'  ' * depth[b]}  site {sites[s] or s} pos={np.round(tree.site_pos[s], 4).tolist()}")
    return "\n".join(lines)


def cmd_fk(args: argparse.Namespace) -> int:
    """Print world poses of bodies and sites (or one frame) for a configuration."""
    tree = load(args.model)
    q = tree.qpos0.copy() if args.q is None else parse_q(args.q, tree, args.deg, args.seed)
    q = within_limits(args, tree, q, "FK of --q as given")
    kinds = [tree.frame(args.frame)] if args.frame else (
        [("body", i) for i in range(1, tree.nbody)] + [("site", i) for i in range(tree.model.nsite)])
    frames = tree.kinematics(q)
    out = []
    for kind, i in kinds:
        T = frames.pose(kind, i)
        out.append({"kind": kind, "name": tree.names(kind)[i], "id": int(i), "pos": T[:3, 3].tolist(),
                    "quat": spatial.mat_to_quat(T[:3, :3]).tolist()})
    if args.json:
        print(strict_json({"q": display_q(tree, q).tolist(), "frames": out}, indent=1))
    else:
        for f in out:
            name = f["name"] or str(f["id"])  # an unnamed body or site: by its id
            print(f"{f['kind']:4} {name:24} pos {fixed(f['pos'], sign=True)}   quat {fixed(f['quat'], sign=True)}")
    return 0


def cmd_ik(args: argparse.Namespace) -> int:
    """Solve IK for one frame: a position, and an orientation when ``--quat`` is given; print q and errors."""
    tree = load(args.model)
    body = tree.frame_body(args.frame)[0]  # a clear error for an unknown name
    if not len(tree.body_dofs[body]):
        why = "the model has no joints" if tree.nv == 0 else "choose a site or body below a joint"
        raise InputError(f"no joint moves {args.frame!r}: {why}")
    joints = None if args.joints is None else [j.strip() for j in args.joints.split(",") if j.strip()]
    for name in joints or []:
        tree.id(name, "joint")  # unknown names: one line listing the model's joints
    for name in (args.root, args.base):
        if name is not None:
            tree.id(name, "body")
    q0 = tree.qpos0.copy() if args.q0 is None else parse_q(args.q0, tree, args.deg, args.seed, "--q0")
    pos = _vec(args.pos, "--pos")
    tree.check_near(pos, f"--pos {args.pos}")
    goals: list[Goal] = [Position(args.frame, pos)]
    if args.quat is not None:
        quat = _numbers(args.quat, 4, "--quat", "w,x,y,z")
        norm = _normalise(quat)
        if norm is not None:
            warn(f"--quat: normalised {args.quat!r} (norm {norm:.6g}) to unit length")
        goals.append(Orientation(args.frame, quat))
    res = solve(tree, goals, q0=q0, method=args.method, tol=args.tol, rot_tol=args.rot_tol,
                seed=0 if args.seed is None else args.seed, root=args.root, joints=joints, base=args.base,
                **search_limits(args))
    q = display_q(tree, res.q)
    report = {"q": q.tolist(), "success": bool(res.success), "error": res.error.tolist(),
              "iterations": int(res.iterations), "status": str(res.status), "restarts": int(res.restarts),
              "method": res.method, "reason": str(res.reason)}
    if args.json:
        print(strict_json(report))
    else:
        why = {"out_of_reach": "; proven out of reach", "limits": "; proven blocked by the joint limits",
               "not_found": "; not proven unreachable"}.get(str(res.reason), "")
        print(f"{'success' if res.success else 'failed'}: {res.status} after {report['iterations']} iterations, "
              f"{report['restarts']} restarts ({res.method}){why}")
        print(f"position error {res.error[0]:.3g} m, rotation error {res.error[1]:.3g} rad"
              + ("" if args.quat is not None else " (not a goal)"))
        print("q " + fixed(q))
        print(by_joint(tree, q))
    return 0


def search_limits(args: argparse.Namespace) -> dict[str, Any]:
    """``timeout`` (s per target, ``inf``: none) and ``restarts`` of a command's solves: ``--timeout``, ``--restarts``.

    Without ``--restarts``, the method's own count without a time limit (24 for auto): the limit
    caps a search, it does not make auto restart until the time runs out, as the library's does.
    """
    restarts = args.restarts
    if restarts is None:
        restarts = method_of(getattr(args, "method", "auto"), {}).restart_count(False)
    return {"timeout": args.timeout, "restarts": restarts}


def by_joint(tree: Tree, q: np.ndarray) -> str:
    """``q (nq,)`` one joint a line: its name (or ``joint <id>``), type and values (a free joint's 7, a ball's 4)."""
    names = tree.names("joint")
    width = max((len(n) for n in names), default=0) + 2
    kinds = {0: "free", 1: "ball", 2: "slide", 3: "hinge"}
    lines = []
    for j, (adr, kind) in enumerate(zip(tree.jnt_qadr, tree.jnt_type, strict=True)):
        n = {0: 7, 1: 4}.get(int(kind), 1)
        lines.append(f"  {(names[j] or f'joint {j}'):<{width}}{kinds[int(kind)]:<6}{fixed(q[adr:adr + n], sign=True)}")
    return "\n".join(lines)


def _points(text: str) -> np.ndarray:
    try:
        pts = np.array([[float(v) for v in p.replace(",", " ").split()] for p in text.split(";") if p.strip()])
    except ValueError:
        raise InputError(f"points must look like 'x,y,z; x,y,z; ...', got {text!r}") from None
    if pts.ndim != 2 or pts.shape[1] != 3:
        raise InputError(f"points must be 3-D, 'x,y,z; x,y,z; ...', got {text!r}")
    return pts


def _vec(text: str, what: str) -> np.ndarray:
    return _numbers(text, 3, what, "x,y,z")


def _numbers(text: str, n: int, what: str, form: str) -> np.ndarray:
    try:
        v = np.array([float(x) for x in text.replace(",", " ").split()])
    except ValueError:
        v = np.zeros(0)
    if v.shape != (n,) or not np.isfinite(v).all():
        raise InputError(f"{what} must be {n} finite numbers {form}, got {text!r}")
    return v


def check_output(args: argparse.Namespace, count: int | None) -> int | None:
    """Check ``args.output``, the frame size and, once ``count`` frames are known, ``--frame``, before any work.

    Returns the frame index to write for an image output, None for a video (or while ``count`` is None).
    """
    from ..render import VIDEO_SUFFIXES, check_video_size

    path = check_writable(args.output, VIDEO_SUFFIXES + IMAGE_SUFFIXES)
    for side in ("width", "height"):
        if getattr(args, side) > MAX_SIDE:
            raise InputError(f"--{side} must be at most {MAX_SIDE} pixels, got {getattr(args, side)}")
    image = path.suffix.lower() in IMAGE_SUFFIXES
    if not image:
        check_video_size(path, args.width, args.height, "--width/--height")
        if args.frame is not None:
            raise InputError(f"--frame applies to {'/'.join(IMAGE_SUFFIXES)} output (a video has every frame), "
                             f"got --frame {args.frame} with {str(path)!r}")
    if count is None:
        return None
    if image:
        frame = -1 if args.frame is None else args.frame
        if not -count <= frame < count:
            raise InputError(f"--frame must be in [{-count}, {count - 1}] (-1 = the last) for {count} "
                             f"frame{'s' * (count > 1)}, got {frame}")
        return frame % count
    return None


def write_output(args: argparse.Namespace, tree: Tree, qs: np.ndarray, overlay: Overlay, frame: int | None) -> None:
    """Render ``qs (T, nq)`` to ``args.output``: every frame as a video, or only ``frame`` as an image.

    The camera frames every pose either way, so a still matches the same frame of the video.
    """
    from .. import render

    if frame is None:
        render.write_video(render.frames(tree, qs, args.width, args.height, overlay=overlay), args.output, args.fps)
    else:
        points = np.asarray(overlay.points, dtype=np.float64)
        with render.Painter(tree, args.width, args.height) as painter:
            trail = tree.pose(qs[:frame + 1], overlay.trail)[:, :3, 3] if overlay.trail else None
            image = painter.draw(qs[frame], painter.camera(None, qs, points),
                                 points[frame] if points.ndim == 3 else points, trail, overlay)
        render.write_image(image, args.output)
    wrote(args, len(qs), frame)


def write_images(args: argparse.Namespace, images: Iterable[NDArray[np.uint8]], count: int, frame: int | None) -> None:
    """Write ``count`` rendered frames ``(H, W, 3)`` to ``args.output`` as they come: a video, or ``frame`` only."""
    from .. import render

    if frame is None:
        render.write_video(images, args.output, args.fps)
    else:  # an iterator makes its frames in order: the ones before are drawn and dropped
        render.write_image(next(itertools.islice(images, frame, None)), args.output)
    wrote(args, count, frame)


def wrote(args: argparse.Namespace, count: int, frame: int | None) -> None:
    """Say what was written: ``wrote OUT (N frames | still | frame K of N, WxH)``."""
    what = (f"{count} frame{'s' * (count > 1)}" if frame is None else "still" if count == 1
            else f"frame {frame} of {count}")
    print(f"wrote {args.output} ({what}, {args.width}x{args.height})")


def cmd_demo(args: argparse.Namespace) -> int:
    """Render the showcase: the seeds' arm under three solvers, the 7-DoF arm's path, the primate's walk."""
    from .demo.showcase import scene_frames, showcase

    count = int(args.seconds * args.fps)
    if count < 2:
        raise InputError(f"--seconds x --fps must give at least 2 frames, got {count}")
    total = sum(scene_frames(args.scene, args.seconds, args.fps).values())
    frame = check_output(args, total)
    write_images(args, showcase(args.scene, args.seconds, args.fps, args.width, args.height), total, frame)
    return 0


WALK_FRAMES_PER_STEP = 24


def cmd_walk(args: argparse.Namespace) -> int:
    """Render the primate walking (heel to toe, arms swinging), seen from the side by a tracking camera."""
    from .. import render

    frame = check_output(args, args.steps * WALK_FRAMES_PER_STEP)  # a clear error before the work
    tree = load("primate")
    gait = motion.Gait(stride=args.stride, frames_per_step=WALK_FRAMES_PER_STEP)
    walk = motion.walk_cycle(tree, steps=args.steps, gait=gait, fps=args.fps)
    ok = walk.success if walk.success is not None else np.ones(len(walk.q), bool)
    print(f"walk: {args.steps} steps of {args.stride} m, {len(walk.q)} frames, feet on target in {ok.mean():.0%}")
    write_images(args, render.frames(tree, walk.q, args.width, args.height, view=render.WALK_VIEW, follow=True),
                 len(walk.q), frame)
    return 0


def cmd_trajectory(args: argparse.Namespace) -> int:
    """Solve a Cartesian path for a site frame by frame and save it as a script."""
    check_writable(args.output, (".json",), "--output")
    tree = load(args.model)
    tree.frame(args.frame)  # a clear error before any work
    q0 = tree.model.key_qpos[0].copy() if tree.model.nkey else tree.qpos0.copy()
    q0 = parse_q(args.q0, tree, args.deg, args.seed, "--q0") if args.q0 else q0
    here = tree.pose(q0, args.frame)[:3, 3]
    if args.path == "circle":
        center = _vec(args.center, "--center") if args.center else here
        pts = motion.circle(center, args.radius, args.frames, _vec(args.normal, "--normal"))
    elif args.path == "line":
        end = _vec(args.end, "--end") if args.end else None
        if end is None:
            raise InputError("--path line needs --end x,y,z (it starts at the site)")
        pts = motion.line(_vec(args.start, "--start") if args.start else here, end, args.frames)
    else:
        if not args.points:
            raise InputError("--path waypoints needs --points 'x,y,z; x,y,z; ...'")
        pts = motion.waypoints(np.vstack([here, _points(args.points)]), args.frames)
    traj = motion.follow(tree, args.frame, pts, q0=q0, fps=args.fps, **search_limits(args))
    traj.source = source_of(args.model)
    if args.retime:
        vmax, amax = _numbers(args.retime, 2, "--retime", "VMAX,AMAX")
        traj = motion.retime(traj, vmax, amax, tree=tree)
    traj.save(args.output)
    ok = traj.success if traj.success is not None else np.ones(len(pts), bool)
    jumps = traj.discontinuities(tree)
    late = traj.meta["follow"]["timed_out"]
    print(f"wrote {args.output}: {len(pts)} frames, {ok.mean():.0%} on target, largest joint step "
          f"{traj.jumps(tree).max():.3f}" + (f"; discontinuities at frames {jumps.tolist()}" if len(jumps) else "")
          + (f"; frames {late} ran out of the --timeout {args.timeout:g} s" if late else ""))
    return 0


def cmd_render(args: argparse.Namespace) -> int:
    """Render a configuration or a script to an image or a video."""
    from .. import render

    check_output(args, None)  # the path and sizes now; the frame index once the frame count is known
    tree = load(args.model)
    if args.script:
        traj = motion.Trajectory.load(args.script, tree)
        return render_script(args, tree, traj)
    q = parse_q(args.q, tree, args.deg, args.seed) if args.q else tree.qpos0.copy()
    q = within_limits(args, tree, q, "rendered as given")
    write_output(args, tree, q[None], render.Overlay(), check_output(args, 1))
    return 0


def render_script(args: argparse.Namespace, tree: Tree, traj: motion.Trajectory) -> int:
    """Render a script ``traj`` of ``tree`` (markers at its targets, the trail of its site) to ``args.output``."""
    from .. import render

    qs = within_limits(args, tree, traj.q, "rendered as recorded")
    frame = check_output(args, len(qs))
    overlay = render.Overlay(points=np.zeros((0, 3)) if traj.targets is None else traj.targets, trail=traj.frame)
    write_output(args, tree, qs, overlay, frame)
    return 0


def cmd_replay(args: argparse.Namespace) -> int:
    """Replay a recorded script (no IK) to a video, on the model it was recorded on (or ``--model``)."""
    check_output(args, None)
    traj = motion.Trajectory.load(args.script)
    if args.model:
        tree = load(args.model)
    else:
        source = traj.source or traj.model
        try:
            tree = load(source)
        except MjkinIOError:
            raise MjkinIOError(f"the model of {args.script!r} ({traj.model!r}, from {source!r}) is not found; "
                               f"pass --model PATH (a model with fingerprint {traj.fingerprint})") from None
    traj.check(tree, args.script)
    return render_script(args, tree, traj)


def cmd_workspace(args: argparse.Namespace) -> int:
    """Sample a frame's workspace by batched FK and plot it (reachable and dexterous parts)."""
    from ..explore.workspace import plot, workspace

    check_writable(args.output, IMAGE_SUFFIXES, "--output")
    tree = load(args.model)
    sites = [n for n in tree.names("site") if n]
    frame = args.frame or (sites[-1] if sites else tree.names("body")[-1])  # default: the last site, the tip
    ws = workspace(tree, frame, args.samples)
    shape = (f"planar annulus {ws.inner:.4g} <= r <= {ws.outer:.4g} about {np.round(ws.base, 4).tolist()}"
             if ws.planar else f"{ws.inner:.4g} <= distance from the base <= {ws.outer:.4g}")
    plot(ws, args.output, f"{tree.name} · {frame}: {args.samples} samples")
    print(f"wrote {args.output}: {shape}; box {np.round(ws.lo, 4).tolist()} .. {np.round(ws.hi, 4).tolist()}; "
          f"dexterous {ws.dexterous.mean():.0%} of the samples")
    return 0


def cmd_bench(args: argparse.Namespace) -> int:
    """Run a benchmark, print its tables, and write them with ``--json``."""
    from .bench.suite import main as bench_main

    with tier.waiting():  # compiled code is timed, not interpreted code while a child compiles it
        return bench_main(args)


def cmd_play(args: argparse.Namespace) -> int:
    """Serve the playground page: drag targets, switch IK methods, watch the figure follow."""
    from .play import serve

    return serve(args.model, host=args.host, port=args.port, browser=not args.no_browser, out_dir=args.out)


def cmd_warmup(args: argparse.Namespace) -> int:
    """Compile every kernel once (or load it from the cache), so later runs start at once."""
    from .warmup import GROUPS, warmup

    jobs = args.jobs or len(os.sched_getaffinity(0))
    print(f"preparing mjkin's kernels ({len(GROUPS)} groups, {min(jobs, len(GROUPS))} at a time; compiling them "
          "takes a minute or two, loading them from the cache a second)...", flush=True)
    with tier.waiting():
        seconds, compiled = warmup(jobs)
    done = f"compiled {compiled} kernel{'s' * (compiled > 1)}" if compiled else "none compiled: cached or loaded"
    print(f"kernels ready in {seconds:.1f} s ({done})")
    return 0


def _version() -> str:
    try:
        return metadata.version("mjkin")
    except metadata.PackageNotFoundError:  # run from a source tree that was never installed
        return "unknown (not installed)"


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of the ``mjkin`` command."""
    models = ", ".join(bundled_models())
    p = Parser(prog="mjkin", description="Kinematics for articulated figures in MJCF.")
    p.add_argument("--version", action="version", version=f"mjkin {_version()}")
    sub = p.add_subparsers(dest="command", required=True, metavar="COMMAND")
    model_help = f"MJCF/URDF file or a bundled model name ({models})"

    def q_options(s: argparse.ArgumentParser, flag: str, default: str, where: argparse._ActionsContainer,
                  seed_help: str = "") -> None:
        where.add_argument(flag, help=f"configuration (qpos): nq numbers, a keyframe name (e.g. home) or 'random' "
                                      f"(inside the joint limits; a free root joint keeps its qpos0 pose); a "
                                      f"quaternion that is not unit is normalised, with a warning; default {default}")
        s.add_argument("--deg", action="store_true", help=f"hinge values in {flag} are degrees")
        s.add_argument("--seed", type=nonnegative_int,
                       help=f"seed (>= 0) for {flag} random{seed_help}; without it {flag} random is a new draw "
                            "each run")

    def search_options(s: argparse.ArgumentParser) -> None:
        s.add_argument("--timeout", type=time_limit, default=TIMEOUT, metavar="SECONDS",
                       help=f"time limit per IK target, restarts included; a target that runs out keeps its best "
                            f"pose so far with status timeout (default {TIMEOUT:g}; none or 0: no limit)")
        s.add_argument("--restarts", type=nonnegative_int, metavar="N",
                       help=f"random restarts when a run stalls, at most {MAX_RESTARTS} (default: the method's own, "
                            "24 for auto; the time limit does not add any)")

    s = sub.add_parser("info", help="outline a model's bodies, joints and sites")
    s.add_argument("model", help=model_help)
    s.set_defaults(run=cmd_info)

    s = sub.add_parser("fk", help="world poses of bodies and sites for a configuration")
    s.add_argument("model", help=model_help)
    q_options(s, "--q", "qpos0", s)
    s.add_argument("--clip", action="store_true",
                   help="clip --q into the joint limits (default: use it as given and warn on stderr)")
    s.add_argument("--frame", help="print only this site or body")
    s.add_argument("--json", action="store_true", help="machine-readable output")
    s.set_defaults(run=cmd_fk)

    s = sub.add_parser("ik", help="solve IK: put a site or body at a position (and orientation)",
                       description="Solve IK for one site or body. Every joint may move, a free root joint (the "
                                   "floating base of a figure such as primate) too: the whole figure may shift or "
                                   "lift to reach, unless --root plants a body (a foot, the pelvis) where it is in "
                                   "--q0, or --joints/--base limit the joints that move.")
    s.add_argument("model", help=model_help)
    s.add_argument("--frame", required=True, help="the site or body to place")
    s.add_argument("--pos", required=True, help="target position x,y,z in metres, world frame")
    s.add_argument("--quat", help="target orientation w,x,y,z, world frame (default: position only)")
    q_options(s, "--q0", "qpos0", s, " and for the IK restarts (without it the restarts use seed 0, so a run "
                                     "repeats)")
    s.add_argument("--root", metavar="BODY", help="a body that keeps its pose from --q0 (a planted foot); the free "
                                                  "root joint then moves the rest (default: the free root moves too)")
    s.add_argument("--joints", metavar="J1,J2,...", help="only these joints move (default: all)")
    s.add_argument("--base", metavar="BODY", help="only the joints between this body and --frame move")
    s.add_argument("--method", choices=METHODS, default="auto", help="IK method (default auto, the most robust)")
    s.add_argument("--tol", type=positive_float, default=1e-6, help="position tolerance in metres (default 1e-6)")
    s.add_argument("--rot-tol", type=positive_float, default=1e-5,
                   help="rotation tolerance in radians (default 1e-5)")
    search_options(s)
    s.add_argument("--json", action="store_true",
                   help="print JSON: q, success, error [m, rad], iterations, status, restarts, method")
    s.set_defaults(run=cmd_ik)

    def video_options(s: argparse.ArgumentParser, default: str | None) -> None:
        s.add_argument("-o", "--output", default=default, required=default is None,
                       help="file: .mp4 or .gif (video), .png or .jpg (one frame)" + (f"; default {default}" if default
                                                                                          else ""))
        s.add_argument("--width", type=positive_int, default=640, help=f"pixels, at most {MAX_SIDE} (default 640)")
        s.add_argument("--height", type=positive_int, default=480, help=f"pixels, at most {MAX_SIDE} (default 480)")
        s.add_argument("--fps", type=positive_float, default=30.0, help="frames per second (default 30)")
        s.add_argument("--frame", type=int,
                       help="for an image output: which frame, from 0, negative from the end (default -1, the last); "
                            "only that frame is rendered")

    s = sub.add_parser("demo", help="render the showcase video (the main job): seeds' arm, 7-DoF path, walk")
    video_options(s, "mjkin-demo.mp4")
    s.add_argument("--seconds", type=positive_float, default=15.0, help="length of the showcase (default 15)")
    s.add_argument("--scene", default="all", choices=["all", "seeds", "arm", "walk"], help="one part only")
    s.set_defaults(run=cmd_demo)

    s = sub.add_parser("walk", help="render the bundled primate walking, seen from the side")
    video_options(s, "mjkin-walk.mp4")
    s.add_argument("--steps", type=positive_int, default=4, help="steps (default 4)")
    s.add_argument("--stride", type=positive_float, default=0.3, help="stride length in metres (default 0.3)")
    s.set_defaults(run=cmd_walk)

    s = sub.add_parser("trajectory", help="solve a Cartesian path for a site and save the script (JSON)")
    s.add_argument("model", help=model_help)
    s.add_argument("--frame", "--site", dest="frame", required=True,
                   help="the site (or body) that follows the path (--site: its name before 0.2)")
    s.add_argument("--path", choices=["circle", "line", "waypoints"], required=True, help="the shape of the path")
    s.add_argument("--center", help="circle centre x,y,z (default: the frame at the start)")
    s.add_argument("--radius", type=positive_float, default=0.1, help="circle radius in metres (default 0.1)")
    s.add_argument("--normal", default="0,0,1", help="circle plane normal x,y,z (default 0,0,1)")
    s.add_argument("--start", help="line start x,y,z (default: the site at the start)")
    s.add_argument("--end", help="line end x,y,z")
    s.add_argument("--points", help="waypoints 'x,y,z; x,y,z; ...' (from the site at the start)")
    s.add_argument("--frames", type=positive_int, default=90, help="number of frames, at least 2 (default 90)")
    s.add_argument("--fps", type=positive_float, default=30.0, help="frames per second of the script (default 30)")
    q_options(s, "--q0", "the first keyframe, else qpos0", s)
    s.add_argument("-o", "--output", required=True, help="script file (.json)")
    s.add_argument("--retime", metavar="VMAX,AMAX", help="time-optimal times under joint limits rad/s, rad/s^2")
    search_options(s)
    s.set_defaults(run=cmd_trajectory)

    s = sub.add_parser("retarget", help="retarget mocap clips (BVH, AMASS .npz) or folders of them onto a figure")
    retarget_cli.arguments(s)
    s.set_defaults(run=retarget_cli.run)

    s = sub.add_parser("render", help="render a configuration or a script to .png/.mp4/.gif")
    s.add_argument("model", help=model_help)
    group = s.add_mutually_exclusive_group()
    q_options(s, "--q", "qpos0", group)
    group.add_argument("--script", help="trajectory script from 'mjkin trajectory' (recorded on this model)")
    video_options(s, None)
    s.add_argument("--clip", action="store_true", help="clip joint values into the limits (default: render them "
                                                       "as given and warn on stderr)")
    s.set_defaults(run=cmd_render)

    s = sub.add_parser("replay", help="replay a recorded script without IK")
    s.add_argument("script", help="trajectory script (.json)")
    s.add_argument("--model", metavar="PATH", help="the model to replay it on, with the fingerprint the script "
                                                   "records (default: where the script says it was loaded from)")
    video_options(s, None)
    s.add_argument("--clip", action="store_true", help="clip recorded joint values into the limits (default: "
                                                       "render them as recorded and warn on stderr)")
    s.set_defaults(run=cmd_replay)

    s = sub.add_parser("workspace", help="a frame's reachable and dexterous workspace, plotted (.png)")
    s.add_argument("model", help=model_help)
    s.add_argument("--frame", help="the site or body whose workspace is sampled (default: the model's last site)")
    s.add_argument("--samples", type=positive_int, default=100_000, help="random configurations (default 100000)")
    s.add_argument("-o", "--output", default="workspace.png", help="image file (default workspace.png)")
    s.set_defaults(run=cmd_workspace)

    s = sub.add_parser("reachability", help="a frame's capability map (share of orientations IK reaches per voxel), "
                                            "one slice plotted (.png)")
    placement_cli.reachability_arguments(s)
    s.set_defaults(run=placement_cli.run_reachability)

    s = sub.add_parser("place-base", help="where to put the base so a frame reaches the poses: ranked on the "
                                          "capability map, verified by IK, heat map (.png)")
    placement_cli.place_base_arguments(s)
    s.set_defaults(run=placement_cli.run_place_base)

    s = sub.add_parser("bench", help="benchmarks: mjkin beside its baseline, as ratios")
    bench.add_arguments(s)
    s.set_defaults(run=cmd_bench)

    s = sub.add_parser("play", help="the playground in a browser: drag a target, watch each IK method work")
    s.add_argument("model", nargs="?", default="arm7", help=f"{model_help}; default arm7")
    s.add_argument("--port", type=int, default=8765, help="port to serve on (default 8765; 0 = any free one)")
    s.add_argument("--host", default="127.0.0.1", help="address to serve on (default loopback; another one "
                   "lets anyone who can reach it control the page)")
    s.add_argument("--no-browser", action="store_true", help="only print the URL")
    s.add_argument("--out", default=".", help="folder for recordings (default: here)")
    s.set_defaults(run=cmd_play)

    s = sub.add_parser("warmup", help="compile every kernel ahead of use (a Dockerfile or CI cache step)")
    s.add_argument("--jobs", type=positive_int, help="processes at a time (default: the cores available)")
    s.set_defaults(run=cmd_warmup)
    return p


def join_negative_vectors(argv: Sequence[str]) -> list[str]:
    """``--pos -20,5,0`` as ``--pos=-20,5,0``: argparse takes a value starting with '-' for an option."""
    out: list[str] = []
    for arg in argv:
        if out and out[-1] in VECTOR_OPTIONS and NEGATIVE_NUMBER.match(arg) and "--" not in out:
            out[-1] = f"{out[-1]}={arg}"
        else:
            out.append(arg)
    return out


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``mjkin`` console command.

    Output into a pipe whose reader has gone (``mjkin info primate | head -1``) ends
    the command quietly with :data:`SIGPIPE_EXIT`, as a Unix tool ended by SIGPIPE;
    mjkin does not let SIGPIPE end it, so a video being written is still cleaned up.
    """
    try:
        code = run(sys.argv[1:] if argv is None else argv)
        sys.stdout.flush()  # a closed pipe shows here, not in the interpreter's flush at exit
        return code
    except BrokenPipeError:
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())  # that flush at exit goes nowhere
        return SIGPIPE_EXIT


def run(argv: Sequence[str]) -> int:
    """Parse ``argv`` and run the command; a user mistake is one line on stderr and status 2."""
    try:
        args = build_parser().parse_args(join_negative_vectors(argv))
    except SystemExit as e:  # --help, --version, or a usage error already printed as one line
        return e.code if isinstance(e.code, int) else 2
    progress.enable(True)
    try:
        return int(args.run(args))
    except MjkinError as e:
        print(f"mjkin: error: {e}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("mjkin: interrupted", file=sys.stderr)
        return 130
    finally:
        tier.flush()  # a background compile that goes on says so, as the command ends
        progress.enable(False)


if __name__ == "__main__":
    sys.exit(main())
