"""The goal base classes and the target checks every kind shares.

Every goal defines a residual ``g(q)`` that is zero when the goal is met and its
Jacobian ``dg/dv`` (``v`` is MuJoCo's velocity, so ``(m, nv)``). Solvers minimise
``Σ weight · |g|²`` level by level: priority 0 first, and a larger priority only
uses the freedom the smaller ones leave (weighted goal potentials, effector goals
ordered by priority, as in the Finnish thesis on articulated figures). ``weight=0`` switches a goal off.

A kind is one module of this package: its spec class (a frozen dataclass, below)
and its compiled residual, registered in :mod:`mjkin.goals.registry`.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING, Any, ClassVar, Literal, TypeVar

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .. import spatial
from ..errors import GoalError, InputError
from ..kinematics.qspace import all_finite
from ..runtime.checks import check_array, check_number, check_vector
from ..runtime.jit import njit

if TYPE_CHECKING:
    from ..kinematics.tree import Kind, Tree

Array = NDArray[np.float64]
T = TypeVar("T")
DATA = 12  # per-goal target numbers: [0:3] a point, [3:12] a rotation (row-major) or [3:6] a direction
# what a kind's error is measured in, and so which tolerance judges it (Result.error's two columns)
Units = Literal["metres", "radians", "metres and radians", "joint units"]
METRES: Units = "metres"
RADIANS: Units = "radians"
METRES_AND_RADIANS: Units = "metres and radians"
JOINT_UNITS: Units = "joint units"


def number(value: Any, what: str, minimum: float | None = None) -> float:
    """A goal field as :func:`mjkin.runtime.checks.check_number` takes it: a finite real number, not a bool or text."""
    return _as_goal_error(check_number, value, what, minimum)


def numbers(value: ArrayLike, what: str) -> Array:
    """A goal field as :func:`mjkin.runtime.checks.check_array` takes it: a float64 array of numbers, any shape."""
    return _as_goal_error(check_array, value, what)


def _as_goal_error(check: Callable[..., T], *args: Any) -> T:
    """``check(*args)``, its :class:`InputError` raised as the :class:`GoalError` of a goal's field."""
    try:
        return check(*args)
    except InputError as e:
        raise GoalError(str(e)) from None


def array(value: ArrayLike, shape: tuple[int, ...], what: str) -> Array:
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


MAX_DISTANCE = 1e10  # m: a target point farther from the world origin is refused (its squares overflow on the way)


def point(value: ArrayLike, what: str) -> Array:
    """A world point ``(3,)`` or ``(B, 3)`` (m) as :func:`array`, each coordinate within :data:`MAX_DISTANCE`.

    No figure reaches 1e10 m (25 times the Moon's distance), and a point at 1e308 m made the solver's
    arrays inf (numpy's LinAlgError); refused here, before any solve.
    """
    a = array(value, (3,), what)
    if a.size and float(np.abs(a).max()) > MAX_DISTANCE:
        raise GoalError(f"{what} must be within {MAX_DISTANCE:g} m of the world origin in each coordinate, got "
                        f"{float(a.flat[np.abs(a).argmax()]):.3g} m")
    return a


def broadcast(shapes: Sequence[tuple[int, ...]]) -> tuple[int, ...]:
    """``np.broadcast_shapes`` without its cost (a few µs) when every shape is the same (the usual case)."""
    if len(set(shapes)) <= 1:
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


def unit(value: ArrayLike, what: str) -> Array:
    """A direction ``(3,)`` or ``(B, 3)`` scaled to unit length; zero length is refused."""
    a = array(value, (3,), what)
    n = np.linalg.norm(a, axis=-1, keepdims=True)
    if np.any(n < 1e-12):
        raise GoalError(f"{what} must have non-zero length")
    return a / n


