"""``mjkin bench``: mjkin and the baseline a user would write, side by side in one process.

Same inputs, same work, the same process; ratios > 1 mean mjkin is faster. Nothing
here is asserted by tests (timings on shared machines are noisy): each benchmark
returns a report whose rows the CLI prints and, with ``--json``, writes. This
module holds only the command's options (the CLI builds its parser with them);
:mod:`~mjkin.apps.bench.suite` runs them, :mod:`~mjkin.apps.bench.ik` and the
others hold one benchmark each, :mod:`~mjkin.apps.bench.peers` the peer libraries.
"""

from __future__ import annotations

import argparse

from ..argtypes import nonnegative_int, positive_float, positive_int
from .startup import ENTRIES

REAL_ARMS = {"ur5e": "universal_robots_ur5e/ur5e.xml", "iiwa14": "kuka_iiwa_14/iiwa14.xml",  # under shared/models
             "gen3": "kinova_gen3/gen3.xml", "xarm7": "ufactory_xarm7/xarm7_nohand.xml"}
FK_MODELS = {"arm7": "arm7", "primate": "primate", "panda": "panda",  # panda: models/, the rest under shared/models
             "panda_menagerie": "franka_emika_panda/panda_nohand.xml", **REAL_ARMS, "g1": "unitree_g1/g1.xml"}
