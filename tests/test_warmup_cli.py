"""``mjkin warmup``: compiles (or loads) every kernel and says how long it took."""

from __future__ import annotations

import re

import numba

from mjkin.cli import main
from mjkin.ik import kernel


def test_warmup_compiles_the_solver_and_reports_seconds(capsys):
    assert main(["warmup"]) == 0
    out = capsys.readouterr().out.splitlines()
    assert out[0] == "compiling mjkin's kernels (first run only, about a minute)..."
    assert re.fullmatch(r"done in \d+\.\d s", out[1])
    solver = kernel.solve_batch
    assert isinstance(solver, numba.core.registry.CPUDispatcher) and len(solver.signatures) >= 1
