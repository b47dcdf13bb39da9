"""Shared test helpers: model lists, the MuJoCo oracle, tolerances, seeded generators."""

from __future__ import annotations

import contextlib
import os
import signal
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

# before mujoco is imported: it picks its GL backend then, and a later MUJOCO_GL would stop mjkin's own fallback
# to EGL (found running the suite without MUJOCO_GL: the renderer went to GLFW, with no display)
os.environ.setdefault("MUJOCO_GL", "egl")
# every kernel compiled before its first call, as numba does (not interpreted while a child compiles it,
# mjkin.runtime.tier): the same bits on every run; tests/runtime/test_tier.py tests the other modes
os.environ.setdefault("MJKIN_COMPILE", "wait")

import mujoco
import numpy as np
import pytest
from hypothesis import HealthCheck, settings
from numba.core import event

import mjkin
from mjkin.apps.bench.report import shared_models_dir
from mjkin.runtime.progress import COMPILING

# Hypothesis: CI (env CI set) replays the same examples on every run and keeps no example database, so a run
# depends only on the code; locally each run draws new examples and remembers failures in .hypothesis/ (not
# committed). Wall-clock time is never a test criterion here (numba compiles on first use): no deadline, no
# too-slow health check.
_TIMELESS = {"deadline": None, "suppress_health_check": [HealthCheck.too_slow]}
settings.register_profile("ci", derandomize=True, database=None, print_blob=True, **_TIMELESS)
# parent "default": Hypothesis itself may already have loaded its own "ci" profile when it detects CI
settings.register_profile("dev", parent=settings.get_profile("default"), **_TIMELESS)
settings.load_profile("ci" if os.environ.get("CI") else "dev")

FK_TOL = 1e-10  # FK and Jacobians against MuJoCo
FD_TOL = 1e-6  # finite-difference checks (central differences, step 1e-6)

TESTS = Path(__file__).resolve().parent  # grouped in folders by the package's layers
ROOT = TESTS.parent
GYM_ASSETS = Path(__import__("gymnasium").__file__).parent / "envs" / "mujoco" / "assets"


def bundled() -> list[Path]:
    return list(mjkin.bundled_models().values())


def gym_assets() -> list[Path]:
    return sorted(GYM_ASSETS.glob("*.xml"))


def shared() -> list[Path]:
    root = shared_models_dir()
    return sorted(root.rglob("*.xml")) if root else []


def model_id(p: Path) -> str:
    return f"{p.parent.name}/{p.stem}"


ALL_MODELS = bundled() + gym_assets() + shared()


@pytest.fixture(scope="session", autouse=True)
def mujoco_log(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Path]:
    """Where MuJoCo writes its warnings during the tests: a temporary file, not ``MUJOCO_LOG.TXT`` in the cwd.

    Compiling some models warns (gymnasium's half_cheetah.xml uses the deprecated ``settotalmass``), and MuJoCo
    appends every warning to ``MjLogConfig.logfile``, by default ``MUJOCO_LOG.TXT`` in the working folder. MuJoCo
    before 4.0 has no ``MjLogConfig``: there a log the tests created in the working folder is removed at the end.
    """
    log = tmp_path_factory.mktemp("mujoco") / "MUJOCO_LOG.TXT"
    config = mujoco.MjLogConfig.get() if hasattr(mujoco, "MjLogConfig") else None
    left = Path("MUJOCO_LOG.TXT").resolve()
    there = left.exists()
    if config is not None:
        default, config.logfile = config.logfile, str(log)
        config.set()
    yield log
    if config is not None:
        config.logfile = default
        config.set()
    elif not there:
        left.unlink(missing_ok=True)


@contextlib.contextmanager
def no_hang(seconds: int = 20) -> Iterator[None]:
    """Fail instead of waiting forever (a FIFO read blocks until a writer comes)."""
    def timeout(signum: int, frame: object) -> None:
        raise TimeoutError(f"still reading after {seconds} s")

    old = signal.signal(signal.SIGALRM, timeout)
    signal.alarm(seconds)
    try:
        yield
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, old)


@pytest.fixture
def rng() -> np.random.Generator:
    return np.random.default_rng(12345)


_TREES: dict[str, mjkin.Tree] = {}


def tree_of(src: str | Path) -> mjkin.Tree:
    """Load a model once per session."""
    key = str(src)
    if key not in _TREES:
        _TREES[key] = mjkin.load(src)
    return _TREES[key]


def mujoco_state(model: mujoco.MjModel, q: np.ndarray) -> mujoco.MjData:
    """MjData after ``mj_kinematics`` and ``mj_comPos`` (what ``mj_jac`` needs) at ``q``."""
    data = mujoco.MjData(model)
    data.qpos[:] = q
    mujoco.mj_kinematics(model, data)
    mujoco.mj_comPos(model, data)
    return data


def mujoco_jacobian(model: mujoco.MjModel, data: mujoco.MjData, kind: str, i: int) -> np.ndarray:
    jp, jr = np.zeros((3, model.nv)), np.zeros((3, model.nv))
    (mujoco.mj_jacSite if kind == "site" else mujoco.mj_jacBody)(model, data, jp, jr, i)
    return np.vstack([jp, jr])


