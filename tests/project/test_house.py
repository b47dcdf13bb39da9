"""The house (issue 40): the playground's web stack an extra, its lists read from the registries, short signatures."""

from __future__ import annotations

import ast
import inspect
import subprocess
import sys
from dataclasses import dataclass
from typing import ClassVar

import numpy as np
import pytest

import mjkin
from conftest import ROOT, tree_of
from mjkin import goals as G
from mjkin import motion
from mjkin.apps.play import core
from mjkin.goals import registry
from mjkin.goals.base import METRES, FrameGoal, Units
from mjkin.goals.position import residual as position_residual
from mjkin.ik import DLS, METHODS


# ------------------------------------------------------------------ the packages a wheel holds
def test_every_package_folder_is_in_pyprojects_list():
    """An editable install finds any folder; a wheel holds only the listed packages (runtime/ and explore/ were not)."""
    tomllib = pytest.importorskip("tomllib")  # Python 3.11+
    setup = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]
    folders = {name: ROOT / where for name, where in setup["package-dir"].items()}
    listed = set(setup["packages"])
    found = {".".join(("mjkin", *init.parent.relative_to(ROOT / "mjkin").parts))
             for init in (ROOT / "mjkin").rglob("__init__.py")}
    found |= {name for name, folder in folders.items() if (folder / "__init__.py").is_file() or name == "mjkin.models"}
    assert listed == found


# ------------------------------------------------------------------ what `import mjkin` costs
HEAVY = ("ray", "torch", "stable_baselines3", "matplotlib", "starlette", "uvicorn", "pandas", "pyarrow")


def test_import_mjkin_leaves_the_extras_unimported():
    """Each of these costs a second or more; they load when their part is used (Ray's was imported by every
    ``import mjkin`` once the extra was installed)."""
    code = f"import sys, mjkin; print(*[m for m in {HEAVY!r} if m in sys.modules])"
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=600, check=True)
    assert run.stdout.split() == []


LAZY_IMPORT = """
import sys, numpy as np, mjkin
from mjkin.runtime import numba_private
def caches():
    return sum("_disk_cache" in vars(k) for name, m in list(sys.modules.items()) if name.startswith("mjkin")
               for k in vars(m).values() if numba_private.is_kernel(k))
print("scipy.optimize" in sys.modules, caches())
tree = mjkin.load("planar_2link")
tree.pose(np.zeros(tree.nq), "tip")
print(caches() > 0)
"""


def test_import_mjkin_makes_no_kernel_cache_and_leaves_scipy_optimize_for_the_optimize_method():
    """``import mjkin`` took 1.4-2 s: 0.5 s of it SciPy's optimize package (the ``optimize`` method's SLSQP)
    and 0.3 s making every kernel's disk cache. A kernel's cache is made when the kernel is first used."""
    run = subprocess.run([sys.executable, "-c", LAZY_IMPORT], capture_output=True, text=True, timeout=600, check=True)
    assert run.stdout.split() == ["False", "0", "True"], run.stdout


# ------------------------------------------------------------------ the play extra
WITHOUT_WEB_STACK = """
import sys
sys.modules["starlette"] = sys.modules["uvicorn"] = None  # as if the play extra were not installed
import mjkin, mjkin.apps.cli
sys.exit(mjkin.apps.cli.main(["play", "arm7", "--no-browser", "--port", "0"]))
"""


def test_play_without_its_extra_says_in_one_line_what_to_install():
    run = subprocess.run([sys.executable, "-c", WITHOUT_WEB_STACK], capture_output=True, text=True, timeout=600,
                         cwd=ROOT)
    assert run.returncode == 2, run.stderr
    lines = run.stderr.splitlines()
    assert len(lines) == 1 and "pip install 'mjkin[play]'" in lines[0] and "Traceback" not in run.stderr, run.stderr


def test_the_web_stack_is_the_play_extra_and_the_tests_have_it():
    tomllib = pytest.importorskip("tomllib")  # Python 3.11+
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    web = {"starlette", "uvicorn"}
    assert not {d.split(">")[0].split("=")[0] for d in project["dependencies"]} & web
    extras = project["optional-dependencies"]
    assert {d.split(">")[0] for d in extras["play"]} == web and "mjkin[play]" in extras["test"]


# --------------------------------------------------------- the panel from the registries
@dataclass(frozen=True)
class Beacon(FrameGoal):
    """A goal kind of a user's, made from a placed target: the frame's origin at its point."""

    point: tuple[float, float, float] = (0.0, 0.0, 0.0)
    rows: ClassVar[int] = 3
    units: ClassVar[Units] = METRES

    @classmethod
    def from_target(cls, frame, xyz, quat):
        return cls(frame, point=tuple(xyz))


@dataclass(frozen=True)
class Gentle(DLS):
    """A method of a user's: damped least squares under another name."""

    name: ClassVar[str] = "gentle"


@pytest.fixture
def user_kind(monkeypatch):
    """:class:`Beacon` registered for this test alone (the registry is global)."""
    monkeypatch.setattr(registry, "KINDS", list(registry.KINDS))
    monkeypatch.setattr(registry, "RESIDUALS", list(registry.RESIDUALS))
    G.register(Beacon, residual=position_residual)
    return Beacon


