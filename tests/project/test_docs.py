"""Every ```python block of README.md and docs/**/*.md runs, and the docs' links lead somewhere.

A page's blocks run in order in one namespace (a later block may use what an earlier one made), in a temporary
working folder, with ``MUJOCO_GL=egl`` and ``MJKIN_COMPILE=wait`` as conftest sets them. A block whose first line is
``# docs: skip <reason>`` is not run (it renders a long video, or needs what the machine lacks); one whose first
line is ``# docs: needs MODULE`` runs only where MODULE imports. A failing block's traceback gives the page's own
line numbers.
"""

from __future__ import annotations

import importlib.util
import re
import sys
from pathlib import Path

import pytest

from conftest import ROOT

FENCE = re.compile(r"^```python[^\n]*\n(.*?)^```[ \t]*$", re.M | re.S)
SKIP, NEEDS = "# docs: skip", "# docs: needs "
LINK = re.compile(r"!?\[[^\]]*\]\(([^)\s]+)\)")


def pages() -> list[Path]:
    return [ROOT / "README.md", *sorted((ROOT / "docs").rglob("*.md"))]


def blocks(page: Path) -> list[tuple[int, str]]:
    """``(line, code)`` of each python block, ``line`` the page's line of the block's first code line."""
    text = page.read_text()
    return [(text.count("\n", 0, m.start(1)) + 1, m.group(1)) for m in FENCE.finditer(text)]


def name(page: Path) -> str:
    return str(page.relative_to(ROOT))


RUNNABLE = [p for p in pages() if blocks(p)]


@pytest.mark.parametrize("page", RUNNABLE, ids=name)
def test_the_python_blocks_of_a_page_run(page: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.chdir(tmp_path)
    namespace: dict = {"__name__": "__docs__"}
    ran = 0
    try:
        for line, code in blocks(page):
            first = code.split("\n", 1)[0].strip()
            if first.startswith(SKIP):
                continue
            if first.startswith(NEEDS) and importlib.util.find_spec(first[len(NEEDS):].split()[0]) is None:
                continue
            exec(compile("\n" * (line - 1) + code, str(page), "exec"), namespace)  # noqa: S102 (the docs' code)
            ran += 1
    finally:
        ray = sys.modules.get("ray")
        if ray is not None and ray.is_initialized():  # a page that started a local Ray cluster (the Ray guide)
            ray.shutdown()
    assert ran or all(c.lstrip().startswith((SKIP, NEEDS)) for _, c in blocks(page))


def test_most_blocks_run_and_each_skip_says_why() -> None:
    every = [(p, line, c.split("\n", 1)[0].strip()) for p in pages() for line, c in blocks(p)]
    skipped = [(p, line, first) for p, line, first in every if first.startswith(SKIP)]
    for p, line, first in skipped:
        assert len(first) > len(SKIP) + 10, f"{name(p)}:{line}: '# docs: skip' without a reason"
    assert len(every) >= 20 and len(skipped) <= len(every) // 5, f"{len(skipped)} of {len(every)} blocks skipped"


def anchors(page: Path) -> set[str]:
    """The headings' anchors, as Python-Markdown's toc (and, for these headings, GitHub) makes them."""
    text = FENCE.sub("", page.read_text())
    heads = re.findall(r"^#+ (.+)$", re.sub(r"^```.*?^```", "", text, flags=re.M | re.S), re.M)
    return {re.sub(r"[-\s]+", "-", re.sub(r"[^\w\s-]", "", h).strip().lower()) for h in heads}


def test_the_readme_is_short_and_its_links_lead_somewhere() -> None:
    """The README stays a five-minute read; every relative link of it and of the site leads to a file and heading."""
    assert len((ROOT / "README.md").read_text().splitlines()) <= 200
    for p in pages():
        for target in LINK.findall(p.read_text()):
            if re.match(r"[a-z]+:", target):
                continue  # a web address
            file, _, anchor = target.partition("#")
            path = (p.parent / file).resolve() if file else p
            assert path.exists(), f"{name(p)} links to {target}, which does not exist"
            if anchor and path.suffix == ".md":
                assert anchor in anchors(path), f"{name(p)} links to {target}: no such heading"


def test_every_docs_page_is_in_the_site_navigation() -> None:
    nav = (ROOT / "mkdocs.yml").read_text()
    for p in (ROOT / "docs").rglob("*.md"):
        assert str(p.relative_to(ROOT / "docs")) in nav, f"{name(p)} is not in mkdocs.yml's nav"
