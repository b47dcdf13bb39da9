"""numba set-up and the small 3-D helpers the compiled kernels share.

The kernels (FK, Jacobians, IK iterations) are plain loops over a leading
batch axis compiled by numba: numpy's per-call overhead (~1 µs a call, dozens
of calls per FK) would otherwise dominate single configurations, and its
stacked 3x3 products are slow for large batches. Nothing compiles at import: a
kernel compiles when first called, and is cached on disk (:mod:`mjkin.runtime.cache`),
so only the first run that uses it pays for it.

One rule for the hot kernels: in numba every array bound to a variable, sliced,
or passed across a call costs two atomic reference-count updates (~25 ns
together on a 2-core VM), more than a 3x3 product. So they index arrays element
by element instead of taking views, and the kernels other kernels call in their
loops are inlined by LLVM (:data:`njit_inline`). Inlining does not save the
updates for an inlined kernel's array arguments; the IK loop passes
:func:`borrowed` views, which carry no count.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

import numba
import numpy as np
from llvmlite import ir
from numba import types
from numba.core import cgutils, sigutils
from numba.core.ccallback import CFunc
from numba.experimental import structref
from numba.extending import intrinsic

from . import tier
from .cache import LazyCache, loaded

CLOCK_MONOTONIC = 1  # Linux


def _jit(**options: Any) -> Callable[[Callable], Any]:
    """``numba.njit(**options)`` (nogil, no fastmath) cached on disk by :class:`mjkin.runtime.cache.KernelCache`.

    The dispatcher is a :class:`mjkin.runtime.tier.Kernel`: its first small calls may run interpreted, and
    its cache is made when it is first used.
    """

    def decorate(fn: Callable) -> Any:
        loaded(fn.__code__.co_filename)  # its source as imported: what it compiles, whatever the disk holds later
        if tier._NO_JIT:  # numba's switch for debuggers and coverage: every kernel runs as Python
            return tier.Plain(fn)
        dispatcher = numba.njit(**{"nogil": True, "fastmath": False, **options})(fn)
        dispatcher.__class__ = tier.Kernel
        del dispatcher._cache  # numba's NullCache: a KernelCache is made on first use (LazyCache)
        return dispatcher

    return decorate


njit = _jit()
# Inlined by LLVM wherever another kernel calls it (``forceinline``: LLVM's alwaysinline), compiled once on its own
# and cached: numba's own inlining (``inline="always"``) typed the callee again at every call site, the better part
# of the IK loop's compile time. Called from Python it behaves like ``njit``.
njit_inline = _jit(forceinline=True)
# Inlined into its caller by numba, in numba's IR: for what must live in the caller's own frame (:func:`on_stack`)
# and for kernels called at one place only (the IK loop's layers, the goal kinds' residuals): typed once there, as
# a function of its own would be, and not also compiled and optimised on its own (about a second each).
njit_ir_inline = _jit(inline="always")
# Short entries called from Python once per configuration keep the GIL: releasing and taking it back costs ~0.1 µs
# a call, a third of a 7-DoF pose.
njit_gil = _jit(nogil=False)


class _CFunc(LazyCache, CFunc):
    """numba's cfunc, cached like a kernel."""


def cfunc(signature: Any) -> Callable[[Callable], CFunc]:
    """``numba.cfunc(signature)`` cached like :data:`njit`; not compiled until its ``compile()`` is called."""

    def decorate(fn: Callable) -> CFunc:
        loaded(fn.__code__.co_filename)
        c = _CFunc(fn, sigutils.normalize_signature(signature), locals={}, options={})
        del c._cache  # numba's NullCache: a KernelCache is made on first compile (LazyCache)
        return c

    return decorate


def entry(dispatcher: Any, *types_: Any) -> Callable:
    """The compiled code of ``dispatcher`` for arguments of these numba types, callable without numba's dispatch.

    A dispatcher types every argument of every call (~0.2 µs for three arrays, ~0.6 µs
    for a packed problem), a quarter of a one-q pose. The entry skips that and trusts
    its arguments: the caller must pass exactly these types (dtype, ndim, C-contiguity),
    or it reads memory wrongly. Compiles the version if needed; falls back to the
    dispatcher itself where numba does not expose the entry.
    """
    sig = tuple(types_)
    if sig not in dispatcher.overloads:
        dispatcher.compile(sig)
    return getattr(dispatcher.overloads.get(sig), "entry_point", None) or dispatcher


@njit
def quat_to_mat(w: float, x: float, y: float, z: float, out: np.ndarray) -> None:
    """Write the rotation matrix of the quaternion ``(w, x, y, z)``, normalised, into ``out (3, 3)``."""
    n2 = w * w + x * x + y * y + z * z
    if not n2 < 1e300:  # huge components (1e308): their squares overflow, so scale by the largest first
        m = max(abs(w), abs(x), abs(y), abs(z))
        w, x, y, z = w / m, x / m, y / m, z / m
        n2 = w * w + x * x + y * y + z * z
    n = np.sqrt(n2)
    w, x, y, z = w / n, x / n, y / n, z / n
    out[0, 0] = 1 - 2 * (y * y + z * z)
    out[0, 1] = 2 * (x * y - w * z)
    out[0, 2] = 2 * (x * z + w * y)
    out[1, 0] = 2 * (x * y + w * z)
    out[1, 1] = 1 - 2 * (x * x + z * z)
    out[1, 2] = 2 * (y * z - w * x)
    out[2, 0] = 2 * (x * z - w * y)
    out[2, 1] = 2 * (y * z + w * x)
    out[2, 2] = 1 - 2 * (x * x + y * y)


