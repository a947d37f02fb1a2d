"""Headless Debian chromium driven by playwright: for tests and for the README screenshots.

Playwright's own browser download does not work offline; Debian's chromium does, with these flags
(``shared/notes/viewer_stack.md``). Requests that leave 127.0.0.1 are aborted, so a page can never
hang on the network and runs stay deterministic.
"""

from __future__ import annotations

import contextlib
import tempfile
from collections.abc import Iterator
from pathlib import Path

CHROMIUM = Path("/usr/bin/chromium")
CHROMIUM_ARGS = ["--headless=new", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
                 "--disable-background-networking", "--disable-component-update", "--disable-sync",
                 "--disable-dev-shm-usage", "--use-angle=swiftshader", "--enable-unsafe-swiftshader"]
LOCAL_PREFIXES = ("http://127.0.0.1", "ws://127.0.0.1", "data:", "blob:", "about:")


def _only_loopback(route) -> None:
    if route.request.url.startswith(LOCAL_PREFIXES):
        route.continue_()
    else:
        route.abort()


@contextlib.contextmanager
def chromium(width: int = 1000, height: int = 700, timeout_ms: int = 30_000) -> Iterator:
    """A persistent chromium context (yielded); closed, with its profile folder, on exit."""
    from playwright.sync_api import sync_playwright  # lazy: playwright

    with tempfile.TemporaryDirectory(prefix="deepc-chromium-") as profile, sync_playwright() as p:
        context = p.chromium.launch_persistent_context(
            profile, executable_path=str(CHROMIUM), headless=True, args=CHROMIUM_ARGS,
            viewport={"width": width, "height": height})
        context.set_default_timeout(timeout_ms)
        context.route("**/*", _only_loopback)
        try:
            yield context
        finally:
            context.close()


def dismiss_software_webgl_notice(page) -> None:
    """Close viser's "Software WebGL rendering detected" notification if it is shown."""
    notice = page.get_by_text("Software WebGL rendering detected")
    if notice.count():
        close = page.locator(".mantine-Notification-closeButton")
        if close.count():
            close.first.click()


def rerun_crashed(page) -> bool:
    """True when the rerun web viewer shows its crash screen (visible text, not the page source)."""
    return "Rerun has crashed" in page.locator("body").inner_text()
