"""The decorators mjkin's kernels are compiled with: numba's ``njit`` (nogil, no fastmath), cached on disk.

The kernels (FK, Jacobians, IK iterations) are plain loops over a leading batch axis
compiled by numba: numpy's per-call overhead (~1 µs a call, dozens of calls per FK)
would otherwise dominate single configurations, and its stacked 3x3 products are slow
for large batches. Nothing compiles at import: a kernel compiles when first called (or
runs interpreted meanwhile: :mod:`mjkin.runtime.tier`), and is cached on disk
(:mod:`mjkin.runtime.cache`), so only the first run that uses it pays for it. The
intrinsics the hot kernels share are in :mod:`mjkin.runtime.numba_ext`.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from . import numba_private, tier
from .cache import loaded


def _jit(**options: Any) -> Callable[[Callable], Any]:
    """``numba.njit(**options)`` (nogil, no fastmath) as a :class:`~mjkin.runtime.numba_private.Kernel`.

    Its first small calls may run interpreted (:func:`mjkin.runtime.tier.on_miss`); its cache is made when first used.
    """

    def decorate(fn: Callable) -> Any:
        loaded(fn.__code__.co_filename)  # its package's sources as imported: what it compiles (cache.stamp)
        return numba_private.kernel(fn, tier.on_miss, **{"nogil": True, "fastmath": False, **options})

    return decorate


njit = _jit()
# Inlined by LLVM wherever another kernel calls it (``forceinline``: LLVM's alwaysinline), compiled once on its own
# and cached: numba's own inlining (``inline="always"``) typed the callee again at every call site, the better part
# of the IK loop's compile time. Called from Python it behaves like ``njit``.
njit_inline = _jit(forceinline=True)
# Inlined into its caller by numba, in numba's IR: for what must live in the caller's own frame (``numba_ext.on_stack``)
# and for kernels called at one place only (the IK loop's layers, the goal kinds' residuals): typed once there, as
# a function of its own would be, and not also compiled and optimised on its own (about a second each).
njit_ir_inline = _jit(inline="always")
# Short entries called from Python once per configuration keep the GIL: releasing and taking it back costs ~0.1 µs
# a call, a third of a 7-DoF pose.
njit_gil = _jit(nogil=False)


def cfunc(signature: Any) -> Callable[[Callable], Any]:
    """``numba.cfunc(signature)`` cached like :data:`njit`; not compiled until its ``compile()`` is called."""

    def decorate(fn: Callable) -> Any:
        loaded(fn.__code__.co_filename)
        return numba_private.cfunc(fn, signature)

    return decorate
