"""Motion: keyframes, Cartesian paths solved frame by frame, a walk, and trajectories as script files.

Keyframes are interpolated (:mod:`~mjkin.motion.keyframes`); IK-driven animation
moves a goal a little each frame and re-solves from the previous pose
(:mod:`~mjkin.motion.follow`, :mod:`~mjkin.motion.walk`); the result is recorded as a
script of joint values per frame and replayed without IK (:mod:`~mjkin.motion.trajectory`).
"""

from ..kinematics.tree import fingerprint
from .follow import follow
from .keyframes import circle, interpolate, line, min_jerk, waypoints
from .retime import retime
from .trajectory import FORMAT, LIMIT_TOL, Trajectory, outside_limits
from .walk import HEEL_STRIKE, TOE_OFF, Gait, Rig, sole_points, swing_foot, walk_cycle

__all__ = ["FORMAT", "HEEL_STRIKE", "LIMIT_TOL", "TOE_OFF", "Gait", "Rig", "Trajectory", "circle", "fingerprint",
           "follow", "interpolate", "line", "min_jerk", "outside_limits", "retime", "sole_points", "swing_foot",
           "walk_cycle", "waypoints"]
