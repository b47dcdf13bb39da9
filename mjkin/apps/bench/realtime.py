"""``mjkin bench realtime``: what 6-D IK costs per frame, for chains of 2…128 DoF and for trees.

An animation solves each frame starting from the previous frame's answer (warm);
a one-off query starts from home (cold). Targets follow a smooth path made by FK
of a smooth random joint path, so every target is reachable. Timed is one
``problem.solve`` per frame (a :class:`mjkin.Problem` made once, as real-time code
holds one; ``mjkin.solve`` makes one on every call), on one core.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from ... import goals as G
from ...errors import InputError
from ...ik import Problem
from ...kinematics.build import Link, links_mjcf
from ...kinematics.qspace import FREE
from ...kinematics.tree import Tree, load
from ...runtime.parallel import threads_set
from ...runtime.progress import track
from .report import GC_NOTE, Report, Row, gc_paused

Array = NDArray[np.float64]
RATES = {"60 Hz": 1 / 60, "1 kHz": 1e-3}
AXES = ((0.0, 0.0, 1.0), (0.0, 1.0, 0.0), (1.0, 0.0, 0.0))  # yaw, pitch, roll in turn: a 3-D chain


@dataclass(frozen=True)
class Case:
    """A model, its home, and the frames whose 6-D poses are the goals."""

    name: str
    tree: Tree
    frames: tuple[str, ...]
    home: Array


def chain(dof: int) -> Case:
    """A 3-D chain of ``dof`` hinges (axes z, y, x in turn), 1 m long, limits ±2 rad, home gently bent."""
    links = [Link(f"l{i}", None if i == 0 else f"l{i - 1}", axis=AXES[i % 3], length=1.0 / dof, range=(-2.0, 2.0))
             for i in range(dof)]
    tree = load(links_mjcf(links, name=f"chain{dof}"))
    return Case(f"chain {dof}", tree, ("ee",), np.full(tree.nq, 0.2))  # stretched straight is singular


def tree_cases() -> list[Case]:
    """The bundled primate with both hands as goals, and a four-armed tree with a goal on every arm's tip."""
    primate = load("primate")
    arms = [Link("trunk0", axis=(0, 0, 1), length=0.2, direction=(0, 0, 1), range=(-2, 2)),
            Link("trunk1", "trunk0", axis=(0, 1, 0), length=0.2, direction=(0, 0, 1), range=(-2, 2))]
    for a, d in enumerate(((1, 0, 0), (0, 1, 0), (-1, 0, 0), (0, -1, 0))):
        for i in range(4):
            arms.append(Link(f"a{a}l{i}", "trunk1" if i == 0 else f"a{a}l{i - 1}", axis=AXES[(i + a) % 3],
                             length=0.15, direction=d, range=(-2, 2)))
    multi = load(links_mjcf(arms, name="four_arms"))
    return [Case("primate, 2 hands", primate, ("left_hand", "right_hand"), primate.qpos0.copy()),
            Case(f"4-arm tree ({multi.nv} DoF), 4 tips", multi, tuple(f"a{a}l3_tip" for a in range(4)),
                 np.full(multi.nq, 0.2))]


def smooth_path(case: Case, n: int, rng: np.random.Generator, amplitude: float = 0.5) -> Array:
    """``(n, nq)`` configurations along a smooth random path around home (free joints stay put)."""
    tree = case.tree
    t = np.linspace(0.0, 1.0, n)[:, None]
    freq, phase = rng.uniform(0.5, 1.5, tree.nv), rng.uniform(0.0, 2 * np.pi, tree.nv)
    v = rng.normal(0.0, 0.3, tree.nv) + amplitude * np.sin(2 * np.pi * freq * t + phase)
    for j in np.flatnonzero(tree.jnt_type == FREE):
        v[:, tree.jnt_dofadr[j]:tree.jnt_dofadr[j] + 6] = 0.0
    return tree.clip(tree.integrate(np.broadcast_to(case.home, (n, tree.nq)), v))


def goals_at(case: Case, q: Array) -> list[G.Goal]:
    """6-D pose goals for ``case.frames`` at configuration ``q``."""
    return [G.Pose(f, T=case.tree.pose(q, f)) for f in case.frames]


def follow(case: Case, path: Array, warm: bool) -> tuple[Array, Array, Array, Array]:
    """Solve every frame of ``path``'s poses; returns wall and CPU seconds, success and restarts per frame.

    Warm: each frame starts from the previous answer (the first from home); cold: all from home.
    CPU time is this thread's (``time.thread_time``): the solve's own work, without the waits
    a shared machine adds to the wall clock.
    """
    targets = [goals_at(case, q) for q in path]
    problem = Problem(case.tree, targets[0], tol=1e-4, rot_tol=1e-3)
    problem.solve(case.home)  # compile outside the timing
    wall, cpu, ok, restarts = np.empty(len(path)), np.empty(len(path)), np.empty(len(path), dtype=bool), np.empty(
        len(path))
    q = case.home
    with gc_paused():
        for k, goals in enumerate(targets):
            start, start_cpu = time.perf_counter(), time.thread_time()
            res = problem.solve(q if warm else case.home, goals)
            wall[k], cpu[k] = time.perf_counter() - start, time.thread_time() - start_cpu
            ok[k], restarts[k] = _met(case, res.q, goals), res.restarts
            q = res.q
    return wall, cpu, ok, restarts


def _met(case: Case, q: Array, goals: Sequence[G.Goal]) -> bool:
    """Every pose goal within 1e-4 m / 1e-3 rad, re-checked by FK (not the solver's word)."""
    for g in goals:
        assert isinstance(g, G.Pose) and g.T is not None
        T = case.tree.pose(q, g.frame)
        d = T[:3, :3].T @ np.asarray(g.T)[:3, :3]
        angle = np.arccos(np.clip(0.5 * (np.trace(d) - 1.0), -1.0, 1.0))
        if np.linalg.norm(T[:3, 3] - np.asarray(g.T)[:3, 3]) > 1e-4 or angle > 1e-3:
            return False
    return True


