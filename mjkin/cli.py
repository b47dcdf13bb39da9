"""The ``mjkin`` command: inspect models, compute FK, benchmark.

Every user mistake ends as one line on stderr and exit status 2, never a traceback.
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Callable, Sequence

import numpy as np

from . import bench, motion, progress, spatial
from .errors import InputError, MjkinError
from .goals import Rest
from .qspace import HINGE, JOINT_NAMES
from .tree import Tree, bundled_models, load

Command = Callable[[argparse.Namespace], int]


def parse_q(text: str, tree: Tree, degrees: bool = False) -> np.ndarray:
    """A configuration from ``"0.1 0.2 ..."`` or ``"0.1,0.2,..."``; ``degrees`` converts hinge values."""
    try:
        q = np.array([float(v) for v in text.replace(",", " ").split()])
    except ValueError:
        raise InputError(f"--q must be {tree.nq} numbers separated by spaces or commas, got {text!r}") from None
    q = tree.check_q(q, "--q")
    if degrees:
        hinge = tree.jnt_qadr[tree.jnt_type == HINGE]
        q[hinge] = np.radians(q[hinge])
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
             f"bodies={tree.nbody - 1} joints={tree.njnt} sites={m.nsite}"]
    depth = np.zeros(tree.nbody, dtype=int)
    for b in range(1, tree.nbody):
        depth[b] = depth[tree.body_parent[b]] + 1
        lines.append(f"{'  ' * depth[b]}body {bodies[b] or f'#{b}'}")
        for j in np.flatnonzero(tree.jnt_body == b):
            kind = JOINT_NAMES[int(tree.jnt_type[j])]
            text = f"{'  ' * depth[b]}  joint {joints[j] or f'#{j}'}: {kind}"
            if kind in ("hinge", "slide"):
                text += f" axis={np.round(tree.jnt_axis[j], 4).tolist()}"
            if tree.jnt_limited[j]:
                lo, hi = tree.jnt_range[j]
                text += f" range=[{lo:.4g}, {hi:.4g}]" if kind != "ball" else f" cone={hi:.4g} rad"
            lines.append(text)
        for s in np.flatnonzero(tree.site_body == b):
            lines.append(f"{'  ' * depth[b]}  site {sites[s] or f'#{s}'} pos={np.round(tree.site_pos[s], 4).tolist()}")
    return "\n".join(lines)


def cmd_fk(args: argparse.Namespace) -> int:
    """Print world poses of bodies and sites (or one frame) for a configuration."""
    tree = load(args.model)
    q = tree.qpos0.copy() if args.q is None else parse_q(args.q, tree, args.deg)
    frames = tree.kinematics(q)
    kinds = [tree.frame(args.frame)] if args.frame else (
        [("body", i) for i in range(1, tree.nbody)] + [("site", i) for i in range(tree.model.nsite)])
    out = []
    for kind, i in kinds:
        T = frames.pose(kind, i)
        out.append({"kind": kind, "name": tree.names(kind)[i], "pos": T[:3, 3].tolist(),
                    "quat": spatial.mat_to_quat(T[:3, :3]).tolist()})
    if args.json:
        print(json.dumps({"q": q.tolist(), "frames": out}, indent=1))
    else:
        for f in out:
            pos = " ".join(f"{v: .6f}" for v in f["pos"])  # type: ignore[union-attr]
            quat = " ".join(f"{v: .6f}" for v in f["quat"])  # type: ignore[union-attr]
            print(f"{f['kind']:4} {f['name']:24} pos {pos}   quat {quat}")
    return 0


def _points(text: str) -> np.ndarray:
    try:
        pts = np.array([[float(v) for v in p.replace(",", " ").split()] for p in text.split(";") if p.strip()])
    except ValueError:
        raise InputError(f"points must look like 'x,y,z; x,y,z; ...', got {text!r}") from None
    if pts.ndim != 2 or pts.shape[1] != 3:
        raise InputError(f"points must be 3-D, 'x,y,z; x,y,z; ...', got {text!r}")
    return pts


def _vec(text: str, what: str) -> np.ndarray:
    pts = _points(text)
    if len(pts) != 1:
        raise InputError(f"{what} must be one point 'x,y,z', got {text!r}")
    return pts[0]


def _video_or_image(args: argparse.Namespace, images: np.ndarray) -> None:
    """Write ``images (T, H, W, 3)`` to ``args.output``: a video, or frame ``args.frame`` as an image."""
    from . import render

    path = args.output
    if path.lower().endswith(render.VIDEO_SUFFIXES):
        render.write_video(images, path, args.fps)
        what = f"{len(images)} frame{'s' * (len(images) > 1)}"
    elif path.lower().endswith((".png", ".jpg", ".jpeg")):
        if not -len(images) <= args.frame < len(images):
            raise InputError(f"--frame must be in [{-len(images)}, {len(images) - 1}] (-1 = last), got {args.frame}")
        render.write_image(images[args.frame], path)
        what = f"frame {args.frame % len(images)} of {len(images)}"
    else:
        raise InputError(f"output must end in .mp4, .gif or .png, got {path!r}")
    print(f"wrote {path} ({what}, {images.shape[2]}x{images.shape[1]})")


def demo_trajectory(tree: Tree, frames: int, fps: float = 30.0,
                    smooth: float = 0.3) -> tuple[motion.Trajectory, np.ndarray]:
    """The demo on the bundled 7-DoF arm: its effector through five waypoints and home; returns it and the stops."""
    home = tree.model.key_qpos[0].copy()
    start = tree.pose(home, "ee")[:3, 3]
    stops = np.array([start, [0.45, 0.3, 0.45], [0.5, -0.25, 0.5], [0.3, -0.35, 0.9], [0.25, 0.35, 0.85],
                      [0.45, 0.3, 0.45], start])
    traj = motion.follow(tree, "ee", motion.waypoints(stops, frames), q0=home, fps=fps, smooth=smooth,
                         extra=[Rest(q_rest=home, weight=0.3, priority=1)])  # keep a natural posture
    return traj, stops


def cmd_demo(args: argparse.Namespace) -> int:
    """Render a scripted IK trajectory of the 7-DoF arm reaching through waypoints."""
    from . import render

    tree = load("arm7")
    traj, stops = demo_trajectory(tree, int(args.seconds * args.fps), args.fps)
    ok = traj.success if traj.success is not None else np.ones(len(traj.q), bool)
    print(f"IK: {ok.mean():.0%} of {len(traj.q)} frames on target; largest joint step per frame "
          f"{traj.jumps(tree).max():.3f} rad")
    overlay = render.Overlay(points=stops[1:-1], trail="ee")
    images = render.frames(tree, traj.q, args.width, args.height, overlay=overlay)
    _video_or_image(args, images)
    return 0


def cmd_trajectory(args: argparse.Namespace) -> int:
    """Solve a Cartesian path for a site frame by frame and save it as a script."""
    tree = load(args.model)
    tree.frame(args.site)  # a clear error before any work
    q0 = tree.model.key_qpos[0].copy() if tree.model.nkey else tree.qpos0.copy()
    q0 = parse_q(args.q0, tree, args.deg) if args.q0 else q0
    here = tree.pose(q0, args.site)[:3, 3]
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
    traj = motion.follow(tree, args.site, pts, q0=q0, fps=args.fps)
    traj.save(args.output)
    ok = traj.success if traj.success is not None else np.ones(len(pts), bool)
    jumps = traj.discontinuities(tree)
    print(f"wrote {args.output}: {len(pts)} frames, {ok.mean():.0%} on target, largest joint step "
          f"{traj.jumps(tree).max():.3f}" + (f"; discontinuities at frames {jumps.tolist()}" if len(jumps) else ""))
    return 0


def cmd_render(args: argparse.Namespace) -> int:
    """Render a configuration or a script to an image or a video."""
    from . import render

    tree = load(args.model)
    if args.script:
        traj = motion.Trajectory.load(args.script, tree)
        qs, points, trail = traj.q, traj.targets, traj.site
    else:
        qs = (parse_q(args.q, tree, args.deg) if args.q else tree.qpos0.copy())[None]
        points, trail = None, None
    overlay = render.Overlay(points=np.zeros((0, 3)) if points is None else points, trail=trail)
    _video_or_image(args, render.frames(tree, qs, args.width, args.height, overlay=overlay))
    return 0


def cmd_replay(args: argparse.Namespace) -> int:
    """Replay a recorded script (no IK) to a video."""
    model = args.model or motion.Trajectory.load(args.script).model
    args.model, args.q = model, None
    return cmd_render(args)


def cmd_bench(args: argparse.Namespace) -> int:
    """Run benchmarks and print their tables."""
    names = list(bench.BENCHMARKS) if args.which == "all" else [args.which]
    for name in names:
        for title, rows in bench.BENCHMARKS[name]().items():
            print(f"== mjkin bench {name}: {title}")
            print(bench.format_table(rows))
            print()
    return 0


def cmd_play(args: argparse.Namespace) -> int:
    """Serve the playground page: drag targets, switch IK methods, watch the figure follow."""
    from .play import serve

    return serve(args.model, host=args.host, port=args.port, browser=not args.no_browser, out_dir=args.out)


def cmd_warmup(args: argparse.Namespace) -> int:
    """Compile every kernel once (or load it from the cache), so later runs start at once."""
    from .warmup import warmup

    print("compiling mjkin's kernels (first run only, about a minute)...", flush=True)
    print(f"done in {warmup():.1f} s")
    return 0


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of the ``mjkin`` command."""
    models = ", ".join(bundled_models())
    p = argparse.ArgumentParser(prog="mjkin", description="Kinematics for articulated figures in MJCF.")
    sub = p.add_subparsers(dest="command", required=True)
    model_help = f"MJCF/URDF file or a bundled model name ({models})"

    s = sub.add_parser("info", help="outline a model's bodies, joints and sites")
    s.add_argument("model", help=model_help)
    s.set_defaults(run=cmd_info)

    s = sub.add_parser("fk", help="world poses of bodies and sites for a configuration")
    s.add_argument("model", help=model_help)
    s.add_argument("--q", help="configuration (qpos), nq numbers; default qpos0")
    s.add_argument("--deg", action="store_true", help="hinge values in --q are degrees")
    s.add_argument("--frame", help="print only this site or body")
    s.add_argument("--json", action="store_true", help="machine-readable output")
    s.set_defaults(run=cmd_fk)

    def video_options(s: argparse.ArgumentParser, default: str | None) -> None:
        s.add_argument("-o", "--output", default=default, required=default is None, help="file: .mp4, .gif or .png")
        s.add_argument("--width", type=int, default=640)
        s.add_argument("--height", type=int, default=480)
        s.add_argument("--fps", type=float, default=30.0)
        s.add_argument("--frame", type=int, default=-1, help="for an image output: which frame (default -1, the last)")

    s = sub.add_parser("demo", help="render a scripted IK trajectory of the 7-DoF arm (the main job)")
    video_options(s, "mjkin-demo.mp4")
    s.add_argument("--seconds", type=float, default=6.0)
    s.set_defaults(run=cmd_demo)

    s = sub.add_parser("trajectory", help="solve a Cartesian path for a site and save the script (JSON)")
    s.add_argument("model", help=model_help)
    s.add_argument("--site", required=True, help="the site (or body) that follows the path")
    s.add_argument("--path", choices=["circle", "line", "waypoints"], required=True)
    s.add_argument("--center", help="circle centre x,y,z (default: the site at the start)")
    s.add_argument("--radius", type=float, default=0.1)
    s.add_argument("--normal", default="0,0,1", help="circle plane normal x,y,z")
    s.add_argument("--start", help="line start x,y,z (default: the site at the start)")
    s.add_argument("--end", help="line end x,y,z")
    s.add_argument("--points", help="waypoints 'x,y,z; x,y,z; ...' (from the site at the start)")
    s.add_argument("--frames", type=int, default=90)
    s.add_argument("--fps", type=float, default=30.0)
    s.add_argument("--q0", help="start configuration (default: the first keyframe, else qpos0)")
    s.add_argument("--deg", action="store_true", help="hinge values in --q0 are degrees")
    s.add_argument("-o", "--output", required=True, help="script file (.json)")
    s.set_defaults(run=cmd_trajectory)

    s = sub.add_parser("render", help="render a configuration or a script to .png/.mp4/.gif")
    s.add_argument("model", help=model_help)
    group = s.add_mutually_exclusive_group()
    group.add_argument("--q", help="configuration (qpos); default qpos0")
    group.add_argument("--script", help="trajectory script from 'mjkin trajectory'")
    s.add_argument("--deg", action="store_true", help="hinge values in --q are degrees")
    video_options(s, None)
    s.set_defaults(run=cmd_render)

    s = sub.add_parser("replay", help="replay a recorded script without IK")
    s.add_argument("script", help="trajectory script (.json)")
    s.add_argument("--model", help="model (default: the one named in the script)")
    video_options(s, None)
    s.set_defaults(run=cmd_replay, deg=False)

    s = sub.add_parser("bench", help="benchmarks: mjkin beside its baseline, as ratios")
    s.add_argument("which", choices=[*bench.BENCHMARKS, "all"])
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
    s.set_defaults(run=cmd_warmup)
    return p


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``mjkin`` console command."""
    args = build_parser().parse_args(argv)
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
        progress.enable(False)


if __name__ == "__main__":
    sys.exit(main())
