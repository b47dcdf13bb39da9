"""Headless Chromium on the playground page (playwright): the browser test's driver and the README still.

``python tests/apps/browser.py OUT.png [MODEL]`` serves MODEL (default arm7) on a
free loopback port, opens the page in headless Chromium, drags the target and
saves a screenshot of the page. Needs Debian's ``chromium`` (or ``$MJKIN_CHROMIUM``)
and ``pip install 'mjkin[browser]'``; playwright's own browser download is never used.
"""

from __future__ import annotations

import os
import shutil
import sys
import time
from pathlib import Path
from typing import Any

from mjkin.errors import MjkinError
from mjkin.kinematics.tree import load
from mjkin.runtime.files import atomic_path

FLAGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
         "--disable-background-networking", "--disable-component-update", "--disable-sync"]


def chromium_path() -> str | None:
    """The Chromium to drive: ``$MJKIN_CHROMIUM``, else ``chromium`` on the PATH."""
    path = os.environ.get("MJKIN_CHROMIUM") or shutil.which("chromium") or shutil.which("chromium-browser")
    return path if path and Path(path).is_file() else None


def missing() -> str | None:
    """Why the browser cannot run here (None when it can)."""
    if chromium_path() is None:
        return "no chromium (apt-get install chromium, or set MJKIN_CHROMIUM)"
    try:
        import playwright.sync_api  # noqa: F401
    except ImportError:
        return "no playwright (pip install 'mjkin[browser]')"
    return None


def launch(playwright: Any) -> Any:
    """A headless Chromium browser with the flags this machine needs."""
    return playwright.chromium.launch(executable_path=chromium_path(), args=FLAGS, headless=True)


def open_page(browser: Any, url: str) -> Any:
    """The playground page, loaded: the panel built, the first state read and the first frame shown."""
    page = browser.new_page(viewport={"width": 1040, "height": 700})
    page.goto(url, wait_until="domcontentloaded")
    # ``state``: the page's first /state answer, before which it ignores the mouse (a busy machine answers late)
    page.wait_for_function("document.querySelectorAll('#method option').length > 0 && state !== null && "
                           "document.getElementById('view').naturalWidth > 0", timeout=30_000)
    return page


def mouse_drag(page: Any, x: float, y: float, dx: float, dy: float, button: str = "left", steps: int = 8) -> None:
    """Press ``button`` at page pixel ``(x, y)`` and drag by ``(dx, dy)`` pixels in ``steps`` moves."""
    page.mouse.move(x, y)
    page.mouse.down(button=button)
    for k in range(1, steps + 1):
        page.mouse.move(x + dx * k / steps, y + dy * k / steps)
        time.sleep(0.05)
    page.mouse.up(button=button)


# the state as the page's script fetches it (with the page's token)
STATE = "fetch('/state', {headers: headers()}).then(r => r.json())"


def drag_target(page: Any, frame: str, dx: float, dy: float, steps: int = 8) -> None:
    """Press on ``frame``'s marker in the view and drag it by ``(dx, dy)`` pixels."""
    state = page.evaluate(STATE)
    box = page.locator("#view").bounding_box()
    u, v = state["screen"][frame]
    mouse_drag(page, box["x"] + u * box["width"], box["y"] + v * box["height"], dx, dy, steps=steps)


def turn_view(page: Any, dx: float, dy: float, steps: int = 8) -> None:
    """Right-drag from the middle of the view by ``(dx, dy)`` pixels: the camera orbits."""
    box = page.locator("#view").bounding_box()
    mouse_drag(page, box["x"] + box["width"] / 2, box["y"] + box["height"] / 2, dx, dy, "right", steps)


def screenshot(path: str | Path, model: str = "arm7") -> Path:
    """Serve ``model``, drag its first target in headless Chromium, save the page as PNG."""
    from playwright.sync_api import sync_playwright

    from mjkin.apps.play.server import start_server, stop_server
    from mjkin.apps.play.session import Playground

    reason = missing()
    if reason:
        raise MjkinError(f"cannot take a screenshot: {reason}")
    server, thread = start_server(Playground(load(model)).start())
    try:
        with sync_playwright() as p:
            browser = launch(p)
            page = open_page(browser, server.url)
            frame = next(iter(page.evaluate(STATE)["targets"]))
            drag_target(page, frame, 70, 50)
            page.wait_for_timeout(800)  # the stream shows the last frame, the panel its poll
            with atomic_path(path) as tmp:
                page.screenshot(path=str(tmp))
            browser.close()
    finally:
        stop_server(server, thread)
    return Path(path)


def main(argv: list[str] | None = None) -> int:
    """``python tests/apps/browser.py OUT.png [MODEL]``."""
    args = sys.argv[1:] if argv is None else argv
    if not 1 <= len(args) <= 2:
        print("usage: python tests/apps/browser.py OUT.png [MODEL]", file=sys.stderr)
        return 2
    try:
        print(f"wrote {screenshot(args[0], *args[1:])}")
    except MjkinError as e:
        print(f"mjkin: error: {e}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
