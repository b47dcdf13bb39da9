"""What IK should achieve: goals with a residual, its Jacobian, a weight and a priority.

Every goal defines a residual ``g(q)`` that is zero when the goal is met and
its Jacobian ``dg/dv`` (``v`` is MuJoCo's velocity, so ``(m, nv)``). Solvers
minimise ``Σ weight · |g|²`` level by level: priority 0 first, and a larger
priority only uses the freedom the smaller ones leave (seed 002: weighted goal
potentials, base/effector pairs ordered by priority). ``weight=0`` switches a
goal off.

Frame goals name a site or body (``kind`` as in :meth:`Tree.frame`) and may
act on a point ``offset`` fixed in that frame. Targets may carry a leading
batch axis: ``Position("ee", xyz)`` with ``xyz`` of shape ``(B, 3)`` asks for
``B`` solves at once.

The goal math lives in one compiled evaluator (:mod:`mjkin.ik.kernel`); here
goals are validated and encoded as arrays (:func:`compile_goals`), and
:func:`evaluate` gives residuals and Jacobians for inspection and tests.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING, Any, ClassVar

import numpy as np
from numpy.typing import ArrayLike, NDArray

from . import spatial
from .errors import GoalError, MjkinError
from .jit import njit
from .kinematics.qspace import HINGE, SLIDE, all_finite

if TYPE_CHECKING:
    from .kinematics.tree import Kind, Tree

Array = NDArray[np.float64]

# goal kinds understood by the compiled evaluator
POSITION, ORIENTATION, AXIS, POSE, AIM, LINE, PLANE, HALFSPACE, REST, COUPLING = range(10)
DATA = 12  # per-goal target numbers: [0:3] a point, [3:12] a rotation (row-major) or [3:6] a direction
_AXES = {"x": 0, "y": 1, "z": 2}


def _array(value: ArrayLike, shape: tuple[int, ...], what: str) -> Array:
    """``value`` as float64 with trailing ``shape`` and at most one leading batch axis."""
    try:
        a = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise GoalError(f"{what} must be numbers of shape {shape} or (B, {', '.join(map(str, shape))})") from None
    if a.shape[a.ndim - len(shape):] != shape or a.ndim > len(shape) + 1:
        batched = "(B, " + ", ".join(map(str, shape)) + ")"
        raise GoalError(f"{what} has shape {a.shape}; expected {shape} or {batched}")
    if not all_finite(a.reshape(-1)):
        raise GoalError(f"{what} contains NaN or inf")
    return a


def _broadcast(shapes: Sequence[tuple[int, ...]]) -> tuple[int, ...]:
    """``np.broadcast_shapes`` without its cost (a few µs) when every shape is the same (the usual case)."""
    if all(s == shapes[0] for s in shapes[1:]):
        return tuple(shapes[0]) if shapes else ()
    return tuple(np.broadcast_shapes(*shapes))


@njit
def _rotation_defect(R: Array) -> tuple[float, float]:
    """Largest ``|RRᵀ - I|`` entry and smallest determinant over ``R (n, 3, 3)``."""
    drift, det = 0.0, np.inf
    for n in range(R.shape[0]):
        for i in range(3):
            for k in range(3):
                dot = R[n, i, 0] * R[n, k, 0] + R[n, i, 1] * R[n, k, 1] + R[n, i, 2] * R[n, k, 2]
                drift = max(drift, abs(dot - (1.0 if i == k else 0.0)))
        det = min(det, R[n, 0, 0] * (R[n, 1, 1] * R[n, 2, 2] - R[n, 1, 2] * R[n, 2, 1])
                  - R[n, 0, 1] * (R[n, 1, 0] * R[n, 2, 2] - R[n, 1, 2] * R[n, 2, 0])
                  + R[n, 0, 2] * (R[n, 1, 0] * R[n, 2, 1] - R[n, 1, 1] * R[n, 2, 0]))
    return drift, det


def _unit(value: ArrayLike, what: str) -> Array:
    a = _array(value, (3,), what)
    n = np.linalg.norm(a, axis=-1, keepdims=True)
    if np.any(n < 1e-12):
        raise GoalError(f"{what} must have non-zero length")
    return a / n


def _rotation(value: ArrayLike, what: str) -> Array:
    """A rotation given as quaternion(s) ``(..., 4)`` or matrix(es) ``(..., 3, 3)`` → matrices."""
    a = np.asarray(value, dtype=np.float64) if not isinstance(value, np.ndarray) else value
    if a.shape[-1:] == (4,):
        q = _array(a, (4,), what)
        n = np.linalg.norm(q, axis=-1, keepdims=True)
        if np.any(n < 1e-12):
            raise GoalError(f"{what} is a zero quaternion")
        return spatial.quat_to_mat(q / n)
    R = _array(a, (3, 3), what)
    drift, det = _rotation_defect(np.ascontiguousarray(R).reshape(-1, 3, 3))
    if drift > 1e-6 or det < 0:
        raise GoalError(f"{what} is not a rotation matrix (orthonormal, det +1)")
    return R if drift < 1e-12 else spatial.orthonormalize(R)


@dataclass(frozen=True)
class Goal:
    """Base of all goals: a weight (0 = ignored) and a priority (0 = highest)."""

    weight: float = field(default=1.0, kw_only=True)
    priority: int = field(default=0, kw_only=True)
    code: ClassVar[int]
    rows: ClassVar[int]

    def __post_init__(self) -> None:
        w = float(self.weight)
        if not np.isfinite(w) or w < 0:
            raise GoalError(f"{type(self).__name__}: weight must be a finite number >= 0, got {self.weight!r}")
        if not isinstance(self.priority, (int, np.integer)) or self.priority < 0:
            raise GoalError(f"{type(self).__name__}: priority must be an integer >= 0, got {self.priority!r}")

    def nrows(self, tree: Tree) -> int:
        """Number of residual rows."""
        return self.rows

    def batch(self) -> tuple[int, ...]:
        """Leading batch shape of the targets: ``()`` or ``(B,)``."""
        return ()

    def encode(self, tree: Tree, data: Array) -> int:
        """Write target numbers into ``data (B, DATA)``; return the goal's auxiliary integer."""
        return 0

    _batched: ClassVar[tuple[str, ...]] = ()  # fields that may carry the leading batch axis

    def take(self, lo: int, hi: int) -> Goal:
        """This goal with only the targets ``lo:hi`` of its batch (an unbatched goal as it is).

        For splitting a batched solve into pieces: ``solve(tree, [g.take(lo, hi) for g in goals])``.
        """
        if self.batch() == ():
            return self
        changes: dict[str, Any] = {name: np.asarray(getattr(self, name))[lo:hi] for name in self._batch_fields()}
        return replace(self, **changes)

    def _batch_fields(self) -> list[str]:
        """The fields whose value carries the leading batch axis."""
        out = []
        for name in self._batched:
            value = np.asarray(getattr(self, name))
            core = 2 if name == "T" or (name == "quat" and value.shape[-1:] != (4,)) else 1
            if value.ndim > core:
                out.append(name)
        return out


