"""IK-driven animation: a frame led along points, solved frame by frame from the previous pose."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from .. import goals as G
from ..errors import InputError
from ..goals.program import as_goals
from ..ik import Problem
from ..kinematics.tree import Tree, check_tree, fingerprint
from ..runtime.checks import check_array, check_number
from ..runtime.progress import track
from .trajectory import Trajectory


def follow(tree: Tree, frame: str, targets: ArrayLike, q0: ArrayLike | None = None, fps: float = 30.0,
           extra: Sequence[G.Goal] = (), tol: float = 1e-4, smooth: float = 0.3,
           max_joint_speed: ArrayLike | None = None, **solve_options: Any) -> Trajectory:
    """IK-driven animation: put ``frame`` on ``targets (T, 3)`` frame by frame, warm-starting from the last pose.

    ``extra`` goals (e.g. an orientation, a rest pose at low priority) hold on every
    frame. Warm starts, minimum-norm steps and, with ``smooth > 0``, a rest goal
    of that weight at the previous frame's pose (priority 1: only in the freedom
    the path leaves) keep consecutive poses close, so redundant joints do not
    swing when another low-priority goal (a comfort pose) pulls them. A frame
    that fails from the warm start is retried with random restarts; failures are
    recorded in ``success``. Two :class:`~mjkin.Problem` objects (without and with
    restarts) serve every frame; ``solve_options`` go to both. ``meta["follow"]["timed_out"]`` lists the
    frames whose solve ran out of ``timeout`` (a solve option: seconds per frame's search).

    ``max_joint_speed`` (rad/s for hinges and ball/free rotations, m/s for slides and
    free translations; one number or one per joint ``(njnt,)``) becomes a hard
    :class:`~mjkin.goals.StepLimit` of ``max_joint_speed / fps`` from the previous frame:
    no frame-to-frame change exceeds it (the first frame's is from ``q0``), and a
    target further away is followed as far as that allows.
    """
    check_tree(tree)
    pts = check_array(targets, "targets")
    if pts.ndim != 2 or pts.shape[1] != 3 or len(pts) == 0:
        raise InputError(f"targets must be (T, 3) points, got shape {pts.shape}")
    smooth, fps = check_number(smooth, "smooth", 0.0), check_number(fps, "fps", 0.0, strict=True)
    extra = () if isinstance(extra, (list, tuple)) and not extra else as_goals(extra)
    q = tree.qpos0.copy() if q0 is None else tree.check_q(q0, "q0").copy()
    if q.ndim != 1:
        raise InputError(f"q0 must be one configuration ({tree.nq},), got shape {q.shape}")
    out, ok = np.empty((len(pts), tree.nq)), np.empty(len(pts), bool)
    step = None if max_joint_speed is None else speed_step(tree, max_joint_speed, fps)

    def goals(k: int) -> list[G.Goal]:
        return [G.Position(frame, pts[k]), *extra, *([G.Rest(q_rest=q, weight=smooth, priority=1)] if smooth else []),
                *([] if step is None else [G.StepLimit(q, step)])]

    warm = Problem(tree, goals(0), tol=tol, **{**solve_options, "restarts": 0})
    retry: Problem | None = None
    timed_out: list[int] = []
    for k in track(range(len(pts)), "solve path", total=len(pts)):
        now = goals(k)
        res = warm.solve(q, now)
        late = res.status == "timeout"
        if not res.success:
            retry = retry or Problem(tree, now, tol=tol, **solve_options)
            again = retry.solve(q, now)
            late |= again.status == "timeout"
            res = again if again.success or again.error[0] < res.error[0] else res
        if late:
            timed_out.append(k)
        q = res.q
        out[k], ok[k] = q, bool(res.success)
    return Trajectory(times=np.arange(len(pts)) / fps, q=out, fingerprint=fingerprint(tree), model=tree.name,
                      frame=frame, targets=pts[:, None, :], success=ok, meta={"follow": {"timed_out": timed_out}})


def speed_step(tree: Tree, max_joint_speed: ArrayLike, fps: float) -> np.ndarray:
    """The largest step per frame ``(njnt,)`` of each joint at ``max_joint_speed`` (one number or ``(njnt,)``).

    ``fps`` is :func:`follow`'s, checked there (> 0).

    Raises:
        InputError: a speed that is not one number or one per joint, or not > 0.
    """
    try:
        speed = np.broadcast_to(np.asarray(max_joint_speed, dtype=np.float64), (tree.njnt,))
    except (TypeError, ValueError):
        raise InputError(f"max_joint_speed must be one number or one per joint ({tree.njnt}), got "
                         f"{max_joint_speed!r}") from None
    if not np.all(speed > 0):
        raise InputError(f"max_joint_speed must be > 0 (rad/s, m/s), got {max_joint_speed!r}")
    return speed / fps