@njit
def axis_angle(x: float, y: float, z: float, angle: float, out: np.ndarray) -> None:
    """Write Rodrigues' rotation by ``angle`` about the unit axis ``(x, y, z)`` into ``out (3, 3)``."""
    s, c = np.sin(angle), np.cos(angle)
    t = 1.0 - c
    out[0, 0] = c + t * x * x
    out[0, 1] = t * x * y - s * z
    out[0, 2] = t * x * z + s * y
    out[1, 0] = t * x * y + s * z
    out[1, 1] = c + t * y * y
    out[1, 2] = t * y * z - s * x
    out[2, 0] = t * x * z - s * y
    out[2, 1] = t * y * z + s * x
    out[2, 2] = c + t * z * z


@njit
def matvec3(A: np.ndarray, v: np.ndarray, out: np.ndarray) -> None:
    """``out = A @ v`` for a 3x3 matrix and a 3-vector (``out`` must not alias ``v``)."""
    for i in range(3):
        out[i] = A[i, 0] * v[0] + A[i, 1] * v[1] + A[i, 2] * v[2]


@intrinsic
def _monotonic_ns(typingctx):  # type: ignore[no-untyped-def]
    """Nanoseconds on the monotonic clock (``time.monotonic_ns`` inside compiled code).

    A direct call of libc's ``clock_gettime(CLOCK_MONOTONIC)`` (a vDSO call, ~20 ns),
    named by symbol so that kernels using it stay cacheable.
    """

    def codegen(context, builder, signature, args):  # type: ignore[no-untyped-def]
        i64 = ir.IntType(64)
        timespec = ir.LiteralStructType([i64, i64])
        fn = cgutils.get_or_insert_function(builder.module, ir.FunctionType(ir.IntType(32), [
            ir.IntType(32), timespec.as_pointer()]), "clock_gettime")
        ts = cgutils.alloca_once(builder, timespec)
        builder.call(fn, [ir.Constant(ir.IntType(32), CLOCK_MONOTONIC), ts])
        sec = builder.load(cgutils.gep_inbounds(builder, ts, 0, 0))
        nsec = builder.load(cgutils.gep_inbounds(builder, ts, 0, 1))
        return builder.add(builder.mul(sec, ir.Constant(i64, 1_000_000_000)), nsec)

    return types.int64(), codegen


monotonic_ns: Callable[[], int] = _monotonic_ns  # type: ignore[assignment]


def _without_refcount(context, builder, ty, value):  # type: ignore[no-untyped-def]
    """``value`` of type ``ty`` with every array's meminfo set to null (tuples member by member)."""
    if isinstance(ty, types.Array):
        arr = cgutils.create_struct_proxy(ty)(context, builder, value=value)
        arr.meminfo = cgutils.get_null_value(arr.meminfo.type)
        return arr._getvalue()
    if isinstance(ty, types.BaseTuple):
        for i, member in enumerate(ty.types):
            value = builder.insert_value(value, _without_refcount(context, builder, member,
                                                                  builder.extract_value(value, i)), i)
    return value


@intrinsic
def _borrowed(typingctx, x):  # type: ignore[no-untyped-def]
    def codegen(context, builder, signature, args):  # type: ignore[no-untyped-def]
        return _without_refcount(context, builder, signature.args[0], args[0])

    return x(x), codegen


@intrinsic
def _borrowed_fields(typingctx, ref):  # type: ignore[no-untyped-def]
    if not isinstance(ref, types.StructRef):
        return None
    fields = list(ref.field_dict.items())
    out = types.Tuple([t for _, t in fields])

    def codegen(context, builder, signature, args):  # type: ignore[no-untyped-def]
        data = structref._Utils(context, builder, ref).get_data_struct(args[0])  # numba's own field access
        return context.make_tuple(builder, out, [_without_refcount(context, builder, t, getattr(data, name))
                                                 for name, t in fields])

    return out(ref), codegen


@intrinsic
def _keep_alive(typingctx, x):  # type: ignore[no-untyped-def]
    def codegen(context, builder, signature, args):  # type: ignore[no-untyped-def]
        return context.get_dummy_value()

    return types.none(x), codegen


