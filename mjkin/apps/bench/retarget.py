"""``mjkin bench retarget``: the shared BVH clips onto the primate and the G1, with what the report measures."""

from __future__ import annotations

import os
import time
from pathlib import Path

from ...errors import MjkinIOError
from ...kinematics.tree import Tree, load
from ...motion.retarget import report, retarget
from .report import Report, Row, shared_model, shared_models_dir

CLIPS = ("mixamo_freebvh.bvh", "mocapbank_19joint.bvh")


def mocap_dir() -> Path | None:
    """``../shared/mocap`` beside the shared models, if it is there."""
    models = shared_models_dir()
    folder = None if models is None else models.parent / "mocap"
    return folder if folder is not None and folder.is_dir() else None


def bench_retarget(repeat: int = 3) -> Report:
    """Retarget every shared clip onto every figure; frames/s is the best of ``repeat`` runs after a warm-up.

    ``frames_per_s`` is wall-clock, as :func:`mjkin.retarget` measures it (planning and solving, the
    first frame left out); ``frames_per_cpu_s`` counts the process's CPU time of the whole call
    (reading the file and the first frame too), so other work sharing the cores lowers it less.

    Raises:
        MjkinIOError: the shared clips are not found.
    """
    folder = mocap_dir()
    if folder is None:
        raise MjkinIOError("bench retarget needs the shared clips (../shared/mocap); they are not here")
    figures: list[tuple[str, Tree]] = [("primate", load("primate"))]
    g1 = shared_model("unitree_g1/g1.xml")
    if g1 is not None:
        figures.append(("g1", g1))
    rows: list[Row] = []
    for name, tree in figures:
        for clip in CLIPS:
            path = folder / clip
            retarget(path, tree)  # warm-up: kernels compiled, goal structures cached
            runs, cpu = [], []
            for _ in range(repeat):
                start = time.process_time()
                runs.append(retarget(path, tree))
                cpu.append(time.process_time() - start)
            best = max(runs, key=lambda t: t.meta["retarget"]["frames_per_second"])
            m = report(tree, best)
            rows.append({"model": name, "clip": clip, "frames": m["frames"],
                         "frames_per_s": round(m["frames_per_second"]),
                         "frames_per_cpu_s": round(m["frames"] / min(cpu)),
                         "keypoint_median_cm": round(100 * m["keypoint_error_median"], 2),
                         "skate_mm_per_frame": round(1000 * m["skate_per_frame_mean"], 3),
                         "skate_max_cm": round(100 * m["skate_per_contact_max"], 2),
                         "lowest_sole_mm": round(1000 * m["floor_min"], 1),
                         "limits_ok": m["limits"] is None, "speed_ratio": round(m["speed_limit_ratio"], 3),
                         "self_contact_frames": m["self_contact_frames"],
                         "deepest_mm": round(1000 * m["self_contact_deepest"], 1)})
    busy = ", ".join(f"{x:.2f}" for x in os.getloadavg())  # other work on the machine lowers frames/s
    return Report({"retarget (frames/s: best of runs after a warm-up, one thread)": rows},
                  {"repeat": repeat, "clips": str(folder), "load average (1, 5, 15 min) after": busy})
