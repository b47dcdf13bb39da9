"""``mjkin bench startup``: what a first run costs, from an empty kernel cache, in a child process per entry point.

Each entry point runs in a fresh copy of the installed package (its sources and
the C call path, no ``__pycache__``: as after ``pip install``) with its own empty
caches, then once more in that copy, now warm: the second process is what every
later run costs. A child reports import seconds, its entry's first call, the
seconds numba spent compiling each top-level function in it (its
``"numba:compile"`` events), the process's peak memory (``ru_maxrss``), and, where
a cold kernel ran interpreted meanwhile (:mod:`mjkin.runtime.tier`, the default mode), the
seconds until the background compile was done and that child's peak memory.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

from ...runtime.cache import PACKAGE
from .report import Report, Row

# the child: times the import and one entry point's first call, counts numba's compile events, prints one JSON line
_CHILD = r'''
import json, resource, sys, time
from collections import Counter
compiled, depth = Counter(), []
def start(f):
    depth.append(time.perf_counter())
def end(f):
    seconds = time.perf_counter() - depth.pop()
    if not depth:  # a top-level compile: the seconds of what it compiled in too
        compiled[f"{getattr(f, '__module__', '?')}.{getattr(f, '__qualname__', '?')}"] += seconds
t0 = time.perf_counter()
import mjkin
import mjkin.runtime.tier
imported = time.perf_counter() - t0
mjkin.runtime.numba_private.on_compile(start, end)  # nothing compiles at import
import numpy as np
from mjkin import goals as G
entry = sys.argv[1]
t1 = time.perf_counter()
if entry == "solve":  # the first 6-D pose solve on the Panda (its target made from a known q without mjkin's FK)
    import mujoco
    tree = mjkin.load("panda")
    data = mujoco.MjData(tree.model)
    data.qpos[:] = tree.random_q(np.random.default_rng(0), 1)[0]
    mujoco.mj_kinematics(tree.model, data)
    site = tree.model.site("flange").id
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = data.site_xmat[site].reshape(3, 3), data.site_xpos[site]
    t1 = time.perf_counter()
    ok = bool(mjkin.solve(tree, G.Pose("flange", T=T)).success)
elif entry == "pose":  # one tree.pose of one q (the C call path's kernels)
    tree = mjkin.load("panda")
    t1 = time.perf_counter()
    ok = bool(np.isfinite(tree.pose(tree.qpos0, "flange")).all())
elif entry == "retarget":
    tree = mjkin.load("primate")
    t1 = time.perf_counter()
    ok = len(mjkin.retarget(sys.argv[2], tree).q) > 0
elif entry == "kind":  # a user's own goal kind (KIND, a module beside the package) with a Position, on the Panda
    import height_kind
    G.register(height_kind.Height)
    tree = mjkin.load("panda")
    t1 = time.perf_counter()
    ok = bool(mjkin.solve(tree, [height_kind.Height("flange", z=0.4), G.Position("ee", [0.4, 0.1, 0.45])]).success)
elif entry == "env":
    import gymnasium as gym
    import mjkin.envs  # noqa: F401
    env = gym.make("mjkin/Reach-v0")
    t1 = time.perf_counter()
    env.reset(seed=0)
    ok = all(np.isfinite(env.step(env.action_space.sample())[0]).all() for _ in range(3))
elif entry == "render":
    import mjkin.render
    tree = mjkin.load("arm7")
    qs = tree.random_q(np.random.default_rng(0), 3)
    t1 = time.perf_counter()
    ok = len(list(mjkin.render.frames(tree, qs, 160, 120))) == 3
first = time.perf_counter() - t1
peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
background = mjkin.runtime.tier.settle()  # the children compiling what ran interpreted meanwhile (mjkin.runtime.tier)
print(json.dumps({"import_s": imported, "first_s": first, "ok": ok, "compile_s": sum(compiled.values()),
                  "compiled": compiled.most_common(4), "peak_mb": peak, "background_s": background,
                  "child_peak_mb": resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024}))
'''

# the goal kind of the "kind" entry: a frame's height (one row), as a user would write one (see the README)
KIND = '''
from dataclasses import dataclass
from typing import ClassVar

from mjkin.goals.base import METRES, FrameGoal
from mjkin.runtime.jit import njit_ir_inline


@dataclass(frozen=True)
class Height(FrameGoal):
    z: float = 0.0
    rows: ClassVar[int] = 1
    units: ClassVar = METRES

    def encode(self, tree, data, rest):
        data[:, 0] = self.z


@njit_ir_inline
def residual(kin, ga, ws, rot, pos, irot, ipos, i, b, q, g, J, r0, err):
    J6, pt = ws[0], ws[1]  # the frame's Jacobian and point (mjkin.goals.residuals.goal_frame)
    w = ga.sqrt_w[i]
    g[r0] = w * (pt[0, 2] - ga.data[b, i, 0])
    for j in range(J.shape[1]):
        J[r0, j] = w * J6[0, 2, j]
    err[i, 0] = abs(pt[0, 2] - ga.data[b, i, 0])
'''
ENTRIES = ("solve", "kind", "pose", "retarget", "env", "render")


def fresh_copy(folder: Path) -> Path:
    """A copy of the installed package in ``folder`` (sources and the built C module, no caches); returns ``folder``."""
    shutil.copytree(PACKAGE, folder / PACKAGE.name, ignore=shutil.ignore_patterns("__pycache__"))
    (folder / "height_kind.py").write_text(KIND)
    return folder


def run_child(root: Path, entry: str, *args: str, timeout: float = 1800) -> dict:
    """Run the entry ``entry`` in a child that imports mjkin from ``root`` with no outside kernel cache."""
    env = {k: v for k, v in os.environ.items() if k not in ("NUMBA_CACHE_DIR", "MJKIN_COMPILE")}  # as a user has it
    env["PYTHONPATH"] = os.pathsep.join([str(root), env.get("PYTHONPATH", "")]).rstrip(os.pathsep)
    env["XDG_CACHE_HOME"] = str(root / "xdg")  # nothing cached per user either
    done = subprocess.run([sys.executable, "-c", _CHILD, entry, *args], capture_output=True, text=True, env=env,
                          cwd=root, timeout=timeout)
    if done.returncode:
        raise RuntimeError(f"bench startup {entry}: the child failed: {done.stderr.strip().splitlines()[-1:]}")
    return dict(json.loads(done.stdout.strip().splitlines()[-1]))


def bench_startup(entries: tuple[str, ...] = ENTRIES, clip: Path | None = None) -> Report:
    """Cold and warm rows for each entry point (``retarget`` needs a BVH ``clip``; without one it is skipped)."""
    rows: list[Row] = []
    skipped = []
    for entry in entries:
        if entry == "retarget" and clip is None:
            skipped.append("retarget (no clip: the shared mocap folder is not here)")
            continue
        args = (str(clip),) if entry == "retarget" else ()
        with tempfile.TemporaryDirectory(prefix="mjkin-startup-") as tmp:
            root = fresh_copy(Path(tmp))
            for cache in ("empty", "warm"):
                r = run_child(root, entry, *args)
                rows.append({"entry": entry, "cache": cache, "import_s": round(r["import_s"], 2),
                             "first_call_s": round(r["first_s"], 2),
                             "total_s": round(r["import_s"] + r["first_s"], 2),
                             "compile_s": round(r["compile_s"], 1), "peak_mb": round(r["peak_mb"]),
                             "background_s": None if r["background_s"] is None else round(r["background_s"], 1),
                             "child_peak_mb": None if r["background_s"] is None else round(r["child_peak_mb"]),
                             "ok": r["ok"], "most_compile": ", ".join(f"{name.rsplit('.', 1)[-1]} {s:.1f} s"
                                                                      for name, s in r["compiled"][:3])})
    settings: dict[str, object] = {"package": str(PACKAGE), "cpus": os.cpu_count(),
                                   "load average (1, 5, 15 min) after": ", ".join(f"{x:.2f}" for x in os.getloadavg())}
    if skipped:
        settings["skipped"] = "; ".join(skipped)
    return Report({"startup (a fresh copy of the package; empty caches, then the same copy warm)": rows}, settings)