# ``borrowed(x)``: the arrays of ``x`` (an array, or a tuple of arrays and numbers, nested) as views that
# carry no reference count. Every array bound to a variable or passed into an inlined kernel costs an atomic
# increment and decrement of its count (~5 ns each); the IK loop passes dozens of arrays into its kernels each
# iteration (FK alone: 22), which took half of an iteration's time. The views skip those updates, so they must
# not outlive their arrays: borrow what the caller owns (the packed problem's arrays), or keep a local owner
# alive past the last use of its views with ``keep_alive(owner)``.
borrowed: Callable[[Any], Any] = _borrowed  # type: ignore[assignment]
# ``borrowed_fields(ref)``: every field of a StructRef, in its order, as a tuple of such views (reading a field
# the usual way counts a reference to each array in it: ~80 for a packed IK problem, a third of an easy solve)
borrowed_fields: Callable[[Any], tuple] = _borrowed_fields  # type: ignore[assignment]
keep_alive: Callable[[Any], None] = _keep_alive  # type: ignore[assignment]


# ``unshared``: the same kind of view (no reference count), cut straight out of one flat buffer: the
# one-configuration FK entries unpack a chain's arrays this way without numba's reshape helper.
@intrinsic
def _element_pointer(typingctx, arr, i):  # type: ignore[no-untyped-def]
    """Pointer to ``arr[i]`` of a 1-D C-contiguous array (no bounds check)."""
    if not (isinstance(arr, types.Array) and arr.ndim == 1 and arr.layout == "C" and isinstance(i, types.Integer)):
        return None

    def codegen(context, builder, signature, args):  # type: ignore[no-untyped-def]
        data = context.make_array(signature.args[0])(context, builder, args[0]).data
        return builder.gep(data, [args[1]])

    return types.CPointer(arr.dtype)(arr, i), codegen


@intrinsic
def _int64_pointer(typingctx, arr, i):  # type: ignore[no-untyped-def]
    """Pointer to ``arr[i]`` of a 1-D C-contiguous array of 8-byte items, read as int64 (the bits, not the value)."""
    if not (isinstance(arr, types.Array) and arr.ndim == 1 and arr.layout == "C" and arr.dtype.bitwidth == 64
            and isinstance(i, types.Integer)):
        return None

    def codegen(context, builder, signature, args):  # type: ignore[no-untyped-def]
        data = context.make_array(signature.args[0])(context, builder, args[0]).data
        return builder.bitcast(builder.gep(data, [args[1]]), ir.IntType(64).as_pointer())

    return types.CPointer(types.int64)(arr, i), codegen


@intrinsic
def _stack_floats(typingctx, n):  # type: ignore[no-untyped-def]
    """Pointer to ``n`` float64 on the stack of the compiled function this is inlined into."""
    if not isinstance(n, types.Integer):
        return None

    def codegen(context, builder, signature, args):  # type: ignore[no-untyped-def]
        return builder.alloca(context.get_value_type(types.float64), size=args[0])

    return types.CPointer(types.float64)(n), codegen


tier.python_version(_borrowed, lambda x: x)
tier.python_version(_keep_alive, lambda x: None)
tier.python_version(_monotonic_ns, time.monotonic_ns)
tier.python_version(_borrowed_fields, tuple)  # interpreted, the IK loop is given its packed fields as a tuple


@njit_inline
def unshared(buf: np.ndarray, start: int, shape: tuple[int, ...]) -> np.ndarray:
    """``buf[start:start + prod(shape)].reshape(shape)`` of a 1-D C-contiguous ``buf``, with no reference count.

    A view of this kind carries no owner: numba neither counts its references
    (two atomic updates per view, ~25 ns) nor calls its reshape helper (~30 ns), so
    a kernel can unpack a dozen arrays from one buffer for free. It must not
    outlive ``buf``, which the caller keeps alive (an argument of the compiled call).
    """
    return numba.carray(_element_pointer(buf, start), shape)  # type: ignore[call-arg]  # typed by numba


@njit_inline
def unshared_int64(buf: np.ndarray, start: int, shape: tuple[int, ...]) -> np.ndarray:
    """:func:`unshared` of int64 stored bit for bit in a float64 ``buf`` (``ints.view(np.float64)``)."""
    return numba.carray(_int64_pointer(buf, start), shape)  # type: ignore[call-arg]  # typed by numba


@njit_ir_inline
def on_stack(n: int) -> np.ndarray:
    """``np.empty(n)`` on the stack of the compiled function, not the heap: no allocation, no reference count.

    For scratch of a few KB, taken once at the top of an ``njit`` function (never inside
    one of its loops, nor in an :data:`njit_inline` kernel: each pass would take more
    stack). The space is given back when the function returns, also where LLVM inlines
    it into a caller's loop (it brackets the call with a stack save and restore), so such
    a function may be called any number of times; nothing may keep the array past that.
    """
    return numba.carray(_stack_floats(n), (n,))  # type: ignore[call-arg]  # typed by numba


def unshared_python(buf: np.ndarray, start: int, shape: tuple[int, ...]) -> np.ndarray:
    """:func:`unshared` interpreted (:mod:`mjkin.runtime.tier`): a view."""
    return buf[start:start + int(np.prod(shape))].reshape(shape)


tier.python_version(unshared, unshared_python)
tier.python_version(unshared_int64, lambda buf, start, shape: unshared_python(buf.view(np.int64), start, shape))
tier.python_version(on_stack, np.empty)
