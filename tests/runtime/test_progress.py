"""Progress on a terminal: the first-run compile notice, and no ETA before the first item is done."""

from __future__ import annotations

import io
import os
import re
import subprocess
import sys

import numba
import pytest

from mjkin.runtime import progress


class Terminal(io.StringIO):
    def isatty(self) -> bool:
        return True


@pytest.fixture
def terminal(monkeypatch):
    """stderr as a terminal, progress enabled as the CLI does, the notice not yet printed in this process.

    Patched when the test body runs (pytest resets ``sys.stderr`` between fixture set-up and the test).
    """
    err = Terminal()
    monkeypatch.setattr(progress, "_said", set())
    monkeypatch.setattr(progress._listener, "depth", 0)  # no compile left open by another test's events
    monkeypatch.setattr(progress._listener, "stop", None)
    progress.enable(True)
    yield lambda: monkeypatch.setattr(sys, "stderr", err) or err
    progress.enable(False)


def fresh_kernel():
    """A function numba has never compiled: calling it compiles it for real (milliseconds, not a minute)."""
    @numba.njit(cache=False)
    def add_one(x):
        return x + 1

    return add_one


def test_compiling_is_announced_once_on_a_terminal(terminal):
    terminal = terminal()
    for k in progress.track(range(3), "work"):
        fresh_kernel()(k)  # a compilation inside the loop, as the IK kernels on the first run
    fresh_kernel()(1)
    assert terminal.getvalue().count(progress.COMPILING) == 1


def test_no_notice_without_compiling(terminal, monkeypatch):
    terminal = terminal()
    kernel = fresh_kernel()
    kernel(0)  # compiled (and announced) here
    monkeypatch.setattr(progress, "_said", set())
    for k in progress.track(range(3), "work"):
        kernel(k)  # already compiled: no compilation, no notice
    assert progress.COMPILING not in terminal.getvalue().split(progress.COMPILING, 1)[1]


def test_numbas_own_helpers_compiling_give_no_notice(terminal):
    """numba compiles small helpers of its own in a warm run (an array view, 0.1 s): not "compiling kernels"."""
    terminal = terminal()
    for module in ("numba.np.arrayobj", "mjkin.kinematics.fk"):
        helper = type("F", (), {"__module__": module})
        progress.compile_started(helper)  # as numba_private calls it
        assert terminal.getvalue().count(progress.COMPILING) == (module == "mjkin.kinematics.fk")
        progress.compile_ended(helper)
    assert progress._listener.stop is None  # no ticker left counting into the next test's stderr


def test_the_notice_prints_off_a_terminal_too_but_no_bar(terminal, monkeypatch):
    """In CI or ``| tee`` the first run sat silent for a minute: the notice is for every stderr, bars are not."""
    terminal = terminal()
    monkeypatch.setattr(terminal, "isatty", lambda: False)
    for k in progress.track(range(3), "work"):
        fresh_kernel()(k)
    assert terminal.getvalue() == f"mjkin: {progress.COMPILING}\n"  # once, one line, no bar


def test_a_cold_cache_says_it_compiles_and_a_warm_one_is_silent(tmp_path):
    """The command's stderr is a pipe here, as in CI: the line is there when numba compiles, and only then."""
    from mjkin.apps.bench.startup import fresh_copy

    root = fresh_copy(tmp_path)  # as after pip install: no kernel cache anywhere
    env = {k: v for k, v in os.environ.items() if k != "NUMBA_CACHE_DIR"}
    env.update(PYTHONPATH=str(root), XDG_CACHE_HOME=str(tmp_path / "xdg"))
    command = [sys.executable, "-m", "mjkin.apps.cli", "fk", "planar_2link", "--frame", "tip"]
    cold = subprocess.run(command, env=env, capture_output=True, text=True, cwd=root)
    assert cold.returncode == 0 and cold.stderr == f"mjkin: {progress.COMPILING}\n"
    warm = subprocess.run(command, env=env, capture_output=True, text=True, cwd=root)
    assert warm.returncode == 0 and warm.stderr == "" and warm.stdout == cold.stdout


def test_from_python_the_notice_goes_to_the_mjkin_logger_once_and_no_bar_is_drawn(terminal, caplog):
    """mjkin.retarget_many from a script compiled for 3 minutes in silence: now one warning says so."""
    terminal = terminal()
    progress.enable(False)
    with caplog.at_level("WARNING", logger="mjkin"):
        fresh_kernel()(1)
        fresh_kernel()(2)
    assert [r.getMessage() for r in caplog.records if r.name == "mjkin"] == [f"mjkin: {progress.COMPILING}"]
    assert terminal.getvalue() == ""
    assert list(progress.track(range(4), "quiet")) == [0, 1, 2, 3]
    assert terminal.getvalue() == ""


