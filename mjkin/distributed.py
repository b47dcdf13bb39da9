"""Batch IK and rendering past one machine, on Ray (``pip install "mjkin[ray]"``).

One machine solves millions of targets with :func:`mjkin.solve` alone (its
threads use every core). Reach for Ray when the work outgrows a machine: many
nodes, rendering many clips, slow methods (``optimize``, ``avoid_collisions``)
or datasets larger than memory.

- :func:`solve_many` cuts a batch into chunks, solves them on Ray actors (each
  loads the model once and keeps its kernels compiled) and returns the same
  :class:`~mjkin.Result` as :func:`mjkin.solve`, bit for bit.
- :func:`render_many` renders trajectory scripts (``mjkin trajectory``,
  :meth:`mjkin.motion.Trajectory.save`) to clips, one per task, encoded in the
  worker.
- :func:`random_poses` and :class:`PoseSolver` are Ray Data stages for datasets
  that do not fit in memory: targets are made in the workers, solved there and
  written as Parquet shards, never gathered on the driver::

      import ray
      from mjkin.distributed import PoseSolver, random_poses

      n, chunk, workers = 100_000_000, 20_000, 64
      (ray.data.range(n, override_num_blocks=n // chunk)
          .map_batches(random_poses, fn_kwargs=dict(model="arm7", frame="ee", seed=0), batch_size=chunk)
          .map_batches(PoseSolver, fn_constructor_kwargs=dict(model="arm7", frame="ee", restarts=0),
                       batch_size=chunk, concurrency=workers, num_cpus=1)
          .write_parquet("s3://bucket/arm7-ik"))  # columns: id, position, quaternion, q, success, error

  Leave a CPU free for the read tasks (which also make the targets):
  with ``workers`` equal to the cluster's CPUs, Ray Data waits forever.
  ``examples/ray_dataset.py`` runs this job on one machine.

Both functions attach to a running cluster (``ray.init`` already called, or
``address=``) or start a local one. Workers import the mjkin installed on their
node and use its numba cache: run ``mjkin warmup`` in the node image (or point
``NUMBA_CACHE_DIR`` at a warm cache), else every worker compiles for about a
minute first. Paths given to :func:`render_many` must be on storage every node
sees. mjkin's own errors (:class:`~mjkin.MjkinError`) raised in a worker are
re-raised on the driver with their type; goals and scripts are checked on the
driver before any work is shipped.
"""

from __future__ import annotations

import os
import sys
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any, TypeAlias

import mujoco
import numpy as np
from numpy.typing import ArrayLike, NDArray

from . import goals as G
from . import motion
from .errors import InputError
from .goals.program import key_of
from .ik import History, Problem, Result
from .kinematics.tree import Tree, load
from .runtime.parallel import set_threads, threads
from .runtime.ray_session import connect, module, unwrap
from .spatial import mat_to_quat, quat_to_mat

ray: Any = module()  # this module is Ray's side of mjkin: importing it imports Ray (None without the extra)
IN_FLIGHT = 2  # tasks queued per actor: one runs while the next one's input travels
Model: TypeAlias = str | os.PathLike[str] | mujoco.MjModel | mujoco.MjSpec | Tree


def _tree(model: Model) -> Tree:
    return model if isinstance(model, Tree) else load(model)


class Worker:
    """What runs in a Ray actor: one model, loaded once, and mjkin with ``threads`` solver threads."""

    def __init__(self, model: mujoco.MjModel, threads: int) -> None:
        set_threads(threads)
        self.tree = Tree.from_model(model)
        self.problems: dict[str, Problem] = {}  # by goal structure and options: a job's chunks share one

    def solve(self, goals: list[G.Goal], q0: NDArray | None, options: dict) -> Result:
        """:func:`mjkin.solve` on this worker's model (the result travels without its tree)."""
        key = repr((key_of(tuple(goals)), sorted(options.items())))
        if key not in self.problems:
            self.problems = {key: Problem(self.tree, goals, **options)}  # the last job's only
        return self.problems[key].solve(q0, goals)

    def render(self, traj: motion.Trajectory, path: str, width: int, height: int, fps: float) -> str:
        """Render a script to the clip ``path`` (as ``mjkin replay`` does); returns the path."""
        from . import render

        overlay = render.Overlay(points=np.zeros((0, 3)) if traj.targets is None else traj.targets, trail=traj.frame)
        images = render.frames(self.tree, traj.q, width, height, overlay=overlay)
        return str(render.write_video(images, path, fps))

    def threads(self) -> int:
        """Solver threads this worker runs (:func:`mjkin.threads` in its process)."""
        return threads()


