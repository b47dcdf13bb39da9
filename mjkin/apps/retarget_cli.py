"""``mjkin retarget CLIP.bvh --model M [-o out.json|out.mp4] ...``: motion capture onto a figure, and its report."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from ..errors import InputError
from ..kinematics.tree import load
from ..motion import bvh, retime
from ..motion.retarget import MAX_SPEED, plan, read_mapping, report, retarget, source_mapping
from ..runtime.files import check_writable
from .argtypes import nonnegative_float, positive_float, positive_int

OUTPUTS = (".json", ".mp4", ".gif", ".png")
BESIDE = np.array([0.0, 1.0, 0.0])  # the source skeleton's shift with --side-by-side (m): to the figure's left


def arguments(s: argparse.ArgumentParser) -> None:
    """The command's options."""
    s.add_argument("clip", help="BVH file")
    s.add_argument("--model", required=True, help="bundled model name (primate) or an MJCF/URDF path (e.g. the G1)")
    s.add_argument("-o", "--output", help="script (.json, replay with 'mjkin replay'), video (.mp4, .gif) or a "
                   "still (.png, frame --frame)")
    s.add_argument("--frame", type=int, help="the frame of a .png still, from 0 (default: the middle one)")
    s.add_argument("--mapping", help='JSON {"source": {role: joint}, "figure": {role: body}} for other rigs')
    s.add_argument("--scale", type=positive_float, metavar="M",
                   help="metres per BVH unit (0.01 for centimetres): the figure's root then moves the clip's "
                        "distance in metres (default: the unit from the skeleton's height, and the root path "
                        "fitted to the figure by the ratio of leg lengths)")
    s.add_argument("--max-speed", type=positive_float, default=MAX_SPEED,
                   help=f"joint speed limit, rad/s (default {MAX_SPEED:g})")
    s.add_argument("--clearance", type=nonnegative_float, metavar="M",
                   help="keep the figure's own geoms at least M metres apart in every frame's solve (default: off)")
    s.add_argument("--retime", action="store_true", help="time-optimal times under --max-speed and --max-acceleration")
    s.add_argument("--max-acceleration", type=positive_float, default=100.0,
                   help="joint acceleration limit for --retime, rad/s^2 (default 100)")
    s.add_argument("--side-by-side", action="store_true", help="video: the source skeleton beside the figure, "
                   "not over it")
    s.add_argument("--report", action="store_true", help="print the measured figures as JSON (metres_per_unit: "
                   "the clip's unit used; root_ratio: the figure's root path per metre of the clip's)")
    s.add_argument("--width", type=positive_int, default=640, help="video width in pixels (default 640)")
    s.add_argument("--height", type=positive_int, default=480, help="video height in pixels (default 480)")


def run(args: argparse.Namespace) -> int:
    """Retarget, then write the script or video and print the summary (and the report)."""
    from .. import render
    from ..kinematics.tree import source_of as model_source

    if args.output:
        check_writable(args.output, OUTPUTS, "--output")
    if args.output and Path(args.output).suffix.lower() != ".json":
        render.check_video_size(args.output, args.width, args.height)
    tree = load(args.model)
    clip = bvh.read(args.clip)
    traj = retarget(clip, tree, args.mapping, scale=args.scale, max_speed=args.max_speed, clearance=args.clearance,
                    model_source=model_source(args.model))
    measured = report(tree, traj)
    if args.retime:
        traj = retime(traj, args.max_speed, args.max_acceleration, tree=tree)
    if args.output and Path(args.output).suffix.lower() == ".json":
        traj.save(args.output)
    elif args.output:
        mapping = read_mapping(args.mapping) if args.mapping else None
        joints = sorted(source_mapping(clip, (mapping or {}).get("source")).values())  # the mapped joints only
        skeleton = plan(clip, tree, mapping, args.scale).source[:, joints] + (BESIDE if args.side_by_side else 0.0)
        overlay = render.Overlay(points=skeleton, point_size=0.025, point_rgba=(0.1, 0.45, 0.95, 0.9))
        if Path(args.output).suffix.lower() == ".png":
            k = len(traj.q) // 2 if args.frame is None else args.frame
            if not -len(traj.q) <= k < len(traj.q):
                raise InputError(f"--frame {k} is outside the clip's {len(traj.q)} frames")
            overlay.points = skeleton[[k]]
            render.write_image(next(iter(render.frames(tree, traj.q[[k]], args.width, args.height, overlay=overlay))),
                               args.output)
        else:
            fps = clip.fps if not args.retime else len(traj.q) / max(traj.times[-1] - traj.times[0], 1e-9)
            render.write_video(render.frames(tree, traj.q, args.width, args.height, overlay=overlay), args.output,
                               fps)
    where = f"wrote {args.output}: " if args.output else ""
    print(f"{where}{measured['frames']} frames of {args.clip} on {tree.name} at "
          f"{measured['frames_per_second']:.0f} frames/s, {measured['metres_per_unit']:g} m per BVH unit, root path "
          f"x{measured['root_ratio']:.3g}; key points {100 * measured['keypoint_error_median']:.1f} cm "
          f"(median), foot skate {1000 * measured['skate_per_frame_mean']:.2f} mm/frame, lowest sole "
          f"{100 * measured['floor_min']:+.1f} cm, self-contact in {measured['self_contact_frames']} frames"
          + (f"; retimed to {traj.times[-1] - traj.times[0]:.2f} s" if args.retime else ""))
    if args.report:
        print(json.dumps(measured, indent=1))
    return 0
