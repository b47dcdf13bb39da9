"""The tested range (issue 56): numba and mujoco are asked for at the releases the tests run on, both ends.

CI installs what pyproject.toml allows and runs the suite on it, so the versions installed here are the tested
ones. The lower bound of each is the oldest tested and the upper bound the newest tested: the range is exactly
what this process runs, and a bump of either dependency must come with a run of the tests on it.
"""

from __future__ import annotations

from importlib.metadata import version

import pytest
from packaging.requirements import Requirement
from packaging.version import Version

from conftest import ROOT

tomllib = pytest.importorskip("tomllib")  # Python 3.11+


def _requirement(name: str) -> Requirement:
    deps = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["dependencies"]
    return next(r for d in deps if (r := Requirement(d)).name == name)


@pytest.mark.parametrize("name", ["numba", "mujoco"])
def test_the_range_asked_for_is_the_release_tested(name):
    """Every clause bounds the range at the installed release from below and above (``==`` it, or ``>=``/``<=`` it):
    an open or wider bound would let pip install a release no test ran on."""
    tested = Version(version(name))
    clauses = list(_requirement(name).specifier)
    assert clauses, f"pyproject.toml asks for {name} with no bounds; the tested release is {tested}"
    lowest = [c for c in clauses if c.operator in ("==", ">=")]
    highest = [c for c in clauses if c.operator in ("==", "<=")]
    assert lowest and highest, f"{name}: {_requirement(name).specifier} is open at one end; {tested} is tested"
    for clause in clauses:
        assert clause.operator in ("==", ">=", "<=") and Version(clause.version) == tested, \
            f"pyproject.toml asks for {name}{clause} but the tests run on {name} {tested}"


def test_the_numba_release_checked_at_import_is_the_one_asked_for():
    from mjkin.runtime.numba_private import NUMBA, numba_unsupported

    asked = Version(next(iter(_requirement("numba").specifier)).version)
    assert asked.release[:2] == NUMBA and numba_unsupported(str(asked)) is None
