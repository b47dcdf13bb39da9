"""mjkin: kinematics you can trust for articulated figures described in MJCF.

mjkin computes forward kinematics, Jacobians and inverse kinematics itself;
MuJoCo compiles models, renders and finds contacts. ``q`` is always MuJoCo's
``qpos``.
"""

from __future__ import annotations

from . import goals, spatial
from .errors import GoalError, InputError, MjkinError, MjkinIOError, ModelError, UnknownNameError
from .explore.reachability import place_base, reachability
from .explore.solutions import solutions
from .explore.workspace import workspace
from .ik import Problem, Result, singular_values, solve
from .kinematics import build
from .kinematics.tree import Tree, bundled_models, load
from .motion.dataset import retarget_many
from .motion.retarget import retarget
from .runtime.parallel import set_threads, threads
from .version import __version__ as __version__  # mjkin.__version__

__all__ = [
    "GoalError",
    "InputError",
    "MjkinError",
    "MjkinIOError",
    "ModelError",
    "Problem",
    "Result",
    "Tree",
    "UnknownNameError",
    "build",
    "bundled_models",
    "goals",
    "load",
    "place_base",
    "reachability",
    "singular_values",
    "solutions",
    "retarget",
    "retarget_many",
    "set_threads",
    "solve",
    "spatial",
    "threads",
    "workspace",
]
