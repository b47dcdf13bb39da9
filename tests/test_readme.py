"""The README's two commands are what CI and users run: keep them in step with .ci/run."""

from __future__ import annotations

from conftest import ROOT


def test_ci_runs_the_readme_test_command():
    readme = (ROOT / "README.md").read_text()
    ci = (ROOT / ".ci" / "run").read_text().splitlines()
    command = ci[ci.index("# README test command (tests/test_readme.py keeps the two identical):") + 1]
    assert command in readme
    head = readme.split("\n## ", 1)[0]  # the two commands open the README
    assert command in head and ".venv/bin/mjkin demo" in head
