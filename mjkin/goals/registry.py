"""The table of goal kinds: each kind's class and compiled residual, from which the IK evaluator is built.

A new kind is one module (a :class:`~mjkin.goals.base.Goal` subclass and a
``residual`` compiled with :data:`mjkin.runtime.jit.njit_ir_inline`, see
:mod:`mjkin.goals.residuals` for its signature) and one call of :func:`register`.
The IK loop calls each residual at one place, so numba inlines it there: it is
typed once, as a function of its own would be, and not compiled on its own too.
"""

from __future__ import annotations

import sys
from collections.abc import Callable

from ..errors import GoalError
from .base import Goal

KINDS: list[type[Goal]] = []
RESIDUALS: list[Callable] = []


def register(cls: type[Goal], residual: Callable | None = None) -> type[Goal]:
    """Add a goal kind; ``residual`` defaults to the ``residual`` of the class's module. Returns ``cls``.

    Registering a kind again keeps its first code. The solvers compile an evaluator
    for the kinds registered when they first run (and again after a new one).
    """
    if cls in KINDS:
        return cls
    if residual is None:
        residual = getattr(sys.modules[cls.__module__], "residual", None)
    if residual is None or not hasattr(residual, "py_func"):
        raise GoalError(f"goal kind {cls.__name__}: its residual must be a numba-compiled function "
                        "(mjkin.runtime.jit.njit_inline), given as residual= or as 'residual' in its module")
    cls.code = len(KINDS)
    KINDS.append(cls)
    RESIDUALS.append(residual)
    return cls


def residual_of(code: int) -> Callable:
    """The compiled residual of the kind with this code."""
    return RESIDUALS[code]
