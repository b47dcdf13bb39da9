"""Closed-form IK of a two-link planar arm (the Polish lecture notes, the Chinese course notes).

Reachable iff ``|L1 - L2| <= r <= L1 + L2`` with ``r = sqrt(X² + Y²)``; then
``θ2 = ±acos((r² - L1² - L2²) / (2 L1 L2))`` and
``θ1 = atan2(Y, X) - atan2(L2 sin θ2, L1 + L2 cos θ2)`` — two solutions, mirror
images about the line from the base to the goal. (The seeds write θ1 with an
``acos``; this ``atan2`` form is the same angle, valid for both signs of θ2.)
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any, ClassVar

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..errors import GoalError, InputError
from ..goals import Position, Program
from ..kinematics.qspace import HINGE
from ..kinematics.tree import Tree
from .evaluate import evaluate_program
from .kernel import CONVERGED, UNREACHABLE
from .method import Method, ProblemView
from .result import Result, package

Array = NDArray[np.float64]


def two_link(L1: float, L2: float, x: ArrayLike, y: ArrayLike) -> tuple[Array, NDArray[np.bool_], Array]:
    """Both solutions ``(θ1, θ2)`` for goals ``(x, y)``: arrays ``(..., 2, 2)`` [elbow +, elbow -].

    Returns the solutions, a reachability mask ``(...)``, and for unreachable
    goals the angles of the arm stretched (or folded) toward the goal.
    """
    x, y = np.asarray(x, dtype=np.float64), np.asarray(y, dtype=np.float64)
    r2 = x * x + y * y
    c2 = (r2 - L1 * L1 - L2 * L2) / (2 * L1 * L2)
    reachable = (np.sqrt(r2) <= L1 + L2 + 1e-12) & (np.sqrt(r2) >= abs(L1 - L2) - 1e-12)
    t2 = np.arccos(np.clip(c2, -1.0, 1.0))
    sols = []
    for s in (1.0, -1.0):
        th2 = s * t2
        th1 = np.arctan2(y, x) - np.arctan2(L2 * np.sin(th2), L1 + L2 * np.cos(th2))
        sols.append(np.stack([th1, th2], -1))
    return np.stack(sols, -2), reachable, t2


@dataclass(frozen=True)
class Planar2:
    """A two-hinge planar chain read from a model: joints, link lengths, plane frame."""

    joints: tuple[int, int]
    L1: float
    L2: float
    origin: Array  # anchor of joint 1 at q_ref
    e1: Array  # plane basis: along link 1 at q_ref
    e2: Array
    normal: Array
    phi2: float  # angle of link 2 relative to link 1 at q_ref
    sign2: float  # +1 if joint 2 turns the same way as joint 1 about the normal
    q_ref: Array
    height: float  # goal point's offset along the normal (fixed by the chain)

    @classmethod
    def of(cls, tree: Tree, prog: Program, q_ref: Array) -> Planar2:
        """Read the chain moving the goal's body; raises GoalError unless it is a planar two-hinge chain."""
        if len(prog.goals) != 1 or prog.code[0] != Position.code:
            raise GoalError("method 'analytic2' solves one Position goal on a two-link planar chain")
        body = int(prog.body[0])
        joints = np.unique(tree.plan.dof_jnt[tree.body_dofs[body]])
        if len(joints) != 2 or np.any(tree.jnt_type[joints] != HINGE):
            raise GoalError(f"method 'analytic2' needs exactly two hinge joints moving the goal frame, found "
                            f"{len(joints)} joints ({', '.join(tree.names('joint')[j] or '#' for j in joints)})")
        f = tree.kinematics(q_ref)
        anchors, axes = [], []
        for j in joints:  # the joint's frame: its body's, or the frame after it if another joint follows
            k = tree.plan.jnt_inner[j]
            Rj, xj = (f.inner_rot[0, k], f.inner_pos[0, k]) if k >= 0 else (f.rot[0, tree.jnt_body[j]],
                                                                             f.pos[0, tree.jnt_body[j]])
            anchors.append(xj + Rj @ tree.jnt_pos[j])
            axes.append(Rj @ tree.jnt_axis[j])
        n = axes[0] / np.linalg.norm(axes[0])
        if abs(abs(n @ axes[1]) - 1) > 1e-9:
            raise GoalError("method 'analytic2' needs parallel hinge axes (a planar chain)")
        Rb, xb = f.rot[0, body], f.pos[0, body]
        tip = xb + Rb @ prog.lpos[0]

        def flat(v: Array) -> Array:
            return v - (v @ n) * n

        l1, l2 = flat(anchors[1] - anchors[0]), flat(tip - anchors[1])
        L1, L2 = float(np.linalg.norm(l1)), float(np.linalg.norm(l2))
        if L1 < 1e-12 or L2 < 1e-12:
            raise GoalError("method 'analytic2' needs two links of non-zero length in the plane")
        e1 = l1 / L1
        e2 = np.cross(n, e1)
        return cls(joints=(int(joints[0]), int(joints[1])), L1=L1, L2=L2, origin=anchors[0], e1=e1, e2=e2,
                   normal=n, phi2=float(np.arctan2(l2 @ e2, l2 @ e1)), sign2=float(np.sign(n @ axes[1])),
                   q_ref=q_ref.copy(), height=float((tip - anchors[0]) @ n))

    def configurations(self, tree: Tree, xyz: Array) -> tuple[Array, NDArray[np.bool_]]:
        """Both solutions as configurations ``(B, 2, nq)`` and the reachability mask ``(B,)``."""
        d = xyz - self.origin
        (sol, reachable, _) = two_link(self.L1, self.L2, d @ self.e1, d @ self.e2)
        reachable &= np.abs(d @ self.normal - self.height) <= 1e-9
        q = np.broadcast_to(self.q_ref, sol.shape[:-1] + (tree.nq,)).copy()
        a1, a2 = tree.jnt_qadr[list(self.joints)]
        q[..., a1] = self.q_ref[a1] + sol[..., 0]
        q[..., a2] = self.q_ref[a2] + self.sign2 * (sol[..., 1] - self.phi2)
        return q, reachable


