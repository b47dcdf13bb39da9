"""mjkin: kinematics you can trust for articulated figures described in MJCF.

mjkin computes forward kinematics, Jacobians and inverse kinematics itself;
MuJoCo compiles models, renders and finds contacts. ``q`` is always MuJoCo's
``qpos``.
"""

from __future__ import annotations

import os

if "MUJOCO_GL" not in os.environ and not os.environ.get("DISPLAY") and os.name == "posix":
    os.environ["MUJOCO_GL"] = "egl"  # headless default for offscreen rendering; set before mujoco loads

from . import goals, spatial
from .errors import GoalError, InputError, MjkinError, MjkinIOError, ModelError, UnknownNameError
from .ik import Result, singular_values, solve
from .kinematics.tree import Tree, bundled_models, load
from .parallel import set_threads, threads
from .retarget import retarget
from .workspace import workspace

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
    "retarget",
    "set_threads",
    "solve",
    "spatial",
    "threads",
    "workspace",
]
