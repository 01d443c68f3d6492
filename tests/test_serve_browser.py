"""``cirl-study serve`` as people use it: a real headless Chromium (Debian's, driven by
Playwright) goes through the consent, the instructions, the practice and every task, by arrow
keys, by clicks and by taps, reloads on the way; then the collected store holds exactly those
demonstrations, with the time of every move, and ``run`` and ``analyze`` play and analyse
them as they do the same demonstrations brought in a file.

Skipped only where Debian's Chromium is not installed (``.ci/run`` installs it)."""

from __future__ import annotations

import time
from pathlib import Path

import pytest
from serve_fixtures import (
    CHROMIUM,
    CHROMIUM_FLAGS,
    COLLECTING,
    MOVES,
    ROUND_THE_BOTTOM,
    ROUND_THE_TOP,
    STRAIGHT,
    free_port,
    start_server,
    through_api,
    write_pipeline,
)
from test_logs_helpers import run_records

import cirl_study
from cirl_study.logs.collection import collected, collected_text
from cirl_study.study.pipeline_file import load_pipeline

PAUSE = 0.12
"""Seconds between two moves in the browser."""

pytestmark = pytest.mark.skipif(
    not CHROMIUM.exists(), reason="Debian's chromium is not installed (apt-get install chromium)"
)


def keyboard(page, path: list[list[int]]) -> None:
    for (x0, y0), (x1, y1) in zip(path, path[1:], strict=False):
        time.sleep(PAUSE)
        page.keyboard.press(MOVES[(x1 - x0, y1 - y0)])


def clicks(page, path: list[list[int]], tap: bool = False) -> None:
    for x, y in path[1:]:
        time.sleep(PAUSE)
        cell = page.locator(f'.cell[data-x="{x}"][data-y="{y}"]')
        cell.tap() if tap else cell.click()


def test_a_participant_in_chromium_is_stored_exactly(tmp_path: Path) -> None:
    sync_api = pytest.importorskip("playwright.sync_api")
    pipeline_file = write_pipeline(tmp_path)
    run = tmp_path / "run"
    port = free_port()
    server, _ = start_server(pipeline_file, run, port)
    try:
        with sync_api.sync_playwright() as playwright:
            browser = playwright.chromium.launch(executable_path=str(CHROMIUM), args=CHROMIUM_FLAGS)
            context = browser.new_context(has_touch=True, viewport={"width": 1000, "height": 800})
            page = context.new_page()
            errors: list[str] = []
            page.on("pageerror", lambda error: errors.append(str(error)))
            page.on("console", lambda m: errors.append(m.text) if m.type == "error" else None)
            page.goto(f"http://127.0.0.1:{port}/?PROLIFIC_PID=B01&STUDY_ID=s")

            page.get_by_role("heading", name="Consent").wait_for()
            assert "Your moves are recorded." in page.inner_text("main")
            page.get_by_role("button", name="I agree").click()
            page.get_by_role("heading", name="Instructions").wait_for()
            page.get_by_role("button", name="Continue").click()

            page.get_by_role("heading", name="Practice (not recorded)").wait_for()
            assert page.locator(".cell").count() == 30
            assert page.inner_text("#left") == "13"
            keyboard(page, ROUND_THE_BOTTOM[:3])
            assert page.inner_text("#moves") == "2" and page.inner_text("#left") == "11"
            assert page.locator("#submit").is_disabled()
            page.get_by_role("button", name="Restart this task").click()
            assert page.inner_text("#moves") == "0"
            clicks(page, [[0, 2], [2, 2]])  # not a neighbour: refused on the page
            assert page.inner_text("#moves") == "0" and "neighbouring" in page.inner_text(
                "#message"
            )
            keyboard(page, ROUND_THE_BOTTOM)
            assert page.inner_text("#moves") == "9"
            page.keyboard.press("ArrowRight")  # in the goal: no more moves
            assert page.inner_text("#moves") == "9"
            page.get_by_role("button", name="Submit").click()

            shown = {}
            page.get_by_role("heading", name="Task 1 of 3").wait_for()
            name = page.evaluate("document.querySelector('h2').textContent")
            assert name == "Task 1 of 3"
            keyboard(page, STRAIGHT)
            page.get_by_role("button", name="Submit").click()
            page.get_by_role("heading", name="Task 2 of 3").wait_for()
            shown[1] = STRAIGHT

            page.reload()  # the page keeps its token: she resumes at her second task
            page.get_by_role("heading", name="Task 2 of 3").wait_for()
            clicks(page, ROUND_THE_TOP)
            page.get_by_role("button", name="Submit").click()
            page.get_by_role("heading", name="Task 3 of 3").wait_for()
            shown[2] = ROUND_THE_TOP

            clicks(page, ROUND_THE_BOTTOM, tap=True)
            page.get_by_role("button", name="Submit").click()
            page.get_by_role("heading", name="Thank you!").wait_for()
            shown[3] = ROUND_THE_BOTTOM
            assert page.inner_text("#completion") == "DONE-7"
            assert errors == []
            browser.close()
        # Three more participants, by the API, so that each condition has two.
        for participant in ("A02", "A03", "A04"):
            through_api(port, participant, STRAIGHT)
    finally:
        server.terminate()
        server.wait(30)

    stored = collected(run, load_pipeline(pipeline_file).run_id)
    mine = [shown for shown in stored if shown.recorded.participant == "B01"]
    assert len(stored) == 12 and len(mine) == 3
    for demonstration in mine:
        recorded = demonstration.recorded
        assert recorded.participant == "B01"
        assert [list(cell) for cell in recorded.path] == shown[recorded.order]
        times = recorded.seconds
        assert times is not None and times[0] == 0 and len(times) == len(recorded.path)
        gaps = [b - a for a, b in zip(times, times[1:], strict=False)]
        assert all(gap >= PAUSE * 0.8 for gap in gaps[1:]), gaps
        assert times[-1] < 60

    # The run plays the robots on them, and analyses them as it would a file of them.
    cirl_study.run(pipeline_file, run, workers=1)
    results = cirl_study.analyze(run)
    assert results.participants.design.participants == {"do": 2, "show": 2}
    played = {
        (r.recorded.participant, r.recorded.order): r.recorded
        for r in run_records(run)
        if r.recorded is not None
    }
    assert len(played) == 12
    for demonstration in mine:
        recorded = demonstration.recorded
        assert played["B01", recorded.order] == recorded

    # The same demonstrations in a file, as a lab brings them, analyse alike.
    (tmp_path / "moves.csv").write_text(collected_text(stored))
    experiment = COLLECTING.index("[experiment]")
    from_file = COLLECTING[:experiment] + COLLECTING[COLLECTING.index("[eta_cv]") :]
    filed = tmp_path / "filed.toml"
    filed.write_text(from_file.replace("collect = true", 'file = "moves.csv"'))
    cirl_study.run(filed, tmp_path / "filed", workers=1)
    assert cirl_study.analyze(tmp_path / "filed").participants == results.participants