@dataclass(frozen=True)
class FrameGoal(Goal):
    """A goal on a site or body frame, or on a point ``offset`` fixed in that frame."""

    name: str
    kind: Kind | None = field(default=None, kw_only=True)
    offset: tuple[float, float, float] | None = field(default=None, kw_only=True)

    def frame(self, tree: Tree) -> tuple[int, Array, Array]:
        """Body, local rotation ``(3, 3)`` and local point ``(3,)`` of the goal frame."""
        body, T = tree.frame_body(self.name, self.kind)
        point = T[:3, 3]
        if self.offset is not None:
            point = point + T[:3, :3] @ _array(self.offset, (3,), f"{type(self).__name__} offset")
        return body, T[:3, :3], point

    _cores: ClassVar[tuple[int, ...]] = (1, 1)  # number of non-batch axes of each target

    def _validate(self) -> list[Array]:
        return []

    def _targets(self) -> list[Array]:
        """The validated targets (computed once per goal)."""
        cached = self.__dict__.get("_checked")
        if cached is None:
            cached = self._validate()
            object.__setattr__(self, "_checked", cached)
        return cached

    def encode(self, tree: Tree, data: Array) -> int:
        """Write a point and a direction (the layout of Aim, Line, Plane, HalfSpace) into ``data``."""
        point, direction = self._targets()
        data[:, 0:3] = point
        data[:, 3:6] = direction
        return 0

    def batch(self) -> tuple[int, ...]:
        """Leading batch shape shared by the targets."""
        shapes = [t.shape[: t.ndim - core] for t, core in zip(self._targets(), self._cores, strict=False)]
        try:
            return _broadcast(shapes)
        except ValueError:
            raise GoalError(f"{type(self).__name__}: targets have different batch sizes {shapes}") from None


