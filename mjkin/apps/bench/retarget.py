"""``mjkin bench retarget``: a folder of BVH clips onto figures, per clip and in a dataset's form.

The dataset table is the form retargeting benchmarks on LAFAN1 report speed in: per figure, the
median frames/s over the clips and its spread (the interquartile range), beside the quality
figures :func:`mjkin.motion.retarget.report` measures, summarised over the clips.

On the robots GMR ships (the shared ``gmr_unitree_g1`` and ``gmr_booster_t1``), a third table puts GMR
(:mod:`~mjkin.apps.bench.gmr`, when it is found) beside mjkin on the same clips, both tools' joint
trajectories scored by the one :func:`mjkin.motion.quality.score`.
"""

from __future__ import annotations

import os
import time
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from ...errors import InputError, MjkinIOError
from ...kinematics.tree import Tree, load
from ...motion import Trajectory
from ...motion.dataset import find_clips
from ...motion.quality import score
from ...motion.retarget import report, retarget
from ...runtime.parallel import threads_set
from . import FK_MODELS, gmr
from .peers import Unavailable
from .report import Report, Row, shared_model, shared_models_dir

CLIPS = ("mixamo_freebvh.bvh", "mocapbank_19joint.bvh")
# GMR's robots as it ships them (meshes and all), under ../shared/models: mjkin and GMR side by side on them
PEER_FIGURES = {"gmr_unitree_g1": "gmr_unitree_g1/g1_mocap_29dof.xml", "gmr_booster_t1": "gmr_booster_t1/t1_mocap.xml"}
# the default figures: the bundled humanoid, then those of ../shared/models that are there
FIGURES = ("primate", "g1", *PEER_FIGURES)


def mocap_dir() -> Path | None:
    """``../shared/mocap`` beside the shared models, if it is there."""
    models = shared_models_dir()
    folder = None if models is None else models.parent / "mocap"
    return folder if folder is not None and folder.is_dir() else None


def figures(names: Sequence[str] | None = None) -> list[tuple[str, Tree]]:
    """Figures by name (``primate``, ``g1``) or MJCF path; by default the primate and the G1 when it is there.

    Raises:
        InputError: a named figure is not available.
    """
    out = []
    for name in names or FIGURES:
        if name == "primate" or Path(name).is_file():
            out.append((name if name == "primate" else peer_name(Path(name)) or Path(name).stem, load(name)))
            continue
        where = FK_MODELS.get(name) or PEER_FIGURES.get(name)
        tree = shared_model(where) if where else None
        if tree is not None:
            out.append((name, tree))
        elif names:
            raise InputError(f"--models takes {', '.join(FIGURES)} or MJCF files of figures with a free root; "
                             f"{name!r} is not available")
    return out


def peer_name(path: Path) -> str | None:
    """The :data:`PEER_FIGURES` name of a model file given by path (its folder and file name), else None."""
    return next((n for n, rel in PEER_FIGURES.items() if path.parts[-2:] == tuple(rel.split("/"))), None)


def clip_files(folder: str | os.PathLike[str] | None = None) -> list[Path]:
    """The BVH clips under ``folder`` (searched recursively, by relative path); default :func:`mocap_dir`.

    Raises:
        MjkinIOError: no folder given and no shared clips, or the folder is missing.
        InputError: the folder holds no BVH clips.
    """
    where = mocap_dir() if folder is None else Path(folder)
    if where is None:
        raise MjkinIOError("bench retarget needs a folder of BVH clips (--clips DIR); ../shared/mocap is not here")
    if not where.is_dir():
        raise MjkinIOError(f"--clips must be a folder of BVH clips; {str(where)!r} is not one")
    found = [job.path for job in find_clips([where]) if job.path.suffix.lower() == ".bvh"]
    if not found:
        raise InputError(f"folder {str(where)!r} holds no .bvh clips")
    return found


def best_run(tree: Tree, path: Path, repeat: int) -> tuple[Trajectory, float]:
    """The fastest of ``repeat`` retargets of ``path`` onto ``tree`` (by frames/s) and the least CPU seconds of one."""
    runs, cpu = [], []
    for _ in range(repeat):
        start = time.process_time()
        runs.append(retarget(path, tree))
        cpu.append(time.process_time() - start)
    return max(runs, key=lambda t: t.meta["retarget"]["frames_per_second"]), min(cpu)


