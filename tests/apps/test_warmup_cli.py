"""``mjkin warmup``: compiles (or loads) every kernel and says how long it took."""

from __future__ import annotations

import os
import re
import subprocess
import sys
import types

import numba

from mjkin.apps import warmup
from mjkin.apps.cli import main

_SOLVE = """
import numba, mjkin
from mjkin.goals import Pose
from mjkin.ik.loop import solve_packed as solver  # the loop's one entry from Python
tree = mjkin.load("arm7")
mjkin.solve(tree, Pose("ee", T=tree.pose(tree.qpos0, "ee")))
print(isinstance(solver, numba.core.registry.CPUDispatcher), len(solver.signatures),
      sum(solver.stats.cache_hits.values()), sum(solver.stats.cache_misses.values()))
"""


def test_warmup_fills_the_cache_the_next_solve_loads(capsys):
    """The groups compile in processes of their own; this process then loads the IK loop, compiling nothing."""
    assert main(["warmup"]) == 0
    out = capsys.readouterr().out.splitlines()
    assert out[0].startswith(f"preparing mjkin's kernels ({len(warmup.GROUPS)} groups")
    done = r"\((compiled \d+ kernels?|none compiled: cached or loaded)\)"
    assert re.fullmatch(rf"kernels ready in \d+\.\d s {done}", out[1])
    # in a process of its own: in this one an earlier test may have compiled the loop already (a cold tree)
    run = subprocess.run([sys.executable, "-c", _SOLVE], capture_output=True, text=True, timeout=600, check=True,
                         env={**os.environ, "MJKIN_COMPILE": "wait"})
    dispatcher, signatures, hits, misses = run.stdout.split()
    assert dispatcher == "True" and int(signatures) >= 1
    assert int(hits) >= 1 and int(misses) == 0


def test_warmup_says_whether_it_compiled(capsys, monkeypatch):
    """A second warmup compiles nothing and says so; a kernel compiled during the warmup is counted."""
    assert main(["warmup"]) == 0
    assert main(["warmup", "--jobs", "1"]) == 0
    assert capsys.readouterr().out.splitlines()[-1].endswith("(none compiled: cached or loaded)")
    probe = types.ModuleType("mjkin._warmup_probe")
    probe.kernel = numba.njit(lambda x: x + 1)  # type: ignore[attr-defined]
    monkeypatch.setitem(sys.modules, probe.__name__, probe)
    monkeypatch.setitem(warmup.GROUPS, "probe", lambda chain, figure: probe.kernel(1.5))
    assert main(["warmup", "--jobs", "1"]) == 0
    assert capsys.readouterr().out.splitlines()[-1].endswith("(compiled 1 kernel)")
