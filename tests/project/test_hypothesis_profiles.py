"""Hypothesis runs deterministically in CI and explores locally (profiles in conftest.py)."""

from __future__ import annotations

import os
import subprocess
import sys

from hypothesis import settings

from conftest import ROOT

TESTS = ROOT / "tests"


def test_ci_profile_is_deterministic_and_keeps_no_database():
    ci = settings.get_profile("ci")
    assert ci.derandomize and ci.database is None and ci.deadline is None
    dev = settings.get_profile("dev")
    assert not dev.derandomize and dev.deadline is None


def test_profile_follows_the_ci_variable():
    code = "import conftest, hypothesis; print(hypothesis.settings.default.derandomize)"
    for ci, expect in (("1", "True"), ("", "False")):
        env = {k: v for k, v in os.environ.items() if k != "CI"} | ({"CI": ci} if ci else {})
        out = subprocess.run([sys.executable, "-c", code], cwd=TESTS, env=env, capture_output=True, text=True)
        assert out.stdout.strip() == expect, out.stderr
