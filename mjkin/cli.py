"""The ``mjkin`` command: inspect models, compute FK, benchmark.

Every user mistake ends as one line on stderr and exit status 2, never a traceback.
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Callable, Sequence

import numpy as np

from . import bench, progress, spatial
from .errors import InputError, MjkinError
from .qspace import HINGE, JOINT_NAMES
from .tree import Tree, bundled_models, load

Command = Callable[[argparse.Namespace], int]


def parse_q(text: str, tree: Tree, degrees: bool = False) -> np.ndarray:
    """A configuration from ``"0.1 0.2 ..."`` or ``"0.1,0.2,..."``; ``degrees`` converts hinge values."""
    try:
        q = np.array([float(v) for v in text.replace(",", " ").split()])
    except ValueError:
        raise InputError(f"--q must be {tree.nq} numbers separated by spaces or commas, got {text!r}") from None
    q = tree.check_q(q, "--q")
    if degrees:
        hinge = tree.jnt_qadr[tree.jnt_type == HINGE]
        q[hinge] = np.radians(q[hinge])
    return q


def cmd_info(args: argparse.Namespace) -> int:
    """Print the tree: bodies with their joints, and sites."""
    tree = load(args.model)
    print(describe(tree))
    return 0


def describe(tree: Tree) -> str:
    """Human-readable outline of a tree."""
    m = tree.model
    bodies, joints, sites = tree.names("body"), tree.names("joint"), tree.names("site")
    lines = [f"model {tree.name or '(unnamed)'}: nq={tree.nq} nv={tree.nv} "
             f"bodies={tree.nbody - 1} joints={tree.njnt} sites={m.nsite}"]
    depth = np.zeros(tree.nbody, dtype=int)
    for b in range(1, tree.nbody):
        depth[b] = depth[tree.body_parent[b]] + 1
        lines.append(f"{'  ' * depth[b]}body {bodies[b] or f'#{b}'}")
        for j in np.flatnonzero(tree.jnt_body == b):
            kind = JOINT_NAMES[int(tree.jnt_type[j])]
            text = f"{'  ' * depth[b]}  joint {joints[j] or f'#{j}'}: {kind}"
            if kind in ("hinge", "slide"):
                text += f" axis={np.round(tree.jnt_axis[j], 4).tolist()}"
            if tree.jnt_limited[j]:
                lo, hi = tree.jnt_range[j]
                text += f" range=[{lo:.4g}, {hi:.4g}]" if kind != "ball" else f" cone={hi:.4g} rad"
            lines.append(text)
        for s in np.flatnonzero(tree.site_body == b):
            lines.append(f"{'  ' * depth[b]}  site {sites[s] or f'#{s}'} pos={np.round(tree.site_pos[s], 4).tolist()}")
    return "\n".join(lines)


def cmd_fk(args: argparse.Namespace) -> int:
    """Print world poses of bodies and sites (or one frame) for a configuration."""
    tree = load(args.model)
    q = tree.qpos0.copy() if args.q is None else parse_q(args.q, tree, args.deg)
    frames = tree.kinematics(q)
    kinds = [tree.frame(args.frame)] if args.frame else (
        [("body", i) for i in range(1, tree.nbody)] + [("site", i) for i in range(tree.model.nsite)])
    out = []
    for kind, i in kinds:
        T = frames.pose(kind, i)
        out.append({"kind": kind, "name": tree.names(kind)[i], "pos": T[:3, 3].tolist(),
                    "quat": spatial.mat_to_quat(T[:3, :3]).tolist()})
    if args.json:
        print(json.dumps({"q": q.tolist(), "frames": out}, indent=1))
    else:
        for f in out:
            pos = " ".join(f"{v: .6f}" for v in f["pos"])  # type: ignore[union-attr]
            quat = " ".join(f"{v: .6f}" for v in f["quat"])  # type: ignore[union-attr]
            print(f"{f['kind']:4} {f['name']:24} pos {pos}   quat {quat}")
    return 0


def cmd_bench(args: argparse.Namespace) -> int:
    """Run benchmarks and print their tables."""
    names = list(bench.BENCHMARKS) if args.which == "all" else [args.which]
    for name in names:
        for title, rows in bench.BENCHMARKS[name]().items():
            print(f"== mjkin bench {name}: {title}")
            print(bench.format_table(rows))
            print()
    return 0


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of the ``mjkin`` command."""
    models = ", ".join(bundled_models())
    p = argparse.ArgumentParser(prog="mjkin", description="Kinematics for articulated figures in MJCF.")
    sub = p.add_subparsers(dest="command", required=True)
    model_help = f"MJCF/URDF file or a bundled model name ({models})"

    s = sub.add_parser("info", help="outline a model's bodies, joints and sites")
    s.add_argument("model", help=model_help)
    s.set_defaults(run=cmd_info)

    s = sub.add_parser("fk", help="world poses of bodies and sites for a configuration")
    s.add_argument("model", help=model_help)
    s.add_argument("--q", help="configuration (qpos), nq numbers; default qpos0")
    s.add_argument("--deg", action="store_true", help="hinge values in --q are degrees")
    s.add_argument("--frame", help="print only this site or body")
    s.add_argument("--json", action="store_true", help="machine-readable output")
    s.set_defaults(run=cmd_fk)

    s = sub.add_parser("bench", help="benchmarks: mjkin beside its baseline, as ratios")
    s.add_argument("which", choices=[*bench.BENCHMARKS, "all"])
    s.set_defaults(run=cmd_bench)
    return p


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``mjkin`` console command."""
    args = build_parser().parse_args(argv)
    progress.enable(True)
    try:
        return int(args.run(args))
    except MjkinError as e:
        print(f"mjkin: error: {e}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("mjkin: interrupted", file=sys.stderr)
        return 130
    finally:
        progress.enable(False)


if __name__ == "__main__":
    sys.exit(main())
