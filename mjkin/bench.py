"""Benchmarks: mjkin and its baseline side by side in one process, reported as ratios.

Nothing here is asserted by tests: timings on shared machines are noisy. Each
benchmark returns rows (dicts) and the CLI prints them as a table.
"""

from __future__ import annotations

import os
import time
from collections.abc import Callable
from pathlib import Path

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


BENCHMARKS: dict[str, Callable[[], Tables]] = {"fk": bench_fk, "seeds": bench_seeds}
