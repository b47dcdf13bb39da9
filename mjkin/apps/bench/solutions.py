"""``mjkin bench solutions``: all IK solutions against closed forms; a capability map and a base placement, checked.

Two 6-axis arms (:mod:`~mjkin.apps.bench.arms`) against their closed forms; the
Panda's capability map against brute-force IK; a base placement for 20 poses on
a shelf, verified by IK and by FK.
"""

from __future__ import annotations

import time

import numpy as np

from ... import goals as G
from ...explore.reachability import place_base, reachability
from ...explore.solutions import joint_distance, solutions
from ...ik.solve import solve
from ...kinematics.build import dh_fk
from ...kinematics.tree import load
from .arms import ARMS, CLOSED_FORMS, mjcf
from .report import Report, Row, gc_paused

MATCH = 1e-4  # an analytic solution counts as found when a returned one is this close (largest joint difference, rad)
SINGULAR = 1e-3  # a pose is near a wrist singularity when |sin q5| is below this
MAP = {"resolution": 0.15, "orientations": 12}  # the Panda's map
BRUTE_RESTARTS = 64  # restarts of the brute-force check of a map entry


def _all_found(name: str, n: int, seed: int) -> Row:
    """Solve ``n`` random poses of arm ``name``: share with every closed-form solution found, time per pose."""
    tree = load(mjcf(name))
    rng = np.random.default_rng(seed)
    q = tree.random_q(rng, n)
    T = tree.pose(q, "ee")
    solutions(tree, G.Pose("ee", T[0]))  # warm-up: kernels compiled, the goal structure cached
    extra, counts, times = np.zeros(n, np.int64), [], []
    singular, hit = np.zeros(n, dtype=bool), np.zeros(n, dtype=bool)
    with gc_paused():
        for i in range(n):
            ref = CLOSED_FORMS[name](dh_fk(ARMS[name], q[i]))
            singular[i] = np.abs(np.sin(q[i, 4])) < SINGULAR  # q5 is the wrist's bend on both arms
            start = time.perf_counter()
            res = solutions(tree, G.Pose("ee", T[i]))
            times.append(time.perf_counter() - start)
            d = joint_distance(tree, res.q[:, None], ref[None]) if len(res.q) else np.full((0, len(ref)), np.inf)
            hit[i] = bool(len(ref)) and bool(np.all(d.min(0, initial=np.inf) < MATCH))
            extra[i] = int(np.sum(d.min(1, initial=np.inf) >= MATCH))
            counts.append(len(ref))
    ms = 1000 * np.array(times)
    return {"arm": name, "poses": n, "analytic_mean": round(float(np.mean(counts)), 2),
            "all_found_pct": round(100 * float(hit.mean()), 1), "near_singular": int(singular.sum()),
            "all_found_pct_regular": round(100 * float(hit[~singular].mean()), 1),
            "not_analytic": int(extra.sum()), "not_analytic_regular": int(extra[~singular].sum()),
            "median_ms": round(float(np.median(ms)), 1), "p95_ms": round(float(np.percentile(ms, 95)), 1)}


def _map_agreement(checks: int, seed: int) -> Row:
    """Build the Panda's map (no cache) and check ``checks`` random (voxel, orientation) entries by brute-force IK."""
    tree = load("panda")
    m = reachability(tree, "flange", **MAP)  # type: ignore[arg-type]
    rng = np.random.default_rng(seed)
    cells = rng.integers(0, int(np.prod(m.shape)), checks)
    k = rng.integers(0, len(m.orientations), checks)
    idx = np.stack(np.unravel_index(cells, m.shape), -1)
    bit = m.reached[idx[:, 0], idx[:, 1], idx[:, 2], k]
    centre = m.centres()[idx[:, 0], idx[:, 1], idx[:, 2]]
    goals = [G.Position("flange", centre), G.Orientation("flange", m.orientations[k], axes=m.axes)]
    brute = solve(tree, goals, tol=1e-4, rot_tol=1e-3, restarts=BRUTE_RESTARTS, seed=seed + 1)
    ok = np.asarray(brute.success, dtype=bool)
    proven = np.asarray(brute.reason) == "out_of_reach"
    return {"model": "panda", "voxels": int(np.prod(m.shape)), "resolution_m": m.resolution,
            "orientations": len(m.orientations), "build_s": round(m.seconds, 1), "checks": checks,
            "agree_pct": round(100 * float(np.mean(ok == bit)), 2),
            "agree_pct_not_proven_far": round(100 * float(np.mean((ok == bit)[~proven])), 2),
            "map_reached_pct": round(100 * float(bit.mean()), 1), "brute_reached_pct": round(100 * float(ok.mean()), 1)}


def shelf_poses() -> np.ndarray:
    """20 poses ``(20, 4, 4)`` on the front of a shelf at x = 1.4 m: a 5 x 4 grid, the flange's z axis pointing +x.

    Heights 0.45 to 0.75 m: the Panda reaches no pose straight ahead of its base at 0.25 to 0.35 m with the flange
    level (a shelf that low had 19 of 20 at best, from every base tried).
    """
    R = np.array([[0.0, 0.0, 1.0], [0.0, 1.0, 0.0], [-1.0, 0.0, 0.0]])  # columns x, y, z: x down, z forward
    ys, zs = np.linspace(-0.3, 0.3, 5), np.linspace(0.45, 0.75, 4)
    T = np.broadcast_to(np.eye(4), (20, 4, 4)).copy()
    T[:, :3, :3] = R
    T[:, :3, 3] = [(1.4, y, z) for y in ys for z in zs]
    return T


def _placement(seed: int) -> Row:
    """Place the Panda's base for the shelf poses; check the chosen base's configurations by FK."""
    tree = load("panda")
    poses = shelf_poses()
    start = time.perf_counter()
    p = place_base(tree, "flange", poses, (0.0, -0.5, 1.2, 0.5), seed=seed, **MAP)  # type: ignore[arg-type]
    seconds = time.perf_counter() - start
    world = p.base(0) @ tree.pose(p.q[0], "flange")
    err = np.linalg.norm(world[:, :3, 3] - poses[:, :3, 3], axis=-1)[p.reached[0]]  # the reached ones, by FK
    return {"task": "shelf", "poses": len(poses), "base_x": round(float(p.xy[0, 0]), 3),
            "base_y": round(float(p.xy[0, 1]), 3), "yaw_deg": round(float(np.degrees(p.yaw[0])), 1),
            "reached": int(p.count[0]), "fk_max_error_mm": round(1000 * float(err.max(initial=0)), 4),
            "seconds": round(seconds, 1)}


def bench_solutions(poses: int = 1000, checks: int = 1000, seed: int = 0) -> Report:
    """Every table of ``mjkin bench solutions``."""
    arms = [_all_found(name, poses, seed) for name in ARMS]
    return Report({f"all solutions of {poses} random poses against the closed forms (one thread)": arms,
                   "the Panda's capability map against brute-force IK": [_map_agreement(checks, seed)],
                   "base placement for 20 poses on a shelf, verified by IK and FK": [_placement(seed)]},
                  {"match_rad": MATCH, "near_singular_if_abs_sin_q5_below": SINGULAR, "brute_restarts": BRUTE_RESTARTS,
                   **MAP})
