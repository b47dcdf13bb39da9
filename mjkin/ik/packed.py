"""A problem's arrays packed once into one compiled object, so each solve passes one argument.

numba unboxes every array argument of a compiled call on every call (~0.2 µs each):
a solve passing the tree's 28 arrays, the goals' 13 and a dozen more spent ~10 µs
on that alone, more than a whole easy solve takes. A :class:`Packed` (a numba
``StructRef``) holds them all and crosses into compiled code as one pointer (~1 µs
with the dispatcher). Its arrays are the caller's own buffers, shared, not copied:
what compiled code writes into ``q``, ``err``... the caller reads from its arrays.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numba
import numpy as np
from numba import types
from numba.experimental import structref
from numpy.typing import NDArray

from ..runtime.jit import njit

if TYPE_CHECKING:
    from ..goals.residuals import GoalArrays
    from ..kinematics.fk import Kinematics
    from .kernel import Settings

Array = NDArray[np.float64]
Index = NDArray[np.int64]
FIELDS = ("kin", "ga", "settings", "method", "max_iters", "starts", "restart_q", "active", "q", "iters", "status",
          "used", "binding", "err", "hist_q", "hist_err", "worst", "success")


@structref.register
class PackedType(types.StructRef):
    """The numba type of :class:`Packed` (its fields typed as given, integer literals widened)."""

    def preprocess_fields(self, fields: tuple) -> tuple:  # noqa: D102
        return tuple((name, types.unliteral(t)) for name, t in fields)


class Packed(structref.StructRefProxy):
    """Everything one compiled solve call reads and writes (fields: :data:`FIELDS`, see :func:`pack`)."""

    if TYPE_CHECKING:  # the fields, as compiled code reads them (from Python each is a compiled call)
        kin: Kinematics
        ga: GoalArrays
        settings: Settings
        method: int
        max_iters: int
        starts: Array
        restart_q: NDArray[np.bool_]
        active: NDArray[np.bool_]
        q: Array
        iters: Index
        status: Index
        used: Index
        binding: Index
        err: Array
        hist_q: Array
        hist_err: Array
        worst: Array
        success: NDArray[np.bool_]


structref.define_proxy(Packed, PackedType, list(FIELDS))


@njit
def _pack(kin: Kinematics, ga: GoalArrays, settings: Settings, method: int, max_iters: int, starts: Array,
          restart_q: NDArray[np.bool_], active: NDArray[np.bool_], q: Array, iters: Index, status: Index, used: Index,
          binding: Index, err: Array, hist_q: Array, hist_err: Array, worst: Array,
          success: NDArray[np.bool_]) -> Packed:
    return Packed(kin, ga, settings, method, max_iters, starts, restart_q, active, q, iters, status, used, binding, err,
                  hist_q, hist_err, worst, success)


def packed_kernels(solve_packed: Any, fields: tuple) -> list[tuple[Any, tuple]]:
    """The kernels a packed solve with these :data:`FIELDS` values calls from Python, and their argument types:
    :func:`_pack`, and ``solve_packed`` (the problem's :func:`mjkin.ik.loop.solve_packed`).
    """  # noqa: D205
    typed = tuple(numba.typeof(v) for v in fields)
    packed = PackedType(list(zip(FIELDS, typed, strict=True)))
    return [(_pack, typed), (solve_packed, (packed, numba.int64, numba.int64))]


def pack(kin: Kinematics, ga: GoalArrays, st: Settings, method: int, max_iters: int, starts: Array,
         restart_q: NDArray[np.bool_], active: NDArray[np.bool_], q: Array, iters: Index, status: Index, used: Index,
         binding: Index, err: Array, hist_q: Array, hist_err: Array, worst: Array,
         success: NDArray[np.bool_]) -> Packed:
    """Pack a solve's arrays (shared, not copied) for :func:`mjkin.ik.loop.solve_packed`.

    ``B`` targets of ``G`` goals: ``q (B, nq)`` the starts, overwritten with the answers;
    outputs ``iters``, ``status``, ``used``, ``binding (B,)``, ``err (B, G, 2)``, ``worst (B, 2)``,
    ``success (B,)``; history ``hist_q (B, H, nq)``, ``hist_err (B, H, 2)`` (``H = 0``: none).
    The rest as :func:`mjkin.ik.loop.solve_one` takes them. Scalars are fixed to one type,
    so every problem shares one compiled specialisation.
    """
    return _pack(kin, ga, st, int(method), int(max_iters), starts, restart_q, active, q, iters, status, used, binding,
                 err, hist_q, hist_err, worst, success)
