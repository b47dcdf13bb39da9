"""``mjkin retarget CLIP(.bvh, .npz) --model M [-o out.json|out.mp4] ...``: motion capture onto a figure, reported.

Several clips (``SRC...``, folders searched recursively) go to :func:`mjkin.motion.dataset.retarget_many`:
``-o`` is then a folder that gets a file per clip and ``report.csv``.

Never a silent failure: a clip whose hands, feet and head miss by more than ``--max-error`` (the 95th percentile
over frames of each frame's worst, :func:`mjkin.motion.retarget.frame_errors`) gets one line on stderr naming it
and its worst frame, and once every clip is done the command exits with :data:`FAILED_EXIT` (its file is still
written); so does a clip that could not be retargeted at all.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from ..errors import InputError
from ..kinematics.tree import Tree, load
from ..motion import retime
from ..motion.bvh import Clip
from ..motion.clips import read_clip
from ..motion.dataset import DONE, FORMATS, find_clips, retarget_many, write_motion
from ..motion.retarget import MAX_ERROR, MAX_SPEED, SELF_CLEARANCE, plan, read_mapping, report, retarget, source_mapping
from ..motion.roles import found_mapping
from ..motion.terrain import Terrain
from ..runtime.files import check_writable, write_text
from .argtypes import distance_or_off, positive_float, positive_int

if TYPE_CHECKING:
    from .. import render

MOTION = (".json", ".npz", ".csv")  # written by write_motion; the rest are rendered
OUTPUTS = (*MOTION, ".mp4", ".gif", ".png")
ONE_CLIP = ("--retime", "--side-by-side", "--report", "--frame")  # options of a single clip's output
BESIDE = np.array([0.0, 1.0, 0.0])  # the source skeleton's shift with --side-by-side (m): to the figure's left
FAILED_EXIT = 3  # the exit status when a clip failed (over --max-error, or not retargeted); 2 is a user mistake


def arguments(s: argparse.ArgumentParser) -> None:
    """The command's options."""
    s.add_argument("sources", nargs="+", metavar="SRC", help="BVH file, or AMASS/SMPL-H/SMPL-X .npz (with "
                   "--body-model); several, or folders (searched recursively): -o is a folder")
    s.add_argument("--model", required=True, help="bundled model name (primate) or an MJCF/URDF path (e.g. the G1)")
    s.add_argument("-o", "--output", help="script (.json, replay with 'mjkin replay'), qpos (.npz, .csv), video "
                   "(.mp4, .gif) or a still (.png, frame --frame); with several clips a folder (made if missing): "
                   "a file per clip and report.csv")
    s.add_argument("--format", choices=FORMATS, help="several clips: the files' format (default npz); one clip: "
                   "the suffix of -o says it")
    s.add_argument("--overwrite", action="store_true", help="several clips: redo those done (by default a clip with "
                   "its file and an ok row in report.csv is skipped)")
    s.add_argument("--workers", type=positive_int, metavar="N", help="several clips: N at once in local processes "
                   "(default 1), or with --ray Ray tasks (default: the cluster's CPUs)")
    s.add_argument("--ray", nargs="?", const=True, metavar="ADDRESS", help="several clips: run them as Ray tasks on "
                   "the cluster at ADDRESS (default: the running session, else a local one; pip install "
                   "\"mjkin[ray]\")")
    s.add_argument("--frame", type=int, help="the frame of a .png still, from 0 (default: the middle one)")
    s.add_argument("--body-model", metavar="PATH", help="the SMPL-H or SMPL-X body-model .npz an .npz clip was made "
                   "with (your own copy: mjkin ships none)")
    s.add_argument("--mapping", help='JSON {"source": {role: joint}, "figure": {role: body}} for other rigs')
    s.add_argument("--print-mapping", nargs="?", const="-", metavar="PATH", help="write the roles found for the "
                   "(first) clip and the model as a --mapping file to PATH (.json; default: print it) and stop "
                   "without solving: fix it, then pass it as --mapping")
    s.add_argument("--scale", type=positive_float, metavar="M",
                   help="metres per BVH unit (0.01 for centimetres): the figure's root then moves the clip's "
                        "distance in metres (default: the unit from the skeleton's height, and the root path "
                        "fitted to the figure by the ratio of leg lengths)")
    s.add_argument("--scene", metavar="PATH", help="MJCF whose world geoms are the ground (a floor with ramps and "
                   "steps, a Menagerie scene.xml): planted feet rest on it, the video shows it (default: the floor "
                   "z = 0)")
    s.add_argument("--max-speed", type=positive_float, default=MAX_SPEED,
                   help=f"joint speed limit, rad/s (default {MAX_SPEED:g})")
    s.add_argument("--clearance", type=distance_or_off, metavar="M|off", default=SELF_CLEARANCE,
                   help=f"keep the figure's own geoms at least M metres apart in every frame's solve, or off "
                        f"(faster; limbs may pass through the body) (default {SELF_CLEARANCE:g})")
    s.add_argument("--max-error", type=positive_float, metavar="M", default=MAX_ERROR,
                   help=f"a clip whose hands, feet and head miss their targets by more than M metres (95th "
                        f"percentile over frames of each frame's worst) is failed: a line on stderr, status failed "
                        f"in report.csv, exit status {FAILED_EXIT}; its file is still written (default {MAX_ERROR:g})")
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
    """Retarget, then write the script or video and print the summary (and the report); several clips: run_many."""
    from .. import render
    from ..kinematics.tree import source_of as model_source

    clips = find_clips(args.sources)
    if args.print_mapping is not None:
        return print_mapping(args, clips[0].path)
    if len(clips) > 1 or any(Path(s).is_dir() for s in args.sources):
        return run_many(args)
    args.clip = str(clips[0].path)
    if args.output:
        check_writable(args.output, OUTPUTS, "--output")
    suffix = Path(args.output or "").suffix.lower()
    if args.format and suffix != f".{args.format}":
        raise InputError(f"--format {args.format} is for several clips; with one, -o's suffix says the format "
                         f"(-o NAME.{args.format})")
    if args.retime and suffix in (".npz", ".csv"):
        raise InputError(f"--retime makes the frame times uneven, which {suffix} (a frame rate) cannot hold; write "
                         ".json (times per frame) or leave --retime out")
    if args.output and suffix not in MOTION:
        render.check_video_size(args.output, args.width, args.height)
    tree = load(args.model)
    terrain = Terrain.load(args.scene) if args.scene else None
    clip = read_clip(args.clip, args.body_model)
    traj = retarget(clip, tree, args.mapping, scale=args.scale, max_speed=args.max_speed, clearance=args.clearance,
                    model_source=model_source(args.model), scene=terrain, max_error=args.max_error)
    measured = report(tree, traj)
    status = traj.meta["retarget"]["status"]
    if args.retime:
        traj = retime(traj, args.max_speed, args.max_acceleration, tree=tree)
    if suffix in MOTION:
        write_motion(args.output, traj, tree, clip.fps)
    elif args.output:
        overlay = source_overlay(clip, tree, args, terrain)
        skeleton = overlay.points
        if Path(args.output).suffix.lower() == ".png":
            k = len(traj.q) // 2 if args.frame is None else args.frame
            if not -len(traj.q) <= k < len(traj.q):
                raise InputError(f"--frame {k} is outside the clip's {len(traj.q)} frames")
            overlay.points = skeleton[[k]]
            render.write_image(next(iter(render.frames(tree, traj.q[[k]], args.width, args.height, overlay=overlay,
                                                       terrain=terrain))), args.output)
        else:
            fps = clip.fps if not args.retime else len(traj.q) / max(traj.times[-1] - traj.times[0], 1e-9)
            render.write_video(render.frames(tree, traj.q, args.width, args.height, overlay=overlay,
                                             terrain=terrain), args.output, fps)
    where = f"wrote {args.output}: " if args.output else ""
    print(f"{where}{measured['frames']} frames of {args.clip} on {tree.name} at "
          f"{measured['frames_per_second']:.0f} frames/s, {measured['metres_per_unit']:g} m per BVH unit, root path "
          f"x{measured['root_ratio']:.3g}; key points {errors(measured)}, foot skate "
          f"{1000 * measured['skate_per_frame_mean']:.2f} mm/frame, lowest foot point "
          f"{100 * measured['floor_min']:+.1f} cm, self-contact in {measured['self_contact_frames']} frames"
          + (f"; retimed to {traj.times[-1] - traj.times[0]:.2f} s" if args.retime else ""))
    if args.report:
        print(json.dumps(measured, indent=1))
    if status == "failed":
        print(failure(args.clip, measured, args.max_error), file=sys.stderr)
        return FAILED_EXIT
    return 0


