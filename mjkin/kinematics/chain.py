"""One configuration's FK over only the bodies a frame hangs from: the short path of ``Tree.pose`` and ``Tree.fk``.

A frame's pose depends only on its body's ancestors. :func:`chain_of` copies the
rows of a tree's FK arrays (:class:`mjkin.kinematics.fk.Plan`) for those bodies
into one flat buffer, a *chain*, the bodies renumbered ``0..n-1`` (0 = the world),
and the compiled :func:`chain_pose` unpacks it and runs the one FK formula,
:func:`mjkin.kinematics.fk.fk_kernel`, on them; the frame's pose then goes through
:func:`mjkin.kinematics.fk.frame_world` as on the batched path, so the two agree
to the last bit.

A chain is one float64 array ``(L,)``. Its integers come first, stored bit for bit
(``ints.view(np.float64)``): the header (:data:`HEADER`), the first q address of each
of the tree's quaternions ``(nquat,)`` (to refuse a zero one), per body ``parent``
(its index in the chain), ``jnt_start``, ``jnt_count``, ``fixed_plain`` ``(n,)``
each, per joint ``jnt_inner`` (all -1: no inner frames are kept), ``hinge_coord``,
``anchor_zero``, ``jnt_type``, ``jnt_qadr`` ``(nj,)`` each. Then the floats: a frame
fixed in the last body ``local (4, 4)``, the tree's ``qpos0 (nq,)``, ``fixed_rot
(n, 3, 3)``, ``fixed_pos (n, 3)``, ``jnt_axis (nj, 3)``, ``jnt_pos (nj, 3)``.

Why one buffer: numba's dispatch costs ~0.05 µs per plain array argument, ~0.5 µs
for a structref, and the 14 arrays of the FK would cost more than a 7-DoF arm's FK
itself. Nothing writes a chain, but it is not flagged read-only: numba's dispatch
types a read-only array in Python (~1 µs). The compiled entries have fixed
signatures, compiled (or loaded from the disk cache) by :func:`ready` on the first
one-q pose, not at import: after that a ``q`` of another dtype or layout raises
:class:`TypeError` instead of compiling another version.

``Tree.pose`` and ``Tree.fk`` skip numba's Python wrapper too: :data:`pose_of` and
:data:`poses_of` come from the small C module :mod:`mjkin.kinematics._posecall`
(``_posecall.c``), which checks ``q``, makes the output and calls the kernels as
numba cfuncs through C function pointers, bound by :func:`ready` (before that it
returns None). numba's wrapper's unboxing of three arrays costs ~0.2 µs, as much
as a 7-DoF pose. Without a C compiler at install they are
:func:`pose_numba` and :func:`poses_numba`, which call numba's compiled entry from
Python (:func:`mjkin.runtime.jit.entry`). Both return None for any ``q`` but a native float64
ndarray, 1-D and C-contiguous, or one the kernel refuses: the caller's checked path
then answers, or says what is wrong.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
from numba import carray, types
from numpy.typing import NDArray

from ..runtime import tier
from ..runtime.jit import cfunc, njit_gil, njit_inline
from ..runtime.numba_ext import on_stack, unshared, unshared_int64
from ..runtime.numba_private import entry
from .fk import Bodies, fk_kernel_in, frame_world, poses_kernel

Array = NDArray[np.float64]
Index = NDArray[np.int64]

HEADER = 4  # nq, n (bodies, the world included), nj (their joints), nquat (the tree's quaternions in q)
MAX_BODIES = 1024  # longest chain whose frames (96 bytes a body) the compiled entries keep on the stack


def ancestors(tree: Bodies, body: int) -> list[int]:
    """``body`` and the bodies its pose is composed from, world (0) first, in MuJoCo's order."""
    out = [body]
    while out[-1]:
        out.append(int(tree.plan.parent[out[-1]]))
    return out[::-1]


def chain_of(tree: Bodies, bodies: list[int], local: Array) -> Array:
    """The chain (see above) of ``bodies`` (ascending, 0 first, each one's composition parent among them).

    ``local (4, 4)``: a frame fixed in the last body (:func:`chain_pose` returns its pose).
    """
    p, b = tree.plan, np.array(bodies, dtype=np.int64)
    index = {int(x): i for i, x in enumerate(b)}
    joints = np.concatenate([np.arange(p.jnt_start[x], p.jnt_start[x] + p.jnt_count[x]) for x in b]).astype(np.int64)
    count = p.jnt_count[b]
    quats = tree.layout.quats[:, 0]
    ints = np.concatenate([
        [tree.nq, len(b), len(joints), len(quats)], quats, [index[int(x)] for x in p.parent[b]],
        np.cumsum(count) - count, count, p.fixed_plain[b], np.full(len(joints), -1), p.hinge_coord[joints],
        p.anchor_zero[joints], tree.jnt_type[joints], tree.jnt_qadr[joints]]).astype(np.int64)
    return np.concatenate([ints.view(np.float64), np.asarray(local, dtype=np.float64).reshape(16), tree.qpos0,
                           p.fixed_rot[b].reshape(-1), p.fixed_pos[b].reshape(-1), tree.jnt_axis[joints].reshape(-1),
                           tree.jnt_pos[joints].reshape(-1)])


