"""Regenerate the screenshots of `cirl-study serve`'s pages in docs/serve/.

Usage::

    python scripts/serve_screenshots.py [--out docs/serve]

Serves ``pipelines/people-browser.toml`` into a temporary run directory and walks one
participant through it in Debian's headless Chromium (``/usr/bin/chromium``, driven by
Playwright), taking a screenshot of each page: the consent, the instructions, the practice,
a task on its way and at its goal, the end, and the experimenter's status page.
"""

from __future__ import annotations

import argparse
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from playwright.sync_api import sync_playwright

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))
from serve_fixtures import CHROMIUM, CHROMIUM_FLAGS  # noqa: E402  (the browser test's)

PIPELINE = ROOT / "pipelines" / "people-browser.toml"
KEYS = {(0, 1): "ArrowUp", (0, -1): "ArrowDown", (1, 0): "ArrowRight", (-1, 0): "ArrowLeft"}
ROUND_THE_TOP = [(0, 2), (0, 3), (0, 4), (1, 4), (2, 4), (3, 4), (4, 4), (5, 4), (5, 3), (5, 2)]
STRAIGHT = [(0, 2), (1, 2), (2, 2), (3, 2), (4, 2), (5, 2)]


def press(page, path: list[tuple[int, int]]) -> None:
    for (x0, y0), (x1, y1) in zip(path, path[1:], strict=False):
        page.keyboard.press(KEYS[(x1 - x0, y1 - y0)])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--out", type=Path, default=ROOT / "docs" / "serve")
    out = parser.parse_args().out
    out.mkdir(parents=True, exist_ok=True)
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    with tempfile.TemporaryDirectory() as directory:
        server = subprocess.Popen(
            [sys.executable, "-m", "cirl_study", "serve", str(PIPELINE), "--out",
             f"{directory}/run", "--port", str(port)],
            stdout=subprocess.PIPE, text=True,
        )  # fmt: skip
        assert server.stdout is not None
        status = next(line for line in server.stdout if line.startswith("experimenter: "))
        status = status.split(": ", 1)[1].strip()
        time.sleep(0.5)
        try:
            with sync_playwright() as playwright:
                browser = playwright.chromium.launch(
                    executable_path=str(CHROMIUM), args=CHROMIUM_FLAGS
                )
                page = browser.new_page(viewport={"width": 960, "height": 640})

                def shot(name: str) -> None:
                    page.screenshot(path=str(out / f"{name}.png"))
                    print(out / f"{name}.png")

                page.goto(f"http://127.0.0.1:{port}/?PROLIFIC_PID=5f00example")
                page.get_by_role("heading", name="Consent").wait_for()
                shot("1-consent")
                page.get_by_role("button", name="I agree").click()
                page.get_by_role("heading", name="Instructions").wait_for()
                shot("2-instructions")
                page.get_by_role("button", name="Continue").click()
                page.get_by_role("heading", name="Practice (not recorded)").wait_for()
                press(page, ROUND_THE_TOP[:4])
                shot("3-practice")
                press(page, ROUND_THE_TOP[3:])
                page.get_by_role("button", name="Submit").click()
                page.get_by_role("heading", name="Task 1 of 8").wait_for()
                press(page, STRAIGHT[:3])
                shot("4-task")
                press(page, STRAIGHT[2:])
                shot("5-task-at-goal")
                page.get_by_role("button", name="Submit").click()
                for number in range(2, 9):
                    page.get_by_role("heading", name=f"Task {number} of 8").wait_for()
                    press(page, ROUND_THE_TOP)
                    page.get_by_role("button", name="Submit").click()
                page.get_by_role("heading", name="Thank you!").wait_for()
                shot("6-done")
                page.goto(status)
                shot("7-status")
                browser.close()
        finally:
            server.terminate()
            server.wait(30)


if __name__ == "__main__":
    main()
