"""``mjkin bench constraints``: Clearance inside the solver beside no clearance and the old reject-and-retry.

arm7 and the Panda among three obstacle spheres and a table (a box). Targets are
the effector positions of random configurations whose clearance is at least the
margin, so a clear answer exists. Every answer is re-checked by MuJoCo's
``mj_geomDistance`` over every pair MuJoCo would collide: a *violation* is a
success whose clearance is below ``margin - 1e-6``.
"""

from __future__ import annotations

import time

import numpy as np

from ... import goals as G
from ...ik import Problem
from ...kinematics.distance import fallback_distance
from ...kinematics.geoms import contact_pairs
from ...kinematics.tree import Tree, bundled_models, load
from .report import Report, Row, gc_paused

OBSTACLES = ('<geom name="obstacle0" type="sphere" size="0.1" pos="0.35 0.2 0.6"/>'
             '<geom name="obstacle1" type="sphere" size="0.08" pos="0.3 -0.25 0.45"/>'
             '<geom name="obstacle2" type="sphere" size="0.1" pos="-0.3 0.3 0.7"/>'
             '<geom name="table" type="box" size="0.3 0.3 0.02" pos="0.55 0 0.25"/>')
MODELS = {"arm7": "ee", "panda": "flange"}
RETRIES = 8  # the old avoid_collisions: re-solve from this many seeded random starts


def cluttered(name: str) -> Tree:
    """A bundled arm with the bench's obstacles in its world."""
    return load(bundled_models()[name].read_text().replace("<worldbody>", "<worldbody>" + OBSTACLES, 1))


def clearance(tree: Tree, q: np.ndarray) -> float:
    """The least signed distance (m) over MuJoCo's contact pairs, by ``mujoco.mj_geomDistance``."""
    return min(fallback_distance(tree, q, int(a), int(b))[0] for a, b in contact_pairs(tree))


def bench_constraints(targets: int = 200, margin: float = 0.005, seed: int = 0) -> Report:
    """Solve ``targets`` reachable, clear positions per model three ways; success, violations, median time."""
    rows = [row for name, frame in MODELS.items() for row in _model_rows(name, frame, targets, margin, seed)]
    return Report({f"constraints (clearance >= {margin} m; MuJoCo mj_geomDistance re-check; one thread)": rows},
                  {"targets": targets, "margin": margin, "seed": seed})


def _model_rows(name: str, frame: str, targets: int, margin: float, seed: int) -> list[Row]:
    tree = cluttered(name)
    rng = np.random.default_rng(seed)
    qs = tree.random_q(rng, 20 * targets)
    qs = qs[tree.distances(qs).min(axis=-1) >= margin][:targets]
    points = tree.pose(qs, frame)[:, :3, 3]
    q0 = tree.qpos0
    starts = tree.random_q(np.random.default_rng(seed + 1), RETRIES)
    plain = Problem(tree, G.Position(frame, points[0]))
    single = Problem(tree, G.Position(frame, points[0]), restarts=0)
    clear = Problem(tree, [G.Position(frame, points[0]), G.Clearance(margin)])

    def retry(p: np.ndarray) -> tuple[np.ndarray, bool]:  # the old way: solve, then re-solve until clear
        res = plain.solve(q0, G.Position(frame, p))
        if res.success and clearance(tree, res.q) >= margin:
            return res.q, True
        for s in starts:
            res = single.solve(s, G.Position(frame, p))
            if res.success and clearance(tree, res.q) >= margin:
                return res.q, True
        return res.q, False

    ways = {"no clearance": lambda p: _ok(plain.solve(q0, G.Position(frame, p))),
            "Clearance (hard, in the solver)": lambda p: _ok(clear.solve(q0, [G.Position(frame, p),
                                                                             G.Clearance(margin)])),
            "reject and retry (old avoid_collisions)": retry}
    rows: list[Row] = []
    for way, solve in ways.items():
        solve(points[0])  # warm-up: kernels compiled
        times, wins, bad = [], 0, 0
        for p in points:
            with gc_paused():
                t = time.perf_counter()
                q, ok = solve(p)
                times.append(time.perf_counter() - t)
            if ok:
                wins += 1
                bad += clearance(tree, q) < margin - 1e-6
        rows.append({"model": name, "solver": way, "targets": len(points),
                     "success_pct": round(100 * wins / len(points), 1), "violations": bad,
                     "median_ms": round(1e3 * float(np.median(times)), 3)})
    return rows


def _ok(res: object) -> tuple[np.ndarray, bool]:
    return np.asarray(res.q), bool(res.success)  # type: ignore[attr-defined]
