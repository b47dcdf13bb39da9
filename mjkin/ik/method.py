"""The base of the IK methods: a method is an object holding its own options, run by a :class:`~mjkin.Problem`.

``method="lm"`` (a name) and ``method=mjkin.ik.LM(restarts=8)`` (an object) select
the same thing; a name takes the method's options as keywords (``max_iters=...``).
"""

from __future__ import annotations

from dataclasses import dataclass, fields
from typing import TYPE_CHECKING, Any, ClassVar, Protocol

import numpy as np
from numpy.typing import NDArray

from ..errors import InputError
from ..runtime.checks import check_count

if TYPE_CHECKING:
    from ..goals import Program
    from ..goals.program import Structure
    from ..kinematics.tree import Tree
    from .result import Result

Array = NDArray[np.float64]
MAX_RESTARTS = 10_000  # restarts a method takes at most: their starts are drawn ahead, (restarts, nq) floats
MAX_ITERS = 10**9  # iterations (and patience) a run takes at most: hours of work, and within the loops' int64
# iterations a target may take over all its runs (max_iters x (restarts + 1)) when no timeout bounds it: about
# 10 s on a 7-DoF arm, 1 000 times the defaults' budget; past it a timeout must say how long to search
MAX_UNTIMED = 10**7


class ProblemView(Protocol):
    """What a method reads of the :class:`mjkin.Problem` it runs for (set once, at the problem's construction)."""

    tree: Tree
    structure: Structure  # the goals' arrays, sorted by priority
    method_name: str
    tol: float  # metres
    rot_tol: float  # radians
    time_limit: float | None  # seconds per target
    history: bool
    avoid_collisions: bool
    base: str | None
    joints: list[str] | None
    root: str | None
    active: NDArray[np.bool_]  # (nv,) dofs that may move
    restart_q: NDArray[np.bool_]  # (nq,) entries a restart randomises
    starts: Array  # (K, nq) restart configurations
    prepared: Any  # what the method's prepare made for this problem


class _Options(type):
    """The method classes' type: an unknown option is the one-line error that lists the options.

    ``LM(foo=1)`` says what ``method="lm", foo=1`` says, not the bare TypeError of a dataclass's ``__init__``.
    """

    def __call__(cls, *args: Any, **options: Any) -> Any:
        known = [f.name for f in fields(cls)]  # type: ignore[arg-type]  # every Method is a dataclass
        unknown = sorted(set(options) - set(known))
        if unknown or len(args) > len(known):
            wrong = (f"no option {', '.join(map(repr, unknown))}" if unknown
                     else f"at most {len(known)} options, {len(args)} given by position")
            raise InputError(f"method {getattr(cls, 'name', cls.__name__)!r} takes {wrong}; its options: "
                             f"{', '.join(sorted(known)) or 'none'}")
        return super().__call__(*args, **options)


@dataclass(frozen=True)
class Method(metaclass=_Options):
    """An IK method and its options; subclasses are frozen dataclasses with a ``name``.

    ``restarts``: random restarts (within the limits, only of the joints that move a
    goal frame) when a run stalls, at most :data:`MAX_RESTARTS`; ``None`` lets the method choose.
    """

    name: ClassVar[str]
    restarts: int | None = 0

    def __post_init__(self) -> None:
        if self.restarts is not None:
            check_count(self.restarts, "restarts", 0, whole_floats=True, most=MAX_RESTARTS)

    @classmethod
    def iterative(cls) -> bool:
        """Whether it steps toward the goals and can stop after any step (it takes ``max_iters``).

        Such a method follows a moving target from the current pose, as the playground's panel
        does, and its step mode runs it one iteration a frame; a closed form (``analytic2``) does not.
        """
        return any(f.name == "max_iters" for f in fields(cls))

    def restart_count(self, timed: bool) -> int:
        """How many restart starts a problem prepares (``timed``: a time limit is set)."""
        return 0 if self.restarts is None else int(self.restarts)

    def untimed_iterations(self) -> int:
        """Iterations a target may take over all its runs without a time limit (``max_iters x (restarts + 1)``)."""
        runs = self.restart_count(False) + 1
        return runs * int(getattr(self, "max_iters", 1))

    def default_timeout(self) -> float | None:
        """The time limit per target when none is given (seconds; None: none)."""
        return None

    def prepare(self, problem: ProblemView) -> Any:
        """Check the problem suits this method; return what :meth:`run` keeps for it (once, at its construction).

        The problem holds it as ``prepared`` (None here: nothing). Raises GoalError or
        InputError for goals or options this method cannot take.
        """
        return None

    def run(self, problem: ProblemView, prog: Program, q: Array) -> Result:
        """Solve every target of ``prog`` from the starts ``q (B, nq)`` (overwritten) and package the result."""
        raise NotImplementedError(f"{type(self).__name__} must define run")

    @classmethod
    def with_options(cls, options: dict[str, Any]) -> Method:
        """The method made from keyword options, one line naming any it does not take."""
        return cls(**options)