@dataclass(frozen=True)
class Position(FrameGoal):
    """Put the frame origin (or ``offset``) at ``xyz``: ``g = p - xyz``."""

    xyz: ArrayLike = (0.0, 0.0, 0.0)
    code: ClassVar[int] = POSITION
    rows: ClassVar[int] = 3
    _batched: ClassVar[tuple[str, ...]] = ("xyz",)

    def _validate(self) -> list[Array]:
        return [_array(self.xyz, (3,), "Position xyz")]

    def encode(self, tree: Tree, data: Array) -> int:  # noqa: D102
        data[:, 0:3] = self._targets()[0]
        return 0


@dataclass(frozen=True)
class Orientation(FrameGoal):
    """Turn the frame to ``quat`` (or a rotation matrix): ``g = log(R R_targetᵀ)``, world axes.

    ``axes`` names the frame axes that must match the target's: ``"xyz"`` (all,
    the default) is the full orientation; a single axis such as ``"z"`` leaves
    the rotation about it free (the seed's direction-or-up vector with ``c = 0``).
    """

    quat: ArrayLike = (1.0, 0.0, 0.0, 0.0)
    axes: str = "xyz"
    code: ClassVar[int] = ORIENTATION
    rows: ClassVar[int] = 3
    _batched: ClassVar[tuple[str, ...]] = ("quat",)
    _cores: ClassVar[tuple[int, ...]] = (2,)

    def __post_init__(self) -> None:
        super().__post_init__()
        if not self.axes or set(self.axes) - set(_AXES) or len(set(self.axes)) != len(self.axes):
            raise GoalError(f"Orientation axes must be one or more of 'x', 'y', 'z', got {self.axes!r}")

    def _validate(self) -> list[Array]:
        return [_rotation(self.quat, "Orientation quat")]

    def encode(self, tree: Tree, data: Array) -> int:  # noqa: D102
        data[:, 3:12] = self._targets()[0].reshape(-1, 9)
        return self.axis_index

    @property
    def axis_index(self) -> int:
        """The one constrained axis (0, 1, 2 for x, y, z), or -1 for all three."""
        return _AXES[self.axes] if len(self.axes) == 1 else -1

    @property
    def single_axis(self) -> bool:
        """Only one axis is constrained."""
        return len(self.axes) == 1


@dataclass(frozen=True)
class Pose(FrameGoal):
    """Position and orientation at once, from a 4x4 pose ``T``: rows ``[position; orientation]``."""

    T: ArrayLike = field(default_factory=lambda: np.eye(4))
    code: ClassVar[int] = POSE
    rows: ClassVar[int] = 6
    _batched: ClassVar[tuple[str, ...]] = ("T",)
    _cores: ClassVar[tuple[int, ...]] = (2, 1)

    def _validate(self) -> list[Array]:
        T = _array(self.T, (4, 4), "Pose T")
        return [_rotation(T[..., :3, :3], "Pose T rotation"), T[..., :3, 3]]

    def encode(self, tree: Tree, data: Array) -> int:  # noqa: D102
        R, p = self._targets()
        data[:, 0:3] = p
        data[:, 3:12] = R.reshape(-1, 9)
        return 0


@dataclass(frozen=True)
class Aim(FrameGoal):
    """Point the frame's local ``axis`` at the world ``point`` (look at): ``g = R axis - unit(point - p)``."""

    axis: ArrayLike = (1.0, 0.0, 0.0)
    point: ArrayLike = (0.0, 0.0, 0.0)
    code: ClassVar[int] = AIM
    rows: ClassVar[int] = 3
    _batched: ClassVar[tuple[str, ...]] = ("point",)

    def _validate(self) -> list[Array]:
        axis = _unit(self.axis, "Aim axis")
        if axis.ndim != 1:
            raise GoalError("Aim axis is fixed in the frame: give one (3,) vector")
        return [_array(self.point, (3,), "Aim point"), axis]


