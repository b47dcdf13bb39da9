"""The seeds' reproducible examples (the source documents' worked examples), as data, tables and figures.

1. The three-link planar arm (lengths 15, 10, 5, start ``[π/8, π/4, π/4]``):
   pseudoinverse, transpose, CCD and recursive reach bring the tip to ``(-20, 5)``; toward the
   unreachable ``(-35, 5)`` the plain pseudoinverse's joint steps blow up as the
   arm straightens while damped least squares stays smooth and ends stretched.
   Each solver step is one animation frame; the goal is approached at most
   ``GOAL_STEP`` per frame (``V = G - E`` clamped), as in the seed's frames.
2. CCD on ``n`` unit links toward ``(0.9, 0.75)`` from a random start:
   linear convergence per sweep, faster with more links.
3. The two-link analytic solution: both elbows, and "unreachable" outside the annulus.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from ... import goals as G
from ...ik import Result, solve
from ...ik.analytic import solutions
from ...kinematics import build
from ...kinematics.tree import Tree, load

Array = NDArray[np.float64]

START = np.array([np.pi / 8, np.pi / 4, np.pi / 4])
REACHABLE, UNREACHABLE = np.array([-20.0, 5.0, 0.0]), np.array([-35.0, 5.0, 0.0])
FRAMES = 20
GOAL_STEP = 3.0  # seed units the tip is asked to move per frame
DAMPING = 5.0  # λ of the damped method (a sixth of the arm's reach)
METHODS: dict[str, dict] = {"pinv": {}, "dls": {"damping": DAMPING}, "transpose": {}, "ccd": {}, "reach": {}}
WHOLE_MOVES = ("ccd", "reach")  # methods whose iteration is a whole sweep or pass, not a clamped step


def three_link(method: str, goal: Array, frames: int = FRAMES) -> Result:
    """One seed-1 run: ``frames`` steps of ``method`` from :data:`START`, with history."""
    tree = load("planar_3link")
    opts: dict = dict(METHODS[method])
    if method not in WHOLE_MOVES:
        opts["goal_step"] = GOAL_STEP
    if method != "reach":  # reach has no stall test: its passes run to max_iters
        opts["patience"] = frames + 1
    return solve(tree, G.Position("tip", goal), q0=START, method=method, max_iters=frames, history=True,
                 tol=1e-6, **opts)


def joint_steps(res: Result) -> Array:
    """Largest joint change of each frame of a run, ``(iterations,)``."""
    assert res.history is not None
    q = res.history.q[: int(res.iterations) + 1]
    return np.abs(np.diff(q, axis=0)).max(axis=-1)


def ccd_convergence(n: int, sweeps: int = 7, seed: int = 1) -> Array:
    """Seed 2: tip error after sweeps 0 .. sweeps-1 of CCD on ``n`` unit links, random start.

    A sweep that lands exactly on the goal ends the run; later sweeps repeat its error.
    """
    tree = load(build.planar_chain([1.0] * n))
    q0 = np.random.default_rng(seed).uniform(-np.pi, np.pi, n)
    res = solve(tree, G.Position("ee", [0.9, 0.75, 0.0]), q0=q0, method="ccd", max_iters=sweeps, tol=1e-300,
                history=True, sweep="base_to_tip", patience=sweeps + 1)
    assert res.history is not None
    err = res.history.error[1: sweeps + 1, 0]
    done = np.isnan(err)
    err[done] = err[~done][-1] if (~done).any() else 0.0
    return err


def two_link(goal: Array) -> tuple[Array, bool]:
    """Seed 3: both elbow configurations of the bundled two-link arm for ``goal``, and reachability."""
    q, ok = solutions(load("planar_2link"), goal, "tip")
    return q, bool(ok)


def draw_strip(tree: Tree, runs: dict[str, Result], frames: list[int], goal: Array, path: Path) -> None:
    """A PNG strip: one row per method, one column per frame, the arm drawn from its link tips."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    sites = ["link1_tip", "link2_tip", "tip"]
    fig, axes = plt.subplots(len(runs), len(frames), figsize=(2.2 * len(frames), 2.2 * len(runs)), squeeze=False)
    for row, (name, res) in zip(axes, runs.items(), strict=True):
        assert res.history is not None
        for ax, f in zip(row, frames, strict=True):
            k = min(f, int(res.iterations))
            q = res.history.q[k]
            pts = np.array([[0.0, 0.0]] + [tree.pose(q, s)[:2, 3] for s in sites])
            ax.plot(pts[:, 0], pts[:, 1], "-o", color="tab:blue", lw=2, ms=3)
            ax.plot(*goal[:2], "x", color="tab:red", ms=8, mew=2)
            ax.set_xlim(-36, 31)
            ax.set_ylim(-31, 31)
            ax.set_aspect("equal")
            ax.set_xticks([])
            ax.set_yticks([])
            ax.set_title(f"{name} · frame {f}", fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def plot_errors(runs: dict[str, Result], path: Path, title: str) -> None:
    """Tip error against iteration, one line per run (log scale)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(5, 3.2))
    for name, res in runs.items():
        assert res.history is not None
        e = res.history.error[: int(res.iterations) + 1, 0]
        ax.semilogy(np.arange(len(e)), np.maximum(e, 1e-16), "-o", ms=3, label=name)
    ax.set_xlabel("iteration (frame)")
    ax.set_ylabel("tip error")
    ax.set_title(title, fontsize=9)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def figures(out: Path) -> list[Path]:
    """Write the seed-1 strips and error plots into ``out``; returns the files (none without matplotlib)."""
    try:
        import matplotlib  # noqa: F401
    except ImportError:
        return []
    from ...runtime.files import atomic_path

    out.mkdir(parents=True, exist_ok=True)
    tree = load("planar_3link")
    written = []
    for label, goal, frames, methods in (("reach", REACHABLE, [0, 5, 10, 15, 20], list(METHODS)),
                                         ("unreachable", UNREACHABLE, [0, 10, 18, 19, 20], ["pinv", "dls"])):
        runs = {m: three_link(m, goal) for m in methods}
        with atomic_path(out / f"seed1_{label}_frames.png") as tmp:
            draw_strip(tree, runs, frames, goal, tmp)
        with atomic_path(out / f"seed1_{label}_error.png") as tmp:
            plot_errors(runs, tmp, f"goal {goal[:2]}")
        written += [out / f"seed1_{label}_frames.png", out / f"seed1_{label}_error.png"]
    for method in METHODS:  # one convergence plot per method: both goals, error against iteration
        runs = {f"goal {g[:2]}": three_link(method, g, frames=60) for g in (REACHABLE, UNREACHABLE)}
        unit = {"ccd": "sweep", "reach": "pass"}.get(method, "step")
        with atomic_path(out / f"seed1_convergence_{method}.png") as tmp:
            plot_errors(runs, tmp, f"{method}: tip error per {unit}")
        written.append(out / f"seed1_convergence_{method}.png")
    return written
