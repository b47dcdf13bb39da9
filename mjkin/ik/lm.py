"""The Jacobian methods: Levenberg–Marquardt (``lm``, and ``auto``), damped least squares, pseudoinverse, transpose.

One compiled loop (:mod:`mjkin.ik.loop`) runs them all; they differ in how a
level's step is solved (see :mod:`mjkin.ik.kernel`) and in their defaults.
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from dataclasses import dataclass
from functools import cached_property
from types import ModuleType
from typing import TYPE_CHECKING, ClassVar

import numba
import numpy as np

from ..errors import InputError
from ..runtime import tier
from ..runtime.checks import check_count, check_flag, check_number
from ..runtime.numba_private import entry
from ..runtime.parallel import parallel_chunks
from . import kernel, loop
from .generated import built_in, loop_for
from .method import MAX_ITERS, Array, Method, ProblemView
from .packed import Packed, pack, packed_kernels
from .result import History, Result, result_of

if TYPE_CHECKING:
    from ..goals import Program

AUTO_RESTARTS = 24  # many short runs beat few long ones on hard targets (see mjkin bench ik)
TIMED_RESTARTS = 1000  # with a timeout, auto restarts until the time runs out (as TRAC-IK does)
# lm's initial μ (λ² = λ_min² + μ·cost) and largest joint step per iteration: on the TRAC-IK protocol they took
# fewer iterations than 0.01 / 0.5 on every real arm (docs/benchmarks.md)
LM_MU, LM_MAX_STEP = 0.1, 1.0
# lm's stall test: a run in which no unmet goal's error has fallen by LM_PROGRESS (10 %) within LM_PATIENCE
# iterations restarts. A converging run falls fast; one creeping along a joint limit was kept alive by any gain
# of the merit at all (patience 6, 1e-9). The last run (no restart left) goes on while any error falls.
LM_PATIENCE, LM_PROGRESS = 4, 0.1
MAX_HISTORY = 100_000  # iterations per run at most with history=True: every iterate is kept, (targets, iters, nq)


@dataclass(frozen=True)
class Jacobian(Method):
    """Options every Jacobian method shares.

    Attributes:
        max_iters: iteration limit of each run (the start and every restart).
        damping: λ of ``dls`` (default 5 % of the model's size, ``MjModel.stat.extent``),
            the floor of ``lm``'s λ (default 1e-5 of it).
        max_step: largest joint change per iteration (rad or m).
        halving: iterative goal halving (the Finnish thesis): when a step does not lower the error,
            retract and aim halfway, repeatedly.
        goal_step: the most residual (m, or rad for orientation rows) a step aims to
            remove, so the effector walks toward a far goal (Buss's error clamping).
        patience: iterations without progress before a run counts as stalled.
    """

    code: ClassVar[int]
    max_iters: int = 100
    damping: float | None = None
    max_step: float = np.inf
    halving: bool = False
    goal_step: float = np.inf
    patience: int = 10
    progress: ClassVar[float] = 1e-9  # relative fall of an error that counts as progress
    lm_factor: ClassVar[float] = 0.0
    relative_damping: ClassVar[float] = 0.05

    def __post_init__(self) -> None:
        super().__post_init__()
        check_count(self.max_iters, "max_iters", 0, whole_floats=True, most=MAX_ITERS)
        check_count(self.patience, "patience", whole_floats=True, most=MAX_ITERS)
        check_flag(self.halving, "halving")
        if self.damping is not None:
            check_number(self.damping, "damping", 0, strict=True)
        check_number(self.max_step, "max_step", 0, strict=True, infinite=True)
        check_number(self.goal_step, "goal_step", 0, strict=True, infinite=True)

    def settings(self, problem: ProblemView) -> kernel.Settings:
        """The compiled loop's settings for this problem."""
        extent = float(problem.tree.model.stat.extent) or 1.0
        damping = self.relative_damping * extent if self.damping is None else self.damping
        return kernel.settings(problem.tol, problem.rot_tol, damping, self.lm_factor, self.alpha_value(),
                               self.max_step, self.halving, self.patience, self.goal_step, problem.time_limit,
                               self.progress)

    def alpha_value(self) -> float:
        """The transpose's step size (0 = Buss's), 0 for the others."""
        return 0.0

    def prepare(self, problem: ProblemView) -> Loop:
        """The problem's :class:`Loop`: the compiled loop with this problem's settings, made once.

        Raises:
            InputError: ``history`` with more than :data:`MAX_HISTORY` iterations a run.
        """
        if problem.history and self.max_iters > MAX_HISTORY:
            raise InputError(f"history keeps every iterate: max_iters must be at most {MAX_HISTORY:,} with it, "
                             f"got {self.max_iters}")
        return Loop(problem, self.code, self.settings(problem), int(self.max_iters))

    def run(self, problem: ProblemView, prog: Program, q: Array) -> Result:
        """Every target of ``prog`` from ``q (B, nq)`` (overwritten) through the problem's :class:`Loop`."""
        runner: Loop = problem.prepared
        return runner.solve(prog, q)


@dataclass(frozen=True)
class DLS(Jacobian):
    """Damped least squares with a fixed λ."""

    name: ClassVar[str] = "dls"
    code: ClassVar[int] = kernel.DLS
    max_iters: int = 1000


@dataclass(frozen=True)
class PInv(Jacobian):
    """The SVD pseudoinverse step."""

    name: ClassVar[str] = "pinv"
    code: ClassVar[int] = kernel.PINV


@dataclass(frozen=True)
class Transpose(Jacobian):
    """The Jacobian transpose ``α Jᵀ e``; ``alpha`` None for Buss's ``<e, JJᵀe> / |JJᵀe|²``."""

    name: ClassVar[str] = "transpose"
    code: ClassVar[int] = kernel.TRANSPOSE
    max_iters: int = 2000
    alpha: float | None = None

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.alpha is not None:
            check_number(self.alpha, "alpha", 0, strict=True)

    def alpha_value(self) -> float:  # noqa: D102
        return 0.0 if self.alpha is None else float(self.alpha)


@dataclass(frozen=True)
class LM(Jacobian):
    """Levenberg–Marquardt: an error-dependent λ (``λ² = λ_min² + μ·cost``) and step acceptance."""

    name: ClassVar[str] = "lm"
    code: ClassVar[int] = kernel.LM
    max_iters: int = 50
    max_step: float = LM_MAX_STEP
    patience: int = LM_PATIENCE
    progress: ClassVar[float] = LM_PROGRESS
    lm_factor: ClassVar[float] = LM_MU
    relative_damping: ClassVar[float] = 1e-5


@dataclass(frozen=True)
class Auto(LM):
    """The default: :class:`LM` with 24 seeded random restarts (1000 with a time limit: until it runs out)."""

    name: ClassVar[str] = "auto"
    restarts: int | None = None

    def restart_count(self, timed: bool) -> int:  # noqa: D102
        if self.restarts is not None:
            return int(self.restarts)
        return TIMED_RESTARTS if timed else AUTO_RESTARTS


# the loop modules loaded in this process (Loop.compiled), with whether for goals of common kinds only
_LOADED: set[tuple[ModuleType, bool]] = set()


class Loop:
    """The compiled loop run for one problem: every target of a program from the starts ``q (B, nq)`` (overwritten).

    Targets run in :func:`mjkin.ik.loop.solve_packed` (of :attr:`module`). Each call packs its
    arrays for the compiled code (:mod:`mjkin.ik.packed`), all C-contiguous as every array
    here, so one compiled specialisation serves every batch size. A single target reuses the
    arrays packed at its first solve: only its targets and start are copied in, and the
    answers out (a call made while another thread runs one packs its own).
    """

    def __init__(self, problem: ProblemView, code: int, st: kernel.Settings, max_iters: int) -> None:
        self.problem, self.code, self.st, self.max_iters = problem, code, st, max_iters
        self.H = max_iters + 1 if problem.history else 0
        self.one: tuple | None = None  # (packed, its arrays) of single targets
        self.starts_in_one: Array | None = None  # the problem's restart starts those arrays hold a copy of
        self.call_one: Callable[[Packed, int, int], None] | None = None  # solve_packed on those arrays, compiled
        self.lock = threading.Lock()

    def arrays(self, prog: Program, q: Array) -> tuple:
        """Fresh arrays of a call: the goal arrays, the starts, the restart starts, and the outputs."""
        B, G, nq, H = prog.B, len(prog.goals), self.problem.tree.nq, self.H
        return (prog.arrays, q, np.array(self.problem.starts), np.zeros(B, np.int64), np.zeros(B, np.int64),
                np.zeros(B, np.int64), np.zeros(B, np.int64), np.zeros((B, G, 2)), np.full((B, H, nq), np.nan),
                np.zeros((B, H, 2)), np.empty((B, 2)), np.empty(B, dtype=bool))

    def solve(self, prog: Program, q: Array) -> Result:
        """Solve every target of ``prog`` from ``q (B, nq)`` (overwritten; the result's ``q`` is a view of it)."""
        if prog.B == 1 and self.lock.acquire(blocking=False):
            try:
                return self.single(prog, q)
            finally:
                self.lock.release()
        arrays = self.arrays(prog, q)
        module = self.module
        if self.compiled(prog, arrays):
            packed = self.pack(arrays)
            # the compiled code releases the GIL
            parallel_chunks(lambda lo, hi: module.solve_packed(packed, lo, hi), prog.B)
        else:
            tier.interpreted_call(module.solve_packed, self.fields(arrays), 0, prog.B)
        return self.result(prog, arrays)

    def fields(self, arrays: tuple) -> tuple:
        """The :data:`~mjkin.ik.packed.FIELDS` of a call's ``arrays`` (:meth:`arrays`), in order."""
        ga, q, starts, iters, status, used, binding, err, hist_q, hist_err, worst, success = arrays
        p = self.problem
        return (p.tree.kin, ga, self.st, self.code, self.max_iters, starts, p.restart_q, p.active, q, iters, status,
                used, binding, err, hist_q, hist_err, worst, success)

    def pack(self, arrays: tuple) -> Packed:
        """:func:`mjkin.ik.packed.pack` of ``arrays`` (:meth:`arrays`) with the problem's constants."""
        return pack(*self.fields(arrays))

    @cached_property
    def module(self) -> ModuleType:
        """:mod:`mjkin.ik.loop` for built-in goal kinds; for a kind the user registered, its copy with a branch for it
        (:func:`mjkin.ik.generated.loop_for`).
        """  # noqa: D205
        codes = self.problem.structure.codes
        return loop if built_in(codes) else loop_for(codes)

    def compiled(self, prog: Program, arrays: tuple) -> bool:
        """Whether to run compiled, else interpreted while a child compiles (:func:`mjkin.runtime.tier.compiled`).

        Every problem packs the same types but for the goal arrays' (with the geoms, or without them for common
        kinds only), so a loop loaded once in this process is loaded for every later problem of its kinds: the
        check (numba typing the 18 packed fields, ~1 ms) runs once per loop and such type, not per
        :func:`mjkin.solve` call.
        """
        key = (self.module, self.problem.structure.common)
        if key in _LOADED and tier.mode() != "interpret":
            return True
        kernels = packed_kernels(self.module.solve_packed, self.fields(arrays))
        if tier.compiled(kernels, small=prog.B <= tier.SMALL_BATCH):
            _LOADED.add(key)
            return True
        return False

    def single(self, prog: Program, q: Array) -> Result:
        """One target through the arrays packed once (:meth:`solve` holds the lock)."""
        if self.one is None:
            arrays = self.arrays(prog, q.copy())
            self.one, self.starts_in_one = (None, arrays), self.problem.starts
        packed, arrays = self.one
        if self.call_one is None and self.compiled(prog, arrays):
            packed = self.pack(arrays)
            self.one = (packed, arrays)
            # the packed arrays are always these types: the call skips numba's dispatch (mjkin.runtime.jit.entry)
            self.call_one = entry(self.module.solve_packed, numba.typeof(packed), numba.int64, numba.int64)
        ga, q_in, starts = arrays[:3]
        ga.data[...] = prog.data
        if prog.structure.joint_targets:
            ga.rest_q[...] = prog.rest_q
        q_in[...] = q
        if self.problem.starts is not self.starts_in_one:  # new restart starts each solve (seed=None)
            starts[...] = self.starts_in_one = self.problem.starts
        if self.H:
            arrays[8].fill(np.nan)
            arrays[9].fill(0.0)
        if self.call_one is not None:
            self.call_one(packed, 0, 1)
        else:
            tier.interpreted_call(self.module.solve_packed, self.fields(arrays), 0, 1)
        q[...] = q_in
        if prog.batch:  # the result keeps (views of) its arrays: copies, not the packed ones
            return self.result(prog, (arrays[0], *(a.copy() for a in arrays[1:])))
        ga, _, _, iters, status, used, binding, err, hist_q, hist_err, worst, success = arrays
        history = (hist_q.copy(), hist_err.copy()) if self.H else (None, None)
        return self.result(prog, (ga, q, None, iters, status, used, binding, err.copy(), *history, worst.copy(),
                                  success))

    def result(self, prog: Program, arrays: tuple) -> Result:
        """The :class:`Result` of a call's ``arrays``; they become the result's (unbatched: its numbers)."""
        _, q, _, iters, status, used, binding, err, hist_q, hist_err, worst, success = arrays
        p = self.problem
        history = None
        if self.H:
            history = History(hist_q, hist_err)
            history.error[np.arange(self.H)[None, :] > iters[:, None]] = np.nan
        return result_of(prog, q, worst, success, err, iters, status, used, p.method_name, history, p.tree,
                         binding)