def errors(measured: dict) -> str:
    """The summary's words for a clip's frame errors (:func:`mjkin.motion.retarget.report`'s ``frame_error_*``)."""
    return (f"off by {100 * measured['frame_error_median']:.1f} cm (median), {100 * measured['frame_error_p95']:.1f} "
            f"cm (95th percentile), {100 * measured['frame_error_max']:.1f} cm (max) over frames, each frame's worst")


def failure(clip: str, measured: dict, max_error: float) -> str:
    """The stderr line of a clip over ``--max-error``: its name, its percentile and its worst frame."""
    return (f"mjkin: {clip}: failed: hands, feet and head off by {100 * measured['frame_error_p95']:.1f} cm at the "
            f"95th percentile of frames, over --max-error {100 * max_error:g} cm; worst frame "
            f"{measured['worst_frame']}: {100 * measured['frame_error_max']:.1f} cm")


def source_overlay(clip: Clip, tree: Tree, args: argparse.Namespace, terrain: Terrain | None) -> render.Overlay:
    """The source skeleton to draw: its mapped joints ``(F, n, 3)`` (world, m; :data:`BESIDE` the figure with
    ``--side-by-side``) as dots, and a bone from each to its nearest mapped ancestor (:func:`skeleton_bones`).
    """  # noqa: D205
    from .. import render

    mapping = read_mapping(args.mapping) if args.mapping else None
    joints = sorted(source_mapping(clip, (mapping or {}).get("source")).values())  # the mapped joints only
    skeleton = plan(clip, tree, mapping, args.scale, terrain).source[:, joints] + (BESIDE if args.side_by_side
                                                                                   else 0.0)
    return render.Overlay(points=skeleton, point_size=0.025, point_rgba=(0.1, 0.45, 0.95, 0.9),
                          bones=skeleton_bones(clip.parents, joints))