@dataclass(frozen=True)
class Line(FrameGoal):
    """Keep the frame origin on the line through ``point`` along ``direction``."""

    point: ArrayLike = (0.0, 0.0, 0.0)
    direction: ArrayLike = (0.0, 0.0, 1.0)
    code: ClassVar[int] = LINE
    rows: ClassVar[int] = 3
    _batched: ClassVar[tuple[str, ...]] = ("point", "direction")

    def _validate(self) -> list[Array]:
        return [_array(self.point, (3,), "Line point"), _unit(self.direction, "Line direction")]


@dataclass(frozen=True)
class Plane(FrameGoal):
    """Keep the frame origin on the plane through ``point`` with ``normal``: ``g = n·(p - point)``."""

    point: ArrayLike = (0.0, 0.0, 0.0)
    normal: ArrayLike = (0.0, 0.0, 1.0)
    code: ClassVar[int] = PLANE
    rows: ClassVar[int] = 1
    _batched: ClassVar[tuple[str, ...]] = ("point", "normal")

    def _validate(self) -> list[Array]:
        return [_array(self.point, (3,), f"{type(self).__name__} point"),
                _unit(self.normal, f"{type(self).__name__} normal")]


@dataclass(frozen=True)
class HalfSpace(Plane):
    """Stay on the side of a wall that ``normal`` points to: ``g = min(0, n·(p - point))``."""

    code: ClassVar[int] = HALFSPACE


@dataclass(frozen=True)
class Rest(Goal):
    """Stay near a rest ("comfort") pose: ``g = sqrt(stiffness) · (q ⊖ q_rest)``, one row per dof.

    ``stiffness`` is a number or one per dof (``nv``); stiff joints move less.
    Never counted for success. Usually given a small weight or a low priority.
    """

    q_rest: ArrayLike = ()
    stiffness: ArrayLike = 1.0
    code: ClassVar[int] = REST
    rows: ClassVar[int] = -1
    _batched: ClassVar[tuple[str, ...]] = ("q_rest",)

    def nrows(self, tree: Tree) -> int:  # noqa: D102
        return tree.nv

    def batch(self) -> tuple[int, ...]:  # noqa: D102
        a = np.asarray(self.q_rest, dtype=np.float64)
        return a.shape[:-1] if a.ndim > 1 else ()

    def arrays(self, tree: Tree) -> tuple[Array, Array]:
        """Validated ``q_rest (…, nq)`` and ``sqrt(stiffness) (nv,)``."""
        try:
            q = tree.check_q(self.q_rest, "Rest q_rest")
        except MjkinError as e:
            raise GoalError(str(e)) from None
        k = np.broadcast_to(np.asarray(self.stiffness, dtype=np.float64), (tree.nv,)) \
            if np.ndim(self.stiffness) == 0 else _array(self.stiffness, (tree.nv,), "Rest stiffness")
        if k.ndim != 1 or np.any(k < 0) or not np.isfinite(k).all():
            raise GoalError(f"Rest stiffness must be >= 0, one number or {tree.nv} (nv)")
        return q, np.sqrt(k)


@dataclass(frozen=True)
class Coupling(Goal):
    """A linear equality between hinge/slide joints: ``Σ coef_j q_j = value`` (e.g. coupled fingers)."""

    coefficients: Mapping[str, float] = field(default_factory=dict)
    value: float = 0.0
    code: ClassVar[int] = COUPLING
    rows: ClassVar[int] = 1

    def row(self, tree: Tree) -> Array:
        """Coefficients laid out over the dofs ``(nv,)``."""
        if not self.coefficients:
            raise GoalError("Coupling needs at least one joint coefficient")
        c = np.zeros(tree.nv)
        for name, coef in self.coefficients.items():
            j = tree.id(name, "joint")
            if tree.jnt_type[j] not in (HINGE, SLIDE):
                raise GoalError(f"Coupling joint {name!r} must be a hinge or slide")
            if not np.isfinite(coef):
                raise GoalError(f"Coupling coefficient of {name!r} is not finite")
            c[tree.jnt_dofadr[j]] = coef
        return c

    def encode(self, tree: Tree, data: Array) -> int:  # noqa: D102
        if not np.isfinite(self.value):
            raise GoalError("Coupling value is not finite")
        data[:, 0] = self.value
        return 0


