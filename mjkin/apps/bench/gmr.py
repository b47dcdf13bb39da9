"""GMR (General Motion Retargeting, github YanjieZe/GMR) as a peer of ``mjkin bench retarget``, run in its own venv.

GMR is not on the package index and pins its own versions, so it runs in a subprocess of its venv's Python, through
the runner and BVH converter of its peer folder (``../shared/peers/gmr``, copied with its robot assets linked, see
its README): ``bvh_lafan.py`` renames the clip's joints to LAFAN1's (the only rig GMR's BVH path reads) and
``run_gmr.py`` runs GMR's own loader, retargeter and per-frame ``retarget()`` and prints its timings as JSON. Its
qpos come back as an ``.npz`` and are scored by :func:`mjkin.motion.quality.score` beside mjkin's. None of GMR's
code is in mjkin.

Where GMR is: ``$MJKIN_GMR_PYTHON`` (its venv's Python) and ``$MJKIN_GMR_PEER`` (the peer folder), else
``../gmr-venv/bin/python`` and ``../gmr-peer`` beside the working folder or one of its parents (as ``../shared``).
"""

from __future__ import annotations

import json
import os
import subprocess
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from ...kinematics.qspace import FREE
from ...kinematics.tree import Tree
from ...motion import bvh
from ...motion.roles import source_mapping
from .peers import Unavailable

ROBOTS = {"gmr_unitree_g1": "unitree_g1"}  # shared model folder -> GMR's robot name, where the peer runs it
# per GMR robot, its config for each rest pose of a rig: GMR's bvh_to_g1.json is tuned for LAFAN1's rest pose; the
# peer folder's refits are for rigs at rest in a T-pose and with the arms down (make_gmr_config.py, as GMR's issues
# #27 and #51 advise)
CONFIGS = {"unitree_g1": {"tpose": "bvh_tpose_to_g1.json", "armsdown": "bvh_armsdown_to_g1.json"}}
NO_CONFIG = ("GMR has bvh_to_t1.json, tuned for LAFAN1's rest pose only; the peer folder's runner and rest-pose "
             "refits are for the G1")
HOW = ("set MJKIN_GMR_PYTHON (GMR's venv's python) and MJKIN_GMR_PEER (a copy of ../shared/peers/gmr with its "
       "assets linked), or put them at ../gmr-venv and ../gmr-peer: see ../shared/peers/gmr/README.md")
