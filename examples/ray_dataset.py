"""Batch IK past one machine with Ray: a Parquet dataset job, and the figures that say when Ray pays.

Install the extra first: ``pip install "mjkin[ray]"``, then ``mjkin warmup`` once
per machine (or node image).

``python examples/ray_dataset.py dataset OUT --targets 1000000``
    Ray Data makes random reachable ``ee`` poses of the 7-DoF arm in the workers,
    solves them there and writes Parquet shards under ``OUT`` (columns ``id``,
    ``position``, ``quaternion``, ``q``, ``success``, ``error``); nothing is gathered
    on the driver, so the count is limited by disk, not memory. On a cluster give
    ``--address auto`` and an ``OUT`` every node can write (``s3://...``).

``python examples/ray_dataset.py measure --targets 200000``
    Times :func:`mjkin.solve` in this process against
    :func:`mjkin.distributed.solve_many` on a local cluster with the same cores,
    checks that both give the same answers bit for bit, and prints Ray's costs:
    start-up, a worker's start, and each chunk's round trip.

``python examples/ray_dataset.py render OUT --clips 4 --frames 60``
    Times clips rendered one after another here against :func:`mjkin.distributed.render_many`.
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

import numpy as np

import mjkin
from mjkin import goals as G
from mjkin import motion, render
from mjkin.distributed import PoseSolver, random_poses, render_many, solve_many


def dataset(out: str, n: int, chunk: int, workers: int | None, address: str | None) -> None:
    """Write ``n`` solved random targets as Parquet shards under ``out``.

    ``workers`` solver actors take a CPU each; by default all CPUs but one, which the
    read tasks (that also make the targets) need: with none left the job waits forever.
    """
    import ray

    ray.init(address=address, include_dashboard=False)
    if workers is None:
        workers = max(1, int(ray.cluster_resources().get("CPU", 1)) - 1)
    start = time.perf_counter()
    (ray.data.range(n, override_num_blocks=max(1, n // chunk))
        .map_batches(random_poses, fn_kwargs=dict(model="arm7", frame="ee", seed=0), batch_size=chunk)
        .map_batches(PoseSolver, fn_constructor_kwargs=dict(model="arm7", frame="ee"),
                     batch_size=chunk, concurrency=workers, num_cpus=1)
        .write_parquet(out))
    print(f"{n} targets solved and written to {out} in {time.perf_counter() - start:.1f} s")


def measure(n: int, chunk: int) -> None:
    """Print one process's throughput, solve_many's on the same cores, and Ray's fixed costs."""
    import ray

    tree = mjkin.load("arm7")
    T = tree.pose(tree.random_q(np.random.default_rng(0), n), "ee")
    mjkin.solve(tree, G.Pose("ee", T=T[:2]))  # load the kernels
    start = time.perf_counter()
    want = mjkin.solve(tree, G.Pose("ee", T=T))
    alone = time.perf_counter() - start
    print(f"mjkin.solve, {mjkin.threads()} threads: {n} arm7 pose targets in {alone:.2f} s "
          f"({n / alone:,.0f} targets/s; 1 M would take {1e6 / n * alone:.0f} s)")
    cores = len(os.sched_getaffinity(0))
    start = time.perf_counter()
    ray.init(num_cpus=cores, include_dashboard=False, log_to_driver=False)
    print(f"ray.init (local, {cores} CPUs): {time.perf_counter() - start:.1f} s")
    start = time.perf_counter()
    solve_many(tree, G.Pose("ee", T=T[:1]), progress=False)
    print(f"solve_many of 1 target (workers start, load model and kernels): {time.perf_counter() - start:.2f} s")
    k, cost = 1000, {}
    for size in (k, 1):  # the same targets in one chunk, then in k: the difference is k - 1 round trips
        start = time.perf_counter()
        solve_many(tree, G.Pose("ee", T=T[:k]), chunk=size, restarts=0, progress=False)
        cost[size] = time.perf_counter() - start
    print(f"per chunk round trip (chunk=1 against 1 chunk, {k} targets): {(cost[1] - cost[k]) / (k - 1) * 1e3:.2f} ms")
    start = time.perf_counter()
    got = solve_many(tree, G.Pose("ee", T=T), chunk=chunk, progress=False)
    many = time.perf_counter() - start
    same = all(np.array_equal(getattr(got, f), getattr(want, f)) for f in ("q", "status", "error", "restarts"))
    print(f"solve_many, {cores} workers x 1 thread, chunk {chunk}: {n} targets in {many:.2f} s "
          f"({many / alone:.2f}x mjkin.solve); equal bit for bit: {same}")


def clips(n: int, frames: int, out: str) -> None:
    """Time ``n`` clips of ``frames`` frames rendered in a loop here, then by render_many on all cores."""
    import ray

    tree = mjkin.load("arm7")
    Path(out).mkdir(parents=True, exist_ok=True)
    scripts = []
    for k in range(n):
        q = np.linspace(tree.qpos0, tree.random_q(np.random.default_rng(k), 1)[0], frames)
        traj = motion.Trajectory(np.arange(frames) / 30.0, q, motion.fingerprint(tree), model="arm7", frame="ee")
        scripts.append(traj.save(f"{out}/clip{k}.json"))
    start = time.perf_counter()
    for k, script in enumerate(scripts):
        traj = motion.Trajectory.load(script, tree)
        images = render.frames(tree, traj.q, 640, 480, overlay=render.Overlay(trail=traj.frame))
        render.write_video(images, f"{out}/loop{k}.mp4")
    loop = time.perf_counter() - start
    ray.init(num_cpus=len(os.sched_getaffinity(0)), include_dashboard=False, log_to_driver=False)
    start = time.perf_counter()
    render_many(tree, scripts, out, progress=False)
    many = time.perf_counter() - start
    print(f"{n} clips of {frames} frames (640x480 mp4): a loop {loop:.1f} s, render_many {many:.1f} s "
          f"({loop / many:.2f}x faster)")


def main() -> None:
    """Parse the command line and run one of the two jobs."""
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = p.add_subparsers(dest="job", required=True)
    d = sub.add_parser("dataset", help="solve random targets with Ray Data into Parquet shards")
    d.add_argument("out", help="folder (or s3://... URL) for the shards")
    d.add_argument("--targets", type=int, default=100_000)
    d.add_argument("--chunk", type=int, default=20_000)
    d.add_argument("--workers", type=int, help="solver actors (one CPU each); default all CPUs but one")
    d.add_argument("--address", help="Ray cluster to join ('auto': the local node's); default a new local one")
    m = sub.add_parser("measure", help="time mjkin.solve against solve_many on this machine")
    m.add_argument("--targets", type=int, default=200_000)
    m.add_argument("--chunk", type=int, default=20_000)
    r = sub.add_parser("render", help="time clips rendered in a loop against render_many on this machine")
    r.add_argument("out", help="folder for the scripts and clips (made if missing)")
    r.add_argument("--clips", type=int, default=4)
    r.add_argument("--frames", type=int, default=60)
    args = p.parse_args()
    if args.job == "dataset":
        dataset(args.out, args.targets, args.chunk, args.workers, args.address)
    elif args.job == "measure":
        measure(args.targets, args.chunk)
    else:
        clips(args.clips, args.frames, args.out)


if __name__ == "__main__":
    main()