def test_a_compile_a_minute_after_the_notice_says_so_again(terminal, caplog, monkeypatch):
    """The retargeting guide's retarget_many block compiled for minutes in silence: its first block had said so once."""
    terminal = terminal()
    progress.enable(False)
    now = [1000.0]
    monkeypatch.setattr(progress.time, "monotonic", lambda: now[0])
    monkeypatch.setattr(progress._listener, "said", -float("inf"))
    with caplog.at_level("WARNING", logger="mjkin"):
        fresh_kernel()(1)
        now[0] += progress.QUIET / 2
        fresh_kernel()(2)  # the same stretch of compiling: no second line
        now[0] += progress.QUIET
        fresh_kernel()(3)
    assert [r.getMessage() for r in caplog.records if r.name == "mjkin"] == [f"mjkin: {progress.COMPILING}"] * 2


def test_a_cold_cache_says_it_compiles_from_a_plain_script_too(tmp_path):
    """A script's compile here (retarget_many's; MJKIN_COMPILE=wait) prints the line with no logging set up."""
    from mjkin.apps.bench.startup import fresh_copy

    root = fresh_copy(tmp_path)
    env = {k: v for k, v in os.environ.items() if k != "NUMBA_CACHE_DIR"}
    env.update(PYTHONPATH=str(root), XDG_CACHE_HOME=str(tmp_path / "xdg"), MJKIN_COMPILE="wait")
    script = "import mjkin; print(mjkin.load('planar_2link').pose([0.1, 0.2], 'tip')[0, 3])"
    cold = subprocess.run([sys.executable, "-c", script], env=env, capture_output=True, text=True, cwd=root)
    assert cold.returncode == 0 and cold.stderr.startswith(f"mjkin: {progress.COMPILING}\n"), cold.stderr


def test_from_python_a_long_compile_shows_its_seconds_on_a_terminal(terminal, monkeypatch):
    """The CLI showed a long compile's seconds on a terminal; a script in a terminal sat silent."""
    from types import SimpleNamespace

    terminal = terminal()
    progress.enable(False)
    monkeypatch.setattr(progress, "TICK", 0.0)
    solve = SimpleNamespace(__module__="mjkin.ik.loop", __name__="solve")
    progress.compile_started(solve)  # as numba_private calls it
    stop = progress._listener.stop
    progress.compile_ended(solve)
    assert stop is not None and stop.is_set()


def test_a_long_compile_shows_its_seconds_on_a_terminal(terminal, monkeypatch):
    """mjkin demo sat 81 s without a sign of life on a terminal while it compiled."""
    import time
    from types import SimpleNamespace

    terminal = terminal()
    monkeypatch.setattr(progress, "TICK", 0.2)
    solve = SimpleNamespace(__module__="mjkin.ik.loop", __name__="solve")
    progress.compile_started(solve)
    progress.compile_started(solve)  # nested: one line
    time.sleep(1.6)
    progress.compile_ended(solve)
    assert progress._listener.depth == 1 and progress._listener.stop is not None
    progress.compile_ended(solve)
    time.sleep(0.3)
    text = terminal.getvalue()
    assert "mjkin: compiling solve: 1 s" in text and progress._listener.stop is None
    shown = len(text)
    time.sleep(1.2)
    assert len(terminal.getvalue()) == shown  # stopped with the compile


def seconds(text: str) -> int:
    parts = [int(p) for p in text.split(":")]
    return sum(p * 60**k for k, p in enumerate(reversed(parts)))


def test_no_eta_until_the_first_item_is_done(terminal, monkeypatch):
    import tqdm.std

    terminal = terminal()
    clock = [1000.0]
    monkeypatch.setattr(tqdm.std, "time", lambda: clock[0])
    items = list(progress.track(range(6), "solve path"))
    assert items == list(range(6))
    clock[0] = 1000.0
    for k in progress.track(range(6), "solve path"):
        clock[0] += 70.0 if k == 0 else 1.0  # the first item compiles for 70 s, then 1 s each
    text = terminal.getvalue()
    assert "solve path: 0/6 [starting]" in text
    etas = [seconds(t) for t in re.findall(r"<(\d\d:\d\d(?::\d\d)?)", text)]
    assert etas and max(etas) <= 5  # measured after the first item: 1 s per item, at most 5 to go
