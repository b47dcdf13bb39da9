"""What IK should achieve: goals with a residual, its Jacobian, a weight and a priority.

One module per kind (:mod:`~mjkin.goals.position`, ...) holds its spec class and
its compiled residual; :mod:`~mjkin.goals.registry` lists them, and the solvers'
compiled evaluator is built from that list. Frame goals name a site or body
(``frame``, the first argument) and may act on a point ``offset`` fixed in it;
targets may carry a leading batch axis: ``Position("ee", xyz)`` with ``xyz`` of
shape ``(B, 3)`` asks for ``B`` solves at once.
"""

from __future__ import annotations

from .aim import Aim
from .base import DATA, JOINT_UNITS, METRES, METRES_AND_RADIANS, RADIANS, FrameGoal, Goal, concatenate
from .clearance import Clearance
from .com import Balance, CenterOfMass, ComTarget, balance_residual
from .coupling import Coupling
from .halfspace import HalfSpace
from .line import Line
from .orientation import Orientation
from .plane import Plane
from .pose import Pose
from .position import Position
from .program import Program, Structure, compile_goals
from .registry import KINDS, register
from .rest import Rest
from .steplimit import StepLimit

for _kind in (Position, Orientation, Pose, Aim, Line, Plane, HalfSpace, Rest, Coupling, StepLimit, Clearance,
              ComTarget):
    register(_kind)
register(Balance, balance_residual)

__all__ = ["DATA", "JOINT_UNITS", "KINDS", "METRES", "METRES_AND_RADIANS", "RADIANS", "Aim", "Balance",
           "CenterOfMass", "Clearance", "ComTarget", "Coupling",
           "FrameGoal", "Goal", "HalfSpace", "Line", "Orientation", "Plane", "Pose", "Position", "Program", "Rest",
           "StepLimit", "Structure", "compile_goals", "concatenate", "register"]
