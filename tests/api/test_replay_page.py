"""`drona replay` in headless Chromium (Debian's ``chromium``, driven by Playwright): a run scrubbed to its violation.

The record is made here: on a small geo-referenced workspace, drones a and b meet in one cell at
step 6, and a flies off its plan at step 3. Screenshots go to the folder the test prints
(``replay-screenshots`` in the test's tmp_path), for a person to look at.
"""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import threading
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from drona_gcs.audit import record_line
from tests.api.conftest import REPO

WORKSPACE = {
    "name": "yard", "size": [8, 6, 1], "cell_size_m": 4.0,
    "geo_origin": {"lat": 47.397742, "lon": 8.545594, "alt_m": 488.0},
    "obstacles": [{"box": [[3, 3, 0], [4, 4, 0]]}], "charging_stations": [[0, 5, 0]],
    "drones": {"a": [0, 0, 0], "b": [6, 0, 0]},
}
A = [(0, 0, 0), (1, 0, 0), (2, 0, 0), (2, 0, 0), (3, 0, 0), (3, 1, 0), (3, 1, 0), (3, 2, 0)]
A_PLAN = [(0, 0, 0), (1, 0, 0), (2, 0, 0), (3, 0, 0), (3, 0, 0), (3, 1, 0), (3, 1, 0), (3, 2, 0)]
B = [(6, 0, 0), (6, 1, 0), (5, 1, 0), (4, 1, 0), (4, 1, 0), (4, 1, 0), (3, 1, 0), (2, 1, 0)]
MEET = 6  #: a waits in [3, 1, 0] and b flies into it


@pytest.fixture
def replay(tmp_path: Path) -> Iterator[str]:
    """``drona replay`` on the record above, as a process; its URL once it listens."""
    (tmp_path / "yard.json").write_text(json.dumps(WORKSPACE))
    lines = [record_line(k, "a", c, p, 0) for k, (c, p) in enumerate(zip(A, A_PLAN, strict=True))]
    lines += [record_line(k, "b", c, None, 0) for k, c in enumerate(B)]
    (tmp_path / "run.jsonl").write_text("".join(lines))
    proc = subprocess.Popen([sys.executable, "-m", "fleet.cli", "replay", str(tmp_path / "run.jsonl"),
                             "--workspace", str(tmp_path / "yard.json"), "--port", "0"],
                            cwd=REPO, stdout=subprocess.PIPE, text=True)
    url = _listening(proc)
    try:
        yield url
    finally:
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(10) == 0
        assert proc.stdout is not None
        proc.stdout.close()


def _listening(proc: subprocess.Popen[str]) -> str:
    found: list[str] = []

    def read() -> None:
        assert proc.stdout is not None
        for line in proc.stdout:
            if "listening on " in line:
                found.append(line.split("listening on ", 1)[1].split()[0])
                return

    reader = threading.Thread(target=read, daemon=True)
    reader.start()
    reader.join(30)
    if not found:
        proc.kill()
        pytest.fail("drona replay did not announce its address in 30 s")
    return found[0]


def test_a_replay_scrubbed_to_its_violation_marks_it_on_the_map(browser: Any, replay: str, tmp_path: Path) -> None:
    shots = tmp_path / "replay-screenshots"
    shots.mkdir()
    print(f"screenshots of the replay page: {shots}")
    page = browser.new_page(viewport={"width": 1280, "height": 860})
    errors: list[str] = []
    page.on("pageerror", lambda exc: errors.append(str(exc)))
    outside: list[str] = []
    page.on("request", lambda req: None if req.url.startswith(replay) else outside.append(req.url))
    page.goto(replay)
    page.wait_for_selector("body[data-ready='true']", timeout=10_000)
    assert page.locator("#step").input_value() == "0"
    assert page.locator("#map path.drone").count() == 2
    assert page.locator("#map path.violation").count() == 0  # nothing found at step 0
    assert page.locator("#map path.obstacle").count() == 4  # the 2 x 2 building
    page.screenshot(path=str(shots / "1-start.png"))

    # the list names the collision; clicking it scrubs the slider to its step
    collision = page.locator("#findings button.finding.separation.collision").first
    assert f"step {MEET}" in collision.inner_text()
    collision.click()
    assert page.locator("#step").input_value() == str(MEET)
    assert page.locator("#step-label").inner_text().startswith(f"step {MEET} ")
    marked = page.locator("#map path.violation.separation.collision")
    assert marked.count() >= 1 and marked.first.get_attribute("data-cell") == "[3,1,0]"
    assert page.locator(f"#findings li.current[data-step='{MEET}']").count() >= 1
    # both drones sit in the marked cell: their markers overlap its centre
    box, drones = marked.first.bounding_box(), page.locator("#map path.drone")
    for i in range(2):
        d = drones.nth(i).bounding_box()
        cx, cy = d["x"] + d["width"] / 2, d["y"] + d["height"] / 2
        assert box["x"] <= cx <= box["x"] + box["width"] and box["y"] <= cy <= box["y"] + box["height"]
    page.screenshot(path=str(shots / "2-violation.png"))

    # the step off the plan is listed as a conformance finding and marked at its step
    page.locator("#findings button.finding.conformance").first.click()
    assert page.locator("#step").input_value() == "3"
    assert page.locator("#map path.violation.conformance").count() == 2  # flown and planned cells
    # stepping on leaves it; the arrow buttons move one step
    page.click("#next")
    assert page.locator("#step").input_value() == "4"
    assert page.locator("#map path.violation").count() == 0
    page.screenshot(path=str(shots / "3-stepped.png"))

    # play runs to the end and stops
    page.select_option("#speed", "20")
    page.click("#play")
    page.wait_for_function("document.querySelector('#step').value === '7'", timeout=10_000)
    page.wait_for_selector("#play[aria-pressed='false']", timeout=5_000)
    page.set_viewport_size({"width": 390, "height": 844})
    page.screenshot(path=str(shots / "4-phone.png"), full_page=True)
    assert page.evaluate("document.documentElement.scrollWidth") <= 390
    assert not errors, errors
    assert not outside, f"fetched from outside the replay server: {outside}"
    assert sorted(p.name for p in shots.iterdir()) == ["1-start.png", "2-violation.png", "3-stepped.png",
                                                       "4-phone.png"]
