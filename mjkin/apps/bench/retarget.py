"""``mjkin bench retarget``: a folder of BVH clips onto figures, per clip and in a dataset's form.

The dataset table is the form retargeting benchmarks on LAFAN1 report speed in: per figure, the
median frames/s over the clips and its spread (the interquartile range), beside the quality
figures :func:`mjkin.motion.retarget.report` measures, summarised over the clips.
"""

from __future__ import annotations

import os
import time
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from ...errors import InputError, MjkinIOError
from ...kinematics.tree import Tree, load
from ...motion.dataset import find_clips
from ...motion.retarget import report, retarget
from ...runtime.parallel import threads_set
from . import FK_MODELS
from .report import Report, Row, shared_model, shared_models_dir

CLIPS = ("mixamo_freebvh.bvh", "mocapbank_19joint.bvh")
FIGURES = ("primate", "g1")  # the default figures: the bundled humanoid, the shared G1 when it is there


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
            out.append((name if name == "primate" else Path(name).stem, load(name)))
            continue
        tree = shared_model(FK_MODELS[name]) if name in FK_MODELS else None
        if tree is not None:
            out.append((name, tree))
        elif names:
            raise InputError(f"--models takes {', '.join(FIGURES)} or MJCF files of figures with a free root; "
                             f"{name!r} is not available")
    return out


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


def clip_row(name: str, tree: Tree, path: Path, repeat: int) -> Row:
    """One clip onto one figure: frames/s the best of ``repeat`` runs, the measured figures of that run.

    ``floor_min_mm`` is the lowest point of the foot geoms against the ground under it (mm; negative: below).
    """
    runs, cpu = [], []
    for _ in range(repeat):
        start = time.process_time()
        runs.append(retarget(path, tree))
        cpu.append(time.process_time() - start)
    best = max(runs, key=lambda t: t.meta["retarget"]["frames_per_second"])
    m = report(tree, best)
    return {"model": name, "clip": path.name, "frames": m["frames"],
            "frames_per_s": round(m["frames_per_second"]),
            "frames_per_cpu_s": round(m["frames"] / min(cpu)),
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


def bench_retarget(repeat: int = 3, clips: str | os.PathLike[str] | None = None,
                   models: Sequence[str] | None = None) -> Report:
    """Retarget every clip of ``clips`` (default the shared ones) onto every figure of ``models``, one thread.

    Per clip, ``frames_per_s`` is the best of ``repeat`` runs, wall-clock as :func:`mjkin.retarget`
    measures it (planning and solving, the first frame left out); ``frames_per_cpu_s`` counts the
    process's CPU time of the whole call (reading the file and the first frame too), so other work
    sharing the cores lowers it less. Each figure is warmed up on its first clip (kernels compiled,
    goal structures cached). Per figure, the dataset table (:func:`dataset_row`) sums the clips up;
    its rows are also the JSON's ``"dataset"``.

    Raises:
        MjkinIOError, InputError: no clips, or a figure that is not available.
    """
    folder = mocap_dir() if clips is None else Path(clips)
    paths = clip_files(folder)
    figs = figures(models)
    per_clip: list[Row] = []
    dataset: list[Row] = []
    with threads_set(1):
        for name, tree in figs:
            retarget(paths[0], tree)  # warm-up
            rows = [clip_row(name, tree, path, repeat) for path in paths]
            per_clip.extend(rows)
            dataset.append(dataset_row(rows))
    busy = ", ".join(f"{x:.2f}" for x in os.getloadavg())  # other work on the machine lowers frames/s
    return Report({"retarget per clip (frames/s: best of runs after a warm-up, one thread)": per_clip,
                   "retarget over the clips (dataset form: frames/s median and interquartile range)": dataset},
                  {"repeat": repeat, "clips": str(folder),
                   "load average (1, 5, 15 min) after": busy},
                  {"dataset": dataset})