def rotation(value: ArrayLike, what: str) -> Array:
    """A rotation given as quaternion(s) ``(..., 4)`` or matrix(es) ``(..., 3, 3)`` → matrices."""
    try:
        a = np.asarray(value, dtype=np.float64) if not isinstance(value, np.ndarray) else value
    except (TypeError, ValueError):
        raise GoalError(f"{what} must be numbers: a quaternion (4,) or a rotation matrix (3, 3), or a batch of "
                        f"them") from None
    if a.shape[-1:] == (4,):
        q = array(a, (4,), what)
        n = np.linalg.norm(q, axis=-1, keepdims=True)
        if np.any(n < 1e-12):
            raise GoalError(f"{what} is a zero quaternion")
        return spatial.quat_to_mat(q / n)
    return rotation_matrix(array(a, (3, 3), what), what)


def rotation_matrix(R: Array, what: str) -> Array:
    """Finite float64 matrices ``R (..., 3, 3)`` checked to be rotations (orthonormalised when within 1e-6)."""
    drift, det = _rotation_defect(R.reshape(-1, 3, 3))  # a view where it can (a pose's corner: strided)
    if drift > 1e-6 or det < 0:
        raise GoalError(f"{what} is not a rotation matrix (orthonormal, det +1)")
    return R if drift < 1e-12 else spatial.orthonormalize(R)