@dataclass(frozen=True)
class Program:
    """Goals encoded as arrays for the compiled evaluator, sorted by priority level.

    ``G`` goals, ``B`` targets, ``m`` residual rows. ``level_rows[l]:level_rows[l+1]``
    are the rows of level ``l`` (priorities compressed to 0, 1, ...).
    """

    goals: tuple[Goal, ...]
    batch: tuple[int, ...]  # () or (B,)
    kind: NDArray[np.int64]  # (G,)
    body: NDArray[np.int64]  # (G,) -1 for joint-space goals
    lrot: Array  # (G, 3, 3) goal frame in its body
    lpos: Array  # (G, 3)
    data: Array  # (B, G, DATA)
    aux: NDArray[np.int64]  # (G,) orientation axis (-1 = all), rest or coupling index
    sqrt_w: Array  # (G,)
    row: NDArray[np.int64]  # (G + 1,) first residual row of each goal
    level_rows: NDArray[np.int64]  # (L + 1,)
    rest_q: Array  # (R, B, nq)
    rest_k: Array  # (R, nv) square roots of stiffness
    coupling: Array  # (C, nv)
    counted: NDArray[np.bool_]  # (G,) counts for success (weight > 0 and not a rest goal)

    @property
    def B(self) -> int:
        """Number of targets (1 when unbatched)."""
        return int(self.data.shape[0])


def concatenate(pieces: Sequence[Goal]) -> Goal:
    """One goal from pieces of one batched goal, in order: the inverse of :meth:`Goal.take`.

    Raises:
        GoalError: no pieces, pieces of different goals, or batched and unbatched pieces mixed.
    """
    if not pieces:
        raise GoalError("concatenate needs at least one piece")
    first = pieces[0]
    fields = first._batch_fields() if first.batch() != () else []
    for p in pieces[1:]:
        if type(p) is not type(first) or (p.batch() != ()) != bool(fields) or p._batch_fields() != fields:
            raise GoalError(f"concatenate takes pieces of one goal; got a {type(p).__name__} batched as "
                            f"{p.batch()} after a {type(first).__name__} batched as {first.batch()}")
    if not fields:
        return first
    joined: dict[str, Any] = {f: np.concatenate([np.asarray(getattr(p, f)) for p in pieces]) for f in fields}
    return replace(first, **joined)


def compile_goals(tree: Tree, goals: Goal | Sequence[Goal]) -> Program:
    """Validate goals against ``tree`` and encode them (see :class:`Program`).

    The part that does not depend on the targets (frames, weights, priorities,
    rows) is kept on the tree, keyed by the goals' structure, so a loop of
    solves with new targets only encodes the targets.

    Raises:
        GoalError: a goal is malformed (non-finite, wrong shape, zero direction) or
            batches disagree.
        UnknownNameError: a frame or joint name the model does not have.
    """
    goals = (goals,) if isinstance(goals, Goal) else tuple(goals)
    if not goals:
        raise GoalError("give at least one goal")
    for g in goals:
        if not isinstance(g, Goal):
            raise GoalError(f"goals must be mjkin.goals objects, got {type(g).__name__}")
    key = _structure_key(goals)
    cache: dict = tree.__dict__.setdefault("_goal_structures", {})
    structure = cache.get(key) if key is not None else None
    if structure is None:
        structure = _structure(tree, goals)
        if key is not None and len(cache) < 256:
            cache[key] = structure
    order, prog = structure
    goals = tuple(goals[i] for i in order)
    try:
        batch = _broadcast([g.batch() for g in goals])
    except ValueError:
        raise GoalError(f"goal targets have different batch sizes: {[g.batch() for g in goals]}") from None
    if len(batch) > 1:
        raise GoalError(f"targets may have one leading batch axis, got batch shape {batch}")
    B = batch[0] if batch else 1
    data = np.zeros((B, len(goals), DATA))
    rest_q = np.empty((len(prog.rest_q), B, tree.nq))
    for i, g in enumerate(goals):
        g.encode(tree, data[:, i])
        if isinstance(g, Rest):
            rest_q[prog.aux[i]] = g.arrays(tree)[0]
    return Program(goals, batch, prog.kind, prog.body, prog.lrot, prog.lpos, data, prog.aux, prog.sqrt_w, prog.row,
                   prog.level_rows, rest_q, prog.rest_k, prog.coupling, prog.counted)