@njit_inline
def _chain_fk(chain: Array, q: Array, S: Array) -> bool:
    """:func:`fk_kernel` over a chain for one ``q (nq,)`` into the scratch ``S (12 n + 21,)``.

    Writes the bodies' ``rot (1, n, 3, 3)`` at ``S[0]`` and ``pos (1, n, 3)`` at ``S[9 n]``
    (the kernel's own scratch is the rest). False (nothing written) for a ``q`` of another
    length, with a NaN or inf, or with a zero quaternion: what
    :func:`mjkin.kinematics.qspace.check` refuses (the caller's check then says why).
    """
    head = unshared_int64(chain, 0, (HEADER,))
    nq, n, nj, nquat = head[0], head[1], head[2], head[3]
    if q.shape[0] != nq:
        return False
    for a in range(nq):
        if not np.isfinite(q[a]):
            return False
    quats = unshared_int64(chain, HEADER, (nquat,))
    for i in range(nquat):
        a = quats[i]
        if q[a] ** 2 + q[a + 1] ** 2 + q[a + 2] ** 2 + q[a + 3] ** 2 < 1e-18:
            return False
    o = HEADER + nquat  # the per-body integers
    j = o + 4 * n  # the per-joint integers
    f = j + 5 * nj + 16 + nq  # fixed_rot, after local and qpos0
    rot, pos = unshared(S, 0, (1, n, 3, 3)), unshared(S, 9 * n, (1, n, 3))
    fk_kernel_in(unshared(q, 0, (1, nq)), unshared_int64(chain, o, (n,)), unshared(chain, f, (n, 3, 3)),
                 unshared(chain, f + 9 * n, (n, 3)), unshared_int64(chain, o + n, (n,)),
                 unshared_int64(chain, o + 2 * n, (n,)), unshared_int64(chain, j, (nj,)),
                 unshared_int64(chain, o + 3 * n, (n,)), unshared_int64(chain, j + nj, (nj,)),
                 unshared_int64(chain, j + 2 * nj, (nj,)), unshared_int64(chain, j + 3 * nj, (nj,)),
                 unshared_int64(chain, j + 4 * nj, (nj,)), unshared(chain, f + 12 * n, (nj, 3)),
                 unshared(chain, f + 12 * n + 3 * nj, (nj, 3)), unshared(chain, f - nq, (nq,)),
                 rot, pos, rot, pos,  # no inner frames: jnt_inner is all -1
                 unshared(S, 12 * n, (3, 3)), unshared(S, 12 * n + 9, (3,)), unshared(S, 12 * n + 12, (3, 3)))
    return True


@njit_inline
def _local(chain: Array) -> Array:
    """The chain's frame in its last body ``(4, 4)``."""
    head = unshared_int64(chain, 0, (HEADER,))
    return unshared(chain, HEADER + head[3] + 4 * head[1] + 5 * head[2], (4, 4))


_CHAIN = types.Array(types.float64, 1, "C")
_Q = types.Array(types.float64, 1, "C")  # q of the compiled entries


@njit_gil
def chain_pose(chain: Array, q: Array, T: Array) -> bool:
    """World pose ``T (4, 4)`` of a chain's frame for one ``q (nq,)``.

    False (``T`` unwritten) if ``q`` is not valid, or the chain is longer than :data:`MAX_BODIES`.
    """
    n = unshared_int64(chain, 1, (1,))[0]
    if n > MAX_BODIES:
        return False
    S = on_stack(12 * n + 21)
    if not _chain_fk(chain, q, S):
        return False
    frame_world(unshared(S, 0, (1, n, 3, 3)), unshared(S, 9 * n, (1, n, 3)), 0, n - 1, _local(chain), T)
    return True


@njit_gil
def chain_poses(chain: Array, q: Array, T: Array) -> bool:
    """Pose ``T (n, 4, 4)`` of each body of a chain for one ``q (nq,)``; False (none written) as :func:`chain_pose`."""
    n = unshared_int64(chain, 1, (1,))[0]
    if n > MAX_BODIES:
        return False
    S = on_stack(12 * n + 21)
    if not _chain_fk(chain, q, S):
        return False
    poses_kernel(unshared(S, 0, (n, 3, 3)), unshared(S, 9 * n, (n, 3)), T)
    return True


_KERNEL = types.int32(types.CPointer(types.float64), types.int64, types.CPointer(types.float64), types.int64,
                      types.CPointer(types.float64))  # (chain, L, q, nq, out): what _posecall.c calls


@cfunc(_KERNEL)
def _pose_cfunc(chain: Any, length: int, q: Any, nq: int, T: Any) -> int:
    """:func:`chain_pose` behind a C function pointer, for :mod:`mjkin.kinematics._posecall`."""
    return 1 if chain_pose(carray(chain, (length,)), carray(q, (nq,)), carray(T, (4, 4))) else 0


