"""Compile every kernel once, ahead of use (``mjkin warmup``).

numba compiles mjkin's kernels on first use (minutes on a small machine)
and caches them on disk (see :func:`mjkin.jit.cache_dir`). A Dockerfile or a
CI cache step runs ``mjkin warmup`` once so that later processes start in a
second. The kernels' types do not depend on the model, so two small bundled
models (a hinge chain and a tree with ball and free joints) reach all of them.
"""

from __future__ import annotations

import sys
import time
from collections.abc import Callable

import numpy as np
from numba.core.dispatcher import Dispatcher

from .. import goals as G
from .. import progress
from ..ik import solve
from ..ik.compiled import PREFIX
from ..kinematics.tree import Tree, load


def _steps(chain: Tree, figure: Tree) -> list[tuple[str, Callable[[], object]]]:
    qs = chain.random_q(np.random.default_rng(0), 2)
    fq = figure.random_q(np.random.default_rng(0), 2)
    T = chain.pose(qs, "ee")
    return [
        ("forward kinematics", lambda: (chain.fk(qs), chain.pose(qs[0], "ee"), figure.fk(fq))),
        ("Jacobians", lambda: (chain.jacobian(qs, "ee"), chain.jacobian(qs[0], "ee"), figure.jacobian(fq, "head"))),
        ("q-space arithmetic", lambda: (figure.clip(fq), figure.integrate(fq, np.zeros(figure.nv)),
                                        figure.difference(fq, fq))),
        ("IK solver (auto, lm, dls, pinv, transpose)", lambda: (
            solve(chain, G.Pose("ee", T=T)), solve(chain, G.Pose("ee", T=T[0]), timeout=1.0, history=True),
            solve(figure, [G.Position("left_hand", (0.2, 0.3, 1.2)), G.Rest(figure.qpos0, weight=0.1, priority=1)]))),
        ("CCD", lambda: solve(chain, G.Position("ee", T[0, :3, 3]), method="ccd")),
        ("goal evaluation (optimize)", lambda: solve(chain, G.Position("ee", T[0, :3, 3]), method="optimize")),
    ]


def compilations() -> int:
    """Kernel versions compiled so far in this process, over mjkin's modules (numba's cache misses)."""
    return sum(sum(kernel.stats.cache_misses.values())
               for name, module in list(sys.modules.items())
               if name == "mjkin" or name.startswith(("mjkin.", PREFIX))
               for kernel in vars(module).values() if isinstance(kernel, Dispatcher))


def warmup() -> float:
    """Compile (or load from the cache) every kernel; returns the seconds it took (see :func:`compilations`).

    From the CLI a progress bar names each group on a terminal.
    """
    start = time.perf_counter()
    chain, figure = load("arm7"), load("primate")
    for _, run in progress.track(_steps(chain, figure), "preparing kernels"):
        run()
    return time.perf_counter() - start
