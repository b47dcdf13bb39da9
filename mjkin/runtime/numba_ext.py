"""Intrinsics the hot kernels share: views without reference counts, stack scratch, the monotonic clock.

In numba every array bound to a variable, sliced, or passed across a call costs two
atomic reference-count updates (~25 ns together on a 2-core VM), more than a 3x3
product. So the hot kernels index arrays element by element instead of taking views,
the kernels other kernels call in their loops are inlined by LLVM
(:data:`mjkin.runtime.jit.njit_inline`), and the IK loop passes :func:`borrowed`
views, which carry no count. Written with numba's documented extension API only
(``numba.extending.intrinsic``, the code generator's context and llvmlite); each has
a Python stand-in for interpreted runs (:func:`mjkin.runtime.tier.python_version`).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

import numba
import numpy as np
from llvmlite import ir
from numba import types
from numba.extending import intrinsic

from . import tier
from .jit import njit_inline, njit_ir_inline

CLOCK_MONOTONIC = 1  # Linux
_I32, _I64 = ir.IntType(32), ir.IntType(64)


@intrinsic
def _monotonic_ns(typingctx):  # type: ignore[no-untyped-def]
    """Nanoseconds on the monotonic clock: libc's ``clock_gettime`` (a vDSO call, ~20 ns), named by symbol.

    Named so, kernels using it stay cacheable.
    """

    def codegen(context, builder, signature, args):  # type: ignore[no-untyped-def]
        timespec = ir.LiteralStructType([_I64, _I64])
        fn = builder.module.globals.get("clock_gettime") or ir.Function(
            builder.module, ir.FunctionType(_I32, [_I32, timespec.as_pointer()]), "clock_gettime")
        with builder.goto_entry_block():
            ts = builder.alloca(timespec)
        builder.call(fn, [ir.Constant(_I32, CLOCK_MONOTONIC), ts])
        sec, nsec = (builder.load(builder.gep(ts, [ir.Constant(_I32, 0), ir.Constant(_I32, i)], inbounds=True))
                     for i in (0, 1))
        return builder.add(builder.mul(sec, ir.Constant(_I64, 1_000_000_000)), nsec)

    return types.int64(), codegen


def _without_refcount(context, builder, ty, value):  # type: ignore[no-untyped-def]
    """``value`` of type ``ty`` with every array's meminfo set to null (tuples member by member)."""
    if isinstance(ty, types.Array):
        arr = context.make_helper(builder, ty, value=value)
        arr.meminfo = ir.Constant(arr.meminfo.type, None)
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
        meminfo = context.make_helper(builder, ref, value=args[0]).meminfo  # a structref is its payload's meminfo
        payload = ref.get_data_type()
        pointer = builder.bitcast(context.nrt.meminfo_data(builder, meminfo),
                                  context.get_value_type(payload).as_pointer())
        data = context.make_helper(builder, payload, ref=pointer)
        return context.make_tuple(builder, out, [_without_refcount(context, builder, t, getattr(data, name))
                                                 for name, t in fields])

    return out(ref), codegen


@intrinsic
def _keep_alive(typingctx, x):  # type: ignore[no-untyped-def]
    def codegen(context, builder, signature, args):  # type: ignore[no-untyped-def]
        return context.get_dummy_value()

    return types.none(x), codegen


@intrinsic
def _element_pointer(typingctx, arr, i):  # type: ignore[no-untyped-def]
    """Pointer to ``arr[i]`` of a 1-D C-contiguous array (no bounds check)."""
    if not (isinstance(arr, types.Array) and arr.ndim == 1 and arr.layout == "C" and isinstance(i, types.Integer)):
        return None

    def codegen(context, builder, signature, args):  # type: ignore[no-untyped-def]
        return builder.gep(context.make_array(signature.args[0])(context, builder, args[0]).data, [args[1]])

    return types.CPointer(arr.dtype)(arr, i), codegen


@intrinsic
def _int64_pointer(typingctx, arr, i):  # type: ignore[no-untyped-def]
    """Pointer to ``arr[i]`` of a 1-D C-contiguous array of 8-byte items, read as int64 (the bits, not the value)."""
    if not (isinstance(arr, types.Array) and arr.ndim == 1 and arr.layout == "C" and arr.dtype.bitwidth == 64
            and isinstance(i, types.Integer)):
        return None

    def codegen(context, builder, signature, args):  # type: ignore[no-untyped-def]
        data = context.make_array(signature.args[0])(context, builder, args[0]).data
        return builder.bitcast(builder.gep(data, [args[1]]), _I64.as_pointer())

    return types.CPointer(types.int64)(arr, i), codegen


@intrinsic
def _stack_floats(typingctx, n):  # type: ignore[no-untyped-def]
    """Pointer to ``n`` float64 on the stack of the compiled function this is inlined into."""
    if not isinstance(n, types.Integer):
        return None

    def codegen(context, builder, signature, args):  # type: ignore[no-untyped-def]
        return builder.alloca(context.get_value_type(types.float64), size=args[0])

    return types.CPointer(types.float64)(n), codegen


monotonic_ns: Callable[[], int] = _monotonic_ns  # type: ignore[assignment]
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
    one of its loops, nor in an :data:`~mjkin.runtime.jit.njit_inline` kernel: each pass would
    take more stack). The space is given back when the function returns, also where LLVM
    inlines it into a caller's loop (it brackets the call with a stack save and restore), so
    such a function may be called any number of times; nothing may keep the array past that.
    """
    return numba.carray(_stack_floats(n), (n,))  # type: ignore[call-arg]  # typed by numba


def _unshared_python(buf: np.ndarray, start: int, shape: tuple[int, ...]) -> np.ndarray:
    """:func:`unshared` interpreted: a view."""
    return buf[start:start + int(np.prod(shape))].reshape(shape)


for _kernel, _python in ((_borrowed, lambda x: x), (_keep_alive, lambda x: None), (_monotonic_ns, time.monotonic_ns),
                         (_borrowed_fields, tuple),  # interpreted, the IK loop is given its packed fields as a tuple
                         (unshared, _unshared_python), (on_stack, np.empty),
                         (unshared_int64, lambda buf, start, shape: _unshared_python(buf.view(np.int64), start,
                                                                                     shape))):
    tier.python_version(_kernel, _python)