def clip_row(name: str, tree: Tree, path: Path, repeat: int, run: tuple[Trajectory, float] | None = None) -> Row:
    """One clip onto one figure: frames/s the best of ``repeat`` runs, the measured figures of that run.

    ``floor_min_mm`` is the lowest point of the foot geoms against the ground under it (mm; negative: below).
    ``run``: that best run and its CPU seconds (:func:`best_run`) when already made.
    """
    best, cpu = run or best_run(tree, path, repeat)
    m = report(tree, best)
    return {"model": name, "clip": path.name, "frames": m["frames"],
            "frames_per_s": round(m["frames_per_second"]),
            "frames_per_cpu_s": round(m["frames"] / cpu),
            "keypoint_median_cm": round(100 * m["keypoint_error_median"], 2),
            "skate_mm_per_frame": round(1000 * m["skate_per_frame_mean"], 3),
            "skate_max_cm": round(100 * m["skate_per_contact_max"], 2),
            "floor_min_mm": round(1000 * m["floor_min"], 1),
            "limits_ok": m["limits"] is None, "speed_ratio": round(m["speed_limit_ratio"], 3),
            "self_contact_frames": m["self_contact_frames"],
            "deepest_mm": round(1000 * m["self_contact_deepest"], 1)}


def dataset_row(rows: Sequence[Row]) -> Row:
    """One figure's clips in the dataset form: frames/s median and quartiles over the clips, quality summarised.

    Key points and skate per frame: medians over the clips; the worst clip's skate per contact,
    lowest foot geom (``floor_min_mm``), speed ratio and deepest self-contact; clips inside the limits and self-contact
    frames counted over all clips.
    """
    def col(key: str) -> np.ndarray:
        return np.array([r[key] for r in rows], dtype=float)

    q25, median, q75 = np.percentile(col("frames_per_s"), [25, 50, 75])
    return {"model": rows[0]["model"], "clips": len(rows), "frames": int(col("frames").sum()),
            "frames_per_s_median": round(float(median)), "frames_per_s_iqr": round(float(q75 - q25)),
            "frames_per_s_q25": round(float(q25)), "frames_per_s_q75": round(float(q75)),
            "frames_per_cpu_s_median": round(float(np.median(col("frames_per_cpu_s")))),
            "keypoint_median_cm": round(float(np.median(col("keypoint_median_cm"))), 2),
            "skate_mm_per_frame": round(float(np.median(col("skate_mm_per_frame"))), 3),
            "skate_max_cm": float(col("skate_max_cm").max()), "floor_min_mm": float(col("floor_min_mm").min()),
            "clips_in_limits": int(col("limits_ok").sum()), "speed_ratio": float(col("speed_ratio").max()),
            "self_contact_frames": int(col("self_contact_frames").sum()),
            "deepest_mm": float(col("deepest_mm").min())}


def quality_row(name: str, path: Path, tool: str, tree: Tree, q: np.ndarray, frames_per_s: float) -> Row:
    """One tool's trajectory ``q`` for clip ``path`` on figure ``tree``, scored (:func:`mjkin.motion.quality.score`).

    Key points (hands, feet, head against the source scaled to the figure, each relative to its pelvis): mean and
    95th percentile, cm; self-contact deeper than 1 mm: frames, and the deepest (mm); the deepest foot geom under
    the ground (mm) and the frames with both feet over 3 cm above it (%); a planted sole's slide (cm/s); mean
    joint acceleration (rad/s²); joints inside their limits.
    """
    m = score(tree, q, path)
    return {"model": name, "clip": path.name, "tool": tool, "frames": m["frames"], "frames_per_s": round(frames_per_s),
            "keypoint_mean_cm": round(100 * float(m["keypoint_mean"]), 1),
            "keypoint_p95_cm": round(100 * float(m["keypoint_p95"]), 1),
            "self_contact_frames": m["self_contact_frames"],
            "self_deepest_mm": round(abs(1000 * float(m["self_contact_deepest"])), 1),
            "foot_under_mm": round(1000 * float(m["foot_penetration"]), 1),
            "both_feet_up_pct": round(100 * float(m["float_share"]), 1),
            "slide_cm_s": round(100 * float(m["slide_speed_mean"]), 2),
            "accel_rad_s2": round(float(m["joint_accel_mean"]), 2),
            "limits_ok": m["limits"] is None}