@dataclass(frozen=True)
class Goal:
    """Base of all goals: a weight (0 = ignored) and a priority (0 = highest).

    A kind sets ``rows`` (residual rows; -1 = one per dof), ``units`` (what its
    error is measured in), ``hard`` (a constraint, not a cost: its rows are the
    values ``s`` that must stay ``>= 0``, and its error the violation) and,
    through :func:`mjkin.goals.registry.register`, its ``code`` and compiled ``residual``.
    """

    weight: float = field(default=1.0, kw_only=True)
    priority: int = field(default=0, kw_only=True)
    code: ClassVar[int] = -1
    rows: ClassVar[int]
    units: ClassVar[Units]
    counted: ClassVar[bool] = True  # counts for success (a rest pose does not)
    hard: ClassVar[bool] = False  # a constraint: its rows are values s (unweighted, want s >= 0) and ds/dv
    joint_target: ClassVar[bool] = False  # encodes a configuration (a rest pose) as its target
    common: ClassVar[bool] = False  # cheap: a problem of common kinds only compiles no other (mjkin.ik.loop)
    _batched: ClassVar[tuple[str, ...]] = ()  # fields that may carry the leading batch axis
    _cores: ClassVar[tuple[int, ...]] = ()  # number of non-batch axes of each target of targets()

    def __post_init__(self) -> None:
        w = self.weight
        if not (type(w) is float and 0.0 <= w < math.inf):  # the usual weight passes without a call
            number(w, f"{type(self).__name__} weight", 0.0)
        if not isinstance(self.priority, (int, np.integer)) or self.priority < 0:
            raise GoalError(f"{type(self).__name__}: priority must be an integer >= 0, got {self.priority!r}")

    # ------------------------------------------------------------ structure
    def nrows(self, tree: Tree) -> int:
        """Number of residual rows."""
        return tree.nv if self.rows < 0 else self.rows

    def key(self) -> tuple:
        """What the compiled structure depends on besides the targets (hashable)."""
        return (type(self), float(self.weight), int(self.priority))

    def static(self, tree: Tree) -> tuple[int, Array, Array, int, Array | None]:
        """Target-independent encoding: ``(body, local rotation (3, 3), local point (3,), aux, row (nv,) or None)``.

        ``body`` is -1 for a goal on joints; ``aux`` is the kind's own integer; the
        row (stiffness of a rest pose, coefficients of a coupling) is kept per goal.
        """
        return -1, np.eye(3), np.zeros(3), 0, None

    def column(self, tree: Tree) -> int:
        """The error column that judges this goal: 0 against ``tol`` (metres), 1 against ``rot_tol`` (radians)."""
        return 1 if self.units == RADIANS else 0

    # -------------------------------------------------------------- targets
    def targets(self) -> list[Array]:
        """The validated targets (checked once per goal object)."""
        cached = self.__dict__.get("_checked")
        if cached is None:
            cached = self._validate()
            object.__setattr__(self, "_checked", cached)
        return cached

    def _validate(self) -> list[Array]:
        return []

    def batch(self) -> tuple[int, ...]:
        """Leading batch shape shared by the targets: ``()`` or ``(B,)`` (worked out once per goal object)."""
        cached = self.__dict__.get("_batch")
        if cached is None:
            shapes = [t.shape[: t.ndim - core] for t, core in zip(self.targets(), self._cores, strict=False)]
            try:
                cached = broadcast(shapes)
            except ValueError:
                raise GoalError(f"{type(self).__name__}: targets have different batch sizes {shapes}") from None
            object.__setattr__(self, "_batch", cached)
        return cached

    def encode(self, tree: Tree, data: Array, rest: Array) -> None:
        """Write the target numbers into ``data (B, DATA)`` (and a rest pose into ``rest (B, nq)``)."""

    def take(self, lo: int, hi: int) -> Goal:
        """This goal with only the targets ``lo:hi`` of its batch (an unbatched goal as it is).

        For splitting a batched solve into pieces: ``solve(tree, [g.take(lo, hi) for g in goals])``.
        """
        if self.batch() == ():
            return self
        changes: dict[str, Any] = {name: np.asarray(getattr(self, name))[lo:hi] for name in self._batch_fields()}
        return replace(self, **changes)

    def unbatch(self) -> list[Goal]:
        """Each target of a batched goal as an unbatched goal, ``[target 0, ..., target B-1]``; ``[self]`` unbatched.

        The targets are checked once, for the whole batch, not once per goal: for stepping
        through a batch one solve at a time (a clip's frames, each warm-started from the last).
        """
        batch = self.batch()
        if batch == ():
            return [self]
        B = batch[0]
        fields = self._batch_fields()
        columns = [list(np.broadcast_to(a, batch + a.shape[1:]))  # rows as views
                   for a in (np.asarray(getattr(self, name)) for name in fields)]
        columns += [list(np.broadcast_to(t, batch + t.shape[t.ndim - core:])) if t.ndim > core else [t] * B
                    for t, core in zip(self.targets(), self._cores, strict=False)]
        n, cls, state = len(fields), type(self), self.__dict__
        out = []
        for row in zip(*columns, strict=True):
            goal = object.__new__(cls)  # a copy without __init__: its fields were checked above
            d = goal.__dict__
            d.update(state)
            d.update(zip(fields, row[:n], strict=True))
            d["_checked"] = list(row[n:])
            d["_batch"] = ()
            out.append(goal)
        return out

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
    """A goal on a site or body ``frame``, or on a point ``offset`` fixed in that frame.

    ``kind`` picks ``"site"`` or ``"body"`` when a name is both (``None``: a site first).
    """

    frame: str
    kind: Kind | None = field(default=None, kw_only=True)
    offset: tuple[float, float, float] | None = field(default=None, kw_only=True)
    _cores: ClassVar[tuple[int, ...]] = (1, 1)

    @property
    def name(self) -> str:
        """The frame's name (deprecated: use ``frame``)."""
        warnings.warn("goal.name is now goal.frame", DeprecationWarning, stacklevel=2)
        return self.frame

    def __post_init__(self) -> None:
        super().__post_init__()
        name = type(self).__name__
        if self.kind is not None and not (isinstance(self.kind, str) and self.kind in ("site", "body")):
            raise GoalError(f"{name}: kind must be 'site', 'body' or None, got {self.kind!r}")
        if self.offset is not None:  # kept as three floats: hashable, and checked once
            offset = _as_goal_error(check_vector, self.offset, f"{name} offset")
            object.__setattr__(self, "offset", tuple(offset.tolist()))

    def key(self) -> tuple:  # noqa: D102
        return super().key() + (self.frame, self.kind, self.offset)

    def static(self, tree: Tree) -> tuple[int, Array, Array, int, Array | None]:  # noqa: D102
        body, T = tree.frame_body(self.frame, self.kind)
        point = T[:3, 3]
        if self.offset is not None:
            point = point + T[:3, :3] @ np.array(self.offset)
        return body, T[:3, :3], point, 0, None

    def encode(self, tree: Tree, data: Array, rest: Array) -> None:
        """Write a point and a direction (the layout of Aim, Line, Plane, HalfSpace) into ``data``."""
        point, direction = self.targets()
        data[:, 0:3] = point
        data[:, 3:6] = direction


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
