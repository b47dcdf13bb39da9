"""The README's two commands are what CI and users run: keep them in step with .ci/run (and the CLI reference's
defaults with the parser)."""

from __future__ import annotations

from conftest import ROOT


def test_ci_runs_the_readme_test_command():
    readme = (ROOT / "README.md").read_text()
    ci = (ROOT / ".ci" / "run").read_text().splitlines()
    command = ci[ci.index("# README test command (tests/project/test_readme.py keeps the two identical):") + 1]
    assert command in readme
    head = readme.split("\n## ", 1)[0]  # the two commands open the README
    assert command in head and ".venv/bin/mjkin demo" in head


def test_defaults_shown_in_the_command_line_reference_are_the_real_ones():
    """A number shown as ``[--opt N]`` in the command list of docs/cli.md is the default the parser really has."""
    import argparse
    import re

    from mjkin.apps.cli import build_parser

    reference = (ROOT / "docs" / "cli.md").read_text()
    block = reference.split("```sh", 1)[1].split("```", 1)[0]
    parser = build_parser()
    subs = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction)).choices
    checked = 0
    for line in block.splitlines():
        words = line.split()
        if len(words) < 2 or words[0] != "mjkin" or words[1] not in subs:
            continue
        options = {a.dest: a for a in subs[words[1]]._actions}
        for bracket in re.findall(r"\[([^\]]*)\]", line.split("#", 1)[0]):
            for flag, shown in re.findall(r"(--?[a-z][a-z-]*) ([0-9][0-9.]*)(?=[\s\]]|$)", bracket):
                action = next((a for a in options.values() if flag in a.option_strings), None)
                assert action is not None, f"docs/cli.md shows {flag} for mjkin {words[1]}, which has no such option"
                assert isinstance(action.default, (int, float)) and float(shown) == float(action.default), \
                    f"docs/cli.md: mjkin {words[1]} [{flag} {shown}], but the default is {action.default!r}"
                checked += 1
    assert checked >= 5  # the section really lists defaults (demo, walk)


def test_the_readme_says_what_sigterm_and_a_crash_do_to_a_take():
    """Issue 38 asks the front page, not only the guide, to say it."""
    play = next(line for line in (ROOT / "README.md").read_text().splitlines() if line.startswith("| `mjkin play"))
    assert "SIGTERM saves it and exits 0" in play and "a crash loses at most its last second" in play