def bench_realtime(dofs: Sequence[int] = (2, 4, 8, 16, 32, 64, 128), frames: int = 120, seed: int = 0,
                   plot: str | None = None) -> Report:
    """Per-frame 6-D IK cost, warm (animation) and cold (from home), and the largest chain each rate allows."""
    if frames < 2 or not dofs or min(dofs) < 1:
        raise InputError(f"need --frames >= 2 and chain sizes >= 1, got {frames} and {list(dofs)}")
    with threads_set(1):
        rows, largest = _measure(dofs, frames, seed)
    if plot:
        draw(rows, plot)
    settings = {"frames": frames, "seed": seed, "tol_m": 1e-4, "rot_tol_rad": 1e-3, "method": "auto",
                "threads": "mjkin.set_threads(1): one core",
                "every frame": "warm chains on target in every frame whose slowest frame fits the budget, by wall "
                               "clock and by the thread's CPU time (without a shared machine's waits); largest_dof: "
                               "the largest such chain; all_up_to: the largest N with every measured chain <= N such",
                "restarted_frames": "frames whose solve needed random restarts (the slow ones)", "gc": GC_NOTE}
    return Report({f"6-D IK per frame along a smooth {frames}-frame path: warm = from the previous frame's "
                   "answer, cold = from home; success re-checked by FK": rows,
                   "largest chain solved every frame (warm)": largest}, settings)


def _measure(dofs: Sequence[int], frames: int, seed: int) -> tuple[list[Row], list[Row]]:
    """Rows per case and mode, and the largest chain per rate."""
    rows: list[Row] = []
    warm_chains: list[tuple[int, bool, float, float]] = []  # dof, on target every frame, slowest ms wall, CPU
    cases = [chain(n) for n in sorted(set(dofs))] + tree_cases()
    for case in track(cases, "bench realtime"):
        path = smooth_path(case, frames, np.random.default_rng([seed, case.tree.nv]))
        for mode in ("warm", "cold"):
            wall, cpu, ok, restarts = follow(case, path, mode == "warm")
            skip = 1 if mode == "warm" else 0  # warm: frame 0 starts from home
            ms, cpu_ms = 1e3 * wall[skip:], 1e3 * cpu[skip:]
            rows.append({"model": case.name, "dof": case.tree.nv, "goals": len(case.frames), "start": mode,
                         "median_ms": float(np.median(ms)), "p95_ms": float(np.percentile(ms, 95)),
                         "max_ms": float(ms.max()), "cpu_median_ms": float(np.median(cpu_ms)),
                         "cpu_p95_ms": float(np.percentile(cpu_ms, 95)), "cpu_max_ms": float(cpu_ms.max()),
                         "success": 100.0 * float(ok[skip:].mean()),
                         "restarted_frames": int((restarts[skip:] > 0).sum())})
            if mode == "warm" and case.name.startswith("chain"):
                warm_chains.append((case.tree.nv, bool(ok.all()), float(ms.max()), float(cpu_ms.max())))
    largest: list[Row] = []
    for label, budget in RATES.items():
        row: Row = {"rate": label, "budget_ms": 1e3 * budget}
        for clock, slowest in (("wall", 2), ("cpu", 3)):
            fits = {c[0]: c[1] and c[slowest] <= 1e3 * budget for c in warm_chains}
            row[f"largest_dof_{clock}"] = max((d for d, f in fits.items() if f), default=None)
            row[f"all_up_to_{clock}"] = max((d for d in fits if all(fits[e] for e in fits if e <= d)), default=None)
        row["largest_measured"] = max(dofs)
        largest.append(row)
    return rows, largest


def draw(rows: list[Row], path: str) -> Path:
    """Median (wall) and p95 (CPU) ms per frame against DoF (log x) for the chains; written atomically."""
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        raise InputError("--plot needs matplotlib: pip install 'mjkin[plot]'") from None
    from ...runtime.files import write_with

    fig, ax = plt.subplots(figsize=(6.4, 4.0))
    for mode, colour in (("warm", "tab:blue"), ("cold", "tab:orange")):
        sel = [r for r in rows if str(r["model"]).startswith("chain") and r["start"] == mode]
        dof, median, p95, slowest = (np.array([r[k] for r in sel], dtype=float)
                                     for k in ("dof", "median_ms", "cpu_p95_ms", "cpu_max_ms"))
        ax.plot(dof, median, "o-", color=colour, label=f"{mode}: median")
        ax.plot(dof, p95, "s--", color=colour, alpha=0.6, label=f"{mode}: p95 (CPU time)")
        if mode == "warm":
            ax.plot(dof, slowest, "^:", color="tab:green", label="warm: slowest frame (CPU time)")
    for label, budget in RATES.items():
        ax.axhline(1e3 * budget, color="grey", lw=0.8, ls=":")
        ax.text(float(dof.min()), 1e3 * budget * 1.1, f"{label} budget", color="grey", fontsize=8)
    ax.set(yscale="log", xlabel="chain DoF", ylabel="ms per 6-D solve",
           title="problem.solve per frame (mjkin bench realtime)")
    ax.set_xscale("log", base=2)
    ax.xaxis.set_major_formatter(matplotlib.ticker.ScalarFormatter())
    ax.legend(fontsize=8, loc="center right")
    fig.tight_layout()
    out = write_with(path, lambda p: fig.savefig(p, dpi=120))
    plt.close(fig)
    return out
