"""``mjkin warmup``: compiles (or loads) every kernel and says how long it took."""

from __future__ import annotations

import re
import sys
import types

import numba

from mjkin.apps import warmup
from mjkin.apps.cli import main
from mjkin.goals import Pose
from mjkin.ik.compiled import kernels


def test_warmup_compiles_the_solver_and_reports_seconds(capsys):
    assert main(["warmup"]) == 0
    out = capsys.readouterr().out.splitlines()
    assert out[0].startswith("preparing mjkin's kernels")
    done = r"\((compiled \d+ kernels?|none compiled: cached or loaded)\)"
    assert re.fullmatch(rf"kernels ready in \d+\.\d s {done}", out[1])
    solver = kernels((Pose.code,)).solve_packed  # the Pose loop's one entry from Python
    assert isinstance(solver, numba.core.registry.CPUDispatcher) and len(solver.signatures) >= 1


def test_warmup_says_whether_it_compiled(capsys, monkeypatch):
    """A second warmup compiles nothing and says so; a kernel compiled during the warmup is counted."""
    assert main(["warmup"]) == 0
    assert main(["warmup"]) == 0
    assert capsys.readouterr().out.splitlines()[-1].endswith("(none compiled: cached or loaded)")
    probe = types.ModuleType("mjkin._warmup_probe")
    probe.kernel = numba.njit(lambda x: x + 1)  # type: ignore[attr-defined]
    monkeypatch.setitem(sys.modules, probe.__name__, probe)
    steps = warmup._steps
    monkeypatch.setattr(warmup, "_steps", lambda *a: [*steps(*a), ("probe", lambda: probe.kernel(1.5))])
    assert main(["warmup"]) == 0
    assert capsys.readouterr().out.splitlines()[-1].endswith("(compiled 1 kernel)")