def solve_analytic2(tree: Tree, prog: Program, q0: Array, tol: float) -> Result:
    """Closed-form solve; of the two elbow solutions, the one inside the limits and nearest ``q0``."""
    chain = Planar2.of(tree, prog, tree.qpos0.copy())
    q, reachable = chain.configurations(tree, prog.data[:, 0, :3])
    a = tree.jnt_qadr[list(chain.joints)]
    wrapped = np.angle(np.exp(1j * (q[..., a] - q0[:, None, a])))  # nearest equivalent angles to q0
    q[..., a] = q0[:, None, a] + wrapped
    inside = np.all(tree.clip(q)[..., a] == q[..., a], axis=-1)
    dist = np.linalg.norm(wrapped, axis=-1) + np.where(inside, 0.0, 1e6)
    best = np.take_along_axis(q, np.argmin(dist, axis=1)[:, None, None], axis=1)[:, 0]
    best = tree.clip(best)
    _, _, err = evaluate_program(tree, prog, best)
    status = np.where(reachable & (err[:, 0, 0] <= tol), CONVERGED, UNREACHABLE)
    return package(prog, best, err, np.ones(len(best), np.int64), status, np.zeros(len(best), np.int64), tol,
                   np.inf, "analytic2")


def solutions(tree: Tree, goal: ArrayLike, name: str) -> tuple[Array, NDArray[np.bool_]]:
    """Both elbow configurations ``(..., 2, nq)`` putting frame ``name`` at ``goal (..., 3)``, and reachability."""
    from ..goals import compile_goals

    prog = compile_goals(tree, Position(name, goal))
    q, ok = Planar2.of(tree, prog, tree.qpos0.copy()).configurations(tree, prog.data[:, 0, :3])
    return (q, ok) if prog.batch else (q[0], ok[0])


@dataclass(frozen=True)
class Analytic2(Method):
    """The closed form of a two-link planar arm; of the two elbows, the one inside the limits nearest the start."""

    name: ClassVar[str] = "analytic2"

    @classmethod
    def with_options(cls, options: dict[str, Any]) -> Method:  # noqa: D102
        if options:
            raise _closed_form(list(options))
        return cls()

    def prepare(self, problem: ProblemView) -> None:
        """Refuse what a closed form cannot honour (a subset of joints, a planted root, a history)."""
        bad = ["restarts"] if self.restarts else []
        bad += [k for k in ("base", "joints", "root") if getattr(problem, k) is not None]
        bad += [k for k in ("history", "avoid_collisions") if getattr(problem, k)]
        if bad:
            raise _closed_form(bad)

    def run(self, problem: ProblemView, prog: Program, q: Array) -> Result:  # noqa: D102
        return replace(solve_analytic2(problem.tree, prog, q, problem.tol), tree=problem.tree)


def _closed_form(options: list[str]) -> InputError:
    return InputError(f"method 'analytic2' is closed-form and cannot honour {', '.join(options)}; "
                      "use an iterative method (auto, dls, ...) for those")