def test_a_registered_goal_kind_is_offered_by_the_playground(user_kind):
    kinds = core.goal_kinds()
    assert list(kinds)[:3] == ["position", "pose", "aim"] and "beacon" in kinds
    tree = tree_of("arm7")
    state = core.with_goal(core.initial_state(tree), "beacon")
    (goal,) = core.goals_for(state)
    assert isinstance(goal, Beacon) and goal.frame == "ee"
    np.testing.assert_array_equal(goal.point, state.targets["ee"][:3])
    with pytest.raises(mjkin.InputError, match="beacon"):  # the error lists what the panel offers
        core.with_goal(state, "nowhere")


def test_a_registered_method_is_offered_and_followed_by_the_playground(monkeypatch):
    monkeypatch.setitem(METHODS, "gentle", Gentle)
    methods = core.panel_methods()
    assert "gentle" in methods and "analytic2" not in methods  # a closed form does not step
    assert set(methods) == {name for name, m in METHODS.items() if m.name != "analytic2"}
    tree = tree_of("arm7")
    state = core.with_method(core.initial_state(tree), "gentle")
    target = state.targets["ee"][:3] + [0.03, -0.02, 0.02]
    out = core.apply(tree, core.View.of(core.Camera((0.0, 0.0, 0.5), 2.0, 90.0, -20.0), tree.model, 64, 48), state,
                     core.Place("ee", tuple(target)))
    assert out.method == "gentle" and out.error[0] < 1e-3


# ------------------------------------------------------------------ short signatures
@pytest.mark.parametrize("fn", [mjkin.solve, motion.walk_cycle])
def test_entry_points_take_at_most_ten_parameters(fn):
    assert len(inspect.signature(fn).parameters) <= 10


def test_solve_still_takes_the_problem_options_by_keyword():
    tree = tree_of("arm7")
    goal = G.Position("ee", tree.pose(tree.random_q(np.random.default_rng(3), 1)[0], "ee")[:3, 3])
    joints = [f"j{k}" for k in range(1, 5)]
    res = mjkin.solve(tree, goal, method="dls", timeout=10.0, joints=joints, history=True)
    ref = mjkin.Problem(tree, goal, method="dls", timeout=10.0, joints=joints, history=True).solve()
    np.testing.assert_array_equal(res.q, ref.q)
    np.testing.assert_array_equal(res.q[4:], tree.qpos0[4:])  # only the joints named moved
    assert res.history is not None


def test_a_gait_sets_the_walk_and_refuses_bad_numbers():
    tree = tree_of("primate")
    walk = motion.walk_cycle(tree, steps=1, gait=motion.Gait(stride=0.2, frames_per_step=4))
    assert walk.q.shape == (4, tree.nq) and walk.success.all() and walk.meta["walk"]["stride"] == 0.2
    x = tree.pose(np.vstack([tree.qpos0, walk.q[-1]]), "right_foot", "body")[:, 0, 3]
    assert x[1] - x[0] == pytest.approx(0.1, abs=1e-3)  # the first step: half a stride
    for bad, needle in (({"stride": 0.0}, "stride"), ({"frames_per_step": 1}, "frames_per_step"),
                        ({"lean": float("nan")}, "lean")):
        with pytest.raises(mjkin.InputError, match=needle) as err:
            motion.Gait(**bad)
        assert "\n" not in str(err.value)
    with pytest.raises(mjkin.InputError, match="steps"):
        motion.walk_cycle(tree, steps=0)


def test_no_module_imports_another_modules_private_names():
    """A name shared between modules is public in its home (issue 40: ccd, reach and the IK loop imported ``_`` names).

    A compiled extension module of a package (``_posecall``) is private to its package and may be imported there.
    """
    found = []
    for path in sorted((ROOT / "mjkin").rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ImportFrom) and (node.module or "").startswith("mjkin"):
                found += [f"{path.relative_to(ROOT)}: {alias.name} from {node.module}" for alias in node.names
                          if alias.name.startswith("_") and not (ROOT / (node.module or "").replace(".", "/")
                                                                  / alias.name).with_suffix(".pyi").exists()]
    assert not found, found


def test_no_module_imports_the_package_root():
    """``mjkin/__init__.py`` imports the whole library: a module that imports a name from it runs back up (issue 54:
    ``motion.dataset`` took ``__version__`` from it; it lives in ``mjkin/version.py``). Submodules may be named.
    """  # noqa: D205
    found = []
    for path in sorted((ROOT / "mjkin").rglob("*.py")):
        package = list(path.relative_to(ROOT).parts[:-1])
        if path == ROOT / "mjkin" / "__init__.py":
            continue
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Import):
                found += [f"{path.relative_to(ROOT)}: import mjkin" for a in node.names if a.name == "mjkin"]
            elif isinstance(node, ast.ImportFrom):
                base = package[: len(package) - node.level + 1] if node.level else []
                if ".".join(base + ([node.module] if node.module else [])) == "mjkin":
                    found += [f"{path.relative_to(ROOT)}: {a.name} from mjkin" for a in node.names
                              if not ((ROOT / "mjkin" / a.name).with_suffix(".py").exists()
                                      or (ROOT / "mjkin" / a.name).is_dir())]
    assert not found, found
    assert mjkin.__version__ == mjkin.version.__version__