def assert_goal_jacobian(tree: mjkin.Tree, goal: object, q: np.ndarray, h: float = 1e-6, atol: float = 2e-5) -> None:
    """A goal's Jacobian at ``q (nq,)`` equals central finite differences of its rows along each dof."""
    from mjkin.ik import evaluate

    _, J, _ = evaluate(tree, goal, q)
    for i in range(tree.nv):
        e = np.zeros(tree.nv)
        e[i] = h
        fd = evaluate(tree, goal, tree.integrate(q, e))[0] - evaluate(tree, goal, tree.integrate(q, -e))[0]
        np.testing.assert_allclose(J[0, :, i], fd[0] / (2 * h), atol=atol, err_msg=type(goal).__name__)


def rotation_distance(R1: np.ndarray, R2: np.ndarray) -> np.ndarray:
    """Angle between rotation matrices (radians)."""
    return mjkin.spatial.quat_distance(mjkin.spatial.mat_to_quat(R1), mjkin.spatial.mat_to_quat(R2))


# The slow tests (`pytest -m "not slow"` runs the rest, the library's own laws, in about a minute on a warm cache):
# whole modules that start servers, subprocesses, renders, learners or benchmarks, and single tests that compile a
# loop of their own (balance, clearance) or sweep many targets.
SLOW_MODULES = {"test_bench", "test_bench_constraints", "test_play", "test_play_constraints", "test_render",
                "test_showcase", "test_learning", "test_her_example", "test_docs", "test_cli", "test_warmup_cli",
                "test_tier", "test_jit", "test_progress", "test_distributed", "test_envs", "test_expert_clearance",
                "test_seeds", "test_hypothesis_profiles", "test_entry_fuzz", "test_retarget_dataset",
                "test_com_goal", "test_retarget_quality"}
SLOW_TESTS = {"test_clearance_rows_are_the_closest_pairs_with_their_gradients",
              "test_hard_rows_match_finite_differences",
              "test_a_pair_mjkin_cannot_measure_is_kept_by_its_bounding_sphere",
              "test_clearance_answers_nearly_every_answerable_target_among_obstacles",
              "test_clearance_holds_on_every_success_by_mujoco"}


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """Mark the slow tests (:data:`SLOW_MODULES`, :data:`SLOW_TESTS`); the tests of a module that sets ``FIRST``
    (a compile of minutes in a process of its own) run first, so the other test workers go on meanwhile."""
    for item in items:
        module = getattr(getattr(item, "module", None), "__name__", "")
        if module in SLOW_MODULES or getattr(item, "originalname", item.name) in SLOW_TESTS:
            item.add_marker(pytest.mark.slow)
    items.sort(key=lambda item: not getattr(getattr(item, "module", None), "FIRST", False))  # stable


# `mjkin warmup` beside the tests: on an empty kernel cache it compiles the common kernels in parallel processes
# while the first tests run; a test that needs a kernel the warmup is compiling waits for it (a lock per kernel)
# and loads it, rather than compiling it again. On a warm cache it only loads them (a few seconds of CPU). It is
# started once per run: by pytest-xdist's controller, or by the one process without it. MJKIN_TEST_WARMUP=0 leaves
# it out.
WARMUP = [sys.executable, "-m", "mjkin.apps.cli", "warmup"]
_WARMUP: list[subprocess.Popen] = []


def pytest_sessionstart(session: pytest.Session) -> None:
    config = session.config
    if config.option.collectonly or hasattr(config, "workerinput") or os.environ.get("MJKIN_TEST_WARMUP") == "0":
        return
    _WARMUP.append(subprocess.Popen(WARMUP, cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                                    start_new_session=True))


def pytest_sessionfinish(session: pytest.Session) -> None:
    for proc in _WARMUP:  # a run stopped early (-x, Ctrl-C) leaves no process behind
        with contextlib.suppress(ProcessLookupError):
            os.killpg(proc.pid, signal.SIGKILL)  # the group: the warmup's own workers too (a cache write is atomic)
        proc.wait()


def pytest_report_header(config: pytest.Config) -> str:
    root = shared_models_dir()
    return f"mjkin models: {len(bundled())} bundled, {len(gym_assets())} gymnasium, {len(shared())} shared ({root})"


class _CompileNotice(event.Listener):
    """Says once, past pytest's output capture, that numba is compiling: on a fresh checkout the dots stop for
    minutes while the kernels compile (a helper's clean-clone run read that silence as a hang)."""

    def __init__(self, config: pytest.Config) -> None:
        self.config, self.said = config, False

    def on_start(self, ev: event.Event) -> None:
        plugins = self.config.pluginmanager  # the reporter registers after conftest's configure: looked up here
        reporter, capture = plugins.get_plugin("terminalreporter"), plugins.get_plugin("capturemanager")
        module = getattr(getattr(ev.data.get("dispatcher"), "py_func", None), "__module__", "") or ""
        if reporter is None or capture is None or self.said or not module.startswith("mjkin"):
            return  # a test's own small function (test_jit, test_progress) is not the kernels' compile
        self.said = True
        with capture.global_and_fixture_disabled():  # inside a test, stdout is captured
            reporter.write_line(f"mjkin: {COMPILING}")

    def on_end(self, ev: event.Event) -> None:
        pass


def pytest_configure(config: pytest.Config) -> None:
    config.addinivalue_line("markers", "slow: a test of whole commands, servers or benchmarks (see SLOW_MODULES)")
    event.register("numba:compile", _CompileNotice(config))
