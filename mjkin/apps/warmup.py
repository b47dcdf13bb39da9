"""Compile every kernel once, ahead of use (``mjkin warmup``), in parallel processes.

numba compiles mjkin's kernels on first use and caches them on disk (see
:mod:`mjkin.runtime.cache`). A Dockerfile or a CI cache step runs ``mjkin warmup``
once so that later processes start in a second, from that cache even when it
is read-only. The kernels' types do not depend on the model, so two small
bundled models (a hinge chain and a tree with ball and free joints) reach all
of them. The groups are independent: each compiles in a process of its own,
as many at a time as there are cores (``--jobs``); two processes that compile
the same shared kernel both write it, atomically.
"""

from __future__ import annotations

import multiprocessing
import os
import sys
import time
from collections.abc import Callable
from concurrent.futures import ProcessPoolExecutor, as_completed

import numpy as np

from .. import goals as G
from ..ik import solve
from ..ik.generated import PREFIX
from ..kinematics.tree import Tree, load
from ..runtime import numba_private, progress


def _kinematics(chain: Tree, figure: Tree) -> None:
    qs, fq = chain.random_q(np.random.default_rng(0), 2), figure.random_q(np.random.default_rng(0), 2)
    chain.fk(qs), chain.pose(qs[0], "ee"), chain.fk(qs[0]), figure.fk(fq)
    chain.jacobian(qs, "ee"), chain.jacobian(qs[0], "ee"), figure.jacobian(fq, "head")
    figure.clip(fq), figure.integrate(fq, np.zeros(figure.nv)), figure.difference(fq, fq)


def _ik(chain: Tree, figure: Tree) -> None:
    T = chain.pose(chain.random_q(np.random.default_rng(0), 2), "ee")
    solve(chain, G.Pose("ee", T=T))
    solve(chain, G.Pose("ee", T=T[0]), timeout=1.0, history=True)
    solve(figure, [G.Position("left_hand", (0.2, 0.3, 1.2)), G.Rest(figure.qpos0, weight=0.1, priority=1)])
    solve(chain, G.Position("ee", T[0, :3, 3]), method="optimize")


def _ccd(chain: Tree, figure: Tree) -> None:
    T = chain.pose(chain.random_q(np.random.default_rng(0), 1), "ee")
    solve(chain, G.Position("ee", T[0, :3, 3]), method="ccd")


def _grouped(chain: Tree, figure: Tree) -> None:
    """The loop with clearance and balance (:func:`mjkin.ik.loop.other_goal`)."""
    T = chain.pose(chain.random_q(np.random.default_rng(0), 1), "ee")
    solve(chain, G.Pose("ee", T=T[0]), avoid_collisions=True)
    goals: list = [G.Position("left_hand", (0.2, 0.3, 1.2)), G.CenterOfMass(xyz=(0.0, 0.0, 0.5), weight=0.1),
                   G.CenterOfMass(support=["left_foot", "right_foot"])]  # (CenterOfMass may give a list: it nests)
    solve(figure, goals)


GROUPS: dict[str, Callable[[Tree, Tree], None]] = {
    "IK loop (frame, line, plane and joint goals; every Jacobian method)": _ik,
    "IK loop with clearance and balance": _grouped,
    "forward kinematics, Jacobians, q-space arithmetic": _kinematics,
    "CCD": _ccd,
}  # the longest first, so the others fill the cores beside it


def compilations() -> int:
    """Kernel versions compiled so far in this process, over mjkin's modules (numba's cache misses)."""
    return sum(sum(kernel.stats.cache_misses.values())
               for name, module in list(sys.modules.items())
               if name == "mjkin" or name.startswith(("mjkin.", PREFIX))
               for kernel in vars(module).values() if numba_private.is_kernel(kernel))


def run_group(name: str) -> int:
    """Run one group in this process; returns the kernel versions it compiled."""
    before = compilations()
    GROUPS[name](load("arm7"), load("primate"))
    return compilations() - before


def warmup(jobs: int | None = None) -> tuple[float, int]:
    """Compile (or load from the cache) every kernel; returns the seconds it took and the versions compiled.

    ``jobs``: processes at a time (default: the cores this process may use); 1 runs the groups here,
    one after the other. From the CLI a progress bar counts the groups on a terminal.
    """
    start = time.perf_counter()
    jobs = jobs or len(os.sched_getaffinity(0))
    if jobs == 1:
        compiled = sum(run_group(name) for name, _ in progress.track(list(GROUPS.items()), "preparing kernels"))
        return time.perf_counter() - start, compiled
    # spawned, not forked: a fork of a process that has started LLVM (or threads) is not safe
    with ProcessPoolExecutor(jobs, mp_context=multiprocessing.get_context("spawn")) as pool:
        futures = [pool.submit(run_group, name) for name in GROUPS]
        compiled = sum(f.result() for f in progress.track(as_completed(futures), "preparing kernels",
                                                          total=len(futures)))
    return time.perf_counter() - start, compiled