TIMEOUT = 1800.0  # s for one GMR run
THREADS = {"OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}  # as mjkin's one thread


@dataclass(frozen=True)
class Gmr:
    """Where GMR runs: its venv's Python and the peer folder (``run_gmr.py``, ``bvh_lafan.py``, ``gmr-src/``)."""

    python: Path
    peer: Path


def _beside(name: str) -> Path | None:
    for base in (Path.cwd(), *Path.cwd().parents):
        if (base.parent / name).exists():
            return base.parent / name
    return None


def find() -> Gmr:
    """GMR's Python and peer folder (see the module), checked.

    Raises:
        Unavailable: either is missing, or the G1's assets are not linked into the peer's ``gmr-src/assets``.
    """
    env_py, env_peer = os.environ.get("MJKIN_GMR_PYTHON"), os.environ.get("MJKIN_GMR_PEER")
    python = Path(env_py) if env_py else (lambda v: None if v is None else v / "bin" / "python")(_beside("gmr-venv"))
    peer = Path(env_peer) if env_peer else _beside("gmr-peer")
    if python is None or not python.is_file():
        raise Unavailable(f"GMR was not found (no Python at {python or '../gmr-venv/bin/python'}): {HOW}")
    if peer is None or not (peer / "run_gmr.py").is_file() or not (peer / "bvh_lafan.py").is_file():
        raise Unavailable(f"GMR was not found (no peer folder with run_gmr.py at {peer or '../gmr-peer'}): {HOW}")
    g1 = peer / "gmr-src" / "assets" / "unitree_g1" / "g1_mocap_29dof.xml"
    if not g1.is_file():
        raise Unavailable(f"GMR's G1 is not at {g1}: link ../shared/models/gmr_unitree_g1 there as "
                          f"gmr-src/assets/unitree_g1")
    return Gmr(python.absolute(), peer.absolute())


def rest_pose(clip: bvh.Clip) -> str:
    """``"tpose"`` when the rig's rest pose holds the arms out (within 45 degrees of level), else ``"armsdown"``."""
    roles, p = source_mapping(clip), clip.positions(rest=True)[0]
    up = []
    for s in ("left", "right"):
        arm = p[roles[f"{s}_wrist"]] - p[roles[f"{s}_shoulder"]]
        up.append(arm[1] / max(float(np.linalg.norm(arm)), 1e-12))  # BVH is y-up
    return "tpose" if float(np.mean(up)) > -np.sqrt(0.5) else "armsdown"


def _run(cmd: list[str], what: str) -> str:
    env = {**os.environ, **THREADS}
    try:
        done = subprocess.run(cmd, capture_output=True, text=True, timeout=TIMEOUT, env=env, check=False)
    except subprocess.TimeoutExpired:
        raise Unavailable(f"{what} took over {TIMEOUT:g} s") from None
    if done.returncode != 0:
        tail = (done.stderr.strip().splitlines() or ["(no output)"])[-1]
        raise Unavailable(f"{what} failed (exit {done.returncode}): {tail}")
    return done.stdout


def qpos_names(tree: Tree) -> list[str]:
    """The names GMR's runner gives qpos entries: a free joint's ``NAME_x ... NAME_qz``, else the joint's name."""
    names: list[str] = []
    for j, n in enumerate(tree.names("joint")):
        names += [f"{n}_{c}" for c in ("x", "y", "z", "qw", "qx", "qy", "qz")] if tree.jnt_type[j] == FREE else [n]
    return names


def retarget(gmr: Gmr, clip_path: Path, tree: Tree, robot: str = "unitree_g1",
             workdir: str | os.PathLike[str] | None = None) -> tuple[NDArray[np.float64], dict]:
    """GMR's qpos ``(F, nq)`` for ``clip_path`` on ``tree`` and its runner's timings (with ``config`` chosen).

    The clip is converted to LAFAN1's names in its own units' centimetres; the refit config matches its rest pose
    (:func:`rest_pose`). GMR's qpos are put in ``tree``'s order by name.

    Raises:
        Unavailable: a robot the peer does not run, a failed run, or qpos that do not name ``tree``'s joints.
    """
    if robot not in CONFIGS:
        raise Unavailable(NO_CONFIG)
    clip = bvh.read(clip_path)
    config = CONFIGS[robot][rest_pose(clip)]
    with tempfile.TemporaryDirectory(dir=workdir) as tmp:
        lafan, out = Path(tmp) / "clip_lafan.bvh", Path(tmp) / "gmr.npz"
        _run([str(gmr.python), str(gmr.peer / "bvh_lafan.py"), str(clip_path), str(lafan),
              "--cm-per-unit", repr(100.0 * bvh.unit_scale(clip)[0])], f"GMR's BVH converter on {clip_path.name}")
        text = _run([str(gmr.python), str(gmr.peer / "run_gmr.py"), str(lafan), str(out), "--config",
                     str(gmr.peer / config)], f"GMR on {clip_path.name}")
        with np.load(out) as data:
            q, names = np.array(data["qpos"], dtype=np.float64), [str(n) for n in data["qpos_names"]]
    timings = json.loads(text.strip().splitlines()[-1])
    want = qpos_names(tree)
    if sorted(names) != sorted(want) or q.shape[1:] != (tree.nq,):
        raise Unavailable(f"GMR's qpos name other joints than {tree.name!r}'s")
    return q[:, [names.index(n) for n in want]], {**timings, "config": config}
