"""IK as constrained optimisation (the Finnish thesis, after Zhao & Badler's Jack system).

Minimise the goal potentials ``Σ w |g|²`` level by level (lexicographic
priorities: a level may not raise the cost of the levels above it), subject
to the joint limits as bounds (ball cones as inequalities, see :func:`_cone_gradient`),
:class:`~mjkin.goals.Coupling` goals as linear
equalities and hard goals (:class:`~mjkin.goals.HalfSpace`, ...) as inequalities ``s >= 0``, with
SciPy's SLSQP and analytic gradients ``Jᵀg``. Variables are a velocity ``v``
in the tangent space at the start (``q = q_start ⊕ v``), re-centred a few times
so ball and free joints stay exact. A local minimum is accepted; ``restarts``
tries perturbed starts for another.

SciPy's SLSQP has no time limit of its own, and its callback comes only between
iterations (one iteration can take many evaluations), so the time limit is
checked at every evaluation: when it runs out
the evaluation raises, SciPy's loop unwinds, and the last iterate SciPy reported
stands.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import ClassVar

import numpy as np
from numpy.typing import NDArray

from .. import spatial
from ..goals import Coupling, Program
from ..kinematics.qspace import HINGE, SLIDE
from ..kinematics.tree import Tree
from ..runtime.checks import check_count
from .evaluate import evaluate_program
from .kernel import BINDING, CONSTRAINT, CONVERGED, HARD_TOL, LIMITS, MAX_ITERATIONS, TIMEOUT, UNREACHABLE
from .method import MAX_ITERS, Method, ProblemView
from .result import Result, package

Array = NDArray[np.float64]


def _cone_gradient(q: Array, v: Array) -> Array:
    """Gradient ``(3,)`` of the rotation angle of the unit quaternion ``q = q_start ⊗ exp(v)`` with respect to ``v``.

    A small turn ``δ`` after ``q`` changes the angle by ``uᵀδ`` (``u``: the unit axis of ``q``; the right
    Jacobian's correction terms are orthogonal to it), and ``exp(v + dv) = exp(v) exp(J_r(v) dv)``, so the
    gradient is ``J_r(v)ᵀ u``. Zero at no rotation (there the cone cannot bind).
    """
    phi = spatial.quat_to_rotvec(q)
    angle = float(np.linalg.norm(phi))
    if angle < 1e-12:
        return np.zeros(3)
    t = float(np.linalg.norm(v))
    a, b = (0.5, 1.0 / 6.0) if t < 1e-6 else ((1.0 - np.cos(t)) / t**2, (t - np.sin(t)) / t**3)
    K = spatial.skew(v)
    return (np.eye(3) - a * K + b * K @ K).T @ (phi / angle)


class _OutOfTime(Exception):
    """Raised inside an evaluation SciPy asked for once the time limit has passed; it ends the SLSQP run."""


def _solve_one(tree: Tree, prog: Program, q0: Array, max_iters: int, active: NDArray[np.bool_],
               deadline: float) -> tuple[Array, bool, int, bool]:
    """Lexicographic SLSQP from ``q0``, until ``deadline`` (``time.monotonic()``; ``inf`` = none).

    Returns the configuration, whether SciPy hit its iteration limit, SciPy's iterations summed over the
    priority levels and re-centring passes, and whether the time ran out (then the configuration is the
    last iterate SciPy reported).
    """
    from scipy.optimize import minimize  # loaded by solve_optimize, before any clock starts

    rows = prog.row
    free = np.flatnonzero(active)
    constraint_goal = (prog.code == Coupling.code) | prog.hard
    scalar = np.isin(tree.jnt_type[tree.plan.dof_jnt], (HINGE, SLIDE))
    q_start = q0.copy()
    hit_limit = False
    iterations = 0

    def spread(index: NDArray[np.intp], values: Array) -> Array:  # (nv,), ``values`` at the dofs ``index``
        full = np.zeros(tree.nv)
        full[index] = values
        return full

    last: dict = {}  # SciPy evaluates the objective and each constraint at the same v in turn: integrate once

    def at(v: Array, clocked: bool = True) -> Array:  # every evaluation SciPy asks for comes through here
        if clocked and time.monotonic() > deadline:
            raise _OutOfTime
        key = v.tobytes()
        if last.get("key") != key:
            last["key"], last["q"] = key, tree.integrate(q_start, spread(free, v))
        return last["q"]

    def cone_jac(v: Array, qi: NDArray[np.intp], di: NDArray[np.intp]) -> Array:  # of the constraint limit - angle >= 0
        return -spread(di, _cone_gradient(at(v)[qi], spread(free, v)[di]))[free]

    def rows_of(mask: Array) -> Array:
        return np.concatenate([np.arange(rows[i], rows[i + 1]) for i in np.flatnonzero(mask)] or [np.zeros(0, int)])

    def cost(v: Array, idx: Array) -> tuple[float, Array]:
        g, J, _ = evaluate_program(tree, prog, at(v)[None])
        gi, Ji = g[0, idx], J[0][idx][:, free]
        return 0.5 * float(gi @ gi), Ji.T @ gi

    level_of = np.searchsorted(prog.level_rows, rows[:-1], side="right") - 1
    for _ in range(4):  # re-centre the tangent space (exact for hinge/slide in one pass)
        lo, hi = np.full(tree.nv, -np.inf), np.full(tree.nv, np.inf)
        for d in np.flatnonzero(scalar):
            j = tree.plan.dof_jnt[d]
            if tree.jnt_limited[j]:
                a = tree.jnt_qadr[j]
                lo[d], hi[d] = tree.jnt_range[j, 0] - q_start[a], tree.jnt_range[j, 1] - q_start[a]
        bounds = list(zip(np.minimum(lo[free], 0), np.maximum(hi[free], 0), strict=True))
        cons: list[dict] = []
        for i in np.flatnonzero((prog.code == Coupling.code) & (prog.sqrt_w > 0)):
            cons.append({"type": "eq", "fun": lambda v, r=rows[i]: evaluate_program(tree, prog, at(v)[None])[0][0, r],
                         "jac": lambda v, r=rows[i]: evaluate_program(tree, prog, at(v)[None])[1][0, r, free]})
        hard = rows_of(prog.hard)  # the hard goals' rows: s >= 0
        if len(hard):
            cons.append({"type": "ineq", "fun": lambda v, h=hard: evaluate_program(tree, prog, at(v)[None])[0][0, h],
                         "jac": lambda v, h=hard: evaluate_program(tree, prog, at(v)[None])[1][0][h][:, free]})
        lay = tree.layout
        for qi, di, limit in zip(lay.ball_q, lay.ball_v, lay.ball_max, strict=True):  # ball cones
            if np.isfinite(limit):
                cons.append({"type": "ineq", "fun": lambda v, qi=qi, c=limit: c - float(
                    spatial.quat_distance(at(v)[qi], [1.0, 0.0, 0.0, 0.0])),
                    "jac": lambda v, qi=qi, di=di: cone_jac(v, qi, di)})
        v = np.zeros(len(free))
        levels: list[Array | None] = [sel for lv in range(len(prog.level_rows) - 1)
                                      if len(sel := rows_of((level_of == lv) & ~constraint_goal))]
        for idx in levels or ([None] if cons else []):  # constraints alone: the smallest move that meets them
            reported = [v]  # the start and SciPy's iterates (its callback comes after each iteration)
            objective = (lambda x, _: (0.5 * float(x @ x), x)) if idx is None else cost
            try:
                res = minimize(objective, v, args=(idx,), jac=True, method="SLSQP", bounds=bounds, constraints=cons,
                               options={"maxiter": max_iters, "ftol": 1e-16},
                               callback=lambda x, seen=reported: seen.append(x.copy()))
            except _OutOfTime:
                return tree.clip(at(reported[-1], False)), hit_limit, iterations + len(reported) - 1, True
            hit_limit = hit_limit or res.status == 9
            iterations += int(res.nit)
            v = res.x
            achieved = res.fun
            if idx is not None:
                cons = cons + [{"type": "ineq", "fun": lambda v, idx=idx, c=achieved: c + 1e-12 - cost(v, idx)[0],
                                "jac": lambda v, idx=idx: -cost(v, idx)[1]}]
        q_new = tree.clip(at(v, False))
        done = np.abs(tree.difference(q_new, q_start)).max() < 1e-12
        q_start = q_new
        last.clear()
        if done or not (tree.layout.quats.size):
            break
    return q_start, hit_limit, iterations, False


def solve_optimize(tree: Tree, prog: Program, q: Array, tol: float, rot_tol: float, max_iters: int,
                   active: NDArray[np.bool_], restarts: Array, restart_q: NDArray[np.bool_],
                   timeout: float | None = None) -> Result:
    """Solve every target with SLSQP (see :func:`mjkin.solve`).

    A target that is not met restarts from ``restarts (K, nq)``, taken where
    ``restart_q`` is True and from the target's start elsewhere. ``iterations``
    are SciPy's, summed over every start tried. ``timeout``: seconds per target,
    every start included (None: no limit); a target that runs out keeps the best
    configuration so far with status ``TIMEOUT``.
    """
    import scipy.optimize  # noqa: F401  (~0.5 s, so imported on first use, not with mjkin; before any target's clock)

    B = prog.B
    out = np.empty_like(q)
    err = np.zeros((B, len(prog.goals), 2))
    status = np.zeros(B, np.int64)
    used = np.zeros(B, np.int64)
    iters = np.zeros(B, np.int64)
    binding = np.full(B, -1, np.int64)
    for b in range(B):
        one = prog.target(b)
        g, _, e = evaluate_program(tree, one, q[b][None])  # the start stands until a run ends with a finite cost
        h = one.level_rows[0]  # the hard rows come first, outside the cost
        best, best_key, err[b], status[b] = q[b], (np.inf, np.inf), e[0], UNREACHABLE
        start_cost = float(g[0, h:] @ g[0, h:])  # a run cut short by the clock must also beat the start
        starts = [q[b], *np.where(restart_q, restarts, q[b])]
        deadline = np.inf if timeout is None else time.monotonic() + timeout
        for k, start in enumerate(starts):
            qb, hit, n, late = _solve_one(tree, one, start, max_iters, active, deadline)
            iters[b] += n
            g, _, e = evaluate_program(tree, one, qb[None])
            c = float(g[0, h:] @ g[0, h:])
            key = (max(float(e[0][one.hard].max(initial=0.0)) - HARD_TOL, 0.0), c)  # feasible first, then cost
            if key < best_key and not (late and c >= start_cost):
                best, best_key, err[b], used[b] = qb, key, e[0], k
                ok = key[0] == 0.0 and np.all((e[0][one.counted, 0] <= tol) & (e[0][one.counted, 1] <= rot_tol))
                lay = tree.layout
                at_limit = np.any(np.isclose(qb[lay.scalar_q], lay.scalar_lo, atol=1e-9)
                                  | np.isclose(qb[lay.scalar_q], lay.scalar_hi, atol=1e-9))
                status[b] = CONVERGED if ok else MAX_ITERATIONS if hit else LIMITS if at_limit else UNREACHABLE
                binding[b] = _binding(one, g[0]) if not ok else -1
                if binding[b] >= 0 and status[b] in (UNREACHABLE, LIMITS):
                    status[b] = CONSTRAINT
                if ok:
                    break
            if late:
                status[b] = TIMEOUT if status[b] != CONVERGED else CONVERGED
                break
        out[b] = best
    return package(prog, out, err, iters, status, used, tol, rot_tol, "optimize", tree=tree, binding=binding)


def _binding(prog: Program, g: Array) -> int:
    """The hard goal of ``prog`` (one target) with the lowest row below :data:`BINDING` in ``g (m,)``, or -1."""
    low, found = BINDING, -1
    for i in np.flatnonzero(prog.hard):
        s = float(g[prog.row[i]:prog.row[i + 1]].min())
        if s < low:
            low, found = s, int(i)
    return found


# optimize's time limit per target when none is given: SciPy's SLSQP has no other bound on its wall time (on the
# primate with a half-space and a plane goal and a planted root it ran for minutes), while its usual solves take
# milliseconds (the test suite's slowest target, on ball_chain's cones, 500 SLSQP iterations in about 1 s)
OPTIMIZE_TIMEOUT = 5.0


@dataclass(frozen=True)
class Optimize(Method):
    """SciPy's SLSQP on the weighted cost, with joint limits as bounds and couplings and half-spaces as constraints.

    ``max_iters``: SLSQP iterations per start. Without a ``timeout`` a target may
    take :data:`OPTIMIZE_TIMEOUT` seconds.
    """

    name: ClassVar[str] = "optimize"
    max_iters: int = 500

    def __post_init__(self) -> None:
        super().__post_init__()
        check_count(self.max_iters, "max_iters", 0, whole_floats=True, most=MAX_ITERS)

    def default_timeout(self) -> float | None:  # noqa: D102
        return OPTIMIZE_TIMEOUT

    def run(self, problem: ProblemView, prog: Program, q: Array) -> Result:  # noqa: D102
        return solve_optimize(problem.tree, prog, q, problem.tol, problem.rot_tol, int(self.max_iters),
                              problem.active, problem.starts, problem.restart_q, problem.time_limit)