@cfunc(_KERNEL)
def _poses_cfunc(chain: Any, length: int, q: Any, nq: int, T: Any) -> int:
    """:func:`chain_poses` behind a C function pointer; ``T (n, 4, 4)``, ``n`` read from the chain."""
    c = carray(chain, (length,))
    return 1 if chain_poses(c, carray(q, (nq,)), carray(T, (unshared_int64(c, 1, (1,))[0], 4, 4))) else 0


_FLOAT64 = np.dtype(np.float64)  # native float64 (numba's dispatch can mistake a read-only big-endian array for one)
_direct: list[Callable] = []  # chain_pose's and chain_poses' entries without numba's dispatch (see ready)


_ENTRIES = [(kernel, (_CHAIN, _Q, types.Array(types.float64, ndim, "C"))) for kernel, ndim in ((chain_pose, 2),
                                                                                              (chain_poses, 3))]


def ready() -> bool:
    """Compile (or load from the disk cache) the one-q entries, once, and bind the C module's pointers to them.

    ``Tree.pose`` and ``Tree.fk`` call it for a one-q pose; until it is done :data:`pose_of` and
    :data:`poses_of` return None (nothing compiles at import). False while a child process compiles
    them (:func:`mjkin.runtime.tier.compiled`): the caller runs :func:`one_pose` meanwhile.
    """
    if _direct:
        return True
    # one version each: a read-only q is read through it too (the same memory; neither writes q), so it is not
    # compiled twice (2.4 s of a first pose)
    if not tier.compiled(_ENTRIES, small=True):
        return False
    for kernel, sig in _ENTRIES:
        kernel.compile(sig)
        kernel.disable_compile()  # any other q: TypeError, for the caller's checked path
    _direct.extend(entry(kernel, *sig) for kernel, sig in _ENTRIES)
    if _posecall is not None:
        _pose_cfunc.compile()
        _poses_cfunc.compile()
        _posecall.bind(_pose_cfunc.address, _poses_cfunc.address)
    return True


def one_pose(kernel: Callable, chain: Array, q: Array, T: Array) -> bool:
    """``kernel(chain, q, T)`` (:func:`chain_pose` or :func:`chain_poses`), compiled once :func:`ready`, else as
    Python (:func:`mjkin.runtime.tier.interpreted_call`). ``q (nq,)``: C-contiguous float64.
    """  # noqa: D205
    return bool(kernel(chain, q, T) if ready() else tier.interpreted_call(kernel, chain, q, T))


def is_ready() -> bool:
    """Whether :func:`ready` has run."""
    return bool(_direct)


def _is_plain(q: object) -> bool:
    """Whether ``q`` is what the compiled entries read: a native float64 ndarray, 1-D, C-contiguous."""
    return type(q) is np.ndarray and q.dtype is _FLOAT64 and q.ndim == 1 and q.flags.c_contiguous


def pose_numba(chain: Array, q: object) -> Array | None:
    """:func:`chain_pose` into a new ``(4, 4)``, or None for any other ``q``, one it refuses, or before :func:`ready`.

    What :data:`pose_of` is when :mod:`mjkin.kinematics._posecall` was not built (no C compiler).
    """
    if _direct and _is_plain(q) and _direct[0](chain, q, T := np.empty((4, 4))):
        return T
    return None


def poses_numba(chain: Array, q: object) -> Array | None:
    """:func:`chain_poses` into a new ``(n, 4, 4)``, or None as :func:`pose_numba`."""
    if _direct and _is_plain(q) and _direct[1](chain, q, T := np.empty((int(chain[1:2].view(np.int64)[0]), 4, 4))):
        return T  # n: the chain's second header integer
    return None


SMALL_ROWS = 24  # a plain (B, nq) q of up to this many rows takes the one-q entry row by row (Panda: ~0.6 µs a
# pose row, ~0.75 µs an FK row), not the batched path (~19 µs of Python to set up a pose, ~13 µs FK, then ~0.3 µs a
# row): row by row is the quicker up to ~48 rows of a pose and ~28 of FK


def rows_of(one: Callable[[Array, object], Array | None], chain: Array, q: object) -> Array | None:
    """``one(chain, row)`` (:data:`pose_of` or :data:`poses_of`) of each row of a small ``q (B, nq)``, stacked.

    None for a ``q`` that is not a native float64 C-contiguous 2-D ndarray of 1 to :data:`SMALL_ROWS`
    rows, while :func:`ready` is not (a child compiles the entries), or where ``one`` refuses a row.
    """
    if not (type(q) is np.ndarray and q.dtype is _FLOAT64 and q.ndim == 2 and 0 < q.shape[0] <= SMALL_ROWS
            and q.flags.c_contiguous) or not ready():
        return None
    rows = [one(chain, row) for row in q]
    return None if any(r is None for r in rows) else np.array(rows)


pose_of: Callable[[Array, object], Array | None]  # what Tree.pose and Tree.fk call: see the module's docstring
poses_of: Callable[[Array, object], Array | None]
try:
    from . import _posecall  # built by setup.py where a C compiler is (types: _posecall.pyi)
except ImportError:  # installed without a C compiler
    _posecall = None  # type: ignore[assignment]
    pose_of, poses_of = pose_numba, poses_numba
else:
    pose_of, poses_of = _posecall.pose, _posecall.poses