def skeleton_bones(parents: NDArray[np.int64], joints: Sequence[int]) -> NDArray[np.int64]:
    """Bones ``(k, 2)`` of the drawn ``joints`` (indices into ``parents (J,)``, -1 for a root): positions in
    ``joints`` of each one's nearest drawn ancestor and of itself; a joint with none drawn has no bone.
    """  # noqa: D205
    at = {j: i for i, j in enumerate(joints)}
    bones = []
    for i, j in enumerate(joints):
        up = parents[j]
        while up >= 0 and up not in at:
            up = parents[up]
        if up >= 0:
            bones.append((at[up], i))
    return np.array(bones, dtype=np.int64).reshape(-1, 2)


def print_mapping(args: argparse.Namespace, clip_path: Path) -> int:
    """``--print-mapping``: the roles found for the clip on the model (and ``--mapping``'s), as a mapping file."""
    if args.print_mapping != "-":
        check_writable(args.print_mapping, (".json",), "--print-mapping")
    tree = load(args.model)
    doc, missing = found_mapping(read_clip(clip_path, args.body_model), tree,
                                 read_mapping(args.mapping) if args.mapping else None)
    text = json.dumps(doc, indent=1) + "\n"
    if args.print_mapping == "-":
        print(text, end="")
    else:
        write_text(args.print_mapping, text)
        print(f"wrote {args.print_mapping}: the roles found for {clip_path} on {tree.name}; check it, then pass it "
              "as --mapping")
    if missing:
        print(f"mjkin: warning: not found, to fill in: {', '.join(missing)}", file=sys.stderr)
    return 0


def run_many(args: argparse.Namespace) -> int:
    """Retarget several clips into the folder ``-o`` (:func:`~mjkin.motion.dataset.retarget_many`); print a summary.

    A clip over ``--max-error`` gets a line on stderr, one that could not be retargeted has its error in
    report.csv (a line counts them); with any of either the status is :data:`FAILED_EXIT`, else 0.
    """
    given = [flag for flag in ONE_CLIP if getattr(args, flag[2:].replace("-", "_")) not in (None, False)]
    if given:
        raise InputError(f"{', '.join(given)} {'is' if len(given) == 1 else 'are'} for one clip; several clips get a "
                         "file each and report.csv in -o's folder")
    if not args.output:
        raise InputError("several clips need -o FOLDER: it gets a file per clip and report.csv")
    fmt = args.format or "npz"
    rows = retarget_many(args.sources, args.model, args.output, format=fmt, workers=args.workers, ray=args.ray,
                         overwrite=args.overwrite, body_model=args.body_model, mapping=args.mapping, scale=args.scale,
                         max_speed=args.max_speed, clearance=args.clearance, scene=args.scene,
                         max_error=args.max_error)
    measured = [r for r in rows if r["status"] in DONE]
    broken = [r for r in rows if r["status"] not in DONE]
    out = Path(args.output)
    within = sum(r["status"] == "ok" for r in rows)
    print(f"{within} of {len(rows)} clips on {args.model} within --max-error {100 * args.max_error:g} cm in {out}"
          f"{os.sep} as .{fmt}; report: {out / 'report.csv'}" + (
              f"; key points off by {100 * np.median([r['frame_error_median'] for r in measured]):.1f} cm (median of "
              f"the clips' medians), 95th percentile up to {100 * max(r['frame_error_p95'] for r in measured):.1f} "
              f"cm, max {100 * max(r['frame_error_max'] for r in measured):.1f} cm" if measured else ""))
    for row in measured:
        if row["status"] == "failed":
            print(failure(row["clip"], row, args.max_error), file=sys.stderr)
    if broken:
        print(f"mjkin: {len(broken)} clip{'s' * (len(broken) > 1)} not retargeted (the error in report.csv), "
              f"e.g. {broken[0]['clip']}: {broken[0]['status']}", file=sys.stderr)
    return FAILED_EXIT if within < len(rows) else 0