def _structure_key(goals: tuple[Goal, ...]) -> tuple | None:
    """What a program depends on besides the targets; None when a part is not hashable."""
    parts: list = []
    for g in goals:
        part: tuple = (type(g), g.weight, g.priority)
        if isinstance(g, FrameGoal):
            offset = None if g.offset is None else tuple(np.asarray(g.offset, dtype=float).ravel())
            part += (g.name, g.kind, offset, getattr(g, "axes", None))
        elif isinstance(g, Rest):
            part += (np.asarray(g.stiffness, dtype=float).tobytes(),)
        elif isinstance(g, Coupling):
            part += (tuple(g.coefficients.items()), )
        parts.append(part)
    key = tuple(parts)
    try:
        hash(key)
    except TypeError:
        return None
    return key


def _structure(tree: Tree, goals: tuple[Goal, ...]) -> tuple[list[int], Program]:
    """The priority order of ``goals`` and their target-independent encoding (targets left empty)."""
    order = sorted(range(len(goals)), key=lambda i: goals[i].priority)  # stable: order within a level kept
    goals = tuple(goals[i] for i in order)
    G = len(goals)
    kind = np.array([g.code for g in goals], dtype=np.int64)
    body = np.full(G, -1, dtype=np.int64)
    lrot = np.tile(np.eye(3), (G, 1, 1))
    lpos = np.zeros((G, 3))
    aux = np.zeros(G, dtype=np.int64)
    rest_k: list[Array] = []
    coupling: list[Array] = []
    nrows = []
    for i, g in enumerate(goals):
        if isinstance(g, FrameGoal):
            body[i], lrot[i], lpos[i] = g.frame(tree)
        aux[i] = g.axis_index if isinstance(g, Orientation) else 0
        if isinstance(g, Orientation) and g.single_axis:
            kind[i] = AXIS
        if isinstance(g, Rest):
            aux[i] = len(rest_k)
            rest_k.append(g.arrays(tree)[1])
        if isinstance(g, Coupling):
            aux[i] = len(coupling)
            coupling.append(g.row(tree))
        nrows.append(g.nrows(tree))
    row_list = [0]
    for n in nrows:
        row_list.append(row_list[-1] + n)
    priorities = [g.priority for g in goals]  # sorted: each level's rows are contiguous
    level_rows = np.array([row_list[i] for i in range(G) if i == 0 or priorities[i] != priorities[i - 1]]
                          + [row_list[-1]], dtype=np.int64)
    return order, Program(
        goals=goals, batch=(), kind=kind, body=body, lrot=lrot, lpos=lpos, data=np.zeros((1, G, DATA)), aux=aux,
        sqrt_w=np.sqrt([float(g.weight) for g in goals]), row=np.array(row_list, dtype=np.int64),
        level_rows=level_rows, rest_q=np.zeros((len(rest_k), 1, tree.nq)),
        rest_k=np.array(rest_k).reshape(len(rest_k), tree.nv),
        coupling=np.array(coupling).reshape(len(coupling), tree.nv),
        counted=np.array([g.weight > 0 and not isinstance(g, Rest) for g in goals]),
    )


def evaluate(tree: Tree, goals: Goal | Sequence[Goal], q: ArrayLike) -> tuple[Array, Array, Array]:
    """Weighted residuals ``(B, m)``, Jacobians ``(B, m, nv)`` and per-goal errors ``(B, G, 2)``.

    Errors are ``[position (m), rotation (rad)]`` of each goal in natural units
    (unweighted). Goals come back sorted by priority, as the solvers see them.
    """
    from .ik.kernel import evaluate_program

    prog = compile_goals(tree, goals)
    qs = np.broadcast_to(tree.check_q(q), (prog.B, tree.nq))
    return evaluate_program(tree, prog, np.ascontiguousarray(qs))
