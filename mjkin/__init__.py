"""mjkin: kinematics you can trust for articulated figures described in MJCF.

mjkin computes forward kinematics, Jacobians and inverse kinematics itself;
MuJoCo compiles models, renders and finds contacts. ``q`` is always MuJoCo's
``qpos``.
"""

from __future__ import annotations

import os

if "MUJOCO_GL" not in os.environ and not os.environ.get("DISPLAY") and os.name == "posix":
    os.environ["MUJOCO_GL"] = "egl"  # headless default for offscreen rendering; set before mujoco loads

from . import goals, spatial  # noqa: E402
from .errors import GoalError, InputError, MjkinError, MjkinIOError, ModelError, UnknownNameError  # noqa: E402
from .ik import Result, singular_values, solve  # noqa: E402
from .parallel import set_threads, threads  # noqa: E402
from .tree import Tree, bundled_models, load  # noqa: E402
from .workspace import workspace  # noqa: E402

__version__ = "0.1.0"

__all__ = [
    "GoalError",
    "InputError",
    "MjkinError",
    "MjkinIOError",
    "ModelError",
    "Result",
    "Tree",
    "UnknownNameError",
    "bundled_models",
    "goals",
    "load",
    "singular_values",
    "set_threads",
    "solve",
    "spatial",
    "threads",
    "workspace",
]