ALL = ("fk", "ik", "realtime", "render", "env", "seeds", "play")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """The ``mjkin bench`` subcommands and their options (called by :func:`mjkin.apps.cli.build_parser`)."""
    sub = parser.add_subparsers(dest="which", required=True,
                                metavar="{fk,ik,realtime,render,env,play,seeds,retarget,solutions,constraints,startup,all}",
                                help="which benchmark (each takes --json FILE; see mjkin bench NAME -h)")

    def common(s: argparse.ArgumentParser) -> None:
        s.add_argument("--json", metavar="FILE", help="also write the rows and settings to this .json file")
        s.add_argument("--seed", type=nonnegative_int, default=0,
                       help="seed (>= 0) of the random configurations (default 0)")

    s = sub.add_parser("fk", help="batched FK and one pose, beside mj_kinematics from Python")
    s.add_argument("--models", nargs="+", metavar="NAME|PATH",
                   help=f"models (default: {', '.join(FK_MODELS)}; those of ../shared/models when it is there)")
    s.add_argument("--batch", nargs="+", type=positive_int, default=[1, 100, 10_000], metavar="B",
                   help="batch sizes (default 1 100 10000)")
    common(s)

    s = sub.add_parser("ik", help="6-D pose IK beside MuJoCo DLS, mink, Robotics Toolbox's ik_LM and TRAC-IK; "
                                  "--protocol trac-ik for TRAC-IK's")
    s.add_argument("--models", nargs="+", metavar="NAME|PATH",
                   help="arms by name (arm7, panda, ur5e, iiwa14, gen3, xarm7) or MJCF files (frame: last site, "
                        "else last body); default all available (trac-ik: the five real arms)")
    s.add_argument("--protocol", choices=["default", "trac-ik"], default="default",
                   help="default: home start, --tol/--rot-tol; trac-ik: mid-range start, 1e-5 m / 1e-5 rad, 5 ms")
    s.add_argument("--targets", type=positive_int, help="targets per model (default 1000; trac-ik 10000)")
    s.add_argument("--tol", type=positive_float, help="position tolerance, m (default 1e-4; trac-ik 1e-5)")
    s.add_argument("--rot-tol", type=positive_float, help="rotation tolerance, rad (default 1e-3; trac-ik 1e-5)")
    s.add_argument("--iters", type=positive_int, default=200,
                   help="iteration budget of the single-start rows (mjkin-single-start, mujoco-dls, mink; default 200)")
    s.add_argument("--time-limit", type=positive_float, default=0.005,
                   help="seconds per solve: TRAC-IK's own limit; with --protocol trac-ik every solver's "
                        "(default 0.005)")
    common(s)

    s = sub.add_parser("realtime", help="6-D IK per frame for chains of 2..128 DoF and trees, warm and cold")
    s.add_argument("--dofs", nargs="+", type=positive_int, default=[2, 4, 8, 16, 32, 64, 128], metavar="N",
                   help="chain sizes (default 2 4 8 16 32 64 128)")
    s.add_argument("--frames", type=positive_int, default=120, help="frames of the target path (default 120)")
    s.add_argument("--plot", metavar="FILE.png", help="also draw the cost against DoF into this .png")
    common(s)

    s = sub.add_parser("render", help="mjkin's render pipeline beside a bare mujoco.Renderer loop")
    s.add_argument("--frames", type=positive_int, default=60, help="frames per model (default 60)")
    s.add_argument("--width", type=positive_int, default=640, help="frame width, pixels (default 640)")
    s.add_argument("--height", type=positive_int, default=480, help="frame height, pixels (default 480)")
    common(s)

    s = sub.add_parser("env", help="env steps/s beside gymnasium's Reacher-v5 (and the native vector env)")
    s.add_argument("--steps", type=positive_int, default=2000, help="random steps per env (default 2000)")
    s.add_argument("--num-envs", type=positive_int, default=256, help="envs in the vector env (default 256)")
    common(s)

    s = sub.add_parser("play", help="the playground's frame rate and drag-to-frame latency over HTTP")
    common(s)

    s = sub.add_parser("seeds", help="the seeds' examples as tables, and their figures")
    s.add_argument("--out", default="mjkin-seeds",
                   help="folder for the figures: an existing one, or a new one inside an existing folder "
                        "(default mjkin-seeds)")
    common(s)

    s = sub.add_parser("retarget", help="a folder of BVH clips onto figures: frames/s median and IQR over the clips "
                                        "(the LAFAN1 form), key points, skate, floor, limits, speed, self-contact; "
                                        "GMR beside mjkin on its robots")
    s.add_argument("--clips", metavar="DIR", help="folder of BVH clips, searched recursively (default ../shared/mocap)")
    s.add_argument("--models", nargs="+", metavar="NAME|PATH",
                   help="figures: primate, g1, gmr_unitree_g1, gmr_booster_t1 or MJCF files with a free root "
                        "(default primate and those of ../shared/models that are there); on gmr_unitree_g1 GMR runs "
                        "beside mjkin when found ($MJKIN_GMR_PYTHON and $MJKIN_GMR_PEER, else ../gmr-venv and "
                        "../gmr-peer)")
    s.add_argument("--repeat", type=positive_int, default=3, help="timed runs per clip after a warm-up (default 3)")
    common(s)

    s = sub.add_parser("solutions", help="all IK solutions against closed forms (UR-type and spherical-wrist arms), "
                                         "the Panda's capability map against brute-force IK, a shelf base placement")
    s.add_argument("--poses", type=positive_int, default=1000, help="random poses per arm (default 1000)")
    s.add_argument("--checks", type=positive_int, default=1000,
                   help="map entries checked by brute-force IK (default 1000)")
    common(s)

    s = sub.add_parser("constraints", help="Clearance among obstacles beside no clearance, reject-and-retry and "
                                           "mink; self-clearance and balance of figures; max_joint_speed on a path")
    s.add_argument("--targets", type=positive_int, default=100,
                   help="targets per arm (the figures get half; default 100)")
    s.add_argument("--margin", type=positive_float, default=0.005,
                   help="clearance, m (default 0.005: the Panda's link0-link1 pair is never more than 8 mm apart)")
    common(s)

    s = sub.add_parser("startup", help="a first run from an empty kernel cache and a second one warm, in child "
                                       "processes: import, first call, compile seconds, peak memory")
    s.add_argument("--entries", nargs="+", choices=ENTRIES, default=list(ENTRIES), help="entry points (default all)")
    common(s)

    s = sub.add_parser("all", help="every benchmark above but startup, with its defaults (--json: one file, keyed "
                                   "by name)")
    common(s)