def _actors(tree: Tree, workers: int | None, threads_per_worker: int, jobs: int) -> list[Any]:
    """Start the actors: ``workers`` of them, or as many as the cluster's CPUs hold (never more than jobs)."""
    if (isinstance(threads_per_worker, bool) or not isinstance(threads_per_worker, (int, np.integer))
            or threads_per_worker < 1):
        raise InputError(f"threads_per_worker must be a positive integer, got {threads_per_worker!r}")
    cpus = int(ray.cluster_resources().get("CPU", 0))
    if threads_per_worker > cpus:
        raise InputError(f"threads_per_worker={threads_per_worker} but the Ray cluster has {cpus} CPUs")
    if workers is None:
        workers = max(1, cpus // threads_per_worker)
    elif isinstance(workers, bool) or not isinstance(workers, (int, np.integer)) or workers < 1:
        raise InputError(f"workers must be a positive integer (or None: one per {threads_per_worker} CPUs), "
                         f"got {workers!r}")
    actor = ray.remote(num_cpus=threads_per_worker)(Worker)
    model = ray.put(tree.model)
    return [actor.remote(model, int(threads_per_worker)) for _ in range(min(int(workers), jobs))]


def _dispatch(actors: list[Any], jobs: Sequence[Callable[[Any], Any]], sizes: Sequence[int],
              progress: bool, desc: str) -> list[Any]:
    """Run ``jobs[k](actor)`` on the actors, ``IN_FLIGHT`` per actor, each actor taking the next job when free.

    Returns the jobs' results in job order; the actors are stopped at the end.
    """
    from tqdm import tqdm

    out: list[Any] = [None] * len(jobs)
    todo = iter(range(len(jobs)))
    idle = [a for _ in range(IN_FLIGHT) for a in actors]
    running: dict[Any, tuple[int, Any]] = {}
    bar = tqdm(total=sum(sizes), desc=desc, disable=not (progress and sys.stderr.isatty()), dynamic_ncols=True)
    try:
        while True:
            for actor in idle:
                k = next(todo, None)
                if k is None:
                    break
                running[jobs[k](actor)] = (k, actor)
            if not running:
                return out
            done, _ = ray.wait(list(running), num_returns=1)
            k, actor = running.pop(done[0])
            out[k] = unwrap(done[0])
            idle = [actor]
            bar.update(sizes[k])
    finally:
        bar.close()
        for actor in actors:
            ray.kill(actor)
        for ref in running:  # after an error: collect the abandoned tasks, so Ray does not report them
            try:
                ray.get(ref)
            except Exception:  # noqa: BLE001 - their errors are the same or follow from the kill
                pass


def concatenate(parts: Sequence[Result], tree: Tree | None = None) -> Result:
    """One :class:`~mjkin.Result` from the results of consecutive chunks of one batched solve."""
    if not parts:
        raise InputError("no results to concatenate")
    first = parts[0]
    if any(np.ndim(p.success) != 1 for p in parts):
        raise InputError("only results of batched solves (one leading batch axis) can be concatenated")

    def cat(name: str) -> NDArray:
        return np.concatenate([getattr(p, name) for p in parts])

    history = None
    if first.history is not None:
        hs = [p.history for p in parts if p.history is not None]
        history = History(np.concatenate([h.q for h in hs]), np.concatenate([h.error for h in hs]))
    goals = tuple(G.concatenate(pieces) for pieces in zip(*[p.goals for p in parts], strict=True))
    return Result(q=cat("q"), success=cat("success"), error=cat("error"), iterations=cat("iterations"),
                  status=cat("status"), goal_errors=cat("goal_errors"), goals=goals,
                  method=first.method, restarts=cat("restarts"), history=history,
                  reason=None if first.reason is None else cat("reason"),
                  binding=None if first.binding is None else cat("binding"), tree=tree)


def _check_q0(tree: Tree, q0: ArrayLike | None, B: int) -> NDArray | None:
    if q0 is None:
        return None
    q = tree.check_q(q0, "q0")
    if q.ndim > 2 or (q.ndim == 2 and q.shape[0] != B):
        raise InputError(f"q0 has shape {q.shape}; expected ({tree.nq},) or ({B}, {tree.nq}) for these targets")
    return q


def solve_many(model: Model, goals: G.Goal | Sequence[G.Goal], q0: ArrayLike | None = None, *, chunk: int = 20_000,
               workers: int | None = None, threads_per_worker: int = 1, progress: bool = True,
               address: str | None = None, **solve_options: Any) -> Result:
    """:func:`mjkin.solve` of a batch of targets, in chunks on Ray workers; the same result, bit for bit.

    Args:
        model: a bundled model name, an MJCF path, an XML string, an ``MjModel``/``MjSpec``
            or a :class:`~mjkin.Tree`; loaded on the driver and shipped to each worker once.
        goals: as for :func:`mjkin.solve`, targets with a leading batch axis ``B``.
        q0: start ``(nq,)`` or one per target ``(B, nq)``.
        chunk: targets per task.
        workers: actors to start; default one per ``threads_per_worker`` CPUs of the cluster.
        threads_per_worker: solver threads in each worker (and the CPUs Ray reserves for it).
        progress: a bar of solved targets on a terminal.
        address: the cluster to attach to when Ray is not initialised yet (default: a new local one).
        **solve_options: the options of :func:`mjkin.solve` (``method``, ``tol``, ``restarts``, ...);
            a fixed ``seed`` (the default) keeps the restarts, hence the result, independent of chunking.

    Raises:
        GoalError, UnknownNameError, InputError: as :func:`mjkin.solve`; goals and ``q0`` are
            checked here before any work is shipped, options in the workers.
    """
    if isinstance(chunk, bool) or not isinstance(chunk, (int, np.integer)) or chunk < 1:
        raise InputError(f"chunk must be a positive number of targets, got {chunk!r}")
    tree = _tree(model)
    goal_list = [goals] if isinstance(goals, G.Goal) else list(goals)
    prog = G.compile_goals(tree, goal_list)
    q = _check_q0(tree, q0, prog.B)
    edges = [(0, prog.B)] if prog.batch == () else [(lo, min(lo + chunk, prog.B)) for lo in range(0, prog.B, chunk)]
    connect(address)
    actors = _actors(tree, workers, threads_per_worker, len(edges))

    def job(lo: int, hi: int) -> Callable[[Any], Any]:
        part = goal_list if prog.batch == () else [g.take(lo, hi) for g in goal_list]
        start = q if q is None or q.ndim == 1 else q[lo:hi]
        return lambda actor: actor.solve.remote(part, start, solve_options)

    parts = _dispatch(actors, [job(lo, hi) for lo, hi in edges], [hi - lo for lo, hi in edges], progress,
                      "solve_many")
    return parts[0].with_tree(tree) if len(parts) == 1 else concatenate(parts, tree)


def render_many(model: Model, scripts: Sequence[str | os.PathLike[str]], out_dir: str | os.PathLike[str], *,
                suffix: str = ".mp4", width: int = 640, height: int = 480, fps: float = 30.0,
                workers: int | None = None, progress: bool = True, address: str | None = None) -> list[Path]:
    """Render trajectory scripts to clips ``out_dir/<script stem><suffix>``, one Ray task per script.

    Each clip is what ``mjkin replay SCRIPT -o CLIP`` writes; workers encode the
    video themselves and send back only its path. Scripts are read and checked
    against the model on the driver; ``out_dir`` must be on storage every node sees.

    Returns:
        The clips' paths, in the order of ``scripts``.

    Raises:
        MjkinIOError, InputError: a script cannot be read, was recorded on another model,
            two scripts would write the same clip, or the suffix is not a video's.
    """
    from .render import VIDEO_SUFFIXES

    if suffix.lower() not in VIDEO_SUFFIXES:
        raise InputError(f"suffix must be one of {', '.join(VIDEO_SUFFIXES)}, got {suffix!r}")
    if width <= 0 or height <= 0 or not fps > 0:
        raise InputError(f"width, height and fps must be positive, got {width}, {height}, {fps}")
    tree = _tree(model)
    out = Path(out_dir)
    clips = [out / (Path(s).stem + suffix) for s in scripts]
    if len(set(clips)) != len(clips):
        raise InputError("two scripts have the same file name, so their clips would overwrite each other")
    trajs = [motion.Trajectory.load(s, tree) for s in scripts]
    if not trajs:
        return []
    out.mkdir(parents=True, exist_ok=True)
    connect(address)
    actors = _actors(tree, workers, 1, len(trajs))

    def job(traj: motion.Trajectory, clip: Path) -> Callable[[Any], Any]:
        return lambda actor: actor.render.remote(traj, str(clip), width, height, fps)

    done = _dispatch(actors, [job(t, c) for t, c in zip(trajs, clips, strict=True)], [1] * len(trajs), progress,
                     "render_many")
    return [Path(p) for p in done]


# ----------------------------------------------------------------- Ray Data stages
def random_poses(batch: dict[str, NDArray], model: Model, frame: str, seed: int = 0) -> dict[str, NDArray]:
    """Ray Data stage (a function, so it runs in the read tasks): reachable random poses of ``frame``.

    Input column ``id`` (as made by ``ray.data.range``); adds ``position (n, 3)``
    and ``quaternion (n, 4)`` (w, x, y, z): the frame's pose at random
    configurations within the limits, drawn from a generator seeded with
    ``(seed, first id of the batch)``.
    """
    tree = _tree(model)
    ids = np.asarray(batch["id"])
    rng = np.random.default_rng([int(seed), int(ids[0]) if len(ids) else 0])
    T = tree.pose(tree.random_q(rng, len(ids)), frame).reshape(-1, 4, 4)
    return {**batch, "position": T[:, :3, 3], "quaternion": mat_to_quat(T[:, :3, :3])}


class PoseSolver:
    """Ray Data stage: solve a batch of pose targets for ``frame`` with :func:`mjkin.solve`.

    Input columns ``position (n, 3)`` and ``quaternion (n, 4)``; adds ``q (n, nq)``,
    ``success (n,)`` and ``error (n, 2)`` (worst position, rotation error). The
    model is loaded once per worker; ``threads`` solver threads (give Ray the
    same ``num_cpus``).
    """

    def __init__(self, model: Model, frame: str, threads: int = 1, **solve_options: Any) -> None:
        set_threads(threads)
        self.tree, self.frame = _tree(model), frame
        self.tree.frame(frame)
        self.q0 = solve_options.pop("q0", None)
        self.problem = Problem(self.tree, G.Pose(frame), **solve_options)

    def __call__(self, batch: dict[str, NDArray]) -> dict[str, NDArray]:
        """The batch with its solutions added."""
        goal = G.Pose(self.frame, T=pose_matrices(batch["position"], batch["quaternion"]))
        res = self.problem.solve(self.q0, [goal])
        return {**batch, "q": res.q, "success": res.success, "error": res.error}


def pose_matrices(position: ArrayLike, quaternion: ArrayLike) -> NDArray:
    """4x4 poses ``(n, 4, 4)`` from positions ``(n, 3)`` and quaternions ``(n, 4)`` (w, x, y, z)."""
    p, qt = np.asarray(position, np.float64), np.asarray(quaternion, np.float64)
    T = np.zeros((len(p), 4, 4))
    T[:, :3, :3], T[:, :3, 3], T[:, 3, 3] = quat_to_mat(qt), p, 1.0
    return T

