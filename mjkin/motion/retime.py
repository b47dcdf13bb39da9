"""Time-optimal retiming of a trajectory under joint speed and acceleration limits (toppra).

The frames stay as they are; only their times change. The path through the
frames is a cubic spline in joint-velocity coordinates (``nv``: the running sum
of ``tree.difference`` between frames, so ball and free joints count by their
rotation angle), parametrised by the old times; toppra (Pham & Pham, "A new
approach to time-optimal path parameterization based on reachability analysis",
IEEE T-RO 2018) finds the fastest timing along it under both limits at the frames
and at ``GRID - 1`` points between each pair. The timed spline is then sampled
densely and, if it exceeds a limit anywhere by rounding or between grid points,
the whole timing is slowed by the factor that brings it back inside. The new
times are those of the frames on that timing: between two frames every joint's
mean speed (their difference over the time between them) is one its spline
passed through, so neither limit is exceeded by the samples either.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import replace
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..errors import InputError
from ..kinematics.tree import Tree, fingerprint, load

if TYPE_CHECKING:
    from .trajectory import Trajectory

Array = NDArray[np.float64]
GRID = 4  # toppra grid points per frame interval
MARGIN = 0.99  # plan at this part of each limit, so the dense check rarely has to slow the timing
DENSE = 16  # samples per grid interval of the final check


def _limits(value: ArrayLike, nv: int, what: str) -> Array:
    """``value`` (a number or ``(nv,)``) as ``(nv,)`` positive finite limits."""
    a = (np.broadcast_to(np.asarray(value, dtype=np.float64), (nv,)) if np.ndim(value) == 0 else
        np.asarray(value, dtype=np.float64))
    if a.shape != (nv,) or not (np.isfinite(a).all() and (a > 0).all()):
        raise InputError(f"retime: {what} must be a positive number or {nv} positive numbers (one per dof), "
                         f"got {np.asarray(value).tolist()!r}")
    return np.array(a)


def path_coordinates(tree: Tree, q: Array) -> Array:
    """Frames ``q (T, nq)`` as points ``(T, nv)`` of a path in joint-velocity coordinates, starting at 0."""
    steps = tree.difference(q[1:], q[:-1])
    return np.concatenate([np.zeros((1, tree.nv)), np.cumsum(steps, axis=0)])


def retime(traj: Trajectory, max_velocity: ArrayLike, max_acceleration: ArrayLike,
           tree: Tree | None = None) -> Trajectory:
    """The same frames at time-optimal times: no joint faster than ``max_velocity`` nor ``max_acceleration``.

    Args:
        traj: a :class:`mjkin.motion.Trajectory` with ``q (T, nq)``, ``T >= 2``, at increasing times.
        max_velocity: rad/s (m/s for slides and free translation), one number or ``(nv,)``.
        max_acceleration: rad/s² (m/s²), one number or ``(nv,)``.
        tree: the model the trajectory was recorded on; default: loaded from ``traj.source``.

    Returns:
        A copy of ``traj`` whose ``times (T,)`` start at its first time, at rest at both ends,
        with ``meta["retime"]`` holding the limits and the old duration.

    Raises:
        InputError: limits not positive, fewer than two frames, times not increasing, no motion,
            or a ``tree`` of another model.
    """
    import toppra  # here, not at import: it takes most of a second
    import toppra.algorithm
    import toppra.constraint

    q = np.asarray(traj.q, dtype=np.float64)
    times = np.asarray(traj.times, dtype=np.float64)
    if tree is None:
        if not traj.source:
            raise InputError("retime needs the model: pass tree= (the trajectory names no source)")
        tree = load(traj.source)
    if traj.fingerprint != fingerprint(tree):
        raise InputError(f"retime: the trajectory was recorded on {traj.model!r}, not on {tree.name!r}")
    vmax, amax = _limits(max_velocity, tree.nv, "max_velocity"), _limits(max_acceleration, tree.nv, "max_acceleration")
    if len(q) < 2 or np.any(np.diff(times) <= 0):
        raise InputError(f"retime needs at least two frames at strictly increasing times, got {len(q)} frames")
    x = path_coordinates(tree, q)
    if not np.abs(x - x[0]).max() > 1e-12:
        raise InputError("retime: the trajectory does not move, so it has no timing to optimise")
    s = times - times[0]
    path = toppra.SplineInterpolator(s, x, bc_type="clamped")  # at rest at both ends
    grid = np.concatenate([np.linspace(a, b, GRID, endpoint=False) for a, b in zip(s[:-1], s[1:], strict=True)]
                          + [s[-1:]])
    algo = toppra.algorithm.TOPPRA(
        [toppra.constraint.JointVelocityConstraint(np.stack([-vmax, vmax], 1) * MARGIN),
         toppra.constraint.JointAccelerationConstraint(np.stack([-amax, amax], 1) * MARGIN)],
        path, gridpoints=grid, parametrizer="ParametrizeConstAccel")
    _, sd, _ = algo.compute_parameterization(0.0, 0.0)
    if sd is None or not np.isfinite(sd).all():
        raise InputError("retime: toppra found no timing for this path under these limits")
    dt = 2.0 * np.diff(grid) / (sd[:-1] + sd[1:])  # constant path acceleration within each grid interval
    t_grid = np.concatenate([[0.0], np.cumsum(dt)])
    slow = _overshoot(path, grid, sd, vmax, amax)
    t_new = times[0] + slow * t_grid[::GRID]
    meta = dict(traj.meta)
    meta["retime"] = {"max_velocity": vmax.tolist(), "max_acceleration": amax.tolist(),
                      "old_duration": float(s[-1]), "duration": float(t_new[-1] - t_new[0])}
    return replace(traj, times=t_new, meta=meta)


def _overshoot(path: Callable[[Array, int], Array], grid: Array, sd: Array, vmax: Array, amax: Array) -> float:
    """Factor >= 1 by which to stretch the timing so the spline keeps both limits at ``DENSE`` points per interval.

    Within grid interval ``i`` the path speed is ``sd`` moving at constant path
    acceleration ``(sd[i+1]² - sd[i]²) / (2 Δs)``; joint velocity ``x'(s) ṡ`` and
    acceleration ``x'(s) s̈ + x''(s) ṡ²`` follow.
    """
    u = (np.arange(DENSE) + 0.5) / DENSE
    ds = np.diff(grid)
    sdd = (sd[1:] ** 2 - sd[:-1] ** 2) / (2.0 * ds)
    s = (grid[:-1, None] + u * ds[:, None]).ravel()
    sd2 = np.maximum(0.0, (sd[:-1, None] ** 2 + 2.0 * sdd[:, None] * u * ds[:, None]).ravel())
    acc = np.repeat(sdd, DENSE)
    d1, d2 = path(s, 1), path(s, 2)
    vel = np.abs(d1 * np.sqrt(sd2)[:, None]) / vmax
    accel = np.abs(d1 * acc[:, None] + d2 * sd2[:, None]) / amax
    return float(max(1.0, vel.max() * (1 + 1e-9), np.sqrt(accel.max() * (1 + 1e-9))))
