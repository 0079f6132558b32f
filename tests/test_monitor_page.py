"""The tree monitor's page in a real browser (issue 51, item 2): headless Chromium, driven by
Playwright, opens the page of ``python -m ubf_async.launch --scenario ball-behind --monitor 0``
and sees the tree's nodes, the winner change from ``search`` to ``chase`` when the ball comes
into view, the sources and the state; it looks back along the strip to a tick ``search`` won;
it changes the arbiter from the page and the robot's status line says the tree changed.

Chromium is the system's (Debian's ``chromium`` package; ``.ci/run`` installs it): found on the
PATH or at ``UBF_CHROMIUM``. Without one the test is skipped with that reason — except where
``UBF_REQUIRE_BROWSER`` is set (CI), where a missing browser fails it."""

from __future__ import annotations

import os
import re
import shutil
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from tests.remote_robot import Process

CHROMIUM_ARGS = ["--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
                 "--disable-background-networking", "--disable-component-update",
                 "--disable-sync"]
"""Headless, as root, on a machine whose network is closed: no sandbox (root), and none of
Chromium's calls home (each would be refused)."""
SCREENSHOTS = os.environ.get("UBF_SCREENSHOTS")
"""A folder to save the page's pictures in (docs/images for docs/monitor.md), if set."""


def chromium() -> str:
    path = os.environ.get("UBF_CHROMIUM") or next(
        (found for name in ("chromium", "chromium-browser", "google-chrome")
         if (found := shutil.which(name))), None)
    if path is None:
        reason = ("no Chromium on this machine (apt-get install chromium, or set UBF_CHROMIUM "
                  "to a Chrome or Chromium binary)")
        if os.environ.get("UBF_REQUIRE_BROWSER"):
            pytest.fail(reason)
        pytest.skip(reason)
    return path


@pytest.fixture
def browser_page() -> Iterator[Any]:
    from playwright.sync_api import sync_playwright

    with sync_playwright() as playwright:
        browser = playwright.chromium.launch(executable_path=chromium(), args=CHROMIUM_ARGS)
        try:
            page = browser.new_page(viewport={"width": 1280, "height": 860})
            yield page
        finally:
            browser.close()


def snap(page: Any, tmp_path: Path, name: str) -> None:
    for folder in filter(None, (tmp_path, SCREENSHOTS and Path(SCREENSHOTS))):
        page.screenshot(path=str(Path(folder) / name))


@pytest.mark.slow
def test_the_page_shows_the_tree_live_and_changes_it(
        browser_page: Any, endpoint: str, robot: str, tmp_path: Path) -> None:
    from playwright.sync_api import expect

    page = browser_page
    launched = Process("-m", "ubf_async.launch", "--listen", endpoint, "--robot", robot,
                       "--scenario", "ball-behind", "--duration", "120", "--monitor", "0",
                       "--status-period-s", "0.25")
    try:
        line = launched.wait_for_line("the tree live in a browser on", timeout_s=40)
        url = re.search(r"(http://127\.0\.0\.1:\d+/)", line).group(1)  # type: ignore[union-attr]
        page.goto(url)
        expect(page.locator("#connection")).to_have_attribute("data-state", "open")
        expect(page.locator("#robot")).to_have_text(robot)
        # The tree as a tree: the composite and its three behaviours, each a node.
        for name in ("seek_pink_ball", "search", "chase", "flee"):
            expect(page.locator(f'[data-node="{name}"]')).to_have_count(1)
        expect(page.locator('[data-node="seek_pink_ball"] text.detail')).to_have_text(
            "<PriorityMerge>")
        # The ball starts behind the robot: search wins, until the ball comes into view.
        expect(page.locator('[data-node="search"]')).to_have_attribute(
            "data-winner", "true", timeout=30_000)
        searching_at = float(re.search(  # type: ignore[union-attr]
            r"t (\d+\.\d+) s", page.locator("#clock").inner_text()).group(1))
        snap(page, tmp_path, "monitor-search.png")
        expect(page.locator('[data-node="chase"]')).to_have_attribute(
            "data-winner", "true", timeout=60_000)
        expect(page.locator('[data-testid="drive"]')).to_contain_text("won by chase")
        snap(page, tmp_path, "monitor.png")
        # The sources with their ages, and the state snapshot.
        expect(page.locator('#sources tr[data-source="range/front"] td.age')).to_have_text(
            re.compile(r"^\d+ ms$"))
        expect(page.locator("#state summary", has_text="camera/front")).to_have_count(1)

        # Back along the strip, to the moment search was seen winning.
        index = page.evaluate("t => page.frames.findIndex(f => f.t >= t)", searching_at)
        assert index >= 0
        page.locator("#scrub").fill(str(index))
        expect(page.locator("#live")).to_be_enabled()
        expect(page.locator("#scrub-at")).to_have_text(re.compile(r"^at t \d+\.\d\d s$"))
        expect(page.locator('[data-node="search"]')).to_have_attribute("data-winner", "true")
        page.locator("#live").click()
        expect(page.locator("#scrub-at")).to_have_text("live")

        # A change from the page: the robot applies it and its status line says so.
        page.locator('[data-testid="composite"]').select_option("seek_pink_ball")
        page.locator('[data-testid="arbiter"]').fill("HighestPriority")
        page.locator('[data-testid="set-arbiter"]').click()
        expect(page.locator('[data-testid="reply"]')).to_have_text(
            "set_arbiter: done (changes applied: 1)")
        expect(page.locator('[data-node="seek_pink_ball"] text.detail')).to_have_text(
            "<HighestPriority>")
        launched.wait_for_match(r"\| tree changed 1 \|", timeout_s=15)
        # A refused change: the reason on the page, the tree as it was.
        page.locator('[data-testid="arbiter"]').fill("NoSuchArbiter")
        page.locator('[data-testid="set-arbiter"]').click()
        expect(page.locator('[data-testid="reply"]')).to_contain_text(
            "set_arbiter refused: ")
        expect(page.locator('[data-testid="reply"]')).to_contain_text("NoSuchArbiter")
        expect(page.locator('[data-node="seek_pink_ball"] text.detail')).to_have_text(
            "<HighestPriority>")
        snap(page, tmp_path, "monitor-changed.png")
        assert (tmp_path / "monitor.png").stat().st_size > 10_000
    finally:
        launched.kill()