def beside_gmr(name: str, tree: Tree, path: Path, best: Trajectory, peer: gmr.Gmr | None,
               repeat: int) -> tuple[list[Row], str | None]:
    """The rows of mjkin (its best run) and GMR (the best of ``repeat`` runs) on one clip and robot, and why GMR
    has none (or None).

    GMR's frames/s are its runner's own: per-frame ``retarget()`` calls after the first, timed inside its process
    (``frames_per_s_after_first``), as mjkin's leave the first frame out. ``mjkin_per_gmr`` is mjkin's frames/s
    over GMR's.
    """  # noqa: D205
    mine = quality_row(name, path, "mjkin", tree, best.q, best.meta["retarget"]["frames_per_second"])
    robot = gmr.ROBOTS.get(name)
    if peer is None:
        return [mine], None
    if robot is None:
        return [mine], f"GMR on {name}: {gmr.NO_CONFIG}"
    try:
        runs = [gmr.retarget(peer, path, tree, robot) for _ in range(repeat)]
    except Unavailable as e:
        return [mine], f"GMR on {name}, {path.name}: {e}"
    q, timing = max(runs, key=lambda r: r[1]["frames_per_s_after_first"])
    theirs = quality_row(name, path, "gmr", tree, q, timing["frames_per_s_after_first"])
    theirs["gmr_config"] = timing["config"]
    mine["mjkin_per_gmr"] = round(best.meta["retarget"]["frames_per_second"] / timing["frames_per_s_after_first"], 2)
    return [mine, theirs], None


def bench_retarget(repeat: int = 3, clips: str | os.PathLike[str] | None = None,
                   models: Sequence[str] | None = None) -> Report:
    """Retarget every clip of ``clips`` (default the shared ones) onto every figure of ``models``, one thread.

    Per clip, ``frames_per_s`` is the best of ``repeat`` runs, wall-clock as :func:`mjkin.retarget`
    measures it (planning and solving, the first frame left out); ``frames_per_cpu_s`` counts the
    process's CPU time of the whole call (reading the file and the first frame too), so other work
    sharing the cores lowers it less. Each figure is warmed up on its first clip (kernels compiled,
    goal structures cached). Per figure, the dataset table (:func:`dataset_row`) sums the clips up;
    its rows are also the JSON's ``"dataset"``. On GMR's robots (:data:`PEER_FIGURES`) the third table puts
    GMR beside mjkin (:func:`beside_gmr`) when it is found (:func:`mjkin.apps.bench.gmr.find`); else a note
    says where it was looked for. Its rows are also the JSON's ``"beside_gmr"``.

    Raises:
        MjkinIOError, InputError: no clips, or a figure that is not available.
    """
    folder = mocap_dir() if clips is None else Path(clips)
    paths = clip_files(folder)
    figs = figures(models)
    per_clip: list[Row] = []
    dataset: list[Row] = []
    beside: list[Row] = []
    notes: list[str] = []
    peer = None
    if any(name in PEER_FIGURES for name, _ in figs):
        try:
            peer = gmr.find()
        except Unavailable as e:
            notes.append(str(e))
    with threads_set(1):
        for name, tree in figs:
            retarget(paths[0], tree)  # warm-up
            rows = []
            for path in paths:
                run = best_run(tree, path, repeat)
                rows.append(clip_row(name, tree, path, repeat, run))
                if name in PEER_FIGURES:
                    pair, why = beside_gmr(name, tree, path, run[0], peer, repeat)
                    beside.extend(pair)
                    notes.extend([why] if why and why not in notes else [])
            per_clip.extend(rows)
            dataset.append(dataset_row(rows))
    busy = ", ".join(f"{x:.2f}" for x in os.getloadavg())  # other work on the machine lowers frames/s
    tables = {"retarget per clip (frames/s: best of runs after a warm-up, one thread)": per_clip,
              "retarget over the clips (dataset form: frames/s median and interquartile range)": dataset}
    if beside:
        tables["mjkin beside GMR (one score for both: key points against the source scaled to the robot, "
               "relative to the pelvis; frames/s each tool's own, first frame left out)"] = beside
    settings: dict[str, object] = {"repeat": repeat, "clips": str(folder), "load average (1, 5, 15 min) after": busy}
    if peer is not None:
        settings["gmr"] = f"{peer.python} {peer.peer} ({', '.join(f'{k}={v}' for k, v in gmr.THREADS.items())})"
    return Report(tables, settings, {"dataset": dataset, **({"beside_gmr": beside} if beside else {})}, tuple(notes))
